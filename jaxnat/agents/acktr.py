"""ACKTR (Wu et al. 2017): actor-critic with K-FAC natural gradients and a KL trust region,
PureJaxRL-shaped like `a2c.py` (same loss, same rollout; `kfac.py` preconditions the step).

Defaults are the authors' settings (20 steps per update; `docs/environments.md` section
5) and OpenAI baselines' `acktr` defaults for the rest: lr 0.25 (linearly annealed), momentum
0.9 (SGD with lr * (1 - momentum), as baselines), KL clip 0.001, damping 0.01, factor decay 0.99,
value coef 0.5, Fisher value coef 1.0, entropy 0.01, gamma 0.99, n-step returns, 32 envs
(the ACKTR paper's 32 actors x 20 steps = 640 samples per update).

The Fisher is the joint one of the policy and a unit-variance Gaussian value output, estimated
with actions sampled from the policy and values sampled from `N(V, 1)` (ACKTR's choice). The
optimizer state holds the K-FAC factors, so checkpoints and resumes carry them.
Differences from baselines: the damped factors' inverses are refined every update by
Newton-Schulz steps (`kfac.refine_inverse`; baselines recomputes eigendecompositions
asynchronously); no gradient-norm clipping and no "cold" SGD steps (the KL trust region bounds
the step from the first update on).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import optax
from flax import struct

from jaxnat.agents import distributions, kfac
from jaxnat.agents.a2c import actor_critic_loss
from jaxnat.agents.config import OnPolicyConfig, static
from jaxnat.agents.rollout import HostLearner, Learner, UpdateRule, on_policy_host_learner, on_policy_learner

__all__ = ["ACKTRConfig", "make_train", "make_acktr", "make_host_acktr"]


@struct.dataclass
class ACKTRConfig(OnPolicyConfig):
    """ACKTR's settings: `OnPolicyConfig`'s fields with ACKTR's defaults, and its own."""

    num_envs: int = static(32)
    num_steps: int = static(20)
    lr: float = 0.25
    gae_lambda: float = 1.0
    vf_coef: float = 0.5
    anneal_lr: bool = static(True)
    momentum: float = 0.9
    kl_clip: float = 0.001
    damping: float = 0.01
    stats_decay: float = 0.99
    vf_fisher_coef: float = 1.0


def _optimizer(config: ACKTRConfig, num_updates: int):
    def schedule(count):
        return config.lr * (1.0 - count / num_updates if config.anneal_lr else 1.0)

    return optax.chain(
        kfac.kfac(schedule, damping=config.damping, stats_decay=config.stats_decay, kl_clip=config.kl_clip),
        optax.sgd(lambda count: schedule(count) * (1.0 - config.momentum), momentum=config.momentum),
    )


def _update(config: ACKTRConfig, network, train_state, transitions, advantages, targets, key):
    obs = transitions.obs
    key_action, key_value = jax.random.split(key)

    def losses(params, perturbations):
        (logits, value), inputs, _ = kfac.capture(network, params, obs, perturbations)
        loss, metrics = actor_critic_loss(config, logits, value, transitions.action, advantages, targets)
        # The model's own log-likelihood of sampled outputs, summed over examples so that the
        # output gradients are per example (kfac.factor_statistics).
        sampled_action = distributions.sample(key_action, jax.lax.stop_gradient(logits))
        sampled_value = jax.lax.stop_gradient(value + jax.random.normal(key_value, value.shape))
        fisher = (distributions.log_prob(logits, sampled_action).sum()
                  - config.vf_fisher_coef * 0.5 * ((value - sampled_value) ** 2).sum())
        return (loss, fisher), (metrics, inputs)

    zeros = kfac.zero_perturbations(network, train_state.params, obs)
    _, backward, (metrics, inputs) = jax.vjp(losses, train_state.params, zeros, has_aux=True)
    grads, _ = backward((jnp.ones(()), jnp.zeros(())))
    _, output_grads = backward((jnp.zeros(()), jnp.ones(())))
    updates, opt_state = train_state.tx.update(
        grads, train_state.opt_state, train_state.params,
        statistics=kfac.factor_statistics(inputs, output_grads),
    )
    train_state = train_state.replace(
        step=train_state.step + 1, params=optax.apply_updates(train_state.params, updates), opt_state=opt_state
    )
    return train_state, metrics


# The network computes in float32: K-FAC's statistics want float32 layer inputs.
RULE = UpdateRule(make_optimizer=_optimizer, update_step=_update)


def make_acktr(config: ACKTRConfig, env, env_params) -> Learner:
    """The ACKTR learner (`init`, `run`, `train`, `network`, `num_updates`)."""
    return on_policy_learner(config, env, env_params, RULE)


def make_host_acktr(config: ACKTRConfig, env, compiler_options: dict | None = None, *,
                    seeds: int | None = None) -> HostLearner:
    """The ACKTR learner on a host-batched env (Natural Atari), as the paper ran it: each update's
    K-FAC statistics come from the host rollout, on the device (`rollout.on_policy_host_learner`;
    `seeds`: that many seeds side by side, each with its own factors). One device: K-FAC's
    factors are the whole batch's."""
    return on_policy_host_learner(config, env, compiler_options, rule=RULE, seeds=seeds)


def make_train(config: ACKTRConfig, env, env_params):
    """`train(key, config=config) -> (runner, metrics)`, pure and jittable."""
    return make_acktr(config, env, env_params).train
