"""On-policy training (PPO, A2C) on host-batched envs (`NaturalAtari/*`): a Python loop around
jitted policy and update functions.

    env = jaxnat.make_vec("NaturalAtari/Breakout-v0", 8, background="video")
    learner = make_host_learner(PPOConfig(total_timesteps=100_000), env, ppo.RULE)
    train_state, history = learner.train(jax.random.key(0))

The env steps on the host (the emulator is C++), so the rollout cannot be a `lax.scan`; every
thing else is the jitted learner's: the network (`networks.make_actor_critic`), GAE with
time-limit bootstrapping and the episode metrics (`on_policy`), and the algorithm's optimizer and
update (`UpdateRule`: `ppo.RULE`, `a2c.RULE`). Per env step: one jitted policy call on the
device (observations in, actions back to the host), and one value call on final observations
when an episode ended. Per update: the rollout goes to the device once and one jitted update
runs. The env's `info` must carry `final_observation` and PureJaxRL's episode keys, as
`NaturalAtariVecEnv` does (same-step autoreset).

Bootstrapping: `next_value_t = (1 - terminated_t) * V(final observation_t)`, where the final
observation is the next observation unless the episode ended; a truncated game (time limit)
bootstraps from its last observation, a terminated one does not.
"""

from __future__ import annotations

import functools
import time
from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax.training.train_state import TrainState

from jaxnat.agents import distributions
from jaxnat.agents.networks import init_params, make_actor_critic
from jaxnat.agents.on_policy import Transition, UpdateRule, episode_metrics, gae

__all__ = ["HostLearner", "make_host_learner", "evaluate_host"]

_EPISODE_KEYS = ("returned_episode", "returned_episode_returns", "returned_episode_lengths")


class HostLearner(NamedTuple):
    """`train(key, num_updates=None, callback=None) -> (train_state, history)`, and its parts."""

    init: Callable  # key -> TrainState
    act: Callable  # jitted (params, obs, key) -> (action [B, F], log_prob, value)
    greedy: Callable  # jitted (params, obs, key) -> the most likely action [B, F]
    collect: Callable  # (train_state, obs, key) -> (Transition on the device, next obs, key)
    learn: Callable  # jitted (train_state, transitions, key) -> (train_state, metrics)
    train: Callable
    network: Any
    num_updates: int


def make_host_learner(config, env, rule: UpdateRule, compiler_options: dict | None = None
                      ) -> HostLearner:
    """The host-loop learner for `config` (a `PPOConfig` or `A2CConfig`) on a batched host env.

    `config.num_envs` must equal `env.num_envs` (the env is built with its batch size).
    `compiler_options`: XLA options for every jitted function, e.g.
    `{"xla_backend_optimization_level": 0}` (compiles much faster on CPU).
    """
    if config.num_envs != env.num_envs:
        raise ValueError(f"config.num_envs={config.num_envs} but the env has {env.num_envs} envs")
    num_updates = config.total_timesteps // (config.num_envs * config.num_steps)
    if num_updates < 1:
        raise ValueError(
            f"total_timesteps={config.total_timesteps} is less than one rollout "
            f"(num_envs * num_steps = {config.num_envs * config.num_steps})"
        )
    observation_space = env.single_observation_space
    network = make_actor_critic(observation_space, env.single_action_space, config.trunk)
    scalar_action = not hasattr(env.single_action_space, "nvec")
    jit = functools.partial(jax.jit, compiler_options=compiler_options)

    @jit
    def act(params, obs, key):
        logits, value = network.apply(params, obs)
        action = distributions.sample(key, logits)
        return action, distributions.log_prob(logits, action), value

    @jit
    def greedy(params, obs, key):
        del key  # the same signature as act's first output
        return distributions.mode(network.apply(params, obs)[0])

    @jit
    def value_of(params, obs):
        return network.apply(params, obs)[1]

    @jit
    def learn(train_state, transitions: Transition, key):
        advantages, targets = gae(transitions, config.gamma, config.gae_lambda)
        train_state, losses = rule.update_step(
            config, network, train_state, transitions, advantages, targets, key
        )
        return train_state, {**episode_metrics(transitions.info), **losses}

    @jit  # one compiled program, not hundreds of small eager ones
    def init(key) -> TrainState:
        return TrainState.create(
            apply_fn=network.apply,
            params=init_params(network, observation_space, key),
            tx=rule.make_optimizer(config, num_updates),
        )

    def collect(train_state, obs, key):
        """`config.num_steps` steps of every env; the rollout as one device pytree."""
        steps, params = config.num_steps, train_state.params
        rollout = {name: [] for name in ("obs", "action", "log_prob", "value", "reward", "done",
                                         "terminated", "final_value", *_EPISODE_KEYS)}
        obs_device = jax.device_put(obs)
        for _ in range(steps):
            key, key_act = jax.random.split(key)
            action, log_prob, value = act(params, obs_device, key_act)
            host_action = np.asarray(action)
            next_obs, reward, terminated, truncated, info = env.step(
                host_action[:, 0] if scalar_action else host_action
            )
            done = terminated | truncated
            next_obs_device = jax.device_put(next_obs)
            # V(final observation) where an episode ended; elsewhere the next step's value serves.
            final_value = (value_of(params, jax.device_put(info["final_observation"]))
                           if done.any() else np.zeros(config.num_envs, np.float32))
            for name, x in (("obs", obs_device), ("action", action), ("log_prob", log_prob),
                            ("value", value), ("reward", reward), ("done", done),
                            ("terminated", terminated), ("final_value", final_value)):
                rollout[name].append(x)
            for name in _EPISODE_KEYS:
                rollout[name].append(info[name])
            obs, obs_device = next_obs, next_obs_device
        last_value = value_of(params, obs_device)
        return _transitions(rollout, last_value), obs, key

    def train(key, num_updates: int = num_updates, callback=None):
        """Train from scratch; `callback(update, metrics, seconds)` after every update."""
        key, key_init, key_env = jax.random.split(key, 3)
        train_state = init(key_init)
        seed = int(jax.random.randint(key_env, (), 0, 2**31 - 1))
        obs, _ = env.reset(seed=seed)
        history = []
        for update in range(num_updates):
            start = time.perf_counter()
            transitions, obs, key = collect(train_state, obs, key)
            key, key_update = jax.random.split(key)
            train_state, metrics = learn(train_state, transitions, key_update)
            metrics = {k: float(v) for k, v in jax.device_get(metrics).items()}
            history.append(metrics)
            if callback is not None:
                callback(update + 1, metrics, time.perf_counter() - start)
        return train_state, history

    return HostLearner(init, act, greedy, collect, learn, train, network, num_updates)


@jax.jit
def _transitions(rollout: dict, last_value) -> Transition:
    """Stack the per-step lists (host and device arrays) into a time-major `Transition` on the
    device and bootstrap the values."""
    stacked = {name: jnp.stack(steps) for name, steps in rollout.items()}
    value, done, terminated = stacked["value"], stacked["done"], stacked["terminated"]
    next_value = jnp.concatenate([value[1:], last_value[None]])
    next_value = jnp.where(done, stacked["final_value"], next_value)
    next_value = jnp.where(terminated, 0.0, next_value)
    info = {name: stacked[name] for name in _EPISODE_KEYS}
    info["terminated"] = terminated
    return Transition(
        obs=stacked["obs"],
        action=stacked["action"],
        log_prob=stacked["log_prob"],
        value=value,
        reward=stacked["reward"].astype(jnp.float32),
        done=done.astype(jnp.float32),
        next_value=next_value,
        info=info,
    )


def evaluate_host(learner: HostLearner, params, env, num_episodes: int, key,
                  greedy: bool = False) -> np.ndarray:
    """Whole-game returns (unclipped) of the first `num_episodes` games that end, with the
    learner's policy sampled (or greedy); every env of `env` plays until enough have ended. The
    learner's jitted functions are reused (nothing new to compile)."""
    scalar_action = not hasattr(env.single_action_space, "nvec")
    obs, _ = env.reset()
    returns: list[float] = []
    while len(returns) < num_episodes:
        key, key_act = jax.random.split(key)
        obs_device = jax.device_put(obs)
        action = (learner.greedy(params, obs_device, key_act) if greedy
                  else learner.act(params, obs_device, key_act)[0])
        action = np.asarray(action)
        obs, _, _, _, info = env.step(action[:, 0] if scalar_action else action)
        returns.extend(info["returned_episode_returns"][info["returned_episode"]].tolist())
    return np.asarray(returns[:num_episodes], np.float32)
