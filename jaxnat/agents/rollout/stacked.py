"""Seeds side by side: the states of several seeds stacked along a leading seed axis (every leaf
`[S, ...]`, PRNG keys included), as a host learner built with `seeds=S` holds them
(`on_policy_host_learner`), and the pieces that keep each seed's numbers its own.

- `seed_slice(tree, s)`: seed `s`'s state, the structure a one-seed learner's state has;
  `stack_seeds(trees)`: the inverse (a checkpoint per seed restores into a stacked state).
- `split_keys(key)`: `jax.random.split(key)` as `(key, subkey)`; for stacked keys `[S]` each
  seed's key is split as its own, so seed `s`'s stream is the one it draws training alone.
- `over_seeds(fn, seeds)`: a jitted function of one seed's params, batch and keys made the
  function of the seeds side by side, their envs one after another in one batch.
"""

from __future__ import annotations

from typing import Callable

import jax
import jax.numpy as jnp

__all__ = ["seed_slice", "stack_seeds", "split_keys", "over_seeds"]


def seed_slice(tree, index: int):
    """Seed `index`'s part of a stacked pytree (every leaf's row `index`)."""
    return jax.tree.map(lambda x: x[index], tree)


def stack_seeds(trees):
    """Pytrees of one structure (one per seed) as one stacked pytree, seed `i` at row `i`."""
    return jax.tree.map(lambda *leaves: jnp.stack(leaves), *trees)


# Jitted, so that the host loops' split per env step is one dispatch: unjitted, the split and
# the two rows taken from it are three (bench/results/host_overhead.md).
@jax.jit
def _split_one(key):
    pair = jax.random.split(key)
    return pair[0], pair[1]


@jax.jit
def _split_each(keys):
    pairs = jax.vmap(jax.random.split)(keys)
    return pairs[:, 0], pairs[:, 1]


def split_keys(key) -> tuple:
    """`(key, subkey)`: `jax.random.split(key)` for one key; for stacked keys `[S]`, each row
    split as that seed's own key would be (`(keys, subkeys)`, each `[S]`)."""
    return _split_one(key) if key.shape == () else _split_each(key)


def over_seeds(fn: Callable, seeds: int) -> Callable:
    """`fn(params, batch, *keys)` of one seed (outputs with a leading batch axis) as the same
    function of `seeds` seeds side by side: `params` and `keys` stacked `[seeds, ...]`, `batch`
    the seeds' envs one after another `[seeds * n, ...]` (seed `s`'s rows `s * n .. s * n + n -
    1`), every output laid out the same way. To be jitted (the reshapes are then free)."""

    def per_seed(x):
        return x.reshape(seeds, x.shape[0] // seeds, *x.shape[1:])

    def joined(x):
        return x.reshape(x.shape[0] * x.shape[1], *x.shape[2:])

    def stacked(params, batch, *keys):
        return jax.tree.map(joined, jax.vmap(fn)(params, jax.tree.map(per_seed, batch), *keys))

    return stacked
