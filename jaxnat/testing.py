"""`check_env`: the contract every jaxnat env keeps, as one reusable check; `check_determinism`:
same key, same trajectory, bit for bit (on the GPU too); `check_training_determinism`: same key,
same trained parameters; `check_noise_law`: draws of a noise control follow a pixel-noise law.

Each env's tests call it; it also runs over every registered env whose data is present.
It raises `AssertionError` with a message naming the broken contract.
"""

from __future__ import annotations

import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnat import spaces
from jaxnat.core import Environment

__all__ = ["check_env", "check_determinism", "check_training_determinism", "DeterminismReport",
           "enable_deterministic_ops", "DETERMINISTIC_OPS_FLAG", "check_noise_law"]

# XLA's switch for GPU kernels whose float sums run in a fixed order (scatter-adds, reductions).
DETERMINISTIC_OPS_FLAG = "--xla_gpu_deterministic_ops=true"


def check_env(env: Environment, params=None, *, num_steps: int = 30, num_envs: int = 4, seed: int = 0):
    """Check that `env` keeps the jaxnat contract.

    - `reset`/`step` observations lie in `observation_space(params)`; sampled actions lie in
      `action_space(params)`;
    - rewards are finite float32 scalars, `terminated`/`truncated` bool scalars, never both;
      float observations are finite;
    - `jit(step)` traces once for many steps, and `info` keeps one tree structure;
    - `vmap` over keys, states and actions works and gives per-env outputs;
    - different keys give different resets; the same key gives the same trajectory.
    """
    if params is None:
        params = env.default_params
    obs_space = env.observation_space(params)
    act_space = env.action_space(params)
    key = jax.random.key(seed)

    traces = {"reset": 0, "step": 0}

    def reset(k, p):
        traces["reset"] += 1
        return env.reset(k, p)

    def step(k, s, a, p):
        traces["step"] += 1
        return env.step(k, s, a, p)

    reset_jit, step_jit = jax.jit(reset), jax.jit(step)

    def rollout(key):
        key, k_reset = jax.random.split(key)
        obs, state = reset_jit(k_reset, params)
        _assert_in_space(obs_space, obs, "reset observation")
        trajectory = [obs]
        info_structure = None
        for t in range(num_steps):
            key, k_act, k_step = jax.random.split(key, 3)
            action = act_space.sample(k_act)
            assert bool(act_space.contains(action)), f"sampled action {action} not in {act_space}"
            obs, state, reward, terminated, truncated, info = step_jit(k_step, state, action, params)
            _assert_in_space(obs_space, obs, f"step {t} observation")
            _assert_scalar(reward, jnp.floating, "reward")
            assert np.isfinite(np.asarray(reward)), f"reward {reward} at step {t} is not finite"
            _assert_scalar(terminated, jnp.bool_, "terminated")
            _assert_scalar(truncated, jnp.bool_, "truncated")
            assert not (bool(terminated) and bool(truncated)), (
                f"step {t}: terminated and truncated both set; a time limit is never termination"
            )
            structure = jax.tree_util.tree_structure(info)
            if info_structure is None:
                info_structure = structure
            assert structure == info_structure, f"info changed structure at step {t}"
            trajectory.append(obs)
        return trajectory

    first = rollout(key)
    assert traces == {"reset": 1, "step": 1}, (
        f"jit traced reset/step {traces['reset']}/{traces['step']} times over {num_steps} steps; "
        "something in the state or outputs changes shape or dtype between steps"
    )
    second = rollout(key)
    for t, (a, b) in enumerate(zip(first, second)):
        assert _tree_equal(a, b), f"same key, different observation at step {t}: not deterministic"

    resets = [reset_jit(k, params)[0] for k in jax.random.split(jax.random.key(seed + 1), 8)]
    assert not all(_tree_equal(resets[0], r) for r in resets[1:]), (
        "eight different reset keys gave the same first observation: reset ignores its key"
    )

    keys = jax.random.split(jax.random.key(seed + 2), num_envs)
    obs, state = jax.vmap(env.reset, in_axes=(0, None))(keys, params)
    actions = jax.vmap(act_space.sample)(keys)
    obs, state, reward, terminated, truncated, _ = jax.vmap(env.step, in_axes=(0, 0, 0, None))(
        keys, state, actions, params
    )
    for leaf, space_shape in zip(jax.tree_util.tree_leaves(obs), _leaf_shapes(obs_space)):
        assert leaf.shape == (num_envs, *space_shape), f"vmapped obs has shape {leaf.shape}"
    for name, x in [("reward", reward), ("terminated", terminated), ("truncated", truncated)]:
        assert x.shape == (num_envs,), f"vmapped {name} has shape {x.shape}"


def _assert_in_space(space: spaces.Space, x, what: str) -> None:
    for leaf, (shape, dtype) in zip(jax.tree_util.tree_leaves(x), _leaf_specs(space)):
        assert leaf.shape == shape and leaf.dtype == dtype, (
            f"{what} is {leaf.dtype}{list(leaf.shape)}, the space says {dtype}{list(shape)}"
        )
        if jnp.issubdtype(leaf.dtype, jnp.floating):
            assert bool(jnp.all(jnp.isfinite(leaf))), f"{what} has non-finite values"
    assert bool(space.contains(x)), f"{what} is not contained in {space}"


def _assert_scalar(x, kind, what: str) -> None:
    assert jnp.shape(x) == (), f"{what} must be a scalar, got shape {jnp.shape(x)}"
    assert jnp.issubdtype(jnp.result_type(x), kind), f"{what} has dtype {jnp.result_type(x)}"


def _leaf_specs(space: spaces.Space):
    if isinstance(space, spaces.Dict):
        # Dicts flatten in sorted-key order, as jax.tree_util does.
        return [spec for k in sorted(space.spaces) for spec in _leaf_specs(space.spaces[k])]
    return [(tuple(space.shape), jnp.dtype(space.dtype))]


def _leaf_shapes(space: spaces.Space):
    return [shape for shape, _ in _leaf_specs(space)]


def _tree_equal(a, b) -> bool:
    return all(
        np.array_equal(np.asarray(x), np.asarray(y))
        for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b))
    )


def has_dataset(name: str, split: str = "test") -> bool:
    """Whether a dataset split is installed (for skipping tests that need real data)."""
    from jaxnat.datasets import DatasetNotFoundError, load

    try:
        load(name, split)
    except DatasetNotFoundError:
        return False
    return True


class DeterminismReport(NamedTuple):
    """`check_determinism`'s answer: `identical`, and where the first difference is."""

    env_id: str
    num_envs: int
    steps: int
    identical: bool
    first_difference: dict | None  # {"run": "repeat" | "recompiled", "step", "field", "env"}
    seconds: float  # median wall time of one compiled rollout (the repeats), compile excluded
    what: str = "rollout"  # or the training run checked, e.g. "ppo, 2 updates"

    @property
    def steps_per_second(self) -> float:
        return self.num_envs * self.steps / self.seconds

    def __str__(self) -> str:
        if self.identical:
            return (f"{self.env_id}: {self.what} of {self.num_envs} envs x {self.steps} steps identical bit for bit "
                    "(repeat and recompiled)")
        d = self.first_difference
        where = f" at step {d['step']}" if d.get("step") is not None else ""
        env = f" (env {d['env']})" if d.get("env") is not None else ""
        return f"{self.env_id}: the {d['run']} run differs first{where} in {d['field']}{env}"


def check_determinism(env_id: str, num_envs: int = 256, steps: int = 16, *, seed: int = 0, repeats: int = 2,
                      **env_kwargs) -> DeterminismReport:
    """Roll `num_envs` envs of `env_id` out for `steps` steps with random actions, three times
    under the same key: twice with one compiled program, once more after compiling it again.
    Every output of every step (observation, reward, flags, the state and `info`) must be the
    same bit for bit; the report names the first step, field and env that differ.

    Same key, same trajectory is jaxnat's promise on any backend (same device kind, same
    versions); on a GPU, XLA's scatter-adds may reorder float sums unless
    `--xla_gpu_deterministic_ops=true` is in `XLA_FLAGS`.
    """
    from jaxnat.registration import make

    env, params = make(env_id, **env_kwargs)
    space = env.action_space(params)

    def rollout(key):
        key_reset, key_steps = jax.random.split(key)
        obs, state = jax.vmap(env.reset, in_axes=(0, None))(jax.random.split(key_reset, num_envs), params)

        def body(carry, key):
            state = carry
            key_act, key_env = jax.random.split(key)
            action = jax.vmap(space.sample)(jax.random.split(key_act, num_envs))
            out = jax.vmap(env.step, in_axes=(0, 0, 0, None))(jax.random.split(key_env, num_envs), state, action,
                                                             params)
            return out[1], {"obs": out[0], "reward": out[2], "terminated": out[3], "truncated": out[4],
                            "state": out[1], "info": out[5]}

        return obs, jax.lax.scan(body, state, jax.random.split(key_steps, steps))[1]

    difference, seconds = _run_thrice(rollout, jax.random.key(seed), repeats, _first_difference)
    return DeterminismReport(env_id, num_envs, steps, difference is None, difference, seconds)


def check_training_determinism(env_id: str, algo: str = "ppo", num_envs: int = 64, num_steps: int = 16,
                               updates: int = 2, *, seed: int = 0, repeats: int = 1,
                               **env_kwargs) -> DeterminismReport:
    """Train `algo` (the jitted learner, the family's default settings) for `updates` updates of
    `num_envs` envs x `num_steps` steps, three times under the same key as `check_determinism`
    does; the trained parameters, optimizer and normaliser state, env state and metrics must be
    the same bit for bit. The report names the first differing field (`step` and `env` None).
    """
    from jaxnat.agents import ALGORITHMS, config_for
    from jaxnat.registration import make

    env, params = make(env_id, **env_kwargs)
    config = config_for(algo, env, params, num_envs=num_envs, num_steps=num_steps,
                        total_timesteps=updates * num_envs * num_steps)
    learner = ALGORITHMS[algo].make(config, env, params)
    difference, seconds = _run_thrice(learner.train, jax.random.key(seed), repeats, _first_leaf_difference)
    return DeterminismReport(env_id, num_envs, updates * num_steps, difference is None, difference, seconds,
                             f"{algo}, {updates} updates")


def enable_deterministic_ops() -> None:
    """Make every jaxnat env (and training) bitwise reproducible on a GPU: adds
    `--xla_gpu_deterministic_ops=true` to `XLA_FLAGS`. XLA reads its flags once, when JAX first
    starts a backend, so call this before any JAX computation (or set the variable in the shell:
    `XLA_FLAGS=--xla_gpu_deterministic_ops=true jaxnat train ...`); called later it raises
    `RuntimeError`. It costs throughput where the default is not reproducible (MJX's contact
    code): bench/results/determinism.md.
    """
    import os

    flags = os.environ.get("XLA_FLAGS", "")
    if DETERMINISTIC_OPS_FLAG in flags.split():
        return
    if _backends_started():
        raise RuntimeError("enable_deterministic_ops() came after JAX started its backends, so XLA will not read "
                           "it; call it first thing, or start Python with "
                           f"XLA_FLAGS={DETERMINISTIC_OPS_FLAG}")
    os.environ["XLA_FLAGS"] = f"{flags} {DETERMINISTIC_OPS_FLAG}".strip()


def _backends_started() -> bool:
    """Whether JAX has created a backend (XLA has read its flags); False if JAX no longer says.

    JAX has no public "are the backends up?" (only `jax._src.xla_bridge` has one). Its public
    config option `jax_num_cpu_devices` is documented to be settable only before JAX starts its
    backends: `jax.config.update` then refuses a new value with `RuntimeError`. So ask it for a
    different value and put the old one back; before any backend exists the change is unseen
    (nothing reads the option until a CPU backend is created)."""
    try:
        current = jax.config.jax_num_cpu_devices
        jax.config.update("jax_num_cpu_devices", 2 if current == 1 else 1)
    except RuntimeError:
        return True
    except AttributeError:  # the option is gone: JAX no longer says
        return False
    jax.config.update("jax_num_cpu_devices", current)
    return False


def _run_thrice(fn, key, repeats: int, compare):
    """`fn(key)` jitted: once for reference, `repeats` times more from the same compiled program
    (timed), once after compiling again; `(first difference or None, median seconds)`."""
    compiled = jax.jit(fn)
    reference = jax.device_get(compiled(key))
    runs, times = [], []
    for _ in range(max(1, repeats)):
        start = time.perf_counter()
        outputs = jax.block_until_ready(compiled(key))
        times.append(time.perf_counter() - start)
        runs.append(("repeat", jax.device_get(outputs)))
    jax.clear_caches()
    runs.append(("recompiled", jax.device_get(jax.jit(lambda k: fn(k))(key))))
    for run, outputs in runs:
        difference = compare(reference, outputs)
        if difference is not None:
            return {"run": run, **difference}, float(np.median(times))
    return None, float(np.median(times))


def _first_leaf_difference(reference, other) -> dict | None:
    """The first leaf (in pytree order) whose bits differ: `{"step": None, "field", "env": None}`."""
    flat_a, _ = jax.tree_util.tree_flatten_with_path(reference)
    for (path, a), b in zip(flat_a, jax.tree.leaves(other)):
        a, b = _bits(a), _bits(b)
        if a.shape != b.shape or (a != b).any():
            return {"step": None, "field": jax.tree_util.keystr(path), "env": None}
    return None


def _first_difference(reference, other) -> dict | None:
    """The earliest step (then field, then env) at which two rollouts' outputs differ."""
    (obs_a, steps_a), (obs_b, steps_b) = reference, other
    found = None
    if not _tree_equal(obs_a, obs_b):
        return {"step": "reset", "field": "obs", "env": _first_env(obs_a, obs_b)}
    flat_a, _ = jax.tree_util.tree_flatten_with_path(steps_a)
    flat_b = jax.tree.leaves(steps_b)
    for (path, a), b in zip(flat_a, flat_b):
        a, b = _bits(a), _bits(b)
        if a.shape != b.shape:
            return {"step": 0, "field": jax.tree_util.keystr(path), "env": None}
        differs = (a != b).reshape(a.shape[0], -1).any(-1) if a.ndim else np.asarray([a != b])
        if differs.any():
            step = int(np.argmax(differs))
            if found is None or step < found["step"]:
                rows = (a[step] != b[step]).reshape(a.shape[1], -1).any(-1) if a.ndim > 1 else np.asarray([True])
                found = {"step": step, "field": jax.tree_util.keystr(path), "env": int(np.argmax(rows))}
    return found


def _bits(x) -> np.ndarray:
    """An array compared by its bits (NaN equals NaN; -0.0 differs from 0.0); keys by their data."""
    x = np.asarray(jax.random.key_data(x) if jnp.issubdtype(getattr(x, "dtype", np.float32), jax.dtypes.prng_key) else x)
    return x.view(np.uint8).reshape(*x.shape, -1) if x.dtype.kind in "fc" and x.ndim and x.size else x


def _first_env(a, b) -> int:
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)):
        x, y = _bits(x), _bits(y)
        rows = (x != y).reshape(x.shape[0], -1).any(-1)
        if rows.any():
            return int(np.argmax(rows))
    return 0


def check_noise_law(values, probabilities, what: str = "noise", sigmas: float = 6.0) -> None:
    """Assert that i.i.d. integer draws `values` follow the law `probabilities` (P(value = k),
    k = 0 ... 255): no value outside the law's support, each clip bound (0, 255) reached
    whenever the law gives it more than 20 expected draws and hit as often as the law says, and
    the sample mean and standard deviation equal the law's. Every tolerance is `sigmas`
    standard errors for this sample size (the std's by the delta method, from the law's fourth
    central moment), so a right law fails about never and a wrong one fails on a big sample."""
    values = np.asarray(values).ravel().astype(np.float64)
    p = np.asarray(probabilities, np.float64)
    n, k = values.size, np.arange(256.0)
    support = np.flatnonzero(p > 0)
    lo, hi = values.min(), values.max()
    assert lo >= support[0] and hi <= support[-1], (
        f"{what}: values in [{lo:g}, {hi:g}], outside the law's [{support[0]}, {support[-1]}]")
    for bound in (0, 255):
        expected = p[bound]
        freq = float(np.mean(values == bound))
        if expected * n > 20:
            assert freq > 0, f"{what}: the clip bound {bound} is never reached"
        tol = sigmas * np.sqrt(max(expected * (1 - expected), 1.0 / n) / n)
        assert abs(freq - expected) <= tol, (
            f"{what}: P(value = {bound}) is {freq:.5f}, the law's {expected:.5f} (tolerance {tol:.5f})")
    mean = float(p @ k)
    var = float(p @ (k - mean) ** 2)
    mu4 = float(p @ (k - mean) ** 4)
    tol_mean = sigmas * np.sqrt(var / n)
    assert abs(values.mean() - mean) <= tol_mean, (
        f"{what}: mean {values.mean():.3f}, the law's {mean:.3f} (tolerance {tol_mean:.3f})")
    tol_std = sigmas * np.sqrt(max(mu4 - var**2, 0.0) / (4 * var * n))
    assert abs(values.std() - np.sqrt(var)) <= tol_std, (
        f"{what}: std {values.std():.3f}, the law's {np.sqrt(var):.3f} (tolerance {tol_std:.3f})")
