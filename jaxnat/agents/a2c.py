"""A2C (synchronous advantage actor-critic), PureJaxRL-shaped like `ppo.py`.

Defaults are the authors' settings (`docs/environments.md` section 5): RMSprop lr 7e-4,
eps 1e-5, alpha 0.99, 5 steps per env, value coef 0.5, entropy 0.01, gamma 0.99, n-step
returns (GAE lambda 1.0), max grad norm 0.5, 16 envs.
"""

from __future__ import annotations

import functools

import jax
import optax
from flax import struct

from jaxnat.agents import distributions
from jaxnat.agents.config import OnPolicyConfig, static
from jaxnat.agents.rollout import (Learner, UpdateRule, clip_by_global_norm, dtype_and_memory,
                                   on_policy_host_learner, on_policy_learner, replay)

__all__ = ["A2CConfig", "actor_critic_loss", "make_train", "make_a2c", "make_host_a2c"]


@struct.dataclass
class A2CConfig(OnPolicyConfig):
    """A2C's settings: `OnPolicyConfig`'s fields with A2C's defaults, and its own."""

    num_envs: int = static(16)
    num_steps: int = static(5)
    lr: float = 7e-4
    gae_lambda: float = 1.0
    vf_coef: float = 0.5
    dtype: str = static("float32")  # the trunk's computation dtype: "float32" or "bfloat16" (GPU)
    memory: int = static(0)  # GRU state size (a recurrent policy); 0: feed-forward, as the authors
    rms_eps: float = 1e-5
    rms_alpha: float = 0.99
    max_grad_norm: float = 0.5


def _optimizer(config: A2CConfig, num_updates: int):
    return optax.chain(clip_by_global_norm(config.max_grad_norm),
                       optax.rmsprop(config.lr, decay=config.rms_alpha, eps=config.rms_eps))


def actor_critic_loss(config, logits, value, action, advantages, targets) -> tuple[jax.Array, dict]:
    """A2C's loss, and ACKTR's: the policy gradient on `advantages`, plus `vf_coef` times half the
    squared value error, minus `ent_coef` times the entropy; `(loss, metrics)`."""
    log_prob = distributions.log_prob(logits, action)
    policy_loss = -(jax.lax.stop_gradient(advantages) * log_prob).mean()
    value_loss = 0.5 * ((targets - value) ** 2).mean()
    entropy = distributions.entropy(logits).mean()
    loss = policy_loss + config.vf_coef * value_loss - config.ent_coef * entropy
    return loss, {"policy_loss": policy_loss, "value_loss": value_loss, "entropy": entropy}


def _update(config: A2CConfig, network, train_state, transitions, advantages, targets, key, axis_name=None):
    # Data parallel needs nothing here: the loss is a mean over the device's equal share of the
    # batch, so the devices' mean gradient (`rollout.pmean_gradients`) is the whole batch's.
    del axis_name

    def loss_fn(params):
        logits, value = replay(network, params, transitions.obs, transitions.memory)
        return actor_critic_loss(config, logits, value, transitions.action, advantages, targets)

    grads, losses = jax.grad(loss_fn, has_aux=True)(train_state.params)
    return train_state.apply_gradients(grads=grads), losses


RULE = UpdateRule(make_optimizer=_optimizer, update_step=_update, network_options=dtype_and_memory,
                  data_parallel=True)


def make_a2c(config: A2CConfig, env, env_params, axis_name=None) -> Learner:
    """The A2C learner; `axis_name`: data parallel over that mesh axis (`rollout.on_policy_learner`)."""
    return on_policy_learner(config, env, env_params, RULE, axis_name)


# `make_host_a2c(config, env, compiler_options=None, devices=None, *, seeds=None) -> HostLearner`: as PPO's.
make_host_a2c = functools.partial(on_policy_host_learner, rule=RULE)


def make_train(config: A2CConfig, env, env_params):
    return make_a2c(config, env, env_params).train
