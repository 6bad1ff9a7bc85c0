"""The host driver: a host-batched env (`jaxnat.core.HostBatchedEnv`: Natural Atari, whose
emulator steps in C++ on the host) stepped from a Python loop around jitted calls, and the
Python loop of updates that makes a `HostLearner` of an algorithm's update.

`host_steps` takes the scan driver's callbacks with the part of a pipelined batch last:
`policy(carry, obs, key, t, part)`, `observe(carry, EnvStep, aux, t, part) -> (carry, record)`,
and hands back the records as a list, one per step.

A learner of several seeds side by side (`host_updates(..., seeds=S)`) holds their states
stacked (`rollout.stacked`) and steps one batch of every seed's envs (seed `s`'s a slice reset
as its batch alone: `NaturalAtariVecEnv.reset(seeds=...)`), its keys split per seed
(`stacked.split_keys`) so that each seed draws what it draws training alone.
"""

from __future__ import annotations

import itertools
import time
from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnat.agents.rollout.policy import choose, env_action
from jaxnat.agents.rollout.records import EnvStep, count_updates
from jaxnat.agents.rollout.stacked import split_keys

__all__ = ["HostState", "HostLearner", "check_host_batch", "host_steps", "host_steps_pipelined", "TIMING_KEYS",
           "host_updates"]


class HostState(NamedTuple):
    """A host run's state apart from the env: a pytree (what a checkpoint holds). An emulator's
    state cannot be saved, so `run(state)` starts new games, seeded from `key`. Of several
    seeds side by side: every leaf stacked `[S, ...]` (`stacked.seed_slice` gives one seed's)."""

    learner: Any  # TrainState (PPO, A2C) or dqn.DQNState
    key: jax.Array
    update: jax.Array  # updates done (int32)


class HostLearner(NamedTuple):
    """`train(key) -> (state, history)`, `run(state) -> (state, history)` and their parts.

    With `seeds` (S seeds side by side): `init` and `train` take S keys `[S]`, the state is
    stacked (`HostState`), `params` and `updates_of` give stacked values and each update's
    metrics are arrays `[S]`; `greedy` and `sample` take one seed's params (`stacked.seed_slice`)."""

    init: Callable  # key -> HostState at update 0
    run: Callable  # (state, num_updates=None) -> (state, history)
    train: Callable  # (key, num_updates=None) -> (state, history)
    updates: Callable  # state -> iterator of (state, metrics, seconds), one per update, from fresh games
    params: Callable  # state -> the network's params
    updates_of: Callable  # state -> the updates done
    greedy: Callable  # jitted (params, obs, key) -> the most likely action [B, F]
    sample: Callable  # jitted (params, obs, key) -> an action sampled from the policy [B, F]
    network: Any
    num_updates: int
    # Where the time of `updates` went, added up over the learner's life (`TIMING_KEYS`); the
    # caller may clear it. On-policy learners time their steps too; DQN's only its updates.
    timings: dict | None = None
    seeds: int | None = None  # None: one seed; S: S seeds side by side (see above)


def check_host_batch(config, env, memory: int = 0, share: tuple[int, int] | None = None,
                     seeds: int | None = None) -> int:
    """The run's update count; `config.num_envs` must equal `env.num_envs` (a host-batched env
    is built with its batch size), or with `share` (`(first, size)`, a data-parallel run's
    `jaxnat.sharding.process_share`) `size`, or with `seeds` (side by side) `env.num_envs /
    seeds`; the policy must be feed-forward (`memory` 0)."""
    if share is not None and share[1] != env.num_envs:
        first, size = share
        raise ValueError(f"config.num_envs={config.num_envs} is split over the devices: this process steps envs "
                         f"{first}..{first + size - 1} ({size}) but the env has {env.num_envs} (build it with "
                         "jaxnat.sharding.process_share)")
    if share is None and config.num_envs * (seeds or 1) != env.num_envs:
        each = "" if seeds is None else f" for each of {seeds} seeds"
        raise ValueError(f"config.num_envs={config.num_envs}{each} but the env has {env.num_envs} envs")
    if memory:
        raise ValueError(f"memory={memory}: recurrent policies train on jitted envs only; a host-batched env "
                         "(Natural Atari) takes a feed-forward policy (memory=0) and frame stacking")
    return count_updates(config)


def host_steps(env, num_steps: int, policy: Callable, observe: Callable, carry, obs, key,
               timings: dict | None = None):
    """`num_steps` steps of a host-batched env from Python: per step one jitted `policy` call
    (observations to the device, actions back to the host) and `observe` with the outcome.
    The callbacks are the scan driver's with the part of the batch last, always 0 here:
    `policy(carry, obs, key, t, part)`, `observe(carry, EnvStep, aux, t, part) -> (carry,
    record)`. Returns `((carry, obs, key), records)`, the records a list, one per step.
    `timings`, when given, adds up where the time went (`TIMING_KEYS`)."""
    (carry, obs_parts, key), records = _step_parts([env], num_steps, policy, observe, carry, [obs], key, timings)
    return (carry, obs_parts[0], key), records


def host_steps_pipelined(env, num_steps: int, policy: Callable, observe: Callable, carry, obs, key,
                         timings: dict | None = None):
    """`host_steps` over the parts of a `jaxnat.atari.wrappers.PipelinedVecEnv` (two or more) in
    turn, so that the device's policy call for one part runs while ALE emulates another:

        send part p's actions; finish part p-1's step (outcome, `observe`), dispatch its next
        policy call; then fetch part p+1's actions (computed meanwhile) and send them ...

    Every action is the current policy's on its env's latest observation, as in `host_steps`;
    only the sampling keys differ (one split of `key` per part and step, in that order). The
    callbacks see one part's envs. Parts with `step_async`/`step_wait` emulate while the driver
    finishes the previous part (its host pass, `observe`, the next policy call); others step in
    `send`. Returns `((carry, obs of the whole batch, key), records)`, the records a list in
    the order the steps ran: step `t` of part `p` at `t * len(env.parts) + p`."""
    if len(env.parts) < 2:
        raise ValueError("host_steps_pipelined needs an env of two or more parts")
    (carry, obs_parts, key), records = _step_parts(env.parts, num_steps, policy, observe, carry, env.split(obs),
                                                   key, timings)
    return (carry, np.concatenate(obs_parts), key), records


def _step_parts(parts: list, num_steps: int, policy: Callable, observe: Callable, carry, obs_parts: list, key,
                timings: dict | None):
    """The host driver over `parts` stepped in turn (events `e = t * len(parts) + part`):
    `((carry, each part's last observations, key), records in event order)`. With one part a
    step's outcome is needed before the next action; with more, part p's outcome is awaited
    after part p+1's actions are sent, so its emulation overlaps the driver's work."""
    count = len(parts)
    overlap = count > 1
    clock = _Clock(timings)
    obs_parts = list(obs_parts)
    total = num_steps * count
    queued, in_flight, records = {}, {}, []

    def dispatch(e, part_obs):
        nonlocal key
        key, key_act = split_keys(key)  # one key, or each seed's side by side
        obs_device = jax.device_put(part_obs)
        queued[e] = obs_device, policy(carry, obs_device, key_act, e // count, e % count)

    def send(e):
        obs_device, (action, aux) = queued.pop(e)
        action = np.asarray(action)
        clock.lap("policy_s")
        part = parts[e % count]
        env_actions = env_action(action, part.single_action_space)
        if overlap and hasattr(part, "step_async"):
            part.step_async(env_actions)
            outcome = None
        else:
            outcome = part.step(env_actions)
        in_flight[e] = obs_device, action, aux, outcome
        clock.lap("env_s")

    def finish(e):
        nonlocal carry
        obs_device, action, aux, outcome = in_flight.pop(e)
        part = e % count
        if outcome is None:
            outcome = parts[part].step_wait()
        clock.lap("env_s")
        next_obs, reward, terminated, truncated, info = outcome
        carry, record = observe(carry, EnvStep.after(obs_device, action, next_obs, reward, terminated, truncated,
                                                     info), aux, e // count, part)
        records.append(record)
        obs_parts[part] = next_obs
        clock.lap("observe_s")
        if e + count < total:
            dispatch(e + count, next_obs)
            clock.lap("policy_s")

    for e in range(count):
        dispatch(e, obs_parts[e])
    clock.lap("policy_s")
    lag = 1 if overlap else 0  # how many steps are sent ahead of the one finished
    for e in range(total):
        send(e)
        if e >= lag:
            finish(e - lag)
    if lag:
        finish(total - 1)
    clock.done(num_steps)
    return (carry, obs_parts, key), records


# What `host_steps` and `host_updates` add up in a learner's `timings` (seconds and counts):
# per batched step the policy's round trip (key split, observations to the device, the jitted
# call, actions back), the env's step and `observe`; per update the rollout and the whole
# update (rollout, then stacking, GAE and the jitted update until its metrics are on the host).
TIMING_KEYS = ("steps", "policy_s", "env_s", "observe_s", "rollout_s", "updates", "update_s")


class _Clock:
    """Adds the seconds since the previous lap to `timings[name]`; a no-op without `timings`."""

    def __init__(self, timings: dict | None):
        self.timings = timings
        self.start = self.last = time.perf_counter()

    def lap(self, name: str) -> None:
        if self.timings is not None:
            now = time.perf_counter()
            self.timings[name] = self.timings.get(name, 0.0) + now - self.last
            self.last = now

    def done(self, steps: int) -> None:
        if self.timings is not None:
            self.timings["steps"] = self.timings.get("steps", 0) + steps
            self.timings["rollout_s"] = self.timings.get("rollout_s", 0.0) + time.perf_counter() - self.start


def _draw_game_seed(key):
    return jax.random.randint(key, (), 0, 2**31 - 1)


def _game_seed(key) -> int:
    """The seed of a run's new games (emulator `j` gets it plus `j`), drawn from `key`."""
    return int(_draw_game_seed(key))


def host_updates(env, network, num_updates: int, init_learner: Callable, update: Callable,
                 params: Callable, jit: Callable, timings: dict | None = None, first_env: int = 0,
                 seeds: int | None = None) -> HostLearner:
    """The Python loop of updates on a host-batched env. `update(learner, obs, key, update_index)
    -> (learner, obs, key, metrics)` does one update's env steps and learning; `timings` (the
    one `update` hands its `host_steps`, if any) also gets each update's seconds. `first_env`:
    the index of the env's first env in a batch split over processes (its games are seeded
    as that batch's).

    `seeds` (S): S seeds side by side, `init_learner` and `update` taking and giving their
    stacked learner states and keys; `env` one batch of every seed's envs, which a run resets
    with each seed's own game seed (`reset(seeds=...)`, drawn as one seed's run draws it), so
    seed `s`'s games are those of its run alone. Every seed is at the same
    update (a state whose seeds are not is refused)."""
    timings = {} if timings is None else timings
    shape = () if seeds is None else (seeds,)

    greedy, sample = (jit(lambda params, obs, key, g=g: choose(network.apply(params, obs)[0], key, g))
                      for g in (True, False))

    def init(key) -> HostState:
        key, key_init = split_keys(key)
        return HostState(init_learner(key_init), key, jnp.zeros(shape, jnp.int32))

    def done(state: HostState) -> int:
        counts = np.unique(np.asarray(state.update))
        if len(counts) != 1:
            raise ValueError(f"the seeds side by side are at different updates ({counts.tolist()}): "
                             "they train one chunk at a time together")
        return int(counts[0])

    def updates(state: HostState):
        """Updates `state.update + 1, ...` (up to `num_updates`) on freshly reset envs, one
        `(state, metrics, seconds)` per update; a consumer may stop anywhere (a chunk)."""
        key, key_env = split_keys(state.key)
        if seeds is None:
            obs, _ = env.reset(seed=_game_seed(key_env) + first_env)
        else:
            obs, _ = env.reset(seeds=[int(g) for g in np.asarray(jax.vmap(_draw_game_seed)(key_env))])
        learner = state.learner
        for index in range(done(state), num_updates):
            start = time.perf_counter()
            learner, obs, key, metrics = update(learner, obs, key, index)
            metrics = {k: float(v) if seeds is None else np.asarray(v) for k, v in jax.device_get(metrics).items()}
            seconds = time.perf_counter() - start
            timings["updates"] = timings.get("updates", 0) + 1
            timings["update_s"] = timings.get("update_s", 0.0) + seconds
            yield HostState(learner, key, jnp.full(shape, index + 1, jnp.int32)), metrics, seconds

    def run(state: HostState, num_updates: int = num_updates):
        """Updates `state.update + 1 .. num_updates` on freshly reset envs: `(state, history)`."""
        history = []
        for state, metrics, _ in itertools.islice(updates(state), max(0, num_updates - done(state))):
            history.append(metrics)
        return state, history

    def train(key, num_updates: int = num_updates):
        """Train from scratch."""
        return run(init(key), num_updates)

    return HostLearner(init, run, train, updates, params, lambda state: state.update, greedy, sample, network,
                       num_updates, timings, seeds)
