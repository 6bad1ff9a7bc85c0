"""A replay buffer on the device: a ring buffer pytree, pure and jittable (and vmappable over
seeds, one buffer each).

    buffer = replay_init({"obs": obs[0], "reward": jnp.float32(0)}, capacity=100_000)
    buffer = replay_add(buffer, {"obs": obs, "reward": reward})      # a batch [B, ...]
    batch = replay_sample(buffer, key, 32)                           # uniform over stored items

Items are any pytree; uint8 observations stay uint8 (a quarter of float32's memory).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

__all__ = ["ReplayBuffer", "replay_init", "replay_add", "replay_sample"]


@struct.dataclass
class ReplayBuffer:
    data: Any  # the item pytree, every leaf with a leading [capacity] axis
    position: jax.Array  # where the next item goes (int32)
    size: jax.Array  # items stored, at most capacity (int32)

    @property
    def capacity(self) -> int:
        return jax.tree.leaves(self.data)[0].shape[0]


def replay_init(item, capacity: int) -> ReplayBuffer:
    """An empty buffer for items shaped like `item` (one item, no batch axis)."""
    if capacity < 1:
        raise ValueError(f"replay buffer capacity must be at least 1, got {capacity}")
    data = jax.tree.map(lambda x: jnp.zeros((capacity, *jnp.shape(x)), jnp.asarray(x).dtype), item)
    return ReplayBuffer(data, jnp.zeros((), jnp.int32), jnp.zeros((), jnp.int32))


def replay_add(buffer: ReplayBuffer, batch) -> ReplayBuffer:
    """Store a batch of items (leading axis B), overwriting the oldest when full."""
    count = jax.tree.leaves(batch)[0].shape[0]
    if count > buffer.capacity:
        raise ValueError(f"adding {count} items at once to a replay buffer of capacity {buffer.capacity}; "
                         f"make the buffer at least as large as one batch of env steps")
    index = (buffer.position + jnp.arange(count)) % buffer.capacity
    data = jax.tree.map(lambda d, x: d.at[index].set(x.astype(d.dtype)), buffer.data, batch)
    return ReplayBuffer(data, (buffer.position + count) % buffer.capacity,
                        jnp.minimum(buffer.size + count, buffer.capacity))


def replay_sample(buffer: ReplayBuffer, key, batch_size: int):
    """`batch_size` items drawn uniformly with replacement from those stored (item 0 of an
    empty buffer)."""
    index = jax.random.randint(key, (batch_size,), 0, jnp.maximum(buffer.size, 1))
    return jax.tree.map(lambda d: d[index], buffer.data)
