"""Synthetic backgrounds: i.i.d. Gaussian noise and constant colour, in JAX and NumPy.

The noise law is the public natural_rl_environment repository's: per pixel and channel,
N(0, 1) * scale with scale = 50, clipped at 0 (and at 255, to fit uint8) and truncated to an
integer, so about half the pixels are black and the rest spread over 1 ... ~200.

Drawing a float normal per pixel and rounding it wastes most of the work: the result takes only
256 values. With a fixed (Python number) scale and mean, noise is drawn by inverse transform
from 16 random bits per pixel through a 65,536-entry table of the law's quantiles (each value's
probability is exact to within 2^-16): fewer random bits and no float transcendentals per
pixel, which is faster in JAX and in NumPy (the speed-ups are recorded in
bench/results/natural_sources.md). A traced scale or mean (vmapped over envs) takes the direct
route: a float normal per pixel. The JAX and NumPy versions draw from the same law
with different generators: their values differ, their distributions do not.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from statistics import NormalDist

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["NOISE_SCALE", "gaussian_noise", "gaussian_noise_np", "constant_color",
           "constant_color_np", "noise_table"]

NOISE_SCALE = 50.0
_TABLE_BITS = 16


@functools.lru_cache(maxsize=32)
def noise_table(scale: float = NOISE_SCALE, mean: float = 0.0) -> np.ndarray:
    """uint8 [65536]: the law's value at the midpoint quantile of each of 2^16 equal-probability
    cells, so `table[uniform 16-bit integer]` is a draw of clip(mean + N(0,1) * scale, 0, 255)
    truncated to an integer."""
    if not (math.isfinite(scale) and math.isfinite(mean)) or scale < 0:
        raise ValueError(f"noise needs a finite scale >= 0 and a finite mean, got scale={scale}, "
                         f"mean={mean}")
    size = 1 << _TABLE_BITS
    inverse_cdf = NormalDist().inv_cdf
    z = np.array([inverse_cdf((i + 0.5) / size) for i in range(size)])
    table = np.clip(np.floor(mean + scale * z), 0, 255).astype(np.uint8)
    table.flags.writeable = False
    return table


def _is_number(x) -> bool:
    return isinstance(x, (int, float, np.integer, np.floating))


def gaussian_noise(key: jax.Array, shape: Sequence[int], scale: float | jax.Array = NOISE_SCALE,
                   mean: float | jax.Array = 0.0) -> jax.Array:
    """uint8 noise of `shape`: clip(mean + N(0, 1) * scale, 0, 255), truncated to integers.
    `scale` and `mean` may be traced (vmappable); Python numbers take the fast table route."""
    shape = tuple(shape)
    if _is_number(scale) and _is_number(mean):
        table = jnp.asarray(noise_table(float(scale), float(mean)))
        size = math.prod(shape)
        # Two 16-bit uniforms from each 32-bit word: half the random bits of one word a pixel.
        words = jax.random.bits(key, ((size + 1) // 2,), jnp.uint32)
        index = jnp.concatenate([words & 0xFFFF, words >> 16])[:size]
        return table[index].reshape(shape)
    values = mean + jax.random.normal(key, shape, jnp.float32) * scale
    return jnp.clip(values, 0.0, 255.0).astype(jnp.uint8)


def gaussian_noise_np(rng: np.random.Generator, shape: Sequence[int],
                      scale: float = NOISE_SCALE, mean: float = 0.0) -> np.ndarray:
    """The NumPy twin of `gaussian_noise` (same law), drawn from `rng`."""
    index = rng.integers(0, 1 << _TABLE_BITS, size=tuple(shape), dtype=np.uint16)
    return np.take(noise_table(float(scale), float(mean)), index, mode="clip")


def _color_array(color, channels: int, xp):
    color = xp.asarray(color)
    if color.ndim == 0:
        return xp.broadcast_to(color, (channels,))
    if color.shape != (channels,):
        raise ValueError(f"color must have {channels} values (one per channel) or be a single "
                         f"value, got shape {tuple(color.shape)}")
    return color


def constant_color(shape: Sequence[int], color: int | Sequence[int] | jax.Array) -> jax.Array:
    """uint8 [H, W, C] (or any `shape` ending in C) filled with `color` (one value or C values;
    may be traced)."""
    color = _color_array(color, shape[-1], jnp)
    return jnp.broadcast_to(jnp.clip(color, 0, 255).astype(jnp.uint8), tuple(shape))


def constant_color_np(shape: Sequence[int], color: int | Sequence[int]) -> np.ndarray:
    """The NumPy twin of `constant_color` (a writable array)."""
    color = _color_array(color, shape[-1], np)
    return np.broadcast_to(np.clip(color, 0, 255).astype(np.uint8), tuple(shape)).copy()
