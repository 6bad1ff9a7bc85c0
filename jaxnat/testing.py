"""`check_env`: the contract every jaxnat env keeps, as one reusable check.

Each env's tests call it; it also runs over every registered env whose data is present.
It raises `AssertionError` with a message naming the broken contract.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxnat import spaces
from jaxnat.core import Environment

__all__ = ["check_env"]


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
