"""Play a `FrameBank` one frame per agent step: a jittable cursor and a batched host sampler.

Both follow one law: at reset, a video drawn uniformly and a start frame drawn uniformly within
it; each step, the next frame; after a video's last frame, a new video drawn uniformly, played
from its first frame.

Jittable (JAX envs keep the cursor in their state; all functions vmap):

    cursor = cursor_reset(key, bank)          # bank = load_videos(...).to_device()
    frame = cursor_frame(bank, cursor)        # uint8 [H, W, C]
    cursor = cursor_step(key, cursor, bank)

Host (batched host envs such as ALE): `HostVideoSampler(bank, num_envs, seed)`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxnat.natural.bank import FrameBank

__all__ = ["VideoCursor", "cursor_reset", "cursor_step", "cursor_frame", "cursor_index",
           "HostVideoSampler", "per_env_values", "seed_groups"]


@struct.dataclass
class VideoCursor:
    """Where one env is in the bank: video `video`, frame `offset` within it (int32 scalars)."""

    video: jax.Array
    offset: jax.Array


def _random_video(key: jax.Array, bank: FrameBank, num_videos=None) -> jax.Array:
    count = bank.lengths.shape[0]
    if num_videos is not None:  # the first `num_videos` videos (traced: clipped to [1, count])
        count = jnp.clip(jnp.asarray(num_videos, jnp.int32), 1, count)
    return jax.random.randint(key, (), 0, count, dtype=jnp.int32)


def cursor_reset(key: jax.Array, bank: FrameBank, num_videos=None) -> VideoCursor:
    """A random video and a random start frame within it; `num_videos`: draw among the bank's
    first that many videos only (None: all of them)."""
    key_video, key_offset = jax.random.split(key)
    video = _random_video(key_video, bank, num_videos)
    offset = jax.random.randint(key_offset, (), 0, jnp.asarray(bank.lengths)[video],
                                dtype=jnp.int32)
    return VideoCursor(video=video, offset=offset)


def cursor_step(key: jax.Array, cursor: VideoCursor, bank: FrameBank, num_videos=None) -> VideoCursor:
    """The next frame; after the video's last frame, the first frame of a new random video
    (among the first `num_videos`, as `cursor_reset`)."""
    offset = cursor.offset + 1
    ended = offset >= jnp.asarray(bank.lengths)[cursor.video]
    video = jnp.where(ended, _random_video(key, bank, num_videos), cursor.video)
    return VideoCursor(video=video, offset=jnp.where(ended, 0, offset).astype(jnp.int32))


def cursor_index(bank: FrameBank, cursor: VideoCursor) -> jax.Array:
    """The bank row of the frame under the cursor (for readers that index `bank.frames`
    themselves, as PixelMuJoCo's floor does texel by texel)."""
    return jnp.asarray(bank.starts)[cursor.video] + cursor.offset


def cursor_frame(bank: FrameBank, cursor: VideoCursor) -> jax.Array:
    """The frame under the cursor, uint8 [H, W, C]."""
    return jnp.asarray(bank.frames)[cursor_index(bank, cursor)]


def seed_groups(seed, num_envs: int) -> tuple[list, int]:
    """`seed` of a batch of `num_envs` host envs as `(seeds, size)`: one int (or None) seeds the
    whole batch, `([seed], num_envs)`; a sequence of G seeds makes the batch G equal groups of
    `size` envs, group `g` (envs `g * size ..`) seeded by `seeds[g]` as a batch of its own. A
    one-line `ValueError` where G does not divide `num_envs`."""
    seeds = [seed] if seed is None or np.ndim(seed) == 0 else [int(s) for s in seed]
    if not seeds or num_envs % len(seeds):
        raise ValueError(f"seed: one int, or one per group of equal size; {len(seeds)} groups do not "
                         f"divide num_envs={num_envs}")
    return seeds, num_envs // len(seeds)


def per_env_values(name: str, value, num_envs: int, *, low: float, high: float | None = None,
                   whole: bool = False):
    """`value` (one number, or one per env) checked to be finite and in [low, high] (and a whole
    number when `whole`): a Python number, or an array of `num_envs` (int64 when `whole`, else
    float64); a one-line `ValueError` otherwise. The per-env dials of the host envs share it."""
    array = np.asarray(value)
    if array.ndim > 1 or (array.ndim == 1 and array.size != num_envs):
        raise ValueError(f"{name} takes one number or one per env ({num_envs}), got shape {array.shape}")
    if not np.issubdtype(array.dtype, np.number):
        raise ValueError(f"{name} must be a number, got {value}")
    if whole and not np.all(array == np.round(array)):
        raise ValueError(f"{name} must be a whole number, got {value}")
    if not np.all(np.isfinite(array) & (array >= low) & (array <= (np.inf if high is None else high))):
        bound = (f"be in [{low:g}, {high:g}]" if whole else f"lie in [{low:g}, {high:g}]") if high is not None \
            else (f"be >= {low:g}" if whole else f"be a finite number >= {low:g}")
        raise ValueError(f"{name} must {bound}, got {value}")
    kind = np.int64 if whole else np.float64
    return (int(array) if whole else float(array)) if array.ndim == 0 else array.astype(kind)


class HostVideoSampler:
    """`num_envs` cursors over a host (numpy) bank, advanced together, one frame per env per step.

        sampler = HostVideoSampler(bank, num_envs=8, seed=0)
        frames = sampler.reset()            # uint8 [8, H, W, C]: every env's first frame
        frames = sampler.step()             # every env's next frame
        frames = sampler.reset(done_mask)   # new video and start for the envs where mask is True

    `frames()` returns the current frames without moving. `out=` (an array of the right shape
    and dtype) avoids allocating a new batch each step. Random draws come from
    `np.random.default_rng(seed)`; `seed` may also be one seed per group, the batch then being
    that many equal groups of envs, each drawing as a sampler of its envs alone would (`seed`).

    `frame_rate` (a whole number >= 0, or one per env) is the frames a step moves on (0 freezes
    the frame; a video that ends inside a jump hands over to a new one at its first frame);
    `num_videos` (None: every video, or a count in [1, the bank's videos], or one per env) the
    bank's first videos an env draws from. The defaults are the law above, draw for draw.
    """

    def __init__(self, bank: FrameBank, num_envs: int, seed: int | None = 0, *, frame_rate=1,
                 num_videos=None):
        if num_envs < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        bank = bank.to_host()
        self.bank = bank
        self.num_envs = num_envs
        self.frame_rate = per_env_values("frame_rate", frame_rate, num_envs, low=0, whole=True)
        self.num_videos = None  # every video: today's draws
        if num_videos is not None:
            counts = np.broadcast_to(per_env_values("num_videos", num_videos, num_envs, low=1,
                                                    high=bank.num_videos, whole=True), (num_envs,))
            self.num_videos = None if np.all(counts == bank.num_videos) else counts.astype(np.int64)
        self.video = np.zeros(num_envs, np.int64)
        self.offset = np.zeros(num_envs, np.int64)
        self.seed(seed)
        self.reset()

    def seed(self, seed) -> None:
        """Restart the random draws from `seed` (an int or None) for the whole batch, or from one
        seed per group (a sequence of G): the batch as G equal groups of envs, group `g`
        drawing from `np.random.default_rng(seed[g])` exactly as a sampler of its envs alone
        seeded so (the seeds of a run side by side on one batch). Later `reset` calls redraw."""
        seeds, size = seed_groups(seed, self.num_envs)
        self._groups = [(np.random.default_rng(s), g * size, (g + 1) * size) for g, s in enumerate(seeds)]

    def _draw(self, index: np.ndarray, video: bool) -> np.ndarray:
        """One draw per env of `index` (sorted), each from its group's generator, the group's
        envs in order: video ids (`video`) or uniform floats in [0, 1)."""
        out = np.empty(index.size, np.int64 if video else np.float64)
        for rng, lo, hi in self._groups:
            first, last = np.searchsorted(index, (lo, hi))
            own = index[first:last]
            if not video:
                out[first:last] = rng.random(own.size)
            elif self.num_videos is None:
                out[first:last] = rng.integers(0, self.bank.num_videos, size=own.size)
            else:
                out[first:last] = rng.integers(0, self.num_videos[own])
        return out

    def reset(self, mask: np.ndarray | None = None, out: np.ndarray | None = None) -> np.ndarray:
        """Re-draw video and start for the envs where `mask` is True (all when None); return
        every env's current frame."""
        index = (np.arange(self.num_envs) if mask is None
                 else np.flatnonzero(np.asarray(mask, bool).reshape(self.num_envs)))
        video = self._draw(index, video=True)
        self.video[index] = video
        # floor(u * length) is uniform over [0, length) for each env's own length.
        self.offset[index] = (self._draw(index, video=False) * self.bank.lengths[video]).astype(np.int64)
        return self.frames(out)

    def step(self, out: np.ndarray | None = None) -> np.ndarray:
        """Advance every env by its `frame_rate` frames, one by default (a new random video,
        from its first frame, after a video's last frame) and return the frames, uint8
        [num_envs, H, W, C]."""
        self.offset += self.frame_rate
        ended = np.flatnonzero(self.offset >= self.bank.lengths[self.video])
        if ended.size:
            self.video[ended] = self._draw(ended, video=True)
            self.offset[ended] = 0
        return self.frames(out)

    def frames(self, out: np.ndarray | None = None) -> np.ndarray:
        """Every env's current frame, uint8 [num_envs, H, W, C]."""
        # mode="clip" (the indices are always in range) lets numpy write into `out` directly;
        # the default mode="raise" buffers the whole batch first, a second copy of every frame.
        return np.take(self.bank.frames, self.bank.starts[self.video] + self.offset, axis=0,
                       out=out, mode="clip")
