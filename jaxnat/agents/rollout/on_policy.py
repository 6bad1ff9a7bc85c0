"""The jitted on-policy learner (PPO, A2C, ACKTR): a `lax.scan` of updates, each a rollout of
every env (`scan.scan_steps`), GAE, then the algorithm's `UpdateRule.update_step`.

- **Recurrent policies** (`memory > 0`): each env's `Memory` rides in the runner; the update
  replays whole env rollouts from their first stored state (`policy.replay`), so it sees the
  outputs the rollout saw (to float tolerance: the trunk runs on a bigger batch). The final
  observation of a truncated step is valued with the memory after that step.
- **Data parallel** (`axis_name`, PPO and A2C): inside a `jax.shard_map` over a mesh axis
  (`parallel.py`); 1, 2, 4 ... devices train the same parameters to float tolerance.
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
from flax.training.train_state import TrainState

from jaxnat.agents import distributions, normalize
from jaxnat.agents.config import check_ranges
from jaxnat.agents.networks import Memory, init_params, initial_memory, make_actor_critic
from jaxnat.agents.rollout.parallel import pmean_gradients, shard_slice
from jaxnat.agents.rollout.policy import act, final_value, sample_each
from jaxnat.agents.rollout.records import EnvStep, Transition, bootstrap, count_updates, episode_metrics, gae, step_info
from jaxnat.agents.rollout.scan import Learner, scan_learner, scan_steps, vector_env
from jaxnat.gating import compact_sizes, put_rows, switch_rows, take_rows

__all__ = ["RunnerState", "UpdateRule", "dtype_and_memory", "on_policy_learner"]

# The share of a batch whose final observations are valued in a compacted network call (the
# truncated rows; `act_and_value_final`): a batch in which more truncate at once (envs that
# started together reaching their time limit) values every row.
FINAL_VALUE_SHARE = 0.125


class RunnerState(NamedTuple):
    train_state: TrainState
    env_state: Any
    obs: Any
    key: jax.Array
    update: jax.Array  # updates done so far (int32)
    memory: Any = None  # recurrent policies: each env's `Memory` before its next step
    normalizer: Any = None  # `normalize.Normalizer` when observations or rewards are normalised


class UpdateRule(NamedTuple):
    """An on-policy algorithm's parts that do not depend on how rollouts are collected."""

    make_optimizer: Callable  # (config, num_updates) -> optax.GradientTransformation
    update_step: Callable  # (config, network, train_state, transitions, advantages, targets, key)
    # `update_step` takes `axis_name=` and trains data parallel inside a shard_map (its
    # gradient is a mean over the batch, made whole by `pmean_gradients`).
    data_parallel: bool = False
    # config -> keyword arguments of `networks.make_actor_critic` beyond the trunk
    # (`dtype_and_memory` for configs that have those fields)
    network_options: Callable = lambda config: {}

    def train_state(self, config, network, observation_space, num_updates: int, key) -> TrainState:
        """Fresh parameters and optimizer state for a run of `num_updates` updates."""
        return TrainState.create(apply_fn=network.apply, params=init_params(network, observation_space, key),
                                 tx=self.make_optimizer(config, num_updates))

    def averaged(self, axis_name) -> UpdateRule:
        """This rule trained data parallel over `axis_name`: its optimizer applies the devices'
        mean gradient (`pmean_gradients`); a `ValueError` for a rule that cannot."""
        if not self.data_parallel:
            raise ValueError("this algorithm does not train data parallel (its update needs the whole batch "
                             "on one device): place whole seeds on devices, or leave devices out")
        make_optimizer = self.make_optimizer
        return self._replace(make_optimizer=lambda config, num_updates: pmean_gradients(
            make_optimizer(config, num_updates), axis_name))

    def learn(self, config, network, train_state: TrainState, transitions: Transition, key, axis_name=None):
        """One update on a rollout, as both drivers make it: GAE, then `update_step`. Returns
        `(train_state, metrics)`: the episode metrics and the losses. With `axis_name` (inside
        a shard_map) the rollout is this device's envs and the metrics are the whole batch's."""
        advantages, targets = gae(transitions, config.gamma, config.gae_lambda)
        if axis_name is None:
            train_state, losses = self.update_step(config, network, train_state, transitions, advantages, targets,
                                                   key)
        else:
            local = config.replace(num_envs=transitions.reward.shape[1])
            train_state, losses = self.update_step(local, network, train_state, transitions, advantages, targets,
                                                   key, axis_name=axis_name)
            losses = jax.lax.pmean(losses, axis_name)
        return train_state, {**episode_metrics(transitions.info, axis_name), **losses}


def dtype_and_memory(config) -> dict:
    """`UpdateRule.network_options` of a config with `dtype` and `memory` fields (PPO's, A2C's)."""
    return {"dtype": config.dtype, "memory": config.memory}


def _stack_batches(a, b):
    """Two batches of observations (pytrees alike) as one: `a`'s rows, then `b`'s."""
    return jax.tree_util.tree_map(lambda x, y: jnp.concatenate([x, y]), a, b)


def on_policy_learner(config, env, env_params, rule: UpdateRule, axis_name=None,
                      final_value_share: float | tuple[float, ...] | None = FINAL_VALUE_SHARE) -> Learner:
    """The jitted on-policy learner: a `lax.scan` of updates, each a `lax.scan` rollout of
    `config.num_steps` steps of `config.num_envs` envs, GAE, then `rule.update_step`.

    Args:
        config: the algorithm's config (static fields: num_envs, num_steps, total_timesteps,
            trunk, ...; traced: learning rate, gamma, ...).
        env, env_params: any env with the jaxnat/gymnax API; it should reset itself when an
            episode ends (`jaxnat.make` envs do).
        rule: the algorithm's optimizer, update and network options.
        axis_name: train data parallel over this mesh axis (the functions then run inside a
            `jax.shard_map` over it, the runner's per-env fields split along their env axis,
            the rest replicated; `config.num_envs` counts every device's envs). See the
            module docstring; None: one device, the default learner.
        final_value_share: where observations are not normalised, the share of a batch whose
            final observations are valued in a compacted call (`act_and_value_final`); a batch
            in which more envs truncate values every row; None: every row in any step where
            one truncated (no compacted call).
    """
    check_ranges(config)
    total_updates = count_updates(config)
    observation_space = env.observation_space(env_params)
    action_space = env.action_space(env_params)
    network = make_actor_critic(observation_space, action_space, config.trunk, **rule.network_options(config))
    normalizing = normalize.switches(config, observation_space)
    reset, step = vector_env(env)
    if axis_name is not None:
        rule = rule.averaged(axis_name)
        if network.memory:
            raise ValueError(f"memory={network.memory}: a recurrent policy's minibatches are whole env rollouts, "
                             "which do not split evenly over devices: place whole seeds on devices instead")

    def env_keys(key, config, shape=()):
        """The keys of this device's envs `[*shape, n]` (every env's without `axis_name`)."""
        keys = jax.random.split(key, (*shape, config.num_envs))
        return keys if axis_name is None else shard_slice(keys, axis_name, axis=len(shape))

    def init(key, config=config) -> RunnerState:
        key, key_net, key_env = jax.random.split(key, 3)
        train_state = rule.train_state(config, network, observation_space, total_updates, key_net)
        keys = env_keys(key_env, config)
        obs, env_state = reset(keys, env_params)
        memory = initial_memory(network, config.num_envs) if network.memory else None
        normalizer = normalize.init_normalizer(*normalizing, observation_space, len(keys))
        return RunnerState(train_state, env_state, obs, key, jnp.zeros((), jnp.int32), memory, normalizer)

    def act_and_value_final(params, obs, pending):
        """`(logits, value, V(the previous step's final observations))` in one network call on
        this step's observations and those final ones. Only a truncated step needs its final
        value (`bootstrap` zeroes a terminated one's); where observations are not normalised,
        an episode that went on has this step's observation as its final one, so the call
        takes the truncated rows alone where few envs of the batch truncated (`jaxnat.gating`),
        none where none did, every row where more did."""
        final_obs, truncated = pending
        n = len(truncated)

        def with_rows(extra):  # this step's rows, then `extra`'s, in one call
            logits, values, _ = act(network, params, _stack_batches(obs, extra), None)
            # (Every leaf of the head's output has a row per observation: a Gaussian's log-std
            # is broadcast to the mean's shape.)
            return jax.tree_util.tree_map(lambda x: x[:n], logits), values[:n], values[n:]

        if normalizing[0]:  # the final observation was normalised one step earlier
            return with_rows(final_obs)
        sizes = compact_sizes(final_value_share, n)

        def none_truncated():
            logits, value, _ = act(network, params, obs, None)
            return logits, value, value

        def few_truncated(rows):
            logits, value, finals = with_rows(take_rows(final_obs, rows))
            return logits, value, put_rows(value, rows, finals)

        return switch_rows(truncated, sizes, none_truncated, few_truncated, lambda: with_rows(final_obs))

    def policy(carry, obs, key, t):
        params, memory, normalizer, pending = carry
        normalizer = normalize.observe(normalizer, obs, axis_name)
        obs = normalize.normalize(normalizer, obs)
        if pending is None:  # recurrent: the final observation is valued in `observe`
            logits, value, hidden = act(network, params, obs, memory)
            pending_value = None
        else:  # this step's observations and the previous step's final ones, in one call
            logits, value, pending_value = act_and_value_final(params, obs, pending)
            hidden = None
        if axis_name is None:
            action = distributions.sample(key, logits)
        else:
            action = sample_each(env_keys(key, config), logits)
        return action, (obs, distributions.log_prob(logits, action), value, hidden, normalizer, pending_value)

    def rollout(runner: RunnerState, config):
        """`config.num_steps` steps of every env: `(runner after them, Transition [T, N, ...])`
        (parameters and update count unchanged).

        The value of a step's final observation, as if the episode went on (it bootstraps a
        truncated step), is read in the same network call as the next step's observations (a
        feed-forward policy; the last step's after the loop): a call of its own on every step
        would cost a small network's rollout as many kernel launches again. A recurrent policy
        reads it in `observe`, after this step's memory."""
        params = runner.train_state.params

        def observe(carry, s: EnvStep, aux, t):
            params, memory, _, _ = carry
            obs, log_prob, value, hidden, normalizer, pending_value = aux
            final_obs = normalize.normalize(normalizer, s.final_obs)
            following = None if memory is None else Memory(hidden, s.action, s.reward.astype(jnp.float32),
                                                           jnp.zeros_like(s.done))
            if memory is None:  # V(the previous step's final observation); moved to its step below
                value_final, pending = pending_value, (final_obs, s.done & ~s.terminated)
            else:
                value_final, pending = final_value(network, params, final_obs, following), None
            normalizer, reward = normalize.scale_rewards(normalizer, s.reward, s.done, config.gamma, axis_name,
                                                        clip=config.clip_rewards)
            transition = Transition(obs, s.action, log_prob, value, reward, s.done.astype(jnp.float32),
                                    value_final, step_info(s.info, s.terminated),
                                    None if memory is None else memory._replace(hidden=None))
            next_memory = None if memory is None else following._replace(start=s.done)
            return (params, next_memory, normalizer, pending), transition

        pending = None if runner.memory is not None else (  # (final observations, truncated)
            jax.tree_util.tree_map(jnp.zeros_like, normalize.normalize(runner.normalizer, runner.obs)),
            jnp.zeros(len(jax.tree_util.tree_leaves(runner.obs)[0]), jnp.bool_))
        ((_, memory, normalizer, pending), env_state, obs, key), transitions = scan_steps(
            step, env_params, action_space, config.num_envs, config.num_steps, policy, observe,
            (params, runner.memory, runner.normalizer, pending), runner.env_state, runner.obs, runner.key,
            None if axis_name is None else lambda key, shape: env_keys(key, config, shape))
        final_values = transitions.next_value  # V(final observation), before `bootstrap`
        if runner.memory is not None:  # the state before the rollout's first step (`replay`)
            transitions = transitions._replace(memory=transitions.memory._replace(hidden=runner.memory.hidden[None]))
        else:  # step t's final value was read at step t + 1; the last step's now
            last = final_value(network, params, pending[0])
            final_values = jnp.concatenate([final_values[1:], last[None]])
        transitions = transitions._replace(next_value=bootstrap(final_values, transitions.info["terminated"]))
        return runner._replace(env_state=env_state, obs=obs, key=key, memory=memory, normalizer=normalizer), transitions

    def update(runner: RunnerState, config):
        runner, transitions = rollout(runner, config)
        key, key_update = jax.random.split(runner.key)
        train_state, metrics = rule.learn(config, network, runner.train_state, transitions, key_update,
                                              axis_name)
        return runner._replace(train_state=train_state, key=key, update=runner.update + 1), metrics

    return scan_learner(config, init, update, lambda config: rule.make_optimizer(config, total_updates), network,
                        total_updates, policy_of, per_env, rollout)


def policy_of(runner: RunnerState):
    """What the runner's policy acts with: `(params, normalizer)` (`Learner.policy_of`)."""
    return runner.train_state.params, runner.normalizer


def per_env(runner: RunnerState) -> RunnerState:
    """The runner's parts with an env axis (`Learner.per_env`): the envs' states and
    observations, the memory and the normaliser's running returns."""
    normalizer = None if runner.normalizer is None else normalize.per_env(runner.normalizer)
    return RunnerState(train_state=False, env_state=True, obs=True, key=False, update=False,
                       memory=None if runner.memory is None else True, normalizer=normalizer)
