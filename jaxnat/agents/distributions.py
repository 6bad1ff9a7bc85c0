"""Factored categorical policies: one categorical per action factor, log-probs and entropies
summed (the authors' two heads for move and label)."""

from __future__ import annotations

import jax
import jax.numpy as jnp


def sample(key, logits: tuple) -> jax.Array:
    """Actions `[..., F]` (int32), one per factor."""
    keys = jax.random.split(key, len(logits))
    return jnp.stack([jax.random.categorical(k, l) for k, l in zip(keys, logits)], axis=-1).astype(jnp.int32)


def mode(logits: tuple) -> jax.Array:
    """The most likely action `[..., F]` (greedy)."""
    return jnp.stack([jnp.argmax(l, axis=-1) for l in logits], axis=-1).astype(jnp.int32)


def log_prob(logits: tuple, actions: jax.Array) -> jax.Array:
    total = 0.0
    for i, l in enumerate(logits):
        logp = jax.nn.log_softmax(l)
        total = total + jnp.take_along_axis(logp, actions[..., i : i + 1], axis=-1)[..., 0]
    return total


def entropy(logits: tuple) -> jax.Array:
    total = 0.0
    for l in logits:
        logp = jax.nn.log_softmax(l)
        total = total - jnp.sum(jnp.exp(logp) * logp, axis=-1)
    return total
