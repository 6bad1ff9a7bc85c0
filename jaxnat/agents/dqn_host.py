"""DQN on a host-batched env (Natural Atari): `dqn.py`'s pieces (`DQNParts`) driven from the
host loop of `jaxnat.agents.rollout.host`. One seed per learner (no `seeds=`): `jaxnat train`
trains DQN's seeds one after another, where the on-policy learners train them side by side."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from jaxnat.agents.dqn import DQNConfig, DQNState, epsilon, learning_on, make_dqn_parts, step_callbacks
from jaxnat.agents.rollout import HostLearner, check_host_batch, episode_metrics, host_steps, host_updates

__all__ = ["make_host_dqn"]


def make_host_dqn(config: DQNConfig, env, compiler_options: dict | None = None) -> HostLearner:
    """The host-loop DQN learner on a batched host env (`rollout.host_steps`): per env step one
    jitted epsilon-greedy call and one jitted `store` into the device buffer (donated: updated
    in place); per update one jitted `learn`. The replay buffer lives on the device
    (`buffer_size` x 2 observations: for 84x84x4 Atari frames 56 KB per transition, 5.6 GB at
    the default 100k)."""
    num_updates = check_host_batch(config, env)
    parts = make_dqn_parts(config, env.single_observation_space, env.single_action_space)
    jit = functools.partial(jax.jit, compiler_options=compiler_options)
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
        policy, observe = step_callbacks(config, index * config.num_steps, act, store, exploration)
        (state, obs, key), records = host_steps(env, config.num_steps, policy, observe, state, obs, key)
        key, key_learn = jax.random.split(key)
        state, metrics = learn(state, key_learn, learning_on(config, index), [info for info, _ in records])
        return state, obs, key, {**metrics, "epsilon": records[-1][1]}

    return host_updates(env, parts.network, num_updates, init, update, lambda s: s.learner.train_state.params, jit)
