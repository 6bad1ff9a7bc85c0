"""Distraction as a dial for the vision envs (Classify, Localize): additive pixel noise.

`Distraction` is the params group (`ClassifyParams.distraction`, `LocalizeParams.distraction`)
of traced strengths, so that one jitted, vmapped program evaluates or trains over a whole
difficulty curve (`DistractionSweep.sweep` builds the batched params and their `in_axes`):

- `noise_sigma` (float >= 0, or None, the default): every observed image value becomes
  `clip(round(value + noise_sigma * z), 0, 255)` as uint8, `z` i.i.d. N(0, 1) per pixel and
  channel, fresh every reset and step (`noisy_image`; `round` is half to even, `jnp.round`).
  Only the image channels take noise: Classify's hidden pixels stay 0 and the mask, window and
  footprint planes stay 255/0, so what the agent may know is unchanged, only how clearly it
  sees it. Under one key, `|noisy - clean|` never shrinks as sigma grows (rounding and
  clipping are monotone); at 0 the observation is the plain env's, bit for bit (the integer
  image plus exactly 0).

None switches the dial off: a None leaf is no pytree leaf, so it stays a Python None under
`jit` and the program has no noise in it at all (the plain env, at the plain env's cost). A
number, 0 included, switches it on: the noise is drawn every step and scaled by the traced
sigma, so one program serves every strength and `params.sweep(noise_sigma=...)` vmaps a curve.
There is no branch on the traced value: a `lax.cond` inside a rollout's loop can cost a GPU a
device-to-host round trip per step.

The noise's key is the reset's or the step's key folded with `NOISE_STREAM`, kept in the
state (`noise_key`) because `get_obs` takes no key; the plain env's images and goals come from
the same splits as before the dial.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxnat.core import is_concrete, sweep_distraction

__all__ = ["Distraction", "ClassifyDistraction", "LocalizeDistraction", "DistractionSweep", "NOISE_STREAM", "BACKGROUND_STREAM",
           "noisy_image", "noise_key_data", "observe_with_noise", "check_distraction", "background_image",
           "dimmed_background"]

NOISE_STREAM = 0x6E6F6973  # "nois": the fold-in that makes the noise's key
BACKGROUND_STREAM = 0x62616B67  # "bakg": the fold-in of the reset key that draws Classify's background


@struct.dataclass
class Distraction:
    """The vision envs' distraction strengths (module docstring): traced numbers. A group of
    its own inside the params so that `in_axes` can name it apart from the dataset, which a
    sweep shares. The defaults are the plain env."""

    # Additive N(0, sigma^2) pixel noise on the image channels, >= 0; None: the dial is off
    # (no noise in the program: the module docstring says why not a branch on 0).
    noise_sigma: float | None = None


@struct.dataclass
class ClassifyDistraction(Distraction):
    """Classify's strengths: the vision envs' noise, and a natural photo behind the image.

    `background_alpha` (in [0, 1], or None, the default: off): the image is composited over a
    natural background frame as foreground with opacity `value / 255`, the frame scaled by
    alpha: `clip(round(value + (1 - value / 255) * alpha * frame), 0, 255)` per pixel and
    channel (`background_image`). A digit's bright strokes stay; its black surround shows the
    photo. At 0 the observation is the plain env's bit for bit; the effect grows with alpha.
    The frame (one per episode, drawn at reset from the split's own photos and video frames:
    `Classify(background_alpha=...)` loads them) is revealed with the image, through the window.
    """

    background_alpha: float | None = None


@struct.dataclass
class LocalizeDistraction(Distraction):
    """Localize's strengths: the vision envs' noise, and how much of the scene's natural
    background shows.

    `background_alpha` (in [0, 1], or None, the default: off): every pixel outside the scene's
    objects (the class map's void pixels: the photo behind Clutter's objects, the unlabelled
    parts of a Cityscapes scene) is scaled by alpha, `round(alpha * value)`, the objects'
    pixels unchanged (`dimmed_background`). At 1 the observation is the plain env's bit for bit,
    at 0 the objects on black; the effect grows as alpha falls. As Classify's: 0 no natural
    background, 1 all of it.
    """

    background_alpha: float | None = None


class DistractionSweep:
    """`sweep` for params with a `distraction: Distraction` field."""

    def sweep(self, **values) -> tuple[Any, Any]:
        """`(params, in_axes)`: these params with the named `Distraction` fields replaced by
        arrays of one leading length (a strength axis), and the matching `in_axes` prefix for
        `jax.vmap` (0 on those fields, None elsewhere: the dataset stays shared)::

            swept, axes = params.sweep(noise_sigma=jnp.linspace(0, 64, 5))
            jax.vmap(env.reset, in_axes=(0, axes))(keys, swept)
        """
        return sweep_distraction(self, values, lambda arrays: check_distraction(type(self.distraction)(**arrays)))


def check_distraction(distraction: Distraction) -> None:
    """One-line `ValueError`s for concrete values out of range (traced ones are clipped)."""
    sigma = distraction.noise_sigma
    if sigma is not None and is_concrete(sigma):
        value = np.asarray(sigma, np.float64)
        if not np.all(np.isfinite(value) & (value >= 0.0)):
            raise ValueError(f"noise_sigma must be a finite number >= 0, got {sigma}")
    alpha = getattr(distraction, "background_alpha", None)
    if alpha is not None and is_concrete(alpha):
        value = np.asarray(alpha, np.float64)
        if not np.all(np.isfinite(value) & (value >= 0.0) & (value <= 1.0)):
            raise ValueError(f"background_alpha must be in [0, 1], got {alpha}")


def dimmed_background(image: jax.Array, background: jax.Array, alpha) -> jax.Array:
    """uint8 `image` with its `background` pixels (bool `[H, W]`) scaled to `round(alpha *
    value)`; `alpha` may be traced (clipped to [0, 1]); at 1, `image` exactly."""
    alpha = jnp.clip(jnp.asarray(alpha, jnp.float32), 0.0, 1.0)
    dimmed = jnp.round(alpha * image.astype(jnp.float32)).astype(jnp.uint8)
    return jnp.where(background[..., None], dimmed, image)


def background_image(image: jax.Array, frame: jax.Array, alpha) -> jax.Array:
    """uint8 `clip(round(image + (1 - image / 255) * alpha * frame), 0, 255)`: `image` over the
    natural `frame` (same shape), its values as opacity; `alpha` may be traced (clipped to
    [0, 1]); at 0, `image` exactly."""
    value = image.astype(jnp.float32)
    alpha = jnp.clip(jnp.asarray(alpha, jnp.float32), 0.0, 1.0)
    blended = value + (1.0 - value / 255.0) * alpha * frame.astype(jnp.float32)
    return jnp.clip(jnp.round(blended), 0.0, 255.0).astype(jnp.uint8)


def noise_key_data(key: jax.Array) -> jax.Array:
    """The state's `noise_key`: the raw data of the reset's or step's key (folded with
    `NOISE_STREAM` only when noise is drawn, so the plain env hashes nothing)."""
    return jax.random.key_data(key)


def noisy_image(image: jax.Array, key_data: jax.Array, sigma) -> jax.Array:
    """uint8 `clip(round(image + sigma * z), 0, 255)`, z ~ N(0, 1) per value, drawn from
    `key_data` folded with `NOISE_STREAM`; `sigma` may be traced (negative: 0)."""
    key = jax.random.fold_in(jax.random.wrap_key_data(key_data), NOISE_STREAM)
    sigma = jnp.maximum(jnp.asarray(sigma, jnp.float32), 0.0)
    z = jax.random.normal(key, image.shape, jnp.float32)
    return jnp.clip(jnp.round(image.astype(jnp.float32) + sigma * z), 0.0, 255.0).astype(jnp.uint8)


def observe_with_noise(build, images, index, key_data, sigma):
    """`build(images, index)` (an observation from the dataset and an image index) with the
    image noised (`noisy_image`, passed to `build` as a one-image dataset); exactly
    `build(images, index)` when `sigma` is None (the dial off: nothing drawn)."""
    if sigma is None:
        return build(images, index)
    return build(noisy_image(images[index], key_data, sigma)[None], 0)
