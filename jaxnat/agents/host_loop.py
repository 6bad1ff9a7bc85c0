"""Training on host-batched envs (`NaturalAtari/*`): a Python loop around jitted policy and
update functions, for PPO and A2C (on-policy) and DQN.

    env = jaxnat.make_vec("NaturalAtari/Breakout-v0", 8, background="video")
    learner = make_host_learner(PPOConfig(total_timesteps=100_000), env, ppo.RULE)
    learner = make_host_dqn(DQNConfig(total_timesteps=100_000), env)     # or DQN
    state, history = learner.train(jax.random.key(0))
    state, history = learner.run(state, num_updates=...)                 # continue (a checkpoint)

The env steps on the host (the emulator is C++), so the rollout cannot be a `lax.scan`; every
thing else is the jitted learners': the network (`networks.make_actor_critic`), GAE with
time-limit bootstrapping and the episode metrics (`on_policy`), the algorithm's optimizer and
update (`UpdateRule`: `ppo.RULE`, `a2c.RULE`), and DQN's act/store/learn (`dqn.DQNParts`: the
replay buffer, n-step returns and target network live on the device as in the jitted DQN).

On-policy, per env step: one jitted policy call on the device (observations in, actions back
to the host), and one value call on final observations when an episode ended; per update the
rollout goes to the device once and one jitted update runs. DQN, per env step: one jitted
epsilon-greedy call and one jitted `store` into the device buffer (donated: updated in place);
per update one jitted `learn` (`gradient_steps` TD steps). The env's `info` must carry
`final_observation` and PureJaxRL's episode keys, as `NaturalAtariVecEnv` does (same-step
autoreset).

Bootstrapping: `next_value_t = (1 - terminated_t) * V(final observation_t)`, where the final
observation is the next observation unless the episode ended; a truncated game (time limit)
bootstraps from its last observation, a terminated one does not.

State: `HostState(learner, key, update)` is everything a run needs to go on besides the env
(params and optimizer state; for DQN also the target network and replay buffer), a pytree that
checkpoints as a whole. `run(state)` resets the env (seeded from the state's key) and continues
the update count and key stream from there; an emulator's state cannot be saved, so a resumed
run starts new games.
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
from jaxnat.agents.dqn import DQNConfig, DQNState, epsilon, make_dqn_parts
from jaxnat.agents.networks import init_params, make_actor_critic
from jaxnat.agents.on_policy import Transition, UpdateRule, count_updates, episode_metrics, gae, network_dtype

__all__ = ["HostState", "HostLearner", "make_host_learner", "make_host_dqn", "evaluate_host"]

_EPISODE_KEYS = ("returned_episode", "returned_episode_returns", "returned_episode_lengths")


class HostState(NamedTuple):
    """A host run's state apart from the env: a pytree (what a checkpoint holds)."""

    learner: Any  # TrainState (PPO, A2C) or dqn.DQNState
    key: jax.Array
    update: jax.Array  # updates done (int32)


class HostLearner(NamedTuple):
    """`train(key) -> (state, history)`, `run(state) -> (state, history)` and their parts."""

    init: Callable  # key -> HostState at update 0
    run: Callable  # (state, num_updates=None, callback=None) -> (state, history)
    train: Callable  # (key, num_updates=None, callback=None) -> (state, history)
    params: Callable  # state -> the network's params
    greedy: Callable  # jitted (params, obs, key) -> the most likely action [B, F]
    sample: Callable  # jitted (params, obs, key) -> an action sampled from the policy [B, F]
    network: Any
    num_updates: int


def _check(config, env) -> int:
    """The run's update count; `config.num_envs` must equal `env.num_envs`."""
    if config.num_envs != env.num_envs:
        raise ValueError(f"config.num_envs={config.num_envs} but the env has {env.num_envs} envs")
    if getattr(config, "memory", 0):
        raise ValueError(f"memory={config.memory}: recurrent policies train on jitted envs only; a host-batched env "
                         "(Natural Atari) takes a feed-forward policy (memory=0) and frame stacking")
    return count_updates(config)


def _host_learner(env, network, num_updates: int, init_learner: Callable, update: Callable,
                  params: Callable, jit: Callable) -> HostLearner:
    """The loop both kinds of learner share. `update(learner, obs, key, update_index) ->
    (learner, obs, key, metrics)` does one update's env steps and learning."""

    @jit
    def greedy(params, obs, key):
        del key  # the same signature as sample's
        return distributions.mode(network.apply(params, obs)[0])

    @jit
    def sample(params, obs, key):
        return distributions.sample(key, network.apply(params, obs)[0])

    def init(key) -> HostState:
        key, key_init = jax.random.split(key)
        return HostState(init_learner(key_init), key, jnp.zeros((), jnp.int32))

    def run(state: HostState, num_updates: int = num_updates, callback=None):
        """Updates `state.update + 1 .. num_updates` on freshly reset envs;
        `callback(state, metrics, seconds)` after every update."""
        key, key_env = jax.random.split(state.key)
        obs, _ = env.reset(seed=int(jax.random.randint(key_env, (), 0, 2**31 - 1)))
        learner, history = state.learner, []
        for index in range(int(state.update), num_updates):
            start = time.perf_counter()
            learner, obs, key, metrics = update(learner, obs, key, index)
            metrics = {k: float(v) for k, v in jax.device_get(metrics).items()}
            history.append(metrics)
            state = HostState(learner, key, jnp.asarray(index + 1, jnp.int32))
            if callback is not None:
                callback(state, metrics, time.perf_counter() - start)
        return state, history

    def train(key, num_updates: int = num_updates, callback=None):
        """Train from scratch."""
        return run(init(key), num_updates, callback)

    return HostLearner(init, run, train, params, greedy, sample, network, num_updates)


def _jit(compiler_options):
    return functools.partial(jax.jit, compiler_options=compiler_options)


def make_host_learner(config, env, rule: UpdateRule, compiler_options: dict | None = None
                      ) -> HostLearner:
    """The host-loop learner for `config` (a `PPOConfig` or `A2CConfig`) on a batched host env.

    `config.num_envs` must equal `env.num_envs` (the env is built with its batch size).
    `compiler_options`: XLA options for every jitted function, e.g.
    `{"xla_backend_optimization_level": 0}` (compiles much faster on CPU).
    """
    num_updates = _check(config, env)
    observation_space = env.single_observation_space
    network = make_actor_critic(observation_space, env.single_action_space, config.trunk, network_dtype(config))
    scalar_action = not hasattr(env.single_action_space, "nvec")
    jit = _jit(compiler_options)

    @jit
    def act(params, obs, key):
        logits, value = network.apply(params, obs)
        action = distributions.sample(key, logits)
        return action, distributions.log_prob(logits, action), value

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

    def update(train_state, obs, key, index):
        del index  # on-policy updates do not depend on the update count (schedules are in the optimizer)
        transitions, obs, key = collect(train_state, obs, key)
        key, key_update = jax.random.split(key)
        train_state, metrics = learn(train_state, transitions, key_update)
        return train_state, obs, key, metrics

    return _host_learner(env, network, num_updates, init, update, lambda s: s.learner.params, jit)


def make_host_dqn(config: DQNConfig, env, compiler_options: dict | None = None) -> HostLearner:
    """The host-loop DQN learner (`jaxnat.agents.dqn`'s pieces) on a batched host env; the
    replay buffer lives on the device (`buffer_size` x 2 observations: for 84x84x4 Atari
    frames 56 KB per transition, 5.6 GB at the default 100k)."""
    num_updates = _check(config, env)
    parts = make_dqn_parts(config, env.single_observation_space, env.single_action_space)
    scalar_action = not hasattr(env.single_action_space, "nvec")
    jit = _jit(compiler_options)
    act = jit(parts.act)
    # On the device, without a host sync: the rate goes straight into `act`.
    exploration = jit(lambda env_steps: epsilon(config, env_steps))
    store = jit(parts.store, donate_argnums=0)  # the buffer is updated in place

    @functools.partial(jit, donate_argnums=0)
    def learn(state: DQNState, key, learning, infos: list):
        state, losses = parts.learn(state, key, learning)
        infos = jax.tree.map(lambda *steps: jnp.stack(steps), *infos)
        return state, {**episode_metrics(infos), **losses}

    space = env.single_observation_space

    @jit
    def init(key) -> DQNState:
        return parts.init(key, jnp.zeros((config.num_envs, *space.shape), space.dtype))

    def update(state: DQNState, obs, key, index):
        infos = []
        for t in range(config.num_steps):
            steps_taken = index * config.num_steps + t  # per env, before this step
            rate = exploration(steps_taken * config.num_envs)
            key, key_act = jax.random.split(key)
            obs_device = jax.device_put(obs)
            action = np.asarray(act(state.train_state.params, obs_device, key_act, rate))
            next_obs, reward, terminated, truncated, info = env.step(
                action[:, 0] if scalar_action else action)
            state = store(state, {
                "obs": obs_device, "action": action, "reward": reward,
                "next_obs": info.get("final_observation", next_obs), "terminated": terminated,
                "done": terminated | truncated,
            }, steps_taken)
            infos.append({**{name: info[name] for name in _EPISODE_KEYS}, "terminated": terminated})
            obs = next_obs
        key, key_learn = jax.random.split(key)
        learning = (index + 1) * config.num_steps * config.num_envs >= config.learning_starts
        state, metrics = learn(state, key_learn, learning, infos)
        return state, obs, key, {**metrics, "epsilon": rate}

    return _host_learner(env, parts.network, num_updates, init, update,
                         lambda s: s.learner.train_state.params, jit)


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
    policy = learner.greedy if greedy else learner.sample
    obs, _ = env.reset()
    returns: list[float] = []
    while len(returns) < num_episodes:
        key, key_act = jax.random.split(key)
        action = np.asarray(policy(params, jax.device_put(obs), key_act))
        obs, _, _, _, info = env.step(action[:, 0] if scalar_action else action)
        returns.extend(info["returned_episode_returns"][info["returned_episode"]].tolist())
    return np.asarray(returns[:num_episodes], np.float32)
