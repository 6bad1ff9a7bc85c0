"""Optimizer pieces the algorithms share."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import optax

__all__ = ["clip_by_global_norm"]


def clip_by_global_norm(max_norm) -> optax.GradientTransformation:
    """`optax.clip_by_global_norm` (the same rule and the same, empty, state) with the norm
    taken in one reduction over every gradient at once: optax reduces each parameter array on
    its own, one kernel per array on a GPU, which a small network's update (bound by kernel
    launches, not arithmetic) pays on every minibatch."""

    def update(updates, state, params=None):
        del params
        leaves = jax.tree_util.tree_leaves(updates)
        norm = jnp.sqrt(jnp.sum(jnp.concatenate([jnp.ravel(g).astype(jnp.float32) for g in leaves]) ** 2))
        keep = norm < max_norm
        return jax.tree_util.tree_map(
            lambda g: jnp.where(keep, g, (g / norm.astype(g.dtype)) * max_norm).astype(g.dtype), updates), state

    return optax.GradientTransformation(lambda params: optax.EmptyState(), update)
