"""DQN (Mnih et al. 2015, "Nature DQN"), fully jitted: envs, replay buffer and learner on the
device, vmappable over seeds like `ppo.py`.

    learner = make_dqn(DQNConfig(total_timesteps=1_000_000), env, params)
    runner, metrics = jax.jit(jax.vmap(learner.train))(jax.random.split(jax.random.key(0), 5))

One update: `num_steps` epsilon-greedy steps of `num_envs` envs go into the replay buffer,
then `gradient_steps` Huber-loss steps on minibatches of `batch_size` sampled uniformly from it
(none before `learning_starts` env steps); the target network copies the online one every
`target_update_period` gradient steps. `double_dqn` picks the next action with the online
network and values it with the target one (van Hasselt et al. 2016).

Settings: Nature DQN's (RMSprop lr 2.5e-4, decay 0.95, eps 0.01 (centered, as DeepMind's),
batch 32, gamma 0.99, epsilon 1.0 -> 0.1, one gradient step per 4 env steps, Huber loss),
with the replay memory, exploration period, learning start and target period 10x shorter
(100k, 100k, 10k env steps; 1k gradient steps) since the paper's tasks train for 1-10M steps
rather than Atari's 50M. `optimizer="adam"` uses Adam (eps 1.5e-4, as Dopamine's DQN).
Time limits: the target bootstraps from the final observation of a truncated episode and not
from a terminated one, as in `on_policy.py`.

Factored actions (classification's move and label): one Q head per factor over the shared
trunk ("action branching", Tavakoli et al. 2018) rather than one head over the product space;
every head learns towards the same target, whose next-state value is the mean over the heads
of each head's best value, `r + gamma * mean_f max_a Q_f(s', a)`. The network is jaxnat's
actor-critic whose "logits" are the Q values (its value head is unused), so evaluation's
greedy policy is `argmax Q` per factor (its "sampled" policy is a Boltzmann one over Q).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax
from flax import struct
from flax.training.train_state import TrainState

from jaxnat.agents import distributions
from jaxnat.agents.networks import init_params, make_actor_critic
from jaxnat.agents.on_policy import (Learner, count_updates, episode_metrics, scan_updates, static,
                                     step_info, vector_env)
from jaxnat.agents.replay import ReplayBuffer, replay_add, replay_init, replay_sample

__all__ = ["DQNConfig", "DQNRunner", "epsilon", "make_dqn", "make_train"]

OPTIMIZERS = ("rmsprop", "adam")


@struct.dataclass
class DQNConfig:
    total_timesteps: int = static(1_000_000)
    num_envs: int = static(8)
    num_steps: int = static(4)  # env steps per env per update
    gradient_steps: int = static(8)  # per update: one per 4 env steps with the defaults
    batch_size: int = static(32)
    buffer_size: int = static(100_000)
    optimizer: str = static("rmsprop")
    double_dqn: bool = static(False)
    trunk: str | None = static(None)
    lr: float = 2.5e-4
    rms_decay: float = 0.95
    rms_eps: float = 0.01
    adam_eps: float = 1.5e-4
    gamma: float = 0.99
    eps_start: float = 1.0
    eps_end: float = 0.1
    exploration_steps: int = 100_000  # env steps (per seed) of the linear epsilon decay
    learning_starts: int = 10_000  # env steps (per seed) before the first gradient step
    target_update_period: int = 1_000  # gradient steps


class DQNRunner(NamedTuple):
    train_state: TrainState  # online network; `step` counts gradient steps taken
    target_params: Any
    buffer: ReplayBuffer
    env_state: Any
    obs: Any
    key: jax.Array
    update: jax.Array  # updates done so far (int32)


def epsilon(config: DQNConfig, env_steps):
    """Exploration rate after `env_steps` env steps (per seed): linear from `eps_start` to
    `eps_end` over `exploration_steps`, then constant."""
    done = jnp.clip(env_steps / jnp.maximum(config.exploration_steps, 1), 0.0, 1.0)
    return config.eps_start + (config.eps_end - config.eps_start) * done


def _optimizer(config: DQNConfig):
    if config.optimizer == "rmsprop":
        return optax.rmsprop(config.lr, decay=config.rms_decay, eps=config.rms_eps, centered=True)
    if config.optimizer == "adam":
        return optax.adam(config.lr, eps=config.adam_eps)
    raise ValueError(f"DQN optimizer {config.optimizer!r} is not one of {OPTIMIZERS}")


def td_loss(config: DQNConfig, network, params, target_params, batch) -> tuple[jax.Array, dict]:
    """Mean Huber loss over the batch and the action factors."""
    q, _ = network.apply(params, batch["obs"])
    q_next, _ = network.apply(target_params, batch["next_obs"])
    if config.double_dqn:
        online_next, _ = network.apply(params, batch["next_obs"])
        best = distributions.mode(online_next)
        next_values = [jnp.take_along_axis(qf, best[:, f : f + 1], -1)[:, 0] for f, qf in enumerate(q_next)]
    else:
        next_values = [qf.max(-1) for qf in q_next]
    next_value = jnp.mean(jnp.stack(next_values), axis=0)
    target = batch["reward"] + config.gamma * (1.0 - batch["terminated"]) * next_value
    target = jax.lax.stop_gradient(target)
    taken = [jnp.take_along_axis(qf, batch["action"][:, f : f + 1], -1)[:, 0] for f, qf in enumerate(q)]
    errors = jnp.stack(taken) - target
    loss = optax.huber_loss(errors, delta=1.0).mean()
    return loss, {"loss": loss, "q_mean": jnp.stack(taken).mean()}


def make_dqn(config: DQNConfig, env, env_params) -> Learner:
    """The DQN learner (`init`, `run`, `train`, `network`, `num_updates`)."""
    total_updates = count_updates(config)
    if config.optimizer not in OPTIMIZERS:
        raise ValueError(f"DQN optimizer {config.optimizer!r} is not one of {OPTIMIZERS}")
    if config.buffer_size < config.num_envs:
        raise ValueError(f"buffer_size={config.buffer_size} is smaller than one env step of "
                         f"num_envs={config.num_envs} envs")
    observation_space = env.observation_space(env_params)
    action_space = env.action_space(env_params)
    network = make_actor_critic(observation_space, action_space, config.trunk)
    dims = network.action_dims
    scalar_action = not hasattr(action_space, "nvec")
    reset, step = vector_env(env)

    def init(key, config=config) -> DQNRunner:
        key, key_net, key_env = jax.random.split(key, 3)
        params = init_params(network, observation_space, key_net)
        train_state = TrainState.create(apply_fn=network.apply, params=params, tx=_optimizer(config))
        obs, env_state = reset(jax.random.split(key_env, config.num_envs), env_params)
        item = {
            "obs": jax.tree.map(lambda x: x[0], obs),
            "action": jnp.zeros(len(dims), jnp.int32),
            "reward": jnp.zeros((), jnp.float32),
            "next_obs": jax.tree.map(lambda x: x[0], obs),
            "terminated": jnp.zeros((), jnp.float32),
        }
        buffer = replay_init(item, config.buffer_size)
        return DQNRunner(train_state, params, buffer, env_state, obs, key, jnp.zeros((), jnp.int32))

    def act(params, obs, key, rate):
        key_explore, *keys = jax.random.split(key, 1 + len(dims))
        q, _ = network.apply(params, obs)
        greedy = distributions.mode(q)
        random = jnp.stack([jax.random.randint(k, greedy.shape[:1], 0, n) for k, n in zip(keys, dims)], -1)
        explore = jax.random.uniform(key_explore, greedy.shape[:1]) < rate
        return jnp.where(explore[:, None], random, greedy).astype(jnp.int32)

    def env_step(carry, t, config):
        runner, first_step = carry
        key, key_act, key_env = jax.random.split(runner.key, 3)
        rate = epsilon(config, (first_step + t) * config.num_envs)
        action = act(runner.train_state.params, runner.obs, key_act, rate)
        env_action = action[..., 0] if scalar_action else action
        next_obs, env_state, reward, terminated, done, final_obs, info = step(
            jax.random.split(key_env, config.num_envs), runner.env_state, env_action, env_params
        )
        buffer = replay_add(runner.buffer, {
            "obs": runner.obs, "action": action, "reward": reward.astype(jnp.float32),
            "next_obs": final_obs, "terminated": terminated.astype(jnp.float32),
        })
        runner = runner._replace(buffer=buffer, env_state=env_state, obs=next_obs, key=key)
        return (runner, first_step), (step_info(info, terminated), rate)

    def gradient_step(carry, key, config, learning):
        train_state, target_params, buffer = carry
        batch = replay_sample(buffer, key, config.batch_size)
        grads, losses = jax.grad(
            lambda p: td_loss(config, network, p, target_params, batch), has_aux=True
        )(train_state.params)
        stepped = train_state.apply_gradients(grads=grads)
        train_state = jax.tree.map(lambda new, old: jnp.where(learning, new, old), stepped, train_state)
        copy = learning & (train_state.step % config.target_update_period == 0)
        target_params = jax.tree.map(lambda p, t: jnp.where(copy, p, t), train_state.params, target_params)
        return (train_state, target_params, buffer), losses

    def update(runner: DQNRunner, config):
        first_step = runner.update * config.num_steps
        (runner, _), (infos, rates) = jax.lax.scan(
            lambda c, t: env_step(c, t, config), (runner, first_step), jnp.arange(config.num_steps)
        )
        env_steps = (first_step + config.num_steps) * config.num_envs
        learning = env_steps >= config.learning_starts
        key, key_learn = jax.random.split(runner.key)
        (train_state, target_params, _), losses = jax.lax.scan(
            lambda c, k: gradient_step(c, k, config, learning),
            (runner.train_state, runner.target_params, runner.buffer),
            jax.random.split(key_learn, config.gradient_steps),
        )
        runner = runner._replace(train_state=train_state, target_params=target_params, key=key,
                                 update=runner.update + 1)
        metrics = {**episode_metrics(infos), **jax.tree.map(jnp.mean, losses), "epsilon": rates[-1]}
        return runner, metrics

    def run(runner: DQNRunner, config=config, num_updates: int = total_updates, callback=None):
        return scan_updates(update, runner, config, num_updates, callback, _optimizer(config))

    def train(key, config=config):
        return run(init(key, config), config)

    return Learner(init, run, train, network, total_updates)


def make_train(config: DQNConfig, env, env_params):
    """`train(key, config=config) -> (runner, metrics)`, pure and jittable."""
    return make_dqn(config, env, env_params).train
