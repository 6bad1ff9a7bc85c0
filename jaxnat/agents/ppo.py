"""PPO (clipped surrogate), PureJaxRL-shaped: `make_train(config, env, params) -> train(key)`.

    import jax, jaxnat
    from jaxnat.agents import ppo
    env, params = jaxnat.make("Classify/Digits-v0")
    train = ppo.make_train(ppo.PPOConfig(total_timesteps=1_000_000, num_envs=64), env, params)
    runner, metrics = jax.jit(jax.vmap(train))(jax.random.split(jax.random.key(0), 5))

Defaults are the authors' settings (`docs/environments.md` section 5): Adam lr 2.5e-4
(linearly annealed), clip 0.1, value coef 1.0, entropy 0.01, gamma 0.99, GAE lambda 0.95,
128 steps per env, 4 minibatches, 4 epochs, max grad norm 0.5, 8 envs.

`memory=N` makes the policy recurrent (a GRU of size N, `networks.ActorCritic`); its minibatches
are then groups of whole env rollouts (`num_envs` must divide by `num_minibatches`).

Data parallel (`make_ppo(..., axis_name=)`, inside a `jax.shard_map`; `rollout`'s docstring):
each minibatch is an equal share of every env's steps (each env's steps shuffled with its own
key), so it splits evenly over any device count (`num_steps` must divide by
`num_minibatches`), and advantages are normalised with the whole minibatch's mean and std.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import optax
from flax import struct

from jaxnat.agents import distributions
from jaxnat.agents.config import OnPolicyConfig, static
from jaxnat.agents.rollout import (Learner, UpdateRule, clip_by_global_norm, dtype_and_memory,
                                   on_policy_host_learner, on_policy_learner, replay)

__all__ = ["PPOConfig", "make_train", "make_ppo", "make_host_ppo"]

@struct.dataclass
class PPOConfig(OnPolicyConfig):
    """PPO's settings: `OnPolicyConfig`'s (8 envs x 128 steps, lr 2.5e-4, gamma 0.99, GAE lambda
    0.95, value coef 1.0, entropy 0.01) and PPO's own."""

    update_epochs: int = static(4)
    num_minibatches: int = static(4)
    anneal_lr: bool = static(True)
    dtype: str = static("float32")  # the trunk's computation dtype: "float32" or "bfloat16" (GPU)
    memory: int = static(0)  # GRU state size (a recurrent policy); 0: feed-forward, as the authors
    clip_eps: float = 0.1
    max_grad_norm: float = 0.5
    weight_decay: float = 0.0  # decoupled (AdamW), scaled by the learning rate; 0: the authors' Adam


# What each update reports beside the episode metrics: means over its minibatches.
LOSS_NAMES = ("policy_loss", "value_loss", "entropy", "approx_kl", "clip_fraction")


def _optimizer(config: PPOConfig, num_updates: int):
    steps_per_update = config.update_epochs * config.num_minibatches

    def schedule(count):
        done = (count // steps_per_update) / num_updates
        return config.lr * (1.0 - done if config.anneal_lr else 1.0)

    return optax.chain(clip_by_global_norm(config.max_grad_norm),
                       optax.adamw(schedule, eps=1e-5, weight_decay=config.weight_decay))


def _in_shard_map() -> bool:
    """Whether the program being traced runs under `jax.shard_map` (its mesh axes are manual)."""
    return bool(jax.sharding.get_abstract_mesh().manual_axes)


def _per_env_minibatches(data, key, num_minibatches: int, axis_name):
    """Data-parallel minibatches from time-major `[T, n, ...]` data: each env's `T` steps
    shuffled with a key of its own (folded from its index among every device's envs), and
    minibatch `m` the `m`-th of `num_minibatches` equal parts of every env's steps:
    `[num_minibatches, n * T / num_minibatches, ...]`, whatever the device count.

    A shuffled copy of the rollout, not indices gathered from it inside the epoch's scan as on
    one device: under `shard_map` with the GSPMD partitioner (which `jaxnat.sharding` switches
    to on several GPUs) XLA aborts compiling that gather in a loop, a failed check in its
    sharding code; the copy compiles. The same rows in the same order either way."""
    steps, envs = jax.tree_util.tree_leaves(data)[0].shape[:2]
    first = jax.lax.axis_index(axis_name) * envs
    orders = jax.vmap(lambda i: jax.random.permutation(jax.random.fold_in(key, first + i), steps))(jnp.arange(envs))

    def split(x):
        x = jax.vmap(lambda rollout, order: rollout[order])(jnp.swapaxes(x, 0, 1), orders)  # [n, T, ...]
        x = x.reshape(envs, num_minibatches, steps // num_minibatches, *x.shape[2:])
        return jnp.swapaxes(x, 0, 1).reshape(num_minibatches, -1, *x.shape[3:])

    return jax.tree_util.tree_map(split, data)


def _update(config: PPOConfig, network, train_state, transitions, advantages, targets, key, axis_name=None):
    batch = config.num_envs * config.num_steps
    data = (transitions.obs, transitions.action, transitions.log_prob, transitions.value, advantages, targets,
            transitions.memory)
    if axis_name is not None:  # data parallel: this device's envs, feed-forward (`rollout.on_policy_learner`)
        if config.num_steps % config.num_minibatches:
            raise ValueError(f"data-parallel PPO takes an equal share of every env's steps into each minibatch: "
                             f"num_steps={config.num_steps} must be divisible by "
                             f"num_minibatches={config.num_minibatches}")
    elif transitions.memory is None:  # minibatches of single steps
        if batch % config.num_minibatches:
            raise ValueError(f"num_envs * num_steps = {batch} is not divisible by num_minibatches={config.num_minibatches}")
        data = jax.tree_util.tree_map(lambda x: x.reshape(batch, *x.shape[2:]), data)
        units = batch
    else:  # a recurrent policy replays whole env rollouts: minibatches of envs, time-major
        if config.num_envs % config.num_minibatches:
            raise ValueError(f"a recurrent policy's minibatches hold whole env rollouts: num_envs={config.num_envs} "
                             f"is not divisible by num_minibatches={config.num_minibatches}")
        data = jax.tree_util.tree_map(lambda x: jnp.swapaxes(x, 0, 1), data)  # [N, T, ...]
        units = config.num_envs

    def loss_fn(params, obs, action, old_log_prob, old_value, advantage, target, memory):
        if memory is not None:  # back to time-major [T, B, ...]
            obs, action, old_log_prob, old_value, advantage, target, memory = jax.tree_util.tree_map(
                lambda x: jnp.swapaxes(x, 0, 1), (obs, action, old_log_prob, old_value, advantage, target, memory))
        logits, value = replay(network, params, obs, memory)
        log_prob = distributions.log_prob(logits, action)
        value_clipped = old_value + jnp.clip(value - old_value, -config.clip_eps, config.clip_eps)
        value_loss = 0.5 * jnp.maximum((value - target) ** 2, (value_clipped - target) ** 2).mean()
        if axis_name is None:
            advantage = (advantage - advantage.mean()) / (advantage.std() + 1e-8)
        else:  # the whole minibatch's moments (every device holds an equal share)
            mean = jax.lax.pmean(advantage.mean(), axis_name)
            std = jnp.sqrt(jax.lax.pmean(jnp.mean((advantage - mean) ** 2), axis_name))
            advantage = (advantage - mean) / (std + 1e-8)
        ratio = jnp.exp(log_prob - old_log_prob)
        policy_loss = -jnp.minimum(
            ratio * advantage, jnp.clip(ratio, 1 - config.clip_eps, 1 + config.clip_eps) * advantage
        ).mean()
        entropy = distributions.entropy(logits).mean()
        loss = policy_loss + config.vf_coef * value_loss - config.ent_coef * entropy
        # How far the policy moved from the one that collected the data (0 on the first
        # minibatch of the first epoch): CleanRL's `approx_kl` (k3 estimator) and clip fraction.
        # One vector, not five scalars: the scans stack it in one write per minibatch.
        log_ratio = log_prob - old_log_prob
        return loss, jnp.stack([policy_loss, value_loss, entropy, jnp.mean(ratio - 1.0 - log_ratio),
                                jnp.mean(jnp.abs(ratio - 1.0) > config.clip_eps)])

    def minibatch_step(train_state, minibatch):
        grads, losses = jax.grad(loss_fn, has_aux=True)(train_state.params, *minibatch)
        return train_state.apply_gradients(grads=grads), losses

    def epoch(train_state, key_or_order):
        if axis_name is not None:
            return jax.lax.scan(minibatch_step, train_state,
                                _per_env_minibatches(data, key_or_order, config.num_minibatches, axis_name))
        if _in_shard_map():  # seeds placed on devices (`--shard seeds`): see `_per_env_minibatches`
            shuffled = jax.tree_util.tree_map(
                lambda x: x[key_or_order].reshape(config.num_minibatches, -1, *x.shape[1:]), data)
            return jax.lax.scan(minibatch_step, train_state, shuffled)
        # Each minibatch gathered from the rollout as it is needed, not a shuffled copy of the
        # whole rollout per epoch: the same rows in the same order, one rollout's memory less
        # (a pixel rollout is most of a large batch's memory).
        def gathered_step(train_state, rows):
            return minibatch_step(train_state, jax.tree_util.tree_map(lambda x: x[rows], data))

        return jax.lax.scan(gathered_step, train_state, key_or_order.reshape(config.num_minibatches, -1))

    if axis_name is None:
        # Every epoch's order from one draw of random bits, sorted (`jax.random.permutation`'s
        # rule for one round), not a key split and a permutation per epoch: on a GPU each
        # draw is a loop of its own.
        epochs = jnp.argsort(jax.random.bits(key, (config.update_epochs, units)), axis=-1)
    else:
        epochs = jax.random.split(key, config.update_epochs)
    train_state, losses = jax.lax.scan(epoch, train_state, epochs)
    return train_state, dict(zip(LOSS_NAMES, jnp.mean(losses, axis=(0, 1))))


RULE = UpdateRule(make_optimizer=_optimizer, update_step=_update, network_options=dtype_and_memory,
                  data_parallel=True)


def make_ppo(config: PPOConfig, env, env_params, axis_name=None) -> Learner:
    """The PPO learner (`init`, `run`, `train`, `network`, `num_updates`); `axis_name`: data
    parallel over that mesh axis (`rollout.on_policy_learner`)."""
    return on_policy_learner(config, env, env_params, RULE, axis_name)


# `make_host_ppo(config, env, compiler_options=None, devices=None, *, seeds=None) -> HostLearner`:
# the PPO learner on a host-batched env (Natural Atari), `rollout.on_policy_host_learner`
# (`devices`: data parallel over them and every process, one env batch per process; `seeds`:
# that many seeds side by side on one batch of all their envs).
make_host_ppo = functools.partial(on_policy_host_learner, rule=RULE)


def make_train(config: PPOConfig, env, env_params):
    """`train(key, config=config) -> (runner, metrics)`, pure and jittable."""
    return make_ppo(config, env, env_params).train
