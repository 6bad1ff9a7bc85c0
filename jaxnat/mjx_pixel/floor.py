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

Filtering (`footprint=`, which `render.Renderer` passes with `floor_filter="mip"`, its
default): far away, one pixel covers many texels, and reading the nearest texel there turns the
checker and the video into moire noise near the horizon. With a footprint, the checker and the
video are read from mip levels (`mip_levels`: each level the 2x2 box average of the one below,
down to 1x1), the level chosen per pixel from the footprint as OpenGL chooses it (`texture_mip`),
so the far floor fades to the texture's average as in MuJoCo's renderer. Without one (or with
`floor_filter="nearest"`) every pixel reads the nearest texel of the full-size texture.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["FLOOR_MODES", "texture_at", "texture_mip", "mip_levels", "floor_rgb"]

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


def mip_levels(texture) -> list:
    """The mip chain of `texture [h, w, C]` (numpy or jax, float): the texture itself, then each
    level half the one before (sizes `max(1, n // 2)`, as OpenGL's), down to 1x1. A texel of a
    level is the average of the texels it covers in the level below: the 2x2 block for even
    sizes, area-weighted for odd ones (so the last level is the texture's exact mean)."""
    xp = np if isinstance(texture, np.ndarray) else jnp
    levels = [texture]
    while levels[-1].shape[0] > 1 or levels[-1].shape[1] > 1:
        level = levels[-1]
        for axis in (0, 1):
            n = level.shape[axis]
            if n == 1:
                continue
            if n % 2 == 0:  # 2:1 box, the cheap path (video frames are decoded to even sizes)
                shape = level.shape[:axis] + (n // 2, 2) + level.shape[axis + 1:]
                level = level.reshape(shape).mean(axis=axis + 1)
            else:
                weights = _area_weights(n, n // 2).astype(np.float32)
                level = xp.moveaxis(xp.tensordot(weights, xp.moveaxis(level, axis, 0), axes=1),
                                    0, axis)
        levels.append(level)
    return levels


def _area_weights(n: int, m: int) -> np.ndarray:
    """[m, n]: the share of each of n source texels in each of m target texels that split the
    same span evenly (rows sum to 1)."""
    edges = np.arange(m + 1) * (n / m)
    lo, hi = edges[:-1, None], edges[1:, None]
    cells = np.arange(n)[None, :]
    overlap = np.clip(np.minimum(hi, cells + 1) - np.maximum(lo, cells), 0.0, None)
    return overlap / (n / m)


def texture_mip(levels, xy, tile, footprint) -> jax.Array:
    """Mip-filtered texels of the chain `levels` (`mip_levels`) at world points `xy [..., 2]`
    -> float32 `[..., C]`, mapped as `texture_at` maps level 0.

    `footprint = ((dx, dy), (dx, dy))`: the world x-y step of the hit point per pixel to the
    right and per pixel down, four float32 `[...]` arrays (`render.Renderer.footprint`). As OpenGL does
    for `GL_LINEAR_MIPMAP_LINEAR` (MuJoCo's setting), the level of detail is log2 of the longer
    of the two steps in level-0 texels, and the pixel blends the two levels around it linearly.
    Unlike OpenGL, each level is read at its nearest texel, not bilinearly: two texel reads per
    pixel instead of eight, and where a pixel covers at most one texel (level of detail <= 0,
    the near floor) the result is exactly the nearest texel, as before filtering. The chosen
    level's texels are at most two pixels wide, so this leaves no visible blocks at 84x84."""
    h, w = levels[0].shape[0], levels[0].shape[1]
    # Sizes and offsets of the levels packed end to end (static, from the shapes).
    sizes = np.array([[lv.shape[0], lv.shape[1]] for lv in levels], np.int32)
    offsets = np.concatenate([[0], np.cumsum(sizes[:, 0] * sizes[:, 1])[:-1]]).astype(np.int32)
    xp = np if all(isinstance(lv, np.ndarray) for lv in levels) else jnp
    packed = xp.concatenate([lv.reshape(-1, lv.shape[-1]) for lv in levels], axis=0)
    packed = jnp.asarray(packed, jnp.float32)
    # Level-0 texels per pixel step, along each screen axis.
    (rx, ry), (dx, dy) = footprint
    su, sv = w / tile[0], h / tile[1]
    rho2 = jnp.maximum((rx * su) ** 2 + (ry * sv) ** 2, (dx * su) ** 2 + (dy * sv) ** 2)
    top = len(levels) - 1
    # nan_to_num: pixels off the floor (sky: infinite depth) carry no footprint; their colour
    # is discarded, but their texel indices must stay in range.
    lod = jnp.clip(jnp.nan_to_num(0.5 * jnp.log2(rho2), nan=0.0), 0.0, float(top))
    low = jnp.floor(lod)
    blend = (lod - low)[..., None]
    low = low.astype(jnp.int32)
    high = jnp.minimum(low + 1, top)
    u = xy[..., 0] / tile[0]
    v = xy[..., 1] / tile[1]
    fu, fv = u - jnp.floor(u), jnp.ceil(v) - v  # as texture_at: columns +x, rows -y

    def fetch(level):
        # The level's size and offset by a chain of selects over the few static levels, not
        # lookups in small tables: elementwise, so XLA keeps them in the pixel loop.
        lh, lw, off = (jnp.full(level.shape, v, jnp.int32) for v in (h, w, 0))
        for k in range(1, top + 1):
            deeper = level >= k
            lh = jnp.where(deeper, int(sizes[k, 0]), lh)
            lw = jnp.where(deeper, int(sizes[k, 1]), lw)
            off = jnp.where(deeper, int(offsets[k]), off)
        col = jnp.clip(jnp.floor(fu * lw.astype(jnp.float32)).astype(jnp.int32), 0, lw - 1)
        row = jnp.clip(jnp.floor(fv * lh.astype(jnp.float32)).astype(jnp.int32), 0, lh - 1)
        return packed[off + row * lw + col]

    return fetch(low) * (1.0 - blend) + fetch(high) * blend


def floor_rgb(mode: str, table, xy, footprint=None, *, frame=None, frame_index=None, tile=None,
              key=None, channels: int = 3, noise=None) -> jax.Array:
    """float32 `[..., 3]` in [0, 1]: the floor's colour at world points `xy [..., 2]`.

    Args:
        mode: one of `FLOOR_MODES`.
        table: the scene's `render.GeomTable` (its floor texture, for "checker").
        xy: world x-y of each pixel's hit point (only floor pixels use the result).
        footprint: each pixel's world x-y step per pixel right and down, `((dx, dy), (dx, dy))`
            (`render.Renderer` passes it with `floor_filter="mip"`): the checker and the video
            are then mip-filtered (`texture_mip`); None reads the nearest texel (`texture_at`).
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
        if footprint is not None:  # the chain is built on the host, once per trace
            levels = mip_levels(np.asarray(table.floor_texture, np.float32))
            return texture_mip(levels, xy, np.asarray(table.floor_tile), footprint)
        return texture_at(jnp.asarray(table.floor_texture), xy, jnp.asarray(table.floor_tile))
    if mode == "video":
        if frame is None or tile is None:
            raise ValueError('floor="video" needs the current video frame and its tile size')
        tile = jnp.asarray(tile, jnp.float32)
        if footprint is not None:
            # The frame changes every step, so its chain is built per frame, on the device:
            # the levels below the frame hold a third of its texels.
            current = frame if frame_index is None else frame[frame_index]
            levels = mip_levels(current.astype(jnp.float32) / 255.0)
            colour = texture_mip(levels, xy, tile, footprint)
            return jnp.broadcast_to(colour, colour.shape[:-1] + (3,))
        colour = texture_at(frame, xy, tile, frame_index)
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
