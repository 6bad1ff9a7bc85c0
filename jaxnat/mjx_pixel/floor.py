"""Floor textures for the floor compositor: which colour each floor pixel gets.

The floor is found by geometry, never by colour: a pixel is floor when its nearest hit
(`render.Hit.geom`) is the floor plane. Those pixels then take their colour from one of three
textures, and only those pixels change between modes (the renderer lights them all the same):

- `"checker"`: the model's own floor texture (Gymnasium's black and grey checker), mapped as
  MuJoCo maps it (the material's `texrepeat` copies across the plane);
- `"video"`: the current frame of a natural video, laid on the floor in world x-y (one copy
  every `tile` metres, repeating), so it stays put under the moving camera and the robot
  walks over it;
- `"noise"`: fresh i.i.d. Gaussian noise per floor pixel, redrawn every frame, from the
  pixel-noise law `noise` (`jaxnat.natural.NOISE_LAWS`; by default N(0, 1) * 50 clipped at 0,
  the paper repository's law).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

__all__ = ["FLOOR_MODES", "texture_at", "floor_rgb"]

FLOOR_MODES = ("checker", "video", "noise")


def texture_at(texture, xy, tile, index=None) -> jax.Array:
    """Nearest texel of `texture [h, w, C]` at world points `xy [..., 2]` -> `[..., C]`.

    One copy of the texture covers `tile = (tx, ty)` metres and repeats; columns run along +x
    and rows along -y, so an image lies upright when seen from a camera looking along +y (the
    robots' tracking cameras). With `index`, `texture` is a stack `[F, h, w, C]` (a video
    bank) and texels come from `texture[index]`, read in place (the frame is never copied)."""
    h, w = texture.shape[-3], texture.shape[-2]
    u = xy[..., 0] / tile[0]
    v = xy[..., 1] / tile[1]
    col = jnp.clip(jnp.floor((u - jnp.floor(u)) * w), 0, w - 1).astype(jnp.int32)
    row = jnp.clip(jnp.floor((jnp.ceil(v) - v) * h), 0, h - 1).astype(jnp.int32)
    return texture[row, col] if index is None else texture[index, row, col]


def floor_rgb(mode: str, table, xy, *, frame=None, frame_index=None, tile=None, key=None,
              channels: int = 3, noise=None) -> jax.Array:
    """float32 `[..., 3]` in [0, 1]: the floor's colour at world points `xy [..., 2]`.

    Args:
        mode: one of `FLOOR_MODES`.
        table: the scene's `render.GeomTable` (its floor texture, for "checker").
        xy: world x-y of each pixel's hit point (only floor pixels use the result).
        frame: uint8 `[h, w, C]` (C = 1 or 3): the video frame, for "video"; or, with
            `frame_index`, the bank's frames `[F, h, w, C]` and the index of the current one.
        tile: metres (x, y) one video frame covers, for "video".
        key: a PRNG key, for "noise".
        channels: 1 draws one noise value per pixel (gray: the law survives the grayscale
            conversion exactly), 3 one per colour channel.
        noise: the law of "noise", a name in `jaxnat.natural.NOISE_LAWS` or a `NoiseLaw`
            (None: `DEFAULT_NOISE`).
    """
    if mode == "checker":
        if table.floor_texture is None:
            return jnp.broadcast_to(jnp.asarray(table.rgb[table.floor]), xy.shape[:-1] + (3,))
        return texture_at(jnp.asarray(table.floor_texture), xy, jnp.asarray(table.floor_tile))
    if mode == "video":
        if frame is None or tile is None:
            raise ValueError('floor="video" needs the current video frame and its tile size')
        colour = texture_at(frame, xy, jnp.asarray(tile, jnp.float32), frame_index)
        return _unit_rgb(colour)
    if mode == "noise":
        if key is None:
            raise ValueError('floor="noise" needs a PRNG key')
        from jaxnat.natural.noise import DEFAULT_NOISE, noise_law

        law = noise_law(DEFAULT_NOISE if noise is None else noise)
        return _unit_rgb(law.sample(key, xy.shape[:-1] + (channels,)))
    raise ValueError(f"floor must be one of {FLOOR_MODES}, got {mode!r}")


def _unit_rgb(pixels) -> jax.Array:
    """uint8 `[..., 1 or 3]` -> float32 `[..., 3]` in [0, 1]."""
    colour = pixels.astype(jnp.float32) / 255.0
    return jnp.broadcast_to(colour, colour.shape[:-1] + (3,))
