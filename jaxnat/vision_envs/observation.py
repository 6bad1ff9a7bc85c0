"""Channels-last uint8 observations `[H, W, C + K]` written as 32-bit words.

The navigation envs observe an image (zeroed where hidden) beside K binary planes (revealed
mask, window, footprint) as uint8 `[H, W, C + K]`. A batched step is memory bound, and XLA
writes a uint8 array with a minor dimension of 3 to 5 one byte per thread, at a fraction of
the memory bandwidth. `masked_image_observation` builds the same bytes as uint32 words (and
reads the image as words) and bitcasts the result, which XLA turns into wide loads and stores
(`bench/classify_throughput.py` measures both paths side by side). On CPUs XLA's byte-wise
code is the faster one, so that path is taken there. `writer=` picks a path by hand (the envs'
`observation_writer` argument); every path writes the same bytes.

Byte layout: pixel `(r, c)`, channel `ch` is byte `(c * P + ch)` of row `r` (P = C + K); a
group of 4 pixels is exactly P words, so when `W % 4 == 0` each output word is an OR of four
shifted bytes whose sources are known at trace time. Other widths use the byte-wise path.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

__all__ = ["masked_image_observation", "masked_image_observation_reference",
           "wordwise_observation", "WRITERS"]

# `writer=` of `masked_image_observation`: "auto" picks by platform at lowering.
WRITERS = ("auto", "wordwise", "bytewise")


def masked_image_observation(images, index, image_mask, planes, writer: str = "auto") -> jax.Array:
    """uint8 `[H, W, C + K]`: `images[index]` where `image_mask` (0 elsewhere), then each of the
    K boolean `planes` as 255/0.

    Args:
        images: uint8 `[N, H, W, C]`, the dataset (the gather reads only `images[index]`).
        index: int scalar.
        image_mask: bool `[H, W]`.
        planes: sequence of bool `[H, W]`.
        writer: "auto" (word-wise, except on CPUs), "wordwise" (`wordwise_observation`) or
            "bytewise" (`masked_image_observation_reference`). Widths that are not a multiple
            of 4 always take the byte-wise path. Every choice gives the same bytes.
    """
    if writer not in WRITERS:
        raise ValueError(f"writer must be one of {WRITERS}, got {writer!r}")
    if writer == "bytewise" or images.shape[2] % 4:
        return masked_image_observation_reference(images, index, image_mask, planes)
    if writer == "wordwise":
        return wordwise_observation(images, index, image_mask, planes)
    # XLA's byte-wise code is the faster one on CPUs (bench/results/classify_throughput.md), so
    # the choice is made per platform, at lowering.
    return jax.lax.platform_dependent(
        images, index, image_mask, list(planes),
        cpu=masked_image_observation_reference,
        default=wordwise_observation,
    )


def wordwise_observation(images, index, image_mask, planes) -> jax.Array:
    """The same observation, built as uint32 words (see the module docstring); needs
    `W % 4 == 0`."""
    _, h, w, c = images.shape
    p = c + len(planes)
    # Free views: [N, H, W*C] bytes -> [N, H, W*C/4] words (little-endian: byte j is bits 8j).
    words = jax.lax.bitcast_convert_type(images.reshape(-1, h, w * c // 4, 4), jnp.uint32)
    image = words[index].reshape(h, w // 4, c)  # pixel group g: C words = 4 pixels x C bytes
    mask = image_mask.reshape(h, w // 4, 4)
    flags = [plane.reshape(h, w // 4, 4) for plane in planes]

    def byte(q):
        """Output byte q (0 .. 4P-1) of a pixel group, as a uint32 in 0..255."""
        pixel, ch = divmod(q, p)
        if ch < c:
            j = pixel * c + ch  # byte j of the group's image words
            value = (image[..., j // 4] >> (8 * (j % 4))) & 0xFF
            return jnp.where(mask[..., pixel], value, jnp.uint32(0))
        return jnp.where(flags[ch - c][..., pixel], jnp.uint32(255), jnp.uint32(0))

    group = [
        byte(4 * k) | byte(4 * k + 1) << 8 | byte(4 * k + 2) << 16 | byte(4 * k + 3) << 24
        for k in range(p)
    ]
    # Stacking computes each word once (a select over an iota would compute all P per word).
    return jax.lax.bitcast_convert_type(jnp.stack(group, -1), jnp.uint8).reshape(h, w, p)


def masked_image_observation_reference(images, index, image_mask, planes) -> jax.Array:
    """The same observation, byte-wise: the specification `masked_image_observation` meets."""
    image = images[index]
    return jnp.concatenate(
        [jnp.where(image_mask[..., None], image, jnp.uint8(0))]
        + [plane[..., None].astype(jnp.uint8) * jnp.uint8(255) for plane in planes],
        axis=-1,
    )
