"""Batch-level conditionals for vmapped code: compute a costly branch only for the rows of a
batch that need it.

Under `jax.vmap` a `lax.cond` on a per-env predicate becomes a select that computes both
branches for every env. Where the costly branch is rare (an episode ending, a truncated
episode's bootstrap value) two tools keep it rare:

- `any_in_batch(flag)`: one unbatched value for the whole batch, so a `lax.cond` on it stays a
  conditional (nothing to compute in a step where no env needs the branch);
- `rows_of(mask, size)`: the indices of the true rows, padded to a static `size` with an
  out-of-range index, for `take_rows` / `put_rows` (gather the few rows, compute on them,
  scatter the results back; the padding rows are dropped).

`AutoResetWrapper` (PixelMuJoCo's renders) and the on-policy rollout (the final-observation
value) use them.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp


@jax.custom_batching.custom_vmap
def any_in_batch(flag):
    """`flag` (a scalar bool) itself; under `vmap`, whether it is true for any env of the batch,
    as one unbatched value (nested `vmap`s reduce each axis), so a `lax.cond` on it stays a
    conditional instead of becoming a select that computes both branches for every env."""
    return flag


@any_in_batch.def_vmap
def _any_in_batch_rule(axis_size, in_batched, flag):
    (batched,) = in_batched
    return any_in_batch(jnp.any(flag) if batched else flag), False


def compact_sizes(shares, batch: int) -> tuple[int, ...]:
    """The row counts of the compacted branches of a batch of `batch`, ascending and distinct:
    `ceil(share * batch)` (at least 1) for each share. `shares`: one share in (0, 1], several in
    increasing order (tiers: a step takes the smallest that holds its rows), or None for no
    compacted branch."""
    if shares is None:
        return ()
    shares = tuple(shares) if isinstance(shares, (tuple, list)) else (shares,)
    for share in shares:
        if not (isinstance(share, (int, float)) and 0.0 < share <= 1.0):
            raise ValueError(f"share must be in (0, 1] (the fraction of a batch computed compacted) or None, "
                             f"got {share!r}")
    if list(shares) != sorted(set(shares)) or not shares:
        raise ValueError(f"shares must be increasing, got {shares!r}")
    return tuple(sorted({max(1, math.ceil(share * batch)) for share in shares}))


def switch_rows(mask: jax.Array, sizes: tuple[int, ...], none, few, every):
    """One `lax.switch` on how many rows of the 1-D `mask` need a branch, unbatched (under
    `vmap`, the most any batch needs: `any_in_batch`): `none()` where no row does,
    `few(rows_of(mask, size))` for the smallest of `sizes` that holds them, `every()` where more
    do (or `sizes` is empty). The branches return the same shapes."""
    count = jnp.sum(mask)
    tier = sum((any_in_batch(count > size).astype(jnp.int32) for size in sizes), jnp.int32(0))
    branch = jnp.where(any_in_batch(count > 0), 1 + tier, 0)
    tiers = [lambda size=size: few(rows_of(mask, size)) for size in sizes]
    return jax.lax.switch(branch, (none, *tiers, every))


def rows_of(mask: jax.Array, size: int) -> jax.Array:
    """Indices `[size]` of the true entries of the 1-D `mask`, in order, padded with
    `len(mask)` (out of range: `put_rows` drops those rows). At most `size` are kept."""
    return jnp.nonzero(mask, size=size, fill_value=mask.shape[0])[0]


def take_rows(tree, rows: jax.Array):
    """The leading-axis `rows` of every leaf; padding indices read the last row."""
    return jax.tree.map(lambda x: x[jnp.minimum(rows, x.shape[0] - 1)], tree)


def put_rows(tree, rows: jax.Array, values):
    """`tree` with its leading-axis `rows` replaced by `values` (padding rows dropped)."""
    return jax.tree.map(lambda x, v: x.at[rows].set(v, mode="drop"), tree, values)
