"""Synthetic backgrounds: i.i.d. Gaussian noise and constant colour, in JAX and NumPy.

The noise law is the public natural_rl_environment repository's: per pixel and channel,
N(0, 1) * scale with scale = 50, clipped at 0 (and at 255, to fit uint8), so about half the
pixels are black and the rest spread over 1 ... ~200. The JAX and NumPy versions draw from the
same law with different generators: their values differ, their distributions do not.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["NOISE_SCALE", "gaussian_noise", "gaussian_noise_np", "constant_color",
           "constant_color_np"]

NOISE_SCALE = 50.0


def gaussian_noise(key: jax.Array, shape: Sequence[int], scale: float | jax.Array = NOISE_SCALE,
                   mean: float | jax.Array = 0.0) -> jax.Array:
    """uint8 noise of `shape`: clip(mean + N(0, 1) * scale, 0, 255), truncated to integers.
    `scale` and `mean` may be traced (vmappable)."""
    values = mean + jax.random.normal(key, tuple(shape), jnp.float32) * scale
    return jnp.clip(values, 0.0, 255.0).astype(jnp.uint8)


def gaussian_noise_np(rng: np.random.Generator, shape: Sequence[int],
                      scale: float = NOISE_SCALE, mean: float = 0.0) -> np.ndarray:
    """The NumPy twin of `gaussian_noise` (same law), drawn from `rng`."""
    values = rng.standard_normal(tuple(shape), dtype=np.float32)
    values *= scale
    values += mean
    return np.clip(values, 0.0, 255.0, out=values).astype(np.uint8)


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
