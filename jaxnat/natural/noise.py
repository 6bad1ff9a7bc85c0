"""Synthetic backgrounds: i.i.d. Gaussian noise and constant colour, in JAX and NumPy.

The noise laws of the noise controls (`NOISE_LAWS`, one `NoiseLaw` each; every family's noise
control takes its law from here, by name, with `DEFAULT_NOISE` as the default):

- `"authors"` (the default): per pixel and channel, N(0, 1) * 50 clipped at 0 (and at 255, to
  fit uint8) and truncated to an integer, so about half the pixels are black and the rest
  spread over 1 ... ~200 (mean ~19.5, std ~29.0). This is the public natural_rl_environment
  repository's `NoiseSource` (`np.maximum(np.random.randn(h, w, 3) * 50, 0)`, written into the
  uint8 frame), the only noise code the authors published; the paper itself says only
  "i.i.d. Gaussian noise". It is the default so that the noise controls reproduce the paper's
  experiments.
- `"centred"`: N(127.5, 50) rounded to the nearest integer and clipped to [0, 255] (mean 127.5,
  std ~49.6): noise centred in the pixel range, with almost no clipped values. Not the
  authors'; offered for users who want noise that fills the range.

Drawing a float normal per pixel and rounding it wastes most of the work: the result takes only
256 values. With a fixed (Python number) scale and mean, noise is drawn by inverse transform
from 16 random bits per pixel through a 65,536-entry table of the law's quantiles (each value's
probability is exact to within 2^-16): fewer random bits and no float transcendentals per
pixel, which is faster in JAX and in NumPy (the speed-ups are recorded in
bench/results/natural_sources.md). A traced scale or mean (vmapped over envs) takes the direct
route: a float normal per pixel. The JAX and NumPy versions draw from the same law
with different generators: their values differ, their distributions do not.

A noise *strength* dial (`scaled_noise`, the distraction's `noise_sigma`) keeps the table
route's draws and scales each cell's quantile by a traced sigma, so one key gives the same
cells at every strength (monotone in sigma, pixel by pixel) and the law's own scale gives the
table's values bit for bit.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from statistics import NormalDist

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["NOISE_SCALE", "NoiseLaw", "NOISE_LAWS", "DEFAULT_NOISE", "noise_law",
           "gaussian_noise", "gaussian_noise_np", "constant_color", "constant_color_np",
           "noise_table", "scaled_noise"]

NOISE_SCALE = 50.0
_TABLE_BITS = 16


@dataclass(frozen=True)
class NoiseLaw:
    """A pixel-noise law: uint8 `clip(floor(mean + scale * N(0, 1)), 0, 255)`, i.i.d. per pixel
    and channel (`floor(x + 0.5)` is rounding to the nearest integer)."""

    name: str
    mean: float
    scale: float

    def sample(self, key: jax.Array, shape: Sequence[int]) -> jax.Array:
        """Draws of `shape` (uint8, JAX): `gaussian_noise` with this law."""
        return gaussian_noise(key, shape, self.scale, self.mean)

    def sample_scaled(self, key: jax.Array, shape: Sequence[int], sigma) -> jax.Array:
        """Draws of `shape` (uint8, JAX) at strength `sigma` (may be traced): `scaled_noise`
        with this law; `sigma == self.scale` is `sample` bit for bit."""
        return scaled_noise(key, shape, sigma, self.scale, self.mean)

    def sample_np(self, rng: np.random.Generator, shape: Sequence[int]) -> np.ndarray:
        """Draws of `shape` (uint8, NumPy): `gaussian_noise_np` with this law."""
        return gaussian_noise_np(rng, shape, self.scale, self.mean)

    def probabilities(self) -> np.ndarray:
        """float64 [256]: the exact P(value = k), k = 0 ... 255."""
        cdf = NormalDist(self.mean, self.scale).cdf if self.scale > 0 else (
            lambda x: float(x > self.mean))
        upper = np.array([cdf(k + 1) for k in range(255)] + [1.0])  # P(value <= k)
        return np.diff(np.concatenate([[0.0], upper]))

    def moments(self) -> tuple[float, float]:
        """(mean, standard deviation) of one value, exact."""
        p, k = self.probabilities(), np.arange(256.0)
        mean = float(p @ k)
        return mean, float(np.sqrt(p @ (k - mean) ** 2))


NOISE_LAWS = {
    "authors": NoiseLaw("authors", mean=0.0, scale=NOISE_SCALE),
    "centred": NoiseLaw("centred", mean=128.0, scale=NOISE_SCALE),  # round(127.5 + 50 z)
}
DEFAULT_NOISE = "authors"


def noise_law(noise: str | NoiseLaw = DEFAULT_NOISE) -> NoiseLaw:
    """The `NoiseLaw` named `noise` (one of `NOISE_LAWS`), or `noise` itself."""
    if isinstance(noise, NoiseLaw):
        return noise
    if noise not in NOISE_LAWS:
        raise ValueError(f"noise must be one of {tuple(NOISE_LAWS)}, got {noise!r}")
    return NOISE_LAWS[noise]


@functools.lru_cache(maxsize=32)
def noise_table(scale: float = NOISE_SCALE, mean: float = 0.0) -> np.ndarray:
    """uint8 [65536]: the law's value at the midpoint quantile of each of 2^16 equal-probability
    cells, so `table[uniform 16-bit integer]` is a draw of clip(mean + N(0,1) * scale, 0, 255)
    truncated to an integer."""
    if not (math.isfinite(scale) and math.isfinite(mean)) or scale < 0:
        raise ValueError(f"noise needs a finite scale >= 0 and a finite mean, got scale={scale}, "
                         f"mean={mean}")
    table = np.clip(np.floor(mean + scale * _quantiles()), 0, 255).astype(np.uint8)
    table.flags.writeable = False
    return table


@functools.lru_cache(maxsize=2)
def _quantiles(dtype=np.float64) -> np.ndarray:
    """[65536]: N(0, 1)'s midpoint quantile of each of `noise_table`'s equal-probability cells."""
    size = 1 << _TABLE_BITS
    inverse_cdf = NormalDist().inv_cdf
    z = np.array([inverse_cdf((i + 0.5) / size) for i in range(size)]).astype(dtype)
    z.flags.writeable = False
    return z


def _cell_index(key: jax.Array, size: int) -> jax.Array:
    """uint32 [size]: a uniform 16-bit cell per value, two from each 32-bit word (half the
    random bits of one word a value)."""
    words = jax.random.bits(key, ((size + 1) // 2,), jnp.uint32)
    return jnp.concatenate([words & 0xFFFF, words >> 16])[:size]


def scaled_noise(key: jax.Array, shape: Sequence[int], sigma: float | jax.Array,
                 scale: float = NOISE_SCALE, mean: float = 0.0) -> jax.Array:
    """uint8 noise of `shape` at strength `sigma` (may be traced; negative is clipped to 0):
    clip(floor(mean + sigma * z), 0, 255), z the quantile of the cell that `gaussian_noise`'s
    table route draws for the law `(scale, mean)` with the same key.

    Why the same cells: a strength sweep under one key then moves every value away from `mean`
    monotonically as sigma grows, sigma = 0 is the constant `floor(mean)`, and sigma == `scale`
    selects the law's table itself, so the default strength is `gaussian_noise(key, shape,
    scale, mean)` bit for bit (the float32 product alone may differ from the float64 table by
    one level at a cell's edge)."""
    shape = tuple(shape)
    index = _cell_index(key, math.prod(shape))
    table = jnp.asarray(noise_table(float(scale), float(mean)))[index]
    sigma = jnp.maximum(jnp.asarray(sigma, jnp.float32), 0.0)
    values = jnp.floor(jnp.float32(mean) + sigma * jnp.asarray(_quantiles(np.float32))[index])
    scaled = jnp.clip(values, 0.0, 255.0).astype(jnp.uint8)
    return jnp.where(sigma == jnp.float32(scale), table, scaled).reshape(shape)


def _is_number(x) -> bool:
    return isinstance(x, (int, float, np.integer, np.floating))


def gaussian_noise(key: jax.Array, shape: Sequence[int], scale: float | jax.Array = NOISE_SCALE,
                   mean: float | jax.Array = 0.0) -> jax.Array:
    """uint8 noise of `shape`: clip(mean + N(0, 1) * scale, 0, 255), truncated to integers.
    `scale` and `mean` may be traced (vmappable); Python numbers take the fast table route."""
    shape = tuple(shape)
    if _is_number(scale) and _is_number(mean):
        table = jnp.asarray(noise_table(float(scale), float(mean)))
        return table[_cell_index(key, math.prod(shape))].reshape(shape)
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
