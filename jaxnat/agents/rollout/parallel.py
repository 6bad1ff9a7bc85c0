"""Data parallel inside a `jax.shard_map` over a mesh axis: each device steps its share of the
envs (`shard_slice`) and the optimizer applies the devices' mean gradient (`pmean_gradients`).
Every random draw is per env (env `i` of all `num_envs` gets the same keys on any device count)
and every statistic over the batch (normalisation moments, metrics, PPO's advantage
normalisation and minibatches: an equal share of every env's steps) is the whole batch's, so
1, 2, 4 ... devices train the same parameters to float tolerance. It is not the default
learner's stream of random draws."""

from __future__ import annotations

import jax
import optax

__all__ = ["pmean_gradients", "shard_slice"]


def pmean_gradients(tx: optax.GradientTransformation, axis_name) -> optax.GradientTransformation:
    """`tx` applied to the mean of the devices' gradients over `axis_name` (before clipping),
    with `tx`'s own state: a data-parallel run's checkpoints hold what a single device's do."""

    def update(updates, state, params=None, **extra):
        return tx.update(jax.lax.pmean(updates, axis_name), state, params, **extra)

    return optax.GradientTransformation(tx.init, update)


def shard_slice(x, axis_name, axis: int = 0):
    """This device's share of `x` along `axis`, inside a shard_map over `axis_name` (e.g. its
    envs' keys out of `jax.random.split(key, num_envs)`)."""
    size = x.shape[axis] // jax.lax.axis_size(axis_name)
    return jax.lax.dynamic_slice_in_dim(x, jax.lax.axis_index(axis_name) * size, size, axis)
