"""What PPO and A2C share: the vmapped rollout, GAE with correct time limits, the training loop.

A learner is pure: `init(key, config) -> RunnerState` and `run(runner, config) -> (runner,
metrics)` run `num_updates` updates in one `lax.scan`, so `jax.jit(jax.vmap(train))(keys)` trains
many seeds at once. Config fields that change shapes (env count, rollout length, epochs,
minibatches, trunk) are static; the rest are traced and may be vmapped too.

Time limits: the value target bootstraps from the final observation of a truncated episode
(`info["final_observation"]`, from `AutoResetWrapper`) and not from a terminated one:
`next_value_t = (1 - terminated_t) * V(final_obs_t)`; the GAE trace is cut at every episode end.
Envs with the five-value step API of gymnax 0.x / PureJaxRL (`done` only) are supported; there
`done` counts as termination, as those libraries do.

Recurrent policies (`config.memory > 0`): each env's `Memory` (GRU state, previous action and
reward, episode start) rides in the runner and is stored per step in the rollout; the update
replays whole env rollouts from their first stored state (`replay`), so it sees the outputs the
rollout saw (to float tolerance: the trunk runs on a bigger batch). The final observation of a
truncated step is valued with the memory after that step, as if the episode went on.
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import optax
from flax import struct
from flax.training.train_state import TrainState

from jaxnat.agents import distributions
from jaxnat.agents.networks import Memory, init_params, initial_memory, make_actor_critic, one_step_sequence
from jaxnat.wrappers import LogWrapper


def static(default):
    """A config field that sets shapes or loop lengths: static under jit, not vmappable."""
    return struct.field(pytree_node=False, default=default)


class Transition(NamedTuple):
    obs: Any
    action: jax.Array  # [F] int32, one entry per action factor
    log_prob: jax.Array
    value: jax.Array
    reward: jax.Array
    done: jax.Array  # the episode ended (terminated or truncated): cuts the GAE trace
    next_value: jax.Array  # (1 - terminated) * V(final observation)
    info: dict
    # Recurrent policies: the `Memory` each step read; its `hidden` is only the state before the
    # rollout's first step, `[1, N, H]` (replay derives the rest).
    memory: Any = None


class RunnerState(NamedTuple):
    train_state: TrainState
    env_state: Any
    obs: Any
    key: jax.Array
    update: jax.Array  # updates done so far (int32)
    memory: Any = None  # recurrent policies: each env's `Memory` before its next step


class UpdateRule(NamedTuple):
    """An algorithm's parts that do not depend on how rollouts are collected: the jitted loop
    here and the host loop (`jaxnat.agents.host_loop`, for host-batched envs) share them."""

    make_optimizer: Callable  # (config, num_updates) -> optax.GradientTransformation
    update_step: Callable  # (config, network, train_state, transitions, advantages, targets, key)


class Learner(NamedTuple):
    """`train(key, config=config) -> (runner, metrics)`; `init`/`run` split it for chunked runs."""

    init: Callable
    run: Callable
    train: Callable
    network: Any
    num_updates: int


def gae(transitions: Transition, gamma, gae_lambda) -> tuple[jax.Array, jax.Array]:
    """Advantages and value targets over a `[T, ...]` rollout (time-major)."""

    def backward(carry, t: Transition):
        delta = t.reward + gamma * t.next_value - t.value
        advantage = delta + gamma * gae_lambda * (1.0 - t.done) * carry
        return advantage, advantage

    _, advantages = jax.lax.scan(
        backward, jnp.zeros_like(transitions.value[0]), transitions, reverse=True
    )
    return advantages, advantages + transitions.value


def _env_step(env, key, state, action, params):
    """-> (obs, state, reward, terminated, done, final_obs, info); `env` is a `LogWrapper`, which
    turns the five-value API into six values (without `final_observation`: done = terminated)."""
    obs, state, reward, terminated, truncated, info = env.step(key, state, action, params)
    final_obs = info.get("final_observation", obs)
    return obs, state, reward, terminated, terminated | truncated, final_obs, info


def act(network, params, obs, memory: Memory | None):
    """One step of the policy over a batch of envs: `(logits, value, hidden after the step)`;
    `memory` is None for a feed-forward network (hidden is then None too)."""
    if memory is None:
        return (*network.apply(params, obs), None)
    logits, value, hidden = network.apply(params, jax.tree_util.tree_map(lambda x: x[None], obs),
                                          one_step_sequence(memory))
    return jax.tree_util.tree_map(lambda x: x[0], logits), value[0], hidden


def replay(network, params, obs, memory: Memory | None):
    """`(logits, value)` of a stored rollout: `obs` `[T, B, ...]` and its per-step memory
    (`Transition.memory`, whose `hidden[0]` is the state before the first step), replayed so
    the recurrent policy's outputs are those the rollout saw; a feed-forward network reads any
    batch shape."""
    if memory is None:
        return network.apply(params, obs)
    logits, value, _ = network.apply(params, obs, memory._replace(hidden=memory.hidden[0]))
    return logits, value


def count_updates(config) -> int:
    """Updates in a run: `total_timesteps // (num_envs * num_steps)`, at least one."""
    total_updates = config.total_timesteps // (config.num_envs * config.num_steps)
    if total_updates < 1:
        raise ValueError(
            f"total_timesteps={config.total_timesteps} is less than one rollout "
            f"(num_envs * num_steps = {config.num_envs * config.num_steps})"
        )
    return total_updates


def vector_env(env) -> tuple[Callable, Callable]:
    """`(reset(keys, params), step(keys, states, actions, params))` over a batch of envs, with
    episode statistics (`LogWrapper`); `step` returns `_env_step`'s seven values."""
    env = LogWrapper(env)
    reset = jax.vmap(env.reset, in_axes=(0, None))
    step = jax.vmap(lambda k, s, a, p: _env_step(env, k, s, a, p), in_axes=(0, 0, 0, None))
    return reset, step


def make_learner(config, env, env_params, *, make_optimizer: Callable, update_step: Callable) -> Learner:
    """Build the shared training loop around an algorithm's optimizer and update.

    Args:
        config: the algorithm's config (static fields: num_envs, num_steps, total_timesteps,
            trunk, ...; traced: learning rate, gamma, ...).
        env, env_params: any env with the jaxnat/gymnax API; it should reset itself when an
            episode ends (`jaxnat.make` envs do).
        make_optimizer: `(config, num_updates) -> optax.GradientTransformation`.
        update_step: `(config, network, train_state, transitions, advantages, targets, key)
            -> (train_state, loss_metrics)`.
    """
    total_updates = count_updates(config)
    observation_space = env.observation_space(env_params)
    action_space = env.action_space(env_params)
    network = make_actor_critic(observation_space, action_space, config.trunk, network_dtype(config),
                                memory=getattr(config, "memory", 0))
    scalar_action = not hasattr(action_space, "nvec")  # Discrete (jaxnat's or gymnax's)

    reset, step = vector_env(env)

    def init(key, config=config) -> RunnerState:
        key, key_net, key_env = jax.random.split(key, 3)
        train_state = TrainState.create(
            apply_fn=network.apply,
            params=init_params(network, observation_space, key_net),
            tx=make_optimizer(config, total_updates),
        )
        obs, env_state = reset(jax.random.split(key_env, config.num_envs), env_params)
        memory = initial_memory(network, config.num_envs) if network.memory else None
        return RunnerState(train_state, env_state, obs, key, jnp.zeros((), jnp.int32), memory)

    def rollout_step(runner: RunnerState, _):
        train_state, env_state, obs, key, update, memory = runner
        key, key_act, key_env = jax.random.split(key, 3)
        logits, value, hidden = act(network, train_state.params, obs, memory)
        action = distributions.sample(key_act, logits)
        log_prob = distributions.log_prob(logits, action)
        env_action = action[..., 0] if scalar_action else action
        keys = jax.random.split(key_env, config.num_envs)
        next_obs, env_state, reward, terminated, done, final_obs, info = step(
            keys, env_state, env_action, env_params
        )
        # The value of the final observation, as if the episode went on (it bootstraps a
        # truncated step): a recurrent policy reads it after this step's memory.
        following = None if memory is None else Memory(hidden, action, reward.astype(jnp.float32), jnp.zeros_like(done))
        _, final_value, _ = act(network, train_state.params, final_obs, following)
        next_value = jnp.where(terminated, 0.0, final_value)
        transition = Transition(obs, action, log_prob, value, reward, done.astype(jnp.float32),
                                next_value, step_info(info, terminated),
                                None if memory is None else memory._replace(hidden=None))
        next_memory = None if memory is None else following._replace(start=done)
        return RunnerState(train_state, env_state, next_obs, key, update, next_memory), transition

    def update(runner: RunnerState, config):
        first_memory = runner.memory
        runner, transitions = jax.lax.scan(rollout_step, runner, None, config.num_steps)
        advantages, targets = gae(transitions, config.gamma, config.gae_lambda)
        if first_memory is not None:  # (after gae, which scans every field over time)
            transitions = transitions._replace(memory=transitions.memory._replace(hidden=first_memory.hidden[None]))
        key, key_update = jax.random.split(runner.key)
        train_state, losses = update_step(
            config, network, runner.train_state, transitions, advantages, targets, key_update
        )
        runner = runner._replace(train_state=train_state, key=key, update=runner.update + 1)
        return runner, {**episode_metrics(transitions.info), **losses}

    def run(runner: RunnerState, config=config, num_updates: int = total_updates, callback=None):
        return scan_updates(update, runner, config, num_updates, callback,
                            make_optimizer(config, total_updates))

    def train(key, config=config):
        return run(init(key, config), config)

    return Learner(init, run, train, network, total_updates)


def scan_updates(update: Callable, runner, config, num_updates: int, callback, tx):
    """`num_updates` times `update(runner, config) -> (runner, metrics)` in one `lax.scan`,
    calling `callback(update count, metrics)` on the host after each; `runner` is a NamedTuple
    with `train_state` and `update`.

    The optimizer `tx` closes over traced hyperparameters, so it is rebuilt from each call's
    config: chunked runs (init and run jitted separately) use their own, live values. The
    runner handed back keeps the caller's optimizer object (a static pytree field), so its
    structure matches the input and a compiled `run` can be fed its own output.
    """
    caller_tx = runner.train_state.tx
    runner = runner._replace(train_state=runner.train_state.replace(tx=tx))

    def body(runner, _):
        runner, metrics = update(runner, config)
        if callback is not None:
            jax.debug.callback(callback, runner.update, metrics)
        return runner, metrics

    runner, metrics = jax.lax.scan(body, runner, None, num_updates)
    return runner._replace(train_state=runner.train_state.replace(tx=caller_tx)), metrics


def step_info(info: dict, terminated) -> dict:
    """What `episode_metrics` needs from one vector step."""
    return {
        "returned_episode": info["returned_episode"],
        "returned_episode_returns": info["returned_episode_returns"],
        "returned_episode_lengths": info["returned_episode_lengths"],
        "terminated": terminated,
    }


def episode_metrics(info: dict) -> dict:
    """Means over the episodes that ended in this rollout (NaN when none did)."""
    ended = info["returned_episode"]
    count = jnp.sum(ended)

    def mean(x):
        return jnp.where(count > 0, jnp.sum(jnp.where(ended, x, 0.0)) / jnp.maximum(count, 1), jnp.nan)

    # A terminated episode ended by the env's own rule (classification: the right label).
    return {
        "episode_return": mean(info["returned_episode_returns"]),
        "episode_length": mean(info["returned_episode_lengths"].astype(jnp.float32)),
        "terminated_fraction": mean(info["terminated"].astype(jnp.float32)),
        "episodes": count,
    }


def network_dtype(config) -> str:
    """The trunk's computation dtype: the config's `dtype` field (PPO, A2C), else float32
    (ACKTR's K-FAC statistics want float32 layer inputs)."""
    return getattr(config, "dtype", "float32")


def clipped_optimizer(max_grad_norm, optimizer: optax.GradientTransformation):
    return optax.chain(optax.clip_by_global_norm(max_grad_norm), optimizer)
