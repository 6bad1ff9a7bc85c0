"""A trained policy, loaded from a `jaxnat train` run directory (`jaxnat eval` plays one: `eval_run`).

    policy = load_policy("runs/Classify_Digits-v0-ppo-20250101-120000")   # seed index 0, test split
    obs, state = policy.env.reset(key, policy.env_params)
    action = policy.act(obs, key, greedy=True)

A run holds everything needed to act (`config.json`'s spec and the checkpoint), but the
checkpoint is the learner's vmapped runner, read only through the learner: this module
rebuilds the run's envs (`device_backend.make_envs`, the trainer's own), its learner and runner
(`load_checkpoint`), and takes one seed's slice of `Learner.policy_of`. Acting is the
trainer's evaluation step (`rollout.act`, `rollout.choose`, `normalize.normalize`,
`rollout.env_action`) on a batch of one, so a loaded policy acts as the trainer scored it.

`play_episodes` plays a policy's episodes in one jitted program (`jaxnat eval`'s);
`sweep_episodes` plays them at every strength of a distraction grid (`params.sweep`), all
strengths in one jitted program on the same episode keys (`jaxnat sweep`'s curve).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any, Callable

import jax
import jax.numpy as jnp

__all__ = ["LoadError", "TrainedPolicy", "load_policy", "episode_program", "play_episodes", "host_episodes",
           "sweep_episodes", "sweep_params", "dial_fields", "episode_limit", "policy_step", "SPLITS"]

SPLITS = ("test", "train")


class LoadError(Exception):
    """A run that cannot be loaded (no run there, no checkpoint, an unsupported run): one line."""


@dataclasses.dataclass(frozen=True, eq=False)
class TrainedPolicy:
    """One seed of a run, ready to act: `act(obs, key, *, greedy=False) -> action`, jitted.

    `obs` is one env's observation (as `env.reset` and `env.step` return it; `jax.vmap(act)`
    for a batch) and the action is in the env's form, ready for `env.step`. `greedy`: the most
    likely action (a Gaussian's mean), else one sampled with `key`. Observations pass through
    the run's normaliser, frozen as the checkpoint holds it, where the run has one.

    `env`, `env_params`: the run's env on `split` ("test": the test split, built as the
    trainer's evaluation builds it, `autoreset=False`; "train": the env it trained on; an env
    without a split gives its one env either way). `apply(params, normalizer, obs, key,
    greedy=False)` is `act` unjitted, taking the parameters as arguments (for your own `jit`).
    """

    run_dir: Path
    env_id: str
    env_kwargs: dict  # the run's `jaxnat.make` kwargs (the split is `split`)
    algo: str
    config: Any  # the run's resolved algorithm config
    split: str
    env: Any
    env_params: Any
    seed_index: int  # among the run's seeds, 0 .. seeds - 1
    seed_value: int  # the seed itself: `seed` in metrics.jsonl and eval.jsonl
    update: int  # the checkpoint's update count
    network: Any
    params: Any  # the network's parameters (this seed's)
    normalization: Any  # `normalize.Normalizer` (this seed's), or None where observations are raw
    apply: Callable = dataclasses.field(repr=False)
    _act: Callable = dataclasses.field(repr=False)
    # Host-emulated policies (Natural Atari): `act_batch(params, obs, key, greedy=False) -> actions`,
    # the learner's jitted policy on a whole batch of observations `[B, ...]` (`host_episodes`);
    # None for JAX envs (`jax.vmap(act)` batches them).
    act_batch: Callable | None = dataclasses.field(default=None, repr=False)

    def act(self, obs, key, *, greedy: bool = False):
        return self._act(self.params, self.normalization, obs, key, greedy=greedy)

    def __repr__(self) -> str:  # the parameters and the env's data are too long to show
        return (f"TrainedPolicy({self.algo} on {self.env_id}, seed {self.seed_value} (index {self.seed_index}), "
                f"update {self.update}, {self.split} split, run_dir={str(self.run_dir)!r})")


def policy_step(network, action_space) -> Callable:
    """`apply(params, normalizer, obs, key, greedy=False) -> action`: the trainer's evaluation
    step (`rollout.evaluate.make_evaluate`) for one observation, as a batch of one, for a
    learner's `network` on an env with `action_space` (`TrainedPolicy.apply`; build one from a
    runner you trained yourself with `Learner.policy_of`)."""
    from jaxnat.agents import normalize
    from jaxnat.agents.rollout import act, choose, env_action

    def apply(params, normalizer, obs, key, greedy: bool = False):
        batch = jax.tree.map(lambda x: jnp.asarray(x)[None], obs)
        logits, _, _ = act(network, params, normalize.normalize(normalizer, batch), None)
        return env_action(choose(logits, key, greedy)[0], action_space)

    return apply


def _read_spec(run_dir: Path):
    """The run's `RunSpec`; a folder that holds no run is a one-line `LoadError`."""
    from jaxnat.training import RunSpec, TrainError

    if not run_dir.is_dir():
        raise LoadError(f"{run_dir} is not a run directory: no such folder")
    config_path = run_dir / "config.json"
    if not config_path.is_file():
        raise LoadError(f"{run_dir} is not a run directory: no config.json there (jaxnat train writes one)")
    try:
        return RunSpec.from_json(json.loads(config_path.read_text())["spec"])
    except TrainError as err:
        raise LoadError(str(err)) from None
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise LoadError(f"{config_path} holds no readable run spec ({type(err).__name__}: {err})") from None


def load_policy(run_dir, *, seed: int = 0, split: str = "test", step: int | None = None,
                compiler_options: dict | None = None) -> TrainedPolicy:
    """Seed `seed` (an index among the run's seeds, 0 .. seeds - 1) of the run in `run_dir`, from
    its latest checkpoint (or `step`'s), with the run's env on `split` ("test" or "train").

    A Natural Atari run (host-emulated) loads as `_load_host_policy` says: its `env` a batch of
    one game (numpy in and out), `env_params` None. Raises `LoadError` (one line) for a folder
    that holds no run, a run without a checkpoint, a seed index out of range, and a recurrent
    policy (`memory > 0`), whose `act` would need its memory.
    `compiler_options`: XLA options for the init program the checkpoint is restored into.
    """
    from jaxnat.training import TrainError, load_checkpoint
    from jaxnat.training.device_backend import compiled_program, make_envs
    from jaxnat.training.host_backend import is_host_env

    run_dir = Path(run_dir)
    spec = _read_spec(run_dir)
    if not 0 <= seed < spec.seeds:
        raise LoadError(f"seed index {seed} is out of range: {run_dir} trained {spec.seeds} seed"
                        f"{'s' * (spec.seeds != 1)}, indices 0 to {spec.seeds - 1}")
    if split not in SPLITS:
        raise LoadError(f"split {split!r} is not one of {', '.join(SPLITS)}")
    if is_host_env(spec.env_id):
        return _load_host_policy(run_dir, spec, seed, split, step, compiler_options)
    if getattr(spec.config, "memory", 0):
        raise LoadError(f"{run_dir} trained a recurrent policy (memory={spec.config.memory}): load_policy "
                        "supports feed-forward policies only, for now")
    if not (run_dir / "checkpoints").is_dir():
        raise LoadError(f"{run_dir} has no checkpoint yet (no checkpoints/ folder): the run wrote none")
    # As load_checkpoint places it: a sharded run loads onto one device here.
    devices = None if spec.shard is None else 1
    placed = spec if devices is None else dataclasses.replace(spec, devices=devices)
    try:
        envs = make_envs(placed)
        # The run's programs: load_checkpoint restores into their init, so its learner is this one.
        learner = compiled_program(placed, compiler_options, envs).learner
        runner, meta = load_checkpoint(run_dir, step, compiler_options=compiler_options, devices=devices)
    except TrainError as err:
        raise LoadError(str(err)) from None
    env, env_params = envs[2:] if split == "test" else envs[:2]
    params, normalizer = jax.tree.map(lambda x: x[seed], learner.policy_of(runner))
    apply = policy_step(learner.network, env.action_space(env_params))
    return TrainedPolicy(run_dir=run_dir, env_id=spec.env_id, env_kwargs=spec.env_kwargs, algo=spec.algo, config=spec.config, split=split,
                         env=env, env_params=env_params, seed_index=seed, seed_value=spec.seed_values[seed],
                         update=int(meta["update"]), network=learner.network, params=params, normalization=normalizer,
                         apply=apply, _act=jax.jit(apply, static_argnames="greedy"))


def _load_host_policy(run_dir: Path, spec, seed: int, split: str, step: int | None,
                      compiler_options: dict | None) -> TrainedPolicy:
    """Seed index `seed` of a host-emulated (Natural Atari) run: the run's learner rebuilt on
    its own batch (the checkpoint `checkpoints/seed_<s>/` holds the learner's `HostState`, whose
    shapes follow the batch), restored, its emulators closed again; the policy then acts on
    `env`, a batch of one game of `split` (`jaxnat.make_vec(env_id, 1, split=...)`: numpy
    observations `[1, ...]` out, actions `[1]` in; rewards unclipped, as evaluation scores
    them). `act(obs, key)` takes one observation (`obs[0]`) and returns one action `[1]` (the
    learner's one factor, which is the env's action: `env.step(action)`); `apply` is the
    learner's jitted greedy or sampled policy on a batch of one."""
    import jaxnat
    from jaxnat.training import TrainError
    from jaxnat.training.checkpoints import Checkpoints
    from jaxnat.training.host_backend import host_errors, make_learner, make_train_env

    value = spec.seed_values[seed]
    folder = run_dir / "checkpoints" / f"seed_{value}"
    missing = LoadError(f"{run_dir} has no checkpoint of seed {value} (index {seed}) yet: {folder.relative_to(run_dir)} "
                        "holds none (a host run's seeds save their first checkpoint together, or one after another with "
                         "--host-seeds sequential)")
    if not folder.is_dir():
        raise missing
    with host_errors(spec.env_id):
        batch = make_train_env(spec.env_id, spec.config.num_envs, spec.env_kwargs, spec.env_parts)
    try:
        learner = make_learner(spec.algo, spec.config, batch, compiler_options)
        checkpoints = Checkpoints(folder)
        try:
            if checkpoints.latest_step() is None:
                raise missing
            state, meta = checkpoints.restore(learner.init(jax.random.key(value)), step)
        except TrainError as err:
            raise LoadError(str(err)) from None
        finally:
            checkpoints.close()
    finally:
        batch.close()
    with host_errors(spec.env_id):
        env = jaxnat.make_vec(spec.env_id, 1, split=split, **spec.env_kwargs)

    def apply(params, normalizer, obs, key, greedy: bool = False):
        return (learner.greedy if greedy else learner.sample)(params, jnp.asarray(obs)[None], key)[0]

    def act_batch(params, obs, key, greedy: bool = False):
        return (learner.greedy if greedy else learner.sample)(params, jnp.asarray(obs), key)

    return TrainedPolicy(run_dir=run_dir, env_id=spec.env_id, env_kwargs=spec.env_kwargs, algo=spec.algo,
                         config=spec.config, split=split, env=env, env_params=None, seed_index=seed, seed_value=value,
                         update=int(meta["update"]), network=learner.network, params=learner.params(state),
                         normalization=None, apply=apply, _act=apply, act_batch=act_batch)


def host_episodes(policy: TrainedPolicy, key, num_episodes: int, *, greedy: bool = False,
                  max_steps: int | None = None, record: bool = False):
    """`play_episodes` for a host-emulated policy (`env_params` None): `num_episodes` whole
    games on `policy.env`, in rounds of its `num_envs` games at once (`load_policy` gives a
    one-game batch: one game after another; `dataclasses.replace(policy, env=jaxnat.make_vec(
    env_id, B, split="test", ...))` plays B at once). Round `r` resets the batch with a seed `s_r`
    drawn from `key`, so its env `i` plays the game of seed `s_r + i` (the same key, the same
    games); each env's first game counts, for at most `max_steps` agent steps (default the
    env's `max_episode_steps`), and the round ends when all of them have ended. An episode ends
    where the env's flags end it (with `preprocessing="deepmind"`, at a lost life, its reward
    the sign). Returns the same per-episode arrays; with `record`, `(seen, results)` where
    `seen[i]` is game `i`'s observations `[length + 1, ...]`, the reset's first."""
    import numpy as np

    env = policy.env
    width = int(env.num_envs)
    limit = int(max_steps or episode_limit(policy))
    key_seeds, key = jax.random.split(key)
    seeds = np.asarray(jax.random.randint(key_seeds, (num_episodes,), 0, 2 ** 30))

    def act(obs, key):  # the learner's one factor per env: `[B, 1]` -> `[B]`
        return np.asarray(policy.act_batch(policy.params, obs, key, greedy=greedy)).reshape(width)

    results = {name: [] for name in ("return", "length", "terminated", "unfinished")}
    seen = []
    for first in range(0, num_episodes, width):
        count = min(width, num_episodes - first)
        obs, _ = env.reset(seed=int(seeds[first // width]))
        frames = [[obs[i]] for i in range(count)]
        total, length = np.zeros(width), np.zeros(width, np.int64)
        ended, terminated = np.zeros(width, bool), np.zeros(width, bool)
        steps = 0
        while steps < limit and not ended[:count].all():
            key, key_act = jax.random.split(key)
            obs, reward, term, trunc, _ = env.step(act(obs, key_act))
            live = ~ended
            total += np.where(live, reward, 0.0)
            length += live
            terminated |= live & term
            ended |= live & (term | trunc)
            steps += 1
            if record:
                for i in np.flatnonzero(live[:count]):
                    frames[i].append(obs[i])
        for i in range(count):
            for name, value in (("return", total[i]), ("length", length[i]), ("terminated", terminated[i]),
                                ("unfinished", not ended[i])):
                results[name].append(value)
        if record:
            seen.extend(np.stack(game) for game in frames)
    dtypes = {"return": np.float32, "length": np.int32, "terminated": bool, "unfinished": bool}
    results = {name: np.asarray(values, dtypes[name]) for name, values in results.items()}
    return (seen, results) if record else results


def episode_program(policy: TrainedPolicy, max_steps: int, greedy: bool, *, env=None,
                    record: str | None = None) -> Callable:
    """`episode(params, normalizer, env_params, key)`: the first episode of an env reset with
    `key`, played with `policy.apply` for at most `max_steps` steps; its return, length,
    `terminated` and `unfinished` (cut at `max_steps`). `env_params` is an argument so that a
    sweep can vmap it over a strength axis. `env`: the env to play (default `policy.env`).
    `record` "obs" or "state": also what the episode saw, `(seen, results)` with `seen[t]`
    the observation (or env state) at step `t`, `t = 0` the reset, valid for `t <= length`."""
    env = policy.env if env is None else env

    def episode(params, normalizer, env_params, key):
        key_reset, key_steps = jax.random.split(key)
        obs, state = env.reset(key_reset, env_params)

        def body(carry, key):
            obs, state, running, total, length, terminated_any = carry
            key_act, key_env = jax.random.split(key)
            action = policy.apply(params, normalizer, obs, key_act, greedy)
            obs, state, reward, terminated, truncated, _ = env.step(key_env, state, action, env_params)
            total = total + jnp.where(running, reward, 0.0)
            length = length + running
            terminated_any = terminated_any | (running & terminated)
            seen = None if record is None else (state if record == "state" else obs)
            return (obs, state, running & ~(terminated | truncated), total, length, terminated_any), seen

        carry = (obs, state, jnp.asarray(True), jnp.zeros(()), jnp.zeros((), jnp.int32), jnp.asarray(False))
        (_, _, running, total, length, terminated), seen = jax.lax.scan(body, carry,
                                                                         jax.random.split(key_steps, max_steps))
        results = {"return": total, "length": length, "terminated": terminated, "unfinished": running}
        if record is None:
            return results
        first = state if record == "state" else obs
        return jax.tree.map(lambda a, rest: jnp.concatenate([a[None], rest]), first, seen), results

    return episode


def play_episodes(policy: TrainedPolicy, key, num_episodes: int, *, greedy: bool = False,
                  max_steps: int | None = None) -> dict:
    """Each of `num_episodes` envs plays its first episode with `policy` (at most `max_steps`
    steps, default the env's time limit), in one jitted program vmapped over the episodes:
    per-episode arrays `return`, `length`, `terminated` (for Classify: classified right;
    Localize: the target found) and `unfinished` (cut at `max_steps`), as numpy. A host
    (Natural Atari) policy plays its games on the host, as many at once as its env has envs
    (`host_episodes`)."""
    if policy.env_params is None:
        return host_episodes(policy, key, num_episodes, greedy=greedy, max_steps=max_steps)
    if max_steps is None:
        max_steps = int(policy.env_params.max_steps_in_episode)
    play = jax.jit(jax.vmap(episode_program(policy, max_steps, greedy), in_axes=(None, None, None, 0)))
    return jax.device_get(play(policy.params, policy.normalization, policy.env_params,
                               jax.random.split(key, num_episodes)))


def episode_limit(policy: TrainedPolicy) -> int:
    """The policy's env's time limit in agent steps (a host env's `max_episode_steps`)."""
    if policy.env_params is None:
        return int(policy.env.max_episode_steps)
    return int(policy.env_params.max_steps_in_episode)


def dial_fields(env_params) -> tuple[str, ...]:
    """The names of `env_params`' distraction dial (`env_params.distraction`'s fields, which
    `env_params.sweep` takes), or () for an env without one."""
    group = getattr(env_params, "distraction", None)
    if group is None or not hasattr(env_params, "sweep") or not dataclasses.is_dataclass(group):
        return ()
    return tuple(f.name for f in dataclasses.fields(group))


def sweep_params(policy: TrainedPolicy, **values) -> tuple[Any, Any]:
    """`(params, in_axes)`: `policy.env_params` with the named distraction fields swept
    (`env_params.sweep(**values)`: arrays of one leading length, the strength axis), checked by
    the sweep and by the env (`check_params`: e.g. PixelMuJoCo's `video_alpha` needs
    `floor="video"`). Raises `ValueError` (one line) for an env without a dial, a name that is
    not one of its fields, or a value out of range."""
    fields = dial_fields(policy.env_params)
    if not fields:
        raise ValueError(f"{policy.env_id} has no distraction dial: sweeps need an env whose params have "
                         "a `distraction` group (PixelMuJoCo, Classify, Localize)")
    unknown = sorted(set(values) - set(fields))
    if unknown or not values:
        raise ValueError(f"{policy.env_id}'s distraction dial has no {', '.join(map(repr, unknown)) or 'field given'}; "
                         f"its fields: {', '.join(fields)}")
    swept, axes = policy.env_params.sweep(**values)
    check = getattr(policy.env, "check_params", None)
    if check is not None:
        check(swept)
    return swept, axes


def sweep_episodes(policy: TrainedPolicy, key, num_episodes: int, *, greedy: bool = False,
                   max_steps: int | None = None, **values) -> dict:
    """`play_episodes` at every strength of a distraction grid, in ONE jitted program vmapped
    over the strengths (and, inside, over the episodes): a generalisation curve.

        curve = sweep_episodes(policy, jax.random.key(0), 100, greedy=True,
                               noise_sigma=jnp.array([0.0, 16.0, 32.0, 64.0]))
        curve["return"].mean(axis=1)  # one mean return per strength

    `values` are `policy.env_params.sweep`'s (distraction fields -> arrays of one length S,
    checked there and by the env: `sweep_params`, whose `ValueError`s are one line). Every
    strength plays the same `num_episodes` keys, `jax.random.split(key, num_episodes)` as
    `play_episodes` splits them (common random numbers: the strengths differ only in the
    dial), so at a strength equal to the policy's own params a row is `play_episodes(policy,
    key, num_episodes)`. Returns `play_episodes`' arrays, each of shape [S, num_episodes]."""
    swept, axes = sweep_params(policy, **values)
    if max_steps is None:
        max_steps = int(policy.env_params.max_steps_in_episode)
    per_strength = jax.vmap(episode_program(policy, max_steps, greedy), in_axes=(None, None, None, 0))
    play = jax.jit(jax.vmap(per_strength, in_axes=(None, None, axes, None)))
    return jax.device_get(play(policy.params, policy.normalization, swept, jax.random.split(key, num_episodes)))
