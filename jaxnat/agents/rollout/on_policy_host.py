"""The on-policy learner on a host-batched env (PPO, A2C on Natural Atari): per env step one
jitted policy call, per update one jitted update (the jitted learner's `UpdateRule.learn`).

Data parallel across processes (`devices=`): each process steps its share of a host-batched
env (one ALE batch per host) and the update runs under `jax.shard_map` over every process's
devices, so every process holds the same parameters.

Seeds side by side (`seeds=S`): one batch of every seed's envs, one vmapped policy call per
step for all of them and one vmapped update, each seed's numbers its own (`rollout.stacked`).
"""

from __future__ import annotations

import functools
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import PartitionSpec

from jaxnat.agents import distributions, normalize
from jaxnat.agents.config import check_ranges
from jaxnat.agents.networks import make_actor_critic
from jaxnat.agents.rollout.host import HostLearner, check_host_batch, host_steps, host_steps_pipelined, host_updates
from jaxnat.agents.rollout.on_policy import UpdateRule
from jaxnat.agents.rollout.policy import final_value, sample_each
from jaxnat.agents.rollout.records import EPISODE_KEYS, EnvStep, Transition, bootstrap, step_info
from jaxnat.agents.rollout.stacked import over_seeds, split_keys
from jaxnat.sharding import AXIS, device_mesh, local_copy, process_share, put_global, replicated, shard_program, sharded

__all__ = ["on_policy_host_learner"]


def on_policy_host_learner(config, env, compiler_options: dict | None = None, devices=None, *,
                           rule: UpdateRule, seeds: int | None = None) -> HostLearner:
    """The host-loop on-policy learner for `config` (a `PPOConfig` or `A2CConfig`) on a batched
    host env: per env step one jitted policy call, and one value call on final observations
    when an episode ended; per update the rollout goes to the device once and one jitted
    update runs (`rule.update_step`, as the jitted learner's).

    On a `jaxnat.atari.wrappers.PipelinedVecEnv` of two or more parts the steps run through
    `host_steps_pipelined`: each part's policy call overlaps the other parts' emulation. Same
    policy, same update; the action samples use other keys, so the run is not the one-batch
    run bit for bit (with one batch, it is the run it always was).

    `devices` (a count, "all", devices or a mesh: `jaxnat.sharding.device_mesh`): train data
    parallel over them, and over every process of a `jax.distributed` run (one ALE batch per
    host). `env` then holds this process's share of the `config.num_envs` envs
    (`jaxnat.sharding.process_share`), whose games are seeded as that share of one batch; env
    `i` of the whole batch samples its actions with key `i` of each step's `num_envs` keys; the
    update runs under `jax.shard_map` over the mesh on every process's rollouts (`rule.learn`
    with `axis_name`: the gradients averaged by `pmean_gradients`, batch statistics whole), so
    every process holds the same parameters and any process or device count trains the same
    ones to float tolerance (with env parts: given the same parts per process, whose turns
    the step keys follow). Its random draws are not the default learner's (`devices=None`,
    unchanged).

    `seeds` (S): S seeds side by side (`HostLearner.seeds`), on one batch of S *
    `config.num_envs` envs, seed `s`'s envs `s * num_envs ..`, whose `reset(seeds=...)` resets
    each seed's envs as a batch of their own (`host_backend.make_train_env(..., seeds=S)`: one
    ALE batch; also taken: a `PipelinedVecEnv` of one part per seed), stepped as one batch. Per env
    step one policy call acts for every seed, per update one update trains them all (both
    `jax.vmap`ped over the stacked states); the keys are split per seed and each seed's envs
    are reset with its game seed, so seed `s` trains as the one-seed learner on its own batch
    given `init` its key `s` (to float tolerance: vmapped programs may round otherwise). One
    device: not with `devices`. In pipelined parts: a `PipelinedVecEnv` with `groups=S`
    (`make_train_env(..., parts=P, seeds=S)`: each part an equal slice of every seed's envs),
    stepped in turn as above with one policy call per part for every seed, so seed `s` trains
    as the one-seed learner on its own batch in the same parts."""
    check_ranges(config)
    options = rule.network_options(config)
    if seeds is not None:
        if devices is not None:
            raise ValueError("seeds side by side train on one device: leave devices out, or train one seed at a time "
                             "data parallel")
        _check_seed_batch(env, seeds, config.num_envs)
    mesh = None if devices is None else device_mesh(devices)
    if mesh is not None:
        rule = rule.averaged(AXIS)
    share = None if mesh is None else process_share(config.num_envs, mesh)
    num_updates = check_host_batch(config, env, options.get("memory", 0), share, seeds)
    observation_space = env.single_observation_space
    if config.normalize_observations or config.normalize_rewards:  # (None, the default, is off here)
        raise ValueError("normalize_observations and normalize_rewards apply to jitted envs; a host-batched "
                         "env (Natural Atari) trains on raw frames and clipped rewards: leave them off")
    network = make_actor_critic(observation_space, env.single_action_space, config.trunk, **options)
    jit = functools.partial(jax.jit, compiler_options=compiler_options)  # XLA options for every program

    def act(params, obs, key, first=None):
        logits, value = network.apply(params, obs)
        if first is None:
            action = distributions.sample(key, logits)
        else:  # data parallel: env i of the whole batch draws with key i (`first`: this call's first env)
            action = sample_each(jax.random.split(key, config.num_envs)[first:first + len(obs)], logits)
        return action, (distributions.log_prob(logits, action), value)

    if seeds is None:
        policy = jit(act, static_argnames="first")
        value_of = jit(functools.partial(final_value, network))
        init, learn, local_params = _host_programs(config, network, rule, observation_space, num_updates, jit, mesh)
    else:
        stacked_policy = jit(over_seeds(act, seeds))
        policy = lambda params, obs, key, first=None: stacked_policy(params, obs, key)  # noqa: E731
        value_of = jit(over_seeds(functools.partial(final_value, network), seeds))
    parts = getattr(env, "parts", None)
    # Parts are stepped in turn; of seeds side by side only parts holding a slice of every
    # seed's envs (`groups`), not one part per seed, which step as one batch.
    pipelined = parts is not None and len(parts) > 1 and (seeds is None or getattr(env, "groups", None) == seeds)
    if seeds is not None:
        init, learn, local_params = _seed_programs(config, network, rule, observation_space, num_updates, jit, seeds,
                                                   len(parts) if pipelined else 1)
    offsets = env.offsets[:-1] if pipelined else [0]
    # Each part's first env in the whole batch (data parallel), or None: the default sampling.
    starts = [None if share is None else share[0] + int(offset) for offset in offsets]
    timings = {}

    def update(train_state, obs, key, index):
        del index  # on-policy updates do not depend on the update count (schedules are in the optimizer)
        params = local_params(train_state)

        def observe(carry, s: EnvStep, aux, t, part):
            log_prob, value = aux
            # V(final observation) where an episode ended; elsewhere the next step's value serves.
            value_final = (value_of(params, jax.device_put(s.final_obs)) if s.done.any()
                           else np.zeros(len(s.done), np.float32))
            return carry, {"obs": s.obs, "action": s.action, "log_prob": log_prob, "value": value, "reward": s.reward,
                           "done": s.done, "terminated": s.terminated, "final_value": value_final,
                           **{k: s.info[k] for k in EPISODE_KEYS}}

        steps = host_steps_pipelined if pipelined else host_steps
        (_, obs, key), records = steps(env, config.num_steps,
                                       lambda carry, o, k, t, part: policy(params, o, k, first=starts[part]),
                                       observe, None, obs, key, timings)
        last_value = [value_of(params, jax.device_put(o)) for o in (env.split(obs) if pipelined else [obs])]
        # name -> one entry per part of the batch: its steps. Host arrays (actions, rewards,
        # flags, episode statistics) stacked here go to the device as one transfer per name and
        # part, not one per step.
        count = len(parts) if pipelined else 1
        rollout = {name: [[r[name] for r in records[p::count]] for p in range(count)] for name in records[0]}
        rollout = {name: [np.stack(steps) if all(isinstance(x, np.ndarray) for x in steps) else steps
                          for steps in part_steps] for name, part_steps in rollout.items()}
        transitions = _host_transitions(rollout, last_value, config.clip_rewards)
        key, key_update = split_keys(key)
        train_state, metrics = learn(train_state, transitions, key_update)
        return train_state, obs, key, metrics

    return host_updates(env, network, num_updates, init, update, lambda s: local_params(s.learner), jit, timings,
                        0 if share is None else share[0], seeds)


def _check_seed_batch(env, seeds: int, num_envs: int) -> None:
    """A `ValueError` unless `env` holds `seeds` x `num_envs` envs (a `PipelinedVecEnv` of
    parts: one part of `num_envs` per seed, or parts of `groups=seeds`)."""
    parts = getattr(env, "parts", None)
    sizes = [int(part.num_envs) for part in parts or [env]]
    in_parts = parts is not None and getattr(env, "groups", None) != seeds and sizes != [num_envs] * seeds
    if seeds < 1 or int(env.num_envs) != seeds * num_envs or in_parts:
        raise ValueError(f"seeds={seeds} side by side take one batch of seeds x config.num_envs = "
                         f"{seeds} x {num_envs} envs (host_backend.make_train_env(..., seeds={seeds})); the env "
                         f"has {sizes if len(sizes) > 1 else env.num_envs} envs")


def _seed_programs(config, network, rule: UpdateRule, observation_space, num_updates: int, jit: Callable,
                   seeds: int, parts: int = 1):
    """`_host_programs`' `(init, learn, local_params)` of `seeds` seeds side by side: `init(keys
    [S])` and `learn(train_state, transitions, keys [S])` vmapped over the stacked train
    states, the transitions of the seeds' envs side by side `[T, S * n, ...]` (seed `s`'s envs
    `s * n ..`; in `parts` pipelined parts, part after part, each holding `n / parts` envs of
    every seed: `[T, P * S * n / P, ...]`) regrouped per seed inside the program, each seed's
    envs in the order of its batch alone (part by part); `local_params` the stacked params."""
    make_state = jit(jax.vmap(lambda key: rule.train_state(config, network, observation_space, num_updates, key)))

    def per_seed(x):  # [T, P * S * k, ...] -> [S, T, P * k, ...]
        steps, envs = x.shape[:2]
        x = jnp.moveaxis(x.reshape(steps, parts, seeds, envs // (parts * seeds), *x.shape[2:]), 2, 0)
        return x.reshape(seeds, steps, envs // seeds, *x.shape[4:])

    @jit
    def learn(train_state, transitions: Transition, keys):
        return jax.vmap(lambda state, rollout, key: rule.learn(config, network, state, rollout, key))(
            train_state, jax.tree.map(per_seed, transitions), keys)

    return make_state, learn, lambda train_state: train_state.params


def _host_programs(config, network, rule: UpdateRule, observation_space, num_updates: int, jit: Callable, mesh):
    """`(init, learn, local_params)` of an on-policy host learner: `init(key) -> TrainState`,
    `learn(train_state, transitions, key) -> (train_state, metrics)` on this process's rollout,
    and `local_params(train_state)`, the parameters its policy calls read. Without `mesh`,
    programs of one device. With it, data parallel (`rule` is then `UpdateRule.averaged`): the
    train state replicated over the mesh, and `learn` runs `rule.learn`
    with `AXIS` under `jax.shard_map` on every process's rollouts side by side (each process
    gives its own: `jax.make_array_from_process_local_data`) with the same key in every
    process; the policy reads this process's copy of the parameters."""
    # One compiled program, not hundreds of small eager ones.
    make_state = jit(lambda key: rule.train_state(config, network, observation_space, num_updates, key))
    if mesh is None:
        learn = jit(lambda train_state, transitions, key: rule.learn(config, network, train_state, transitions, key))
        return make_state, learn, lambda train_state: train_state.params
    whole, per_env = PartitionSpec(), PartitionSpec(None, AXIS)  # replicated; split along the env axis
    program = shard_program(lambda train_state, transitions, key: rule.learn(
        config, network, train_state, transitions, key, AXIS), mesh, (whole, per_env, whole), (whole, whole), jit)

    def init(key):
        return put_global(make_state(key), replicated(mesh))

    def learn(train_state, transitions, key):
        transitions = jax.make_array_from_process_local_data(sharded(mesh, 1), transitions)
        return program(train_state, transitions, put_global(key, replicated(mesh)))

    return init, learn, lambda train_state: local_copy(train_state.params)


@functools.partial(jax.jit, static_argnames="clip")
def _host_transitions(rollout: dict, last_value: list, clip: bool = False) -> Transition:
    """Stack the per-step lists (host and device arrays, or arrays stacked already; one per part
    of the batch, the parts side by side) into a time-major `Transition` on the device; the value after a step
    is the next step's (the last one's: `last_value`, one array per part), or V(final
    observation) where the episode ended. The rewards are the training rewards of
    `normalize.scale_rewards` (`clip`: sign-clipped; never scaled here: this learner refuses
    `normalize_rewards`); the episode statistics stay the env's."""
    stacked = {name: jnp.concatenate([jnp.stack(steps) if isinstance(steps, list) else steps for steps in parts],
                                     axis=1)
               for name, parts in rollout.items()}
    value, done, terminated = stacked["value"], stacked["done"], stacked["terminated"]
    following = jnp.concatenate([value[1:], jnp.concatenate(last_value)[None]])
    info = {name: stacked[name] for name in EPISODE_KEYS}
    return Transition(
        obs=stacked["obs"],
        action=stacked["action"],
        log_prob=stacked["log_prob"],
        value=value,
        reward=normalize.scale_rewards(None, stacked["reward"], done, None, clip=clip)[1],
        done=done.astype(jnp.float32),
        next_value=bootstrap(jnp.where(done, stacked["final_value"], following), terminated),
        info=step_info(info, terminated),
    )
