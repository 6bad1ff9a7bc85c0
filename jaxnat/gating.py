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


def compact_size(share: float | None, batch: int) -> int:
    """Rows kept for the compacted branch of a batch of `batch`: `ceil(share * batch)`, at
    least 1; `share` in (0, 1], or None for no compacted branch (0 rows)."""
    if share is None:
        return 0
    if not 0.0 < share <= 1.0:
        raise ValueError(f"share must be in (0, 1] (the fraction of a batch computed compacted) or None, got {share}")
    return max(1, math.ceil(share * batch))


def count_branch(mask: jax.Array, size: int) -> jax.Array:
    """The branch a batch with the 1-D `mask` of rows in need takes, one unbatched int32 for
    `lax.switch` (under `vmap` the most any batch needs): 0 where no row needs it, 1 where at
    most `size` do (compute those rows alone), 2 where more do (compute every row)."""
    count = jnp.sum(mask)
    return jnp.where(any_in_batch(count > size), 2, jnp.where(any_in_batch(count > 0), 1, 0)).astype(jnp.int32)


def switch_rows(mask: jax.Array, size: int, none, few, every):
    """`none()`, `few(rows_of(mask, size))` or `every()` by `count_branch`; with `size` 0
    (`compact_size(None, ...)`) there is no compacted branch: `every()` where any row needs it.
    The branches return the same shapes."""
    branch = count_branch(mask, size)
    if size == 0:
        return jax.lax.switch(branch // 2, (none, every))
    return jax.lax.switch(branch, (none, lambda: few(rows_of(mask, size)), every))


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
