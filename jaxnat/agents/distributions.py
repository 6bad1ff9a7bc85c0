"""The policies' action distributions, behind one set of functions (`sample`, `mode`,
`log_prob`, `entropy`) that dispatch on what the network's policy head returned:

- a tuple of logits: factored categoricals, one per action factor (Discrete, MultiDiscrete:
  the authors' two heads for move and label); actions int32 `[..., F]`, log-probs and
  entropies summed over the factors;
- a `Gaussian(mean, log_std)`: a diagonal Gaussian over a `Box` (continuous control), with a
  state-independent, learned log-std as in the authors' baselines code, CleanRL and Brax;
  actions float32 `[..., D]`, log-probs and entropies summed over the dimensions. Samples are
  not squashed: they are clipped to the space's bounds at the env boundary
  (`rollout.env_action`), while the log-prob is that of the unclipped sample (the one stored).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["Gaussian", "sample", "mode", "log_prob", "entropy"]

_LOG_2PI = float(np.log(2.0 * np.pi))


class Gaussian(NamedTuple):
    """A diagonal Gaussian: `mean` `[..., D]`, `log_std` `[D]` (or broadcastable to the mean)."""

    mean: jax.Array
    log_std: jax.Array


def sample(key, dist) -> jax.Array:
    """Actions `[..., F]` (int32 categories) or `[..., D]` (float32)."""
    if isinstance(dist, Gaussian):
        std = jnp.exp(dist.log_std)
        return dist.mean + std * jax.random.normal(key, jnp.shape(dist.mean), jnp.float32)
    # One Gumbel draw for every factor (argmax of logits + Gumbel noise: `jax.random.categorical`'s
    # rule), not a key split and a draw per factor: on a GPU each draw is a loop of its own, and
    # a rollout draws on every step.
    sizes = [l.shape[-1] for l in dist]
    noise = jax.random.gumbel(key, (*jnp.shape(dist[0])[:-1], sum(sizes)), jnp.float32)
    starts = np.cumsum([0, *sizes])
    return jnp.stack([jnp.argmax(l + noise[..., a:b], axis=-1) for l, a, b in zip(dist, starts, starts[1:])],
                     axis=-1).astype(jnp.int32)


def mode(dist) -> jax.Array:
    """The most likely action (greedy): the argmax per factor, or the Gaussian's mean."""
    if isinstance(dist, Gaussian):
        return dist.mean
    return jnp.stack([jnp.argmax(l, axis=-1) for l in dist], axis=-1).astype(jnp.int32)


def log_prob(dist, actions: jax.Array) -> jax.Array:
    if isinstance(dist, Gaussian):
        z = (actions - dist.mean) * jnp.exp(-dist.log_std)
        return jnp.sum(-0.5 * z**2 - dist.log_std - 0.5 * _LOG_2PI, axis=-1)
    # The chosen entry picked by a comparison, not an indexed gather: its gradient is then a
    # select, where a gather's is a scatter (a kernel of its own per minibatch on a GPU).
    return sum(jnp.sum(jnp.where(jnp.arange(l.shape[-1]) == actions[..., i : i + 1], jax.nn.log_softmax(l), 0.0),
                       axis=-1)
               for i, l in enumerate(dist))


def entropy(dist) -> jax.Array:
    if isinstance(dist, Gaussian):
        per_dim = jnp.broadcast_to(dist.log_std + 0.5 * (1.0 + _LOG_2PI), jnp.shape(dist.mean))
        return jnp.sum(per_dim, axis=-1)
    return sum(-jnp.sum(jnp.exp(logp) * logp, axis=-1) for logp in map(jax.nn.log_softmax, dist))
