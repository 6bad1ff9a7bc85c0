"""The frame stack of PixelMuJoCo's pixel observation: the newest frame and the ones before it.

`FrameStack(height, width, channels, depth)` holds one semantics (`pixel.PixelMuJoCo`,
**Observation**): the observation is uint8 `[H, W, C * depth]`, the last `depth` frames oldest
first; at an episode's first state it is the newest frame repeated. The env's state keeps the
newest frame (`latest`, uint8 `[H, W, C]`) apart from the older ones (`history`), so a step
renders one frame and carries the others over. Two layouts of `history`, chosen by the shape:

- **packed** (one channel, four frames: the default grayscale x 4): uint32 `[H, W]`, the three
  older frames in its three low bytes, oldest lowest, the top byte zero. The stack is
  `history | latest << 24` and the observation its bytes (`lax.bitcast_convert_type`, which
  puts the low byte first on every backend JAX targets: little-endian); dropping the oldest
  frame is `>> 8`.
- **bytes** (any other shape): uint8 `[H, W, C * (depth - 1)]`; the stack is a concatenation and
  dropping the oldest frame a slice.

Both give the same observations bit for bit (tests/test_pixel_mujoco.py). Why two: under
`vmap` over tens of thousands of envs, XLA turns the concatenation and the slice along a minor
axis of 3 or 4 bytes into copy fusions that run far below the memory bandwidth, once per
branch of the autoreset's switch; shifts and ors of whole uint32 words are elementwise.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

__all__ = ["FrameStack"]


class FrameStack:
    """The stack of `depth` frames of `channels` channels, `height` x `width`; see the module."""

    def __init__(self, height: int, width: int, channels: int, depth: int):
        if min(height, width, channels, depth) < 1:
            raise ValueError(f"height, width, channels and depth must be >= 1, got "
                             f"{height}, {width}, {channels}, {depth}")
        self.height, self.width, self.channels, self.depth = height, width, channels, depth
        self.packed = channels == 1 and depth == 4

    def empty(self) -> jax.Array:
        """`history` with every older frame zero (a placeholder until a frame is written)."""
        if self.packed:
            return jnp.zeros((self.height, self.width), jnp.uint32)
        return jnp.zeros((self.height, self.width, self.channels * (self.depth - 1)), jnp.uint8)

    def observation(self, history: jax.Array, latest: jax.Array, fresh) -> jax.Array:
        """uint8 `[H, W, C * depth]`: `history`'s frames then `latest`, oldest first; `latest`
        repeated where `fresh` (an episode's first state)."""
        if self.packed:
            return jax.lax.bitcast_convert_type(self._words(history, latest, fresh), jnp.uint8)
        stack = jnp.concatenate([history, latest], axis=-1)
        return jnp.where(fresh, jnp.tile(latest, self.depth), stack)

    def push(self, history: jax.Array, latest: jax.Array, fresh) -> jax.Array:
        """The `history` that follows: the stack `observation` shows, less its oldest frame."""
        if self.packed:
            return self._words(history, latest, fresh) >> 8
        return self.observation(history, latest, fresh)[..., self.channels:]

    @staticmethod
    def _words(history, latest, fresh):
        """The packed stack as uint32 `[H, W]`: byte k holds frame k, oldest first."""
        newest = latest[..., 0].astype(jnp.uint32)
        return jnp.where(fresh, newest * jnp.uint32(0x01010101), history | (newest << 24))
