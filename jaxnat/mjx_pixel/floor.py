"""Floor textures for the floor compositor: which colour each floor pixel gets.

The floor is found by geometry, never by colour: a pixel is floor when its nearest hit
(`render.Hit.geom`) is the floor plane. Those pixels then take their colour from one of three
textures, and only those pixels change between modes (the renderer lights them all the same):

- `"checker"`: the model's own floor texture (Gymnasium's black and grey checker), mapped as
  MuJoCo maps it (the material's `texrepeat` copies across the plane);
- `"video"`: the current frame of a natural video, laid on the floor in world x-y (one copy
  every `tile` metres, repeating), so it stays put under the moving camera and the robot
  walks over it; with `video_alpha` (`PixelParams.distraction`), blended over the checker
  (`blend_video`: 0 is the checker, 1 the video, each exactly);
- `"noise"`: fresh i.i.d. Gaussian noise per floor pixel, redrawn every frame, from the
  pixel-noise law `noise` (`jaxnat.natural.NOISE_LAWS`; by default N(0, 1) * 50 clipped at 0,
  the paper repository's law).

Filtering (`footprint=`, which `render.Renderer` passes with `floor_filter="mip"`, its
default): far away, one pixel covers many texels, and reading the nearest texel there turns the
checker and the video into moire noise near the horizon. With a footprint, the video (and any
floor texture other than a 2x2 checker) is read from mip levels (`mip_levels`: each level the
2x2 box average of the one below, down to 1x1), packed end to end (`pack_mips`); each pixel
reads the nearest texel of the level nearest its level of detail, chosen from the footprint as
OpenGL chooses it (`texture_mip`), so the far floor fades to the texture's average as in
MuJoCo's renderer, at the cost of one texel read per pixel, as unfiltered. The video's chains
are built per bank frame, once when the bank is loaded (`PixelParams.video_mips`). MuJoCo's
builtin checker, a 2x2 pattern, is filtered in closed form instead (`checker_box`: a tent
average of two square waves over the footprint's extent along each axis), which reads no texel
at all and lies closer to MuJoCo's trilinear floor. A checker whose colours lie on one line
(MuJoCo's two-colour builtin) is one number per pixel. Without a footprint (or with
`floor_filter="nearest"`) every pixel reads the nearest texel of the full-size texture.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["FLOOR_MODES", "Footprint", "texture_at", "texture_mip", "checker_box", "mip_levels",
           "mip_sizes", "pack_mips", "floor_rgb", "blend_video"]

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


def mip_sizes(h: int, w: int) -> list:
    """`[(h, w), ...]`: the sizes of the levels of `mip_levels` for an `h x w` texture."""
    sizes = [(int(h), int(w))]
    while sizes[-1] != (1, 1):
        sizes.append((max(1, sizes[-1][0] // 2), max(1, sizes[-1][1] // 2)))
    return sizes


def pack_mips(texture):
    """The mip chain of `texture` packed for `texture_mip`: every level's texels end to end,
    row-major, level 0 first.

    `texture [h, w, C]` (numpy float, e.g. the checker): float32 `[M, C]`, M the texels of all
    levels. A stack of uint8 frames `[F, h, w, C]` (a video bank, numpy or jax): uint8
    `[F, M, C]`, each frame's chain (levels rounded to the nearest 8-bit value; level 0 is the
    frame itself). Built once per bank (`PixelMuJoCo` puts it in `PixelParams.video_mips`): 4/3
    of the bank's memory, level 0 included so that a pixel reads one array, and a step only
    reads texels."""
    if texture.ndim == 3:
        levels = mip_levels(np.asarray(texture, np.float32))
        return np.concatenate([lv.reshape(-1, lv.shape[-1]) for lv in levels]).astype(np.float32)

    def one(frame):
        levels = mip_levels(frame.astype(jnp.float32))
        packed = jnp.concatenate([lv.reshape(-1, lv.shape[-1]) for lv in levels])
        return jnp.round(packed).astype(jnp.uint8)  # level 0 stays exact

    return jax.jit(lambda frames: jax.lax.map(one, frames, batch_size=64))(jnp.asarray(texture))


class Footprint:
    """Each pixel's footprint on the floor plane: the world x-y step of its hit point when the
    pixel moves one to the right (`right = (x, y)`) or one down (`down`), `depth` times the
    per-unit-depth steps `right`/`down` (`depth` None: the steps are absolute).

    `render.Renderer.footprint` makes one. With a tracking camera (a constant orientation) and
    a floor fixed to the world, `right` and `down` are host constants (numpy `[H, W]`), so the
    level of detail costs one log2 per pixel (`lod`); otherwise they are traced arrays."""

    def __init__(self, right, down, depth=None):
        self.right, self.down, self.depth = right, down, depth

    def lod(self, scale, aspect: float = 1.0) -> jax.Array:
        """log2 of the longer of the two steps, in texels of `scale` per metre along x and
        `scale * aspect` along y (`aspect` a host number): OpenGL's level of detail. +inf
        where nothing is hit (infinite depth); possibly NaN there with traced steps
        (`texture_mip` reads the last level for +inf, level 0 for NaN)."""
        (rx, ry), (dx, dy) = self.right, self.down
        if all(isinstance(a, np.ndarray) for a in (rx, ry, dx, dy)):
            longest = np.maximum(rx * rx + (aspect * ry) ** 2, dx * dx + (aspect * dy) ** 2)
            base = (0.5 * np.log2(np.maximum(longest, 1e-30))).astype(np.float32)
        else:
            longest = jnp.maximum(rx * rx + (aspect * ry) ** 2, dx * dx + (aspect * dy) ** 2)
            base = 0.5 * jnp.log2(longest)
        if self.depth is None:
            return base + jnp.log2(jnp.asarray(scale, jnp.float32))
        return jnp.log2(self.depth * jnp.asarray(scale, jnp.float32)) + base


    def extent(self) -> tuple:
        """`(x, y)`: the world extent of the pixel's footprint along x and along y, `|right| +
        |down|` per axis (the bounding box of the parallelogram the pixel covers)."""
        (rx, ry), (dx, dy) = self.right, self.down
        xp = np if all(isinstance(a, np.ndarray) for a in (rx, ry, dx, dy)) else jnp
        ex, ey = xp.abs(rx) + xp.abs(dx), xp.abs(ry) + xp.abs(dy)
        if self.depth is None:
            return ex, ey
        return self.depth * ex, self.depth * ey


def _as_footprint(footprint) -> Footprint:
    if isinstance(footprint, Footprint):
        return footprint
    right, down = footprint
    return Footprint(tuple(right), tuple(down))


def texture_mip(levels, xy, tile, footprint, *, shape=None, index=None) -> jax.Array:
    """Mip-filtered texels at world points `xy [..., 2]` -> `[..., C]`, mapped as
    `texture_at` maps level 0: float32 for a float chain, the chain's dtype (uint8) for a packed
    video bank.

    `levels`: the chain, a list (`mip_levels`) or packed (`pack_mips`; then `shape = (h, w)`,
    level 0's size, and, for a bank `[F, M, C]`, `index` the frame). `footprint`: a `Footprint`
    (`render.Renderer.footprint`), or `((dx, dy), (dx, dy))`, the world x-y step of the hit
    point per pixel right and down. As OpenGL, the level of detail is log2 of the longer of the
    two steps in level-0 texels; the pixel then reads the nearest texel of the nearest level
    (OpenGL's `GL_NEAREST_MIPMAP_NEAREST`: level 0 up to a level of detail of 1/2). MuJoCo's
    renderer is trilinear (`GL_LINEAR_MIPMAP_LINEAR`: four texels bilinearly in each of the two
    levels around the level of detail, blended): here one texel per pixel, as the unfiltered
    floor reads, so the near floor (up to sqrt(2) texels per pixel) is exactly the nearest
    texel, and where the level changes the floor steps from one level to the next instead of
    blending (the chosen level's texels are 0.7 to 1.4 pixels wide)."""
    if isinstance(levels, (list, tuple)):
        shape = levels[0].shape[:2]
        levels = pack_mips(levels[0]) if isinstance(levels[0], np.ndarray) else jnp.concatenate(
            [jnp.asarray(lv, jnp.float32).reshape(-1, lv.shape[-1]) for lv in levels])
    h, w = int(shape[0]), int(shape[1])
    sizes = mip_sizes(h, w)
    offsets = np.concatenate([[0], np.cumsum([a * b for a, b in sizes])[:-1]])
    if offsets[-1] >= 2**24:
        raise ValueError(f"a {h}x{w} texture is too large for float32 texel indices")
    if np.ndim(tile) == 0:  # square copies (the video's tile, which may be traced)
        tile_x = tile_y = tile
        aspect = h / w
    else:  # host numbers (x, y): the checker's
        tile_x, tile_y = float(tile[0]), float(tile[1])
        aspect = (h / w) * (tile_x / tile_y)
    lod = _as_footprint(footprint).lod(w / tile_x, aspect)
    # The nearest level: the largest k with lod > k - 1/2 (NaN, no hit: level 0). Its size is
    # level 0's halved k times (`mip_sizes`), its offset one select per level: elementwise, so
    # XLA keeps it in the pixel loop, and in float32 (exact: a chain holds fewer than 2**24
    # texels, and halving is exact).
    k = jnp.clip(jnp.ceil(jnp.nan_to_num(lod - 0.5, nan=0.0)), 0.0, len(sizes) - 1.0)
    half = jnp.exp2(-k)
    lw = jnp.maximum(jnp.floor(w * half), 1.0)
    lh = jnp.maximum(jnp.floor(h * half), 1.0)
    off = jnp.zeros(lod.shape, jnp.float32)
    for level in range(1, len(sizes)):
        off = jnp.where(k == level, float(offsets[level]), off)
    u = xy[..., 0] / tile_x
    v = xy[..., 1] / tile_y
    fu, fv = u - jnp.floor(u), jnp.ceil(v) - v  # as texture_at: columns +x, rows -y
    col = jnp.minimum(jnp.floor(fu * lw), lw - 1.0)  # fu, fv in [0, 1]: only the top end clips
    row = jnp.minimum(jnp.floor(fv * lh), lh - 1.0)
    flat = (off + row * lw + col).astype(jnp.uint32)  # unsigned: no negative-index fix-up
    levels = jnp.asarray(levels)
    return levels[flat] if index is None else levels[index, flat]


def checker_box(cells, xy, tile, footprint, *, texels: int) -> jax.Array:
    """A 2x2 checker texture, `cells = (a, b)` (`a` top-left and bottom-right), filtered over
    each pixel's footprint in closed form -> float32 `[..., 1]`, mapped as `texture_at` maps
    it (`tile = (tx, ty)` host metres per copy, `texels` the texture's width).

    A checker is the product of two square waves, one along x and one along y, and a square
    wave's average under a tent (triangle) window is a second difference of its second
    integral, a periodic piecewise quadratic: so filtering costs a few arithmetic operations
    and no texel read. Each wave is filtered over the footprint's own extent along its axis
    (`Footprint.extent`, `_tent_width`), so the far floor, stretched along y, averages to the
    two colours' mean, as the mip chain's last level, while the squares' edges across x stay
    as sharp as the pixels allow (closer to MuJoCo's trilinear floor than the nearest mip
    level: bench/results/pixel_mujoco.md). Along an axis where the footprint is under sqrt(2)
    texels (the mip chain's level 0) the wave is read exactly, as unfiltered."""
    tile_x, tile_y = float(tile[0]), float(tile[1])
    extent_x, extent_y = _as_footprint(footprint).extent()
    u = xy[..., 0] / tile_x
    v = -xy[..., 1] / tile_y  # rows run along -y
    wave = (_tent_square_wave(u, _tent_width(extent_x / tile_x, texels))
            * _tent_square_wave(v, _tent_width(extent_y / tile_y, texels)))
    a, b = cells
    blend = 0.5 * (a + b) + 0.5 * (a - b) * wave
    return jnp.where(wave == 1.0, a, jnp.where(wave == -1.0, b, blend))[..., None]  # cells exact


def _tent_width(extent, texels: int):
    """The tent's half-width for a footprint `extent` (in copies of the texture): the extent
    itself (a tent twice the footprint wide, as trilinear filtering blends two levels, the
    coarser one texels twice the footprint), at most `_WIDEST` copies (beyond it the average is
    the mean, 0, to float32's precision, and an infinite extent, where nothing is hit, gives 0
    instead of NaN); 0 (no filtering) under sqrt(2) texels or where the extent is NaN."""
    return jnp.where(extent * texels >= np.sqrt(2.0), jnp.minimum(extent, _WIDEST), 0.0)


_WIDEST = 1e4  # copies: |average| <= 1 / (8 * width**2), about 1e-9 here


def _tent_square_wave(x, half_width):
    """The square wave of period 1 (+1 on [0, 1/2), -1 on [1/2, 1)) averaged under a tent
    window of `half_width` centred on `x`; the wave itself where `half_width` is 0.

    The average is a second difference of the wave's second integral over the window, divided
    by its squared half-width. The second integral, periodic and of mean 0, is
    `(1/2 - f) (|f - 1/2| / 2 - 1/4)` with `f` the fractional part: no branch, so a pixel costs
    a few multiply-adds."""
    def second_integral(y):
        f = y - jnp.floor(y)
        return (0.5 - f) * (0.5 * jnp.abs(f - 0.5) - 0.25)

    sharp = jnp.where(x - jnp.floor(x) < 0.5, 1.0, -1.0)
    filtered = half_width > 0
    r = jnp.where(filtered, half_width, 1.0)
    average = (second_integral(x + r) - 2.0 * second_integral(x) + second_integral(x - r)) / (r * r)
    return jnp.where(filtered, average, sharp)


def _checker_cells(values):
    """`(a, b)` when `values [h, w, 1]` is a 2x2 checker (MuJoCo's builtin: four equal blocks,
    `a` top-left and bottom-right, `b != a` in the others), else None."""
    h, w = values.shape[:2]
    if values.shape[-1] != 1 or h % 2 or w % 2:
        return None
    t = values[..., 0]
    a, b = float(t[0, 0]), float(t[0, w // 2])
    blocks = ((t[:h // 2, :w // 2], a), (t[h // 2:, w // 2:], a), (t[:h // 2, w // 2:], b),
              (t[h // 2:, :w // 2], b))
    if a == b or not all(np.all(block == value) for block, value in blocks):
        return None
    return a, b


def floor_rgb(mode: str, table, xy, footprint=None, *, frame=None, frame_index=None, tile=None,
              key=None, channels: int = 3, noise=None, mips=None, video_alpha=None,
              noise_sigma=None) -> jax.Array:
    """float32 `[..., 3]` in [0, 1]: the floor's colour at world points `xy [..., 2]`.

    Args:
        mode: one of `FLOOR_MODES`.
        table: the scene's `render.GeomTable` (its floor texture, for "checker").
        xy: world x-y of each pixel's hit point (only floor pixels use the result).
        footprint: each pixel's `Footprint` on the floor (`render.Renderer` passes it with
            `floor_filter="mip"`), or `((dx, dy), (dx, dy))`, its world x-y step per pixel
            right and down: the checker and the video are then mip-filtered (`texture_mip`);
            None reads the nearest texel (`texture_at`).
        frame: uint8 `[h, w, C]` (C = 1 or 3): the video frame, for "video"; or, with
            `frame_index`, the bank's frames `[F, h, w, C]` and the index of the current one.
        tile: metres one video frame covers, for "video": a scalar (square copies; it may be
            traced) or host numbers (x, y).
        key: a PRNG key, for "noise".
        channels: 1 draws one noise value per pixel (gray: the law survives the grayscale
            conversion exactly), 3 one per colour channel.
        noise: the law of "noise", a name in `jaxnat.natural.NOISE_LAWS` or a `NoiseLaw`
            (None: `DEFAULT_NOISE`).
        mips: the video's mip chains, `pack_mips(frame)` (uint8 `[F, M, C]` for a bank, read
            at `frame_index`), built once per bank: with a footprint, "video" reads them and
            builds nothing per step. Without them it builds the current frame's chain on the
            device every call (a third of the frame's texels more to write, every step).
        video_alpha: for "video", the video's weight over the checker, a float in [0, 1] (may
            be traced; values outside are clipped): `alpha * video + (1 - alpha) * checker`
            (`blend_video`). None: the video alone (as 1, without computing the checker).
        noise_sigma: for "noise", the noise's strength (may be traced): the law's draws with
            their spread scaled to `noise_sigma` (`NoiseLaw.sample_scaled`; the law's own scale
            is its plain draws bit for bit). None: the law as it is.
    """
    if mode == "checker":
        if table.floor_texture is None:
            return jnp.broadcast_to(jnp.asarray(table.rgb[table.floor]), xy.shape[:-1] + (3,))
        texture = np.asarray(table.floor_texture, np.float32)
        base, direction, texture = _colour_line(texture)
        cells = _checker_cells(texture)
        if footprint is not None and cells is not None:
            values = checker_box(cells, xy, np.asarray(table.floor_tile), footprint,
                                 texels=texture.shape[1])
        elif footprint is not None:  # the chain is built on the host, once per trace
            values = texture_mip(pack_mips(texture), xy, np.asarray(table.floor_tile), footprint,
                                 shape=texture.shape[:2])
        else:
            values = texture_at(jnp.asarray(texture), xy, jnp.asarray(table.floor_tile))
        if direction is None:
            return values
        return jnp.asarray(base) + values * jnp.asarray(direction)
    if mode == "video":
        if frame is None or tile is None:
            raise ValueError('floor="video" needs the current video frame and its tile size')
        video = _video_rgb(xy, footprint, frame, frame_index, tile, mips)
        if video_alpha is None:
            return video
        return blend_video(video, floor_rgb("checker", table, xy, footprint), video_alpha)
    if mode == "noise":
        if key is None:
            raise ValueError('floor="noise" needs a PRNG key')
        from jaxnat.natural.noise import DEFAULT_NOISE, noise_law

        law = noise_law(DEFAULT_NOISE if noise is None else noise)
        shape = xy.shape[:-1] + (channels,)
        if noise_sigma is None:
            return _unit_rgb(law.sample(key, shape))
        return _unit_rgb(law.sample_scaled(key, shape, noise_sigma))
    raise ValueError(f"floor must be one of {FLOOR_MODES}, got {mode!r}")


def _video_rgb(xy, footprint, frame, frame_index, tile, mips) -> jax.Array:
    """float32 `[..., 3]`: the video floor's colour at `xy` (see `floor_rgb`)."""
    if footprint is not None:
        if mips is not None:
            colour = texture_mip(mips, xy, tile, footprint, shape=frame.shape[-3:-1],
                                 index=frame_index)
            return _unit_rgb(colour)
        current = frame if frame_index is None else frame[frame_index]
        levels = mip_levels(current.astype(jnp.float32) / 255.0)
        colour = texture_mip(levels, xy, tile, footprint)
        return jnp.broadcast_to(colour, colour.shape[:-1] + (3,))
    tile = jnp.broadcast_to(jnp.asarray(tile, jnp.float32), (2,))
    colour = texture_at(frame, xy, tile, frame_index)
    return _unit_rgb(colour)


def screen_video(frame, frame_index, height: int, width: int) -> jax.Array:
    """float32 `[height, width, 3]` in [0, 1]: the video frame (`frame [h, w, C]`, or the bank
    `[F, h, w, C]` read at `frame_index`) stretched over the whole image, each pixel the texel
    under its centre (nearest: two gathers by host indices, no filtering). The sky's video
    (`Distraction.sky_alpha`): a background fixed to the screen, as the Distracting Control
    Suite's, where the floor's video is fixed to the world."""
    current = frame if frame_index is None else frame[frame_index]
    h, w = current.shape[:2]
    rows = np.minimum(((np.arange(height) + 0.5) * h / height).astype(np.int32), h - 1)
    cols = np.minimum(((np.arange(width) + 0.5) * w / width).astype(np.int32), w - 1)
    return _unit_rgb(jnp.take(jnp.take(current, rows, axis=0), cols, axis=1))


def blend_video(video, checker, alpha) -> jax.Array:
    """`alpha * video + (1 - alpha) * checker` (float32 colours, `alpha` clipped to [0, 1], may
    be traced), exactly `checker` at `alpha = 0` and exactly `video` at 1.

    The endpoints are selected, not left to the blend: IEEE arithmetic gives them exactly only
    if the compiler keeps the expression's form (a reassociated `checker + alpha * (video -
    checker)` is off by a rounding at 1), and a NaN or an infinity in the weightless texture
    (the checker's filter at pixels that miss the floor) would leak through a zero weight. So
    `floor="video"` at `video_alpha=0` renders `floor="checker"`'s frames and at 1 today's
    video floor, bit for bit."""
    alpha = jnp.clip(jnp.asarray(alpha, jnp.float32), 0.0, 1.0)
    video, checker = jnp.broadcast_arrays(video, checker)
    blend = alpha * video + (1.0 - alpha) * checker
    return jnp.where(alpha >= 1.0, video, jnp.where(alpha <= 0.0, checker, blend))


def _colour_line(texture):
    """`(base, direction, values)`: a texture `[h, w, 3]` whose colours lie on one line in
    colour space (a two-colour checker, MuJoCo's builtin, or a grey one) as
    `base + values * direction`, `values [h, w, 1]`; its mip levels lie on the same line (they
    are averages), so the floor reads one number per pixel instead of three. `(None, None,
    texture)` for any other texture."""
    colours = texture.reshape(-1, 3).astype(np.float64)
    base = colours.mean(axis=0)
    _, spread, axes = np.linalg.svd(colours - base, full_matrices=False)
    if spread[1] > 1e-6 * max(float(spread[0]), 1e-30) and spread[1] > 0:
        return None, None, texture
    values = (colours - base) @ axes[0]
    return (base.astype(np.float32), axes[0].astype(np.float32),
            values.reshape(texture.shape[:2] + (1,)).astype(np.float32))


def _unit_rgb(pixels) -> jax.Array:
    """uint8 `[..., 1 or 3]` -> float32 `[..., 3]` in [0, 1]."""
    colour = pixels.astype(jnp.float32) / 255.0
    return jnp.broadcast_to(colour, colour.shape[:-1] + (3,))
