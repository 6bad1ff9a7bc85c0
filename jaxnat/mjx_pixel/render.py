"""A pure-JAX ray caster for MuJoCo models made of primitive geoms. No OpenGL.

`GeomTable.from_model(model)` reads the static part of a scene once, on the host: each visible
geom's type, size and colour, the floor plane, the lights and the floor's texture. Each frame
then needs only the per-step poses `geom_xpos [G, 3]` / `geom_xmat [G, 3, 3]` (from `mjx.Data`
or `mujoco.MjData`) and a camera pose (see `camera.py`):

    table = GeomTable.from_model(model)
    renderer = Renderer(table, height=84, width=84)
    hit = renderer.cast(cam_pos, cam_mat, geom_xpos, geom_xmat)   # nearest hit per pixel
    image = renderer.shade(hit, cam_mat, floor_rgb)                # uint8 [H, W, 3 or 1]
    image = renderer.render(cam_pos, cam_mat, geom_xpos, geom_xmat, floor_fn)  # both, one pass

Everything is jittable and vmappable. The geoms are few and known when tracing, so the geom
loop is unrolled in Python and every pixel's work is straight-line float32 arithmetic over
`[..., H, W]` arrays, with no data-dependent loops and no gathers inside the geom loop. On a
GPU the nearest-hit search runs by default as one Pallas kernel that also skips, per block of
pixels, the geoms that cannot be seen there (`pallas_cast.py`); elsewhere XLA fuses the same
code. See the `Renderer` docstring and docs/design.md for what makes it fast.

Conventions follow MuJoCo: a geom's local frame is `x_world = xpos + xmat @ x_local`; a camera
looks along its local -z with +y up and `fovy` the vertical field of view in degrees; image row
0 is the top (as `mujoco.Renderer` returns it). Shading is Lambertian: MuJoCo's headlight (a
directional light along the view axis) plus the model's lights taken as directional (all
Gymnasium robots have one directional light from above), with optional hard shadows from the
first light. Colours are the geoms' `rgba`; specular terms and floor reflections are omitted.

Floor texture filtering (`floor_filter=`): MuJoCo's OpenGL renderer reads textures with
mipmaps (`GL_LINEAR_MIPMAP_LINEAR`), so its far floor fades to the checker's average grey. By
default (`"mip"`) the renderer gives the floor function each pixel's footprint on the floor
plane (`Renderer.footprint`: the exact step of the hit point per pixel right and down, from its
depth, its ray and the plane's normal: what OpenGL's screen-space derivatives measure), and the
floor function picks the mip level from it (`floor.texture_mip`). With a tracking camera (its
orientation constant) and a floor fixed to the world, the footprint is the pixel's depth times
host constants, so the level of detail costs one log2 per pixel. The departure from OpenGL:
each pixel reads one texel, the nearest of the nearest level (`GL_NEAREST_MIPMAP_NEAREST`;
OpenGL reads four in each of two levels and blends them), so the near floor, where a pixel
covers at most one texel, is exactly the nearest-texel floor, and the filter costs no more
texel reads than no filter; where the level changes, the floor steps from one level to the
next instead of blending. `"nearest"` reads the nearest texel of the full-size texture
everywhere (the renderer before filtering; the bench compares both).
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

__all__ = ["GeomTable", "Renderer", "Hit", "intersect", "PLANE", "SPHERE", "CAPSULE",
           "ELLIPSOID", "CYLINDER", "BOX", "FLOOR_FILTERS"]

# mujoco.mjtGeom values, so this module does not need mujoco to render.
PLANE, HFIELD, SPHERE, CAPSULE, ELLIPSOID, CYLINDER, BOX, MESH = range(8)
_SUPPORTED = {PLANE: "plane", SPHERE: "sphere", CAPSULE: "capsule", ELLIPSOID: "ellipsoid",
              CYLINDER: "cylinder", BOX: "box"}
_MISS = jnp.inf
# The sky of a model without a skybox: Hopper's skybox colours, as declared in its MJCF.
DEFAULT_SKY = ((0.4, 0.5, 0.6), (0.0, 0.0, 0.0))
# `Renderer.render`'s ops carry this name in a compiled program's metadata (tests count renders).
RENDER_SCOPE = "jaxnat_render"
KERNELS = ("xla", "pallas", "auto")
FLOOR_FILTERS = ("mip", "nearest")
# Hits closer than this (metres) are ignored: it keeps shadow rays from re-hitting their own
# starting surface.
_EPS = 1e-4


@dataclasses.dataclass(frozen=True)
class GeomTable:
    """What the renderer needs from a model, as host numpy arrays (static under jit).

    Attributes:
        geom_ids: int [G]: the model's geom index of each rendered geom (invisible geoms,
            group >= 3 or alpha 0 as in MuJoCo's default visualisation, are dropped).
        types: int [G]: mjtGeom type per geom.
        sizes: float32 [G, 3]: MuJoCo `geom_size`.
        rgb: float32 [G, 3]: colour in [0, 1].
        floor: int: index (into the G geoms) of the floor plane, or -1 if there is none.
        light_dirs: float32 [L, 3]: unit direction each light shines along (world frame).
        light_diffuse: float32 [L, 3]; light_ambient: float32 [3] (sum over lights).
        headlight_ambient, headlight_diffuse: float32 [3]: MuJoCo's headlight.
        floor_texture: float32 [h, w, 3] or None: the floor material's texture (its rgb
            role), multiplied by the floor's rgba, in [0, 1].
        floor_tile: float32 [2]: world metres (x, y) one copy of the floor texture covers.
        cast_shadows: bool [G]: whether a geom is tested for shadows (planes never are).
        sky: float32 [2, 3] or None: the model's skybox colours in [0, 1], zenith and nadir
            (`_skybox_colours`), the renderer's sky gradient; None when it has no skybox.
        floor_normal: float32 [3] or None: the floor plane's world normal when the floor is
            fixed to the world (a geom of the world body, as in Gymnasium's models), so the
            renderer knows it before any step; None otherwise.
    """

    geom_ids: np.ndarray
    types: np.ndarray
    sizes: np.ndarray
    rgb: np.ndarray
    floor: int
    light_dirs: np.ndarray
    light_diffuse: np.ndarray
    light_ambient: np.ndarray
    headlight_ambient: np.ndarray
    headlight_diffuse: np.ndarray
    floor_texture: np.ndarray | None
    floor_tile: np.ndarray
    cast_shadows: np.ndarray
    sky: np.ndarray | None = None
    floor_normal: np.ndarray | None = None

    @property
    def num_geoms(self) -> int:
        return len(self.types)

    @classmethod
    def from_model(cls, model) -> "GeomTable":
        """Extract the table from a `mujoco.MjModel` (or anything with its fields)."""
        group = np.asarray(model.geom_group)
        alpha = np.asarray(model.geom_rgba)[:, 3]
        ids = np.flatnonzero((group < 3) & (alpha > 0))
        types = np.asarray(model.geom_type)[ids].astype(np.int32)
        unsupported = sorted({int(t) for t in types} - set(_SUPPORTED))
        if unsupported:
            raise ValueError(
                f"the ray caster renders {sorted(_SUPPORTED.values())} geoms; this model has "
                f"mjtGeom type(s) {unsupported} (hfield=1, mesh=7). Replace them with primitives."
            )
        planes = np.flatnonzero(types == PLANE)
        floor = int(planes[0]) if len(planes) else -1
        rgb = np.asarray(model.geom_rgba)[ids, :3].astype(np.float32)
        texture, tile = None, np.ones(2, np.float32)
        if floor >= 0:
            texture, tile = _floor_texture(model, int(ids[floor]))
            if texture is not None:
                texture = texture * rgb[floor]
        lights = _lights(model)
        return cls(
            geom_ids=ids,
            types=types,
            sizes=np.asarray(model.geom_size)[ids].astype(np.float32),
            rgb=rgb,
            floor=floor,
            light_dirs=lights["dirs"],
            light_diffuse=lights["diffuse"],
            light_ambient=lights["ambient"],
            headlight_ambient=np.asarray(model.vis.headlight.ambient, np.float32),
            headlight_diffuse=np.asarray(model.vis.headlight.diffuse, np.float32),
            floor_texture=texture,
            floor_tile=tile,
            cast_shadows=types != PLANE,
            sky=_skybox_colours(model),
            floor_normal=_world_normal(model, int(ids[floor])) if floor >= 0 else None,
        )


def _lights(model) -> dict:
    n = int(model.nlight)
    if n == 0:
        return {"dirs": np.zeros((0, 3), np.float32), "diffuse": np.zeros((0, 3), np.float32),
                "ambient": np.zeros(3, np.float32)}
    dirs = np.asarray(model.light_dir, np.float64).reshape(n, 3)
    dirs = dirs / np.maximum(np.linalg.norm(dirs, axis=1, keepdims=True), 1e-12)
    return {
        "dirs": dirs.astype(np.float32),
        "diffuse": np.asarray(model.light_diffuse, np.float32).reshape(n, 3),
        "ambient": np.asarray(model.light_ambient, np.float32).reshape(n, 3).sum(0),
    }


def _world_normal(model, geom: int) -> np.ndarray | None:
    """The local z axis of a geom of the world body (body 0: its pose never changes), in the
    world, from its `geom_quat`; None for a geom of any other body."""
    if int(np.asarray(model.geom_bodyid)[geom]) != 0:
        return None
    w, x, y, z = np.asarray(model.geom_quat[geom], np.float64) / np.linalg.norm(model.geom_quat[geom])
    normal = np.array([2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)])
    return normal.astype(np.float32)


_SKYBOX = 2  # mujoco.mjtTexture.mjTEXTURE_SKYBOX


def _skybox_colours(model) -> np.ndarray | None:
    """float32 [2, 3]: the colours of the model's skybox straight up and straight down, as its
    texture stores them, or None without a skybox.

    MuJoCo compiles a skybox, builtin gradients included, into six square faces stacked
    vertically; the third faces up and the fourth down (a `gradient` skybox has `rgb1` at the
    third face's centre and `rgb2` at the fourth's). MuJoCo renders those 8-bit texels, so
    they are the colours to draw (a gradient's texels sit up to one level below its `rgb1`:
    Hopper's 0.4 0.5 0.6 is stored as 101 127 152)."""
    skyboxes = np.flatnonzero(np.asarray(model.tex_type) == _SKYBOX)
    if not len(skyboxes):
        return None
    texid = int(skyboxes[0])
    h, w, c = (int(model.tex_height[texid]), int(model.tex_width[texid]),
               int(model.tex_nchannel[texid]))
    if h != 6 * w:  # not six faces (a skybox from one image file): no zenith to read
        return None
    adr = int(model.tex_adr[texid])
    faces = np.asarray(model.tex_data[adr : adr + h * w * c]).reshape(6, w, w, c)
    centre = slice((w - 1) // 2, w // 2 + 1)  # the middle texel, or the middle 2x2 block
    colours = faces[2:4, centre, centre].reshape(2, -1, c).mean(axis=1) / 255.0
    rgb = colours[:, :3] if c >= 3 else np.repeat(colours[:, :1], 3, axis=1)
    return rgb.astype(np.float32)


def _floor_texture(model, geom: int):
    """The floor material's rgb texture in [0, 1] and the metres one copy spans, as MuJoCo maps
    it on a plane: `texrepeat` copies across the plane's full extent (2 * size), or per metre
    when the material has `texuniform`."""
    mat = int(model.geom_matid[geom])
    if mat < 0:
        return None, np.ones(2, np.float32)
    texids = np.atleast_1d(np.asarray(model.mat_texid[mat]))
    texid = int(texids[1] if len(texids) > 1 and texids[1] >= 0 else texids[0])  # mjTEXROLE_RGB
    if texid < 0:
        return None, np.ones(2, np.float32)
    h, w, c = (int(model.tex_height[texid]), int(model.tex_width[texid]),
               int(model.tex_nchannel[texid]))
    adr = int(model.tex_adr[texid])
    pixels = np.asarray(model.tex_data[adr : adr + h * w * c]).reshape(h, w, c)
    texture = pixels[..., :3].astype(np.float32) / 255.0
    if c == 1:
        texture = np.repeat(pixels.astype(np.float32) / 255.0, 3, axis=-1)
    repeat = np.asarray(model.mat_texrepeat[mat], np.float32)
    size = np.asarray(model.geom_size[geom][:2], np.float32)
    uniform = bool(model.mat_texuniform[mat])
    tile = 1.0 / repeat if uniform or not np.all(size > 0) else 2.0 * size / repeat
    return texture, tile.astype(np.float32)


@struct.dataclass
class Hit:
    """Per-pixel nearest hit. `geom` indexes the table's geoms (-1: nothing, the sky)."""

    depth: jax.Array  # float32 [..., H, W]: distance along the unit ray (inf on a miss)
    geom: jax.Array  # int32 [..., H, W]
    normal: jax.Array  # float32 [..., H, W, 3]: unit world normal (0 on a miss)
    point: jax.Array  # float32 [..., H, W, 3]: world hit point
    lit: jax.Array  # float32 [..., H, W]: 1 where the first light reaches the point, else 0


# ---------------------------------------------------------------------------------------------
# Ray-primitive intersections in the geom's local frame. `o` and `d` are tuples of three
# broadcastable float32 arrays (x, y, z); `d` need not be unit. Each returns the smallest
# t > _EPS with o + t d on the surface, or inf.


def _nearest_root(a, b, c):
    """Smaller positive root of a t^2 + 2 b t + c = 0 (inf if none). `a` is the Python float
    1.0 for unit directions, which saves the division."""
    disc = b * b - a * c
    sq = jnp.sqrt(jnp.maximum(disc, 0.0))
    if isinstance(a, float):
        near, far, valid = (-b - sq) / a, (-b + sq) / a, disc >= 0
    else:
        inv_a = 1.0 / jnp.where(a > 0, a, 1.0)
        near, far, valid = (-b - sq) * inv_a, (-b + sq) * inv_a, (disc >= 0) & (a > 0)
    t = jnp.where(near > _EPS, near, far)
    return jnp.where(valid & (t > _EPS), t, _MISS)


def _dot(u, v):
    return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]


def _sphere(o, d, radius, unit=False):
    return _nearest_root(1.0 if unit else _dot(d, d), _dot(o, d), _dot(o, o) - radius * radius)


def _capsule_from_invariants(od, oo, dd, oz, dz, radius, half):
    """The capsule around the z axis (|z| <= half, radius `radius`), from the ray's invariants in
    its frame: `od = o.d`, `oo = |o|^2`, `dd = |d|^2` (the float 1.0 for unit rays), and the
    axial components `oz`, `dz`. Rotation-free, so a world-frame ray needs only two dot products
    per pixel (`o.d` and `d.axis`): the rest is per frame.

    Two square roots, not three: the ray can only enter the capsule through the lateral surface,
    where it enters the infinite cylinder, or else through the end cap on the side where it
    enters that cylinder (or, starting inside it, on its own side)."""
    a = dd - dz * dz
    b = od - oz * dz
    c = oo - oz * oz - radius * radius
    disc = b * b - a * c
    parallel = a <= 1e-12
    t_side = (-b - jnp.sqrt(jnp.maximum(disc, 0.0))) / jnp.where(parallel, 1.0, a)
    z_side = oz + t_side * dz
    side = ~parallel & (disc >= 0) & (t_side > _EPS) & (jnp.abs(z_side) <= half)
    inside = parallel | (c < 0)
    cap_z = jnp.where(inside, jnp.sign(oz), jnp.sign(z_side)) * half
    # The cap sphere centred at z = cap_z: o' = o - cap_z e_z.
    t_cap = _nearest_root(dd, od - cap_z * dz, oo - cap_z * (2.0 * oz - cap_z) - radius * radius)
    t_cap = jnp.where(inside | (disc >= 0), t_cap, _MISS)
    return jnp.where(side, t_side, t_cap)


def _capsule(o, d, size, unit=False):
    return _capsule_from_invariants(_dot(o, d), _dot(o, o), 1.0 if unit else _dot(d, d),
                                    o[2], d[2], size[0], size[1])


def _side(o, d, radius, half):
    """The lateral surface of the z-axis cylinder, |z| <= half."""
    a = d[0] * d[0] + d[1] * d[1]
    b = o[0] * d[0] + o[1] * d[1]
    c = o[0] * o[0] + o[1] * o[1] - radius * radius
    t = _nearest_root(a, b, c)
    return jnp.where(jnp.abs(o[2] + t * d[2]) <= half, t, _MISS)


def _ellipsoid(o, d, size, unit=False):
    scaled_o = tuple(o[i] / size[i] for i in range(3))
    scaled_d = tuple(d[i] / size[i] for i in range(3))
    return _sphere(scaled_o, scaled_d, 1.0)


def _cylinder(o, d, size, unit=False):
    radius, half = size[0], size[1]
    t = _side(o, d, radius, half)
    safe_dz = jnp.where(d[2] == 0, 1e-30, d[2])
    for z in (half, -half):
        tc = (z - o[2]) / safe_dz
        x, y = o[0] + tc * d[0], o[1] + tc * d[1]
        ok = (tc > _EPS) & (x * x + y * y <= radius * radius)
        t = jnp.minimum(t, jnp.where(ok, tc, _MISS))
    return t


def _box(o, d, size, unit=False):
    near, far = -_MISS, _MISS
    for i in range(3):
        safe = jnp.where(d[i] == 0, 1e-30, d[i])
        t1, t2 = (-size[i] - o[i]) / safe, (size[i] - o[i]) / safe
        near = jnp.maximum(near, jnp.minimum(t1, t2))
        far = jnp.minimum(far, jnp.maximum(t1, t2))
    t = jnp.where(near > _EPS, near, far)
    return jnp.where((far >= near) & (t > _EPS), t, _MISS)


def _plane(o, d, size, unit=False):
    """The local z = 0 plane, seen from above only (as MuJoCo draws it); size[0:2] > 0 bounds
    it to |x| <= size[0], |y| <= size[1]."""
    safe_dz = jnp.where(d[2] == 0, 1e-30, d[2])
    t = -o[2] / safe_dz
    ok = (t > _EPS) & (o[2] > 0)
    for i in range(2):
        if size[i] > 0:  # static: sizes come from the host table
            ok &= jnp.abs(o[i] + t * d[i]) <= size[i]
    return jnp.where(ok, t, _MISS)


# Each takes (o, d, size, unit): `unit=True` promises |d| = 1 (the renderer's rays).
_INTERSECT = {PLANE: _plane, SPHERE: lambda o, d, s, unit=False: _sphere(o, d, s[0], unit),
              CAPSULE: _capsule,
              ELLIPSOID: _ellipsoid, CYLINDER: _cylinder, BOX: _box}


def intersect(geom_type: int, size, origin, direction) -> jax.Array:
    """Distance along `direction` to the first hit of a ray with a primitive in its local frame.

    Args:
        geom_type: mjtGeom value (PLANE, SPHERE, CAPSULE, ELLIPSOID, CYLINDER, BOX).
        size: MuJoCo's `geom_size` for it (host numbers).
        origin, direction: float arrays `[..., 3]` (direction need not be unit).

    Returns:
        float32 `[...]`: t > 0 in units of |direction|, inf where the ray misses.
    """
    origin = jnp.asarray(origin, jnp.float32)
    direction = jnp.asarray(direction, jnp.float32)
    size = tuple(float(s) for s in np.asarray(size))
    o = tuple(origin[..., i] for i in range(3))
    d = tuple(direction[..., i] for i in range(3))
    return _INTERSECT[int(geom_type)](o, d, size)


def _local_normal(geom_type: int, size, p):
    """Unnormalised outward normal at local surface point p (tuple of arrays); `size` may hold
    host numbers or per-pixel arrays (the winning geom's sizes)."""
    x, y, z = p
    zero = jnp.zeros_like(x)
    if geom_type == PLANE:
        return zero, zero, zero + 1.0
    if geom_type in (SPHERE, CAPSULE):
        if geom_type == SPHERE:
            return x, y, z
        return x, y, z - jnp.clip(z, -size[1], size[1])
    if geom_type == ELLIPSOID:
        return tuple(p[i] / (size[i] * size[i]) for i in range(3))
    if geom_type == CYLINDER:
        on_cap = jnp.abs(z) * size[0] >= jnp.sqrt(x * x + y * y) * size[1]  # nearer a cap than the side
        return jnp.where(on_cap, 0.0, x), jnp.where(on_cap, 0.0, y), jnp.where(on_cap, jnp.sign(z), 0.0)
    # BOX: the face whose scaled coordinate is largest.
    s = [jnp.abs(p[i]) / size[i] for i in range(3)]
    ax = (s[0] >= s[1]) & (s[0] >= s[2])
    ay = ~ax & (s[1] >= s[2])
    az = ~ax & ~ay
    return (jnp.where(ax, jnp.sign(x), 0.0), jnp.where(ay, jnp.sign(y), 0.0),
            jnp.where(az, jnp.sign(z), 0.0))


def _orientation(cam_mat):
    """`cam_mat` as a float32 3x3: numpy when its values are known now (a tracking camera's
    constant orientation, so what depends on it is computed on the host), else traced."""
    try:
        return np.asarray(cam_mat, np.float32).reshape(3, 3)
    except jax.errors.TracerArrayConversionError:
        return jnp.asarray(cam_mat, jnp.float32).reshape(3, 3)


def _to_local(vec, xmat):
    """R^T v for world vectors `vec` (tuple of arrays) and one geom's 3x3 `xmat`."""
    return tuple(vec[0] * xmat[0, j] + vec[1] * xmat[1, j] + vec[2] * xmat[2, j] for j in range(3))


def _to_world(vec, xmat):
    return tuple(xmat[i, 0] * vec[0] + xmat[i, 1] * vec[1] + xmat[i, 2] * vec[2] for i in range(3))


# Columns of the per-frame geom terms (`Renderer._frame_terms`): the camera relative to the geom
# in world axes (w = cam_pos - xpos), its orientation (xmat, row-major), |w|^2 and w in the
# geom's axes (R^T w), and the image rows its bounding sphere may cover (`_row_span`).
_W, _XMAT, _WW, _W_LOCAL, _ROW_LO, _ROW_HI = 0, 3, 12, 13, 16, 17
NUM_TERMS = 18


def _xmat_of(term):
    """{(i, j): xmat[i, j]} from a geom's terms (`term(column)`), for `_to_local`/`_to_world`."""
    return {(i, j): term(_XMAT + 3 * i + j) for i in range(3) for j in range(3)}


class Renderer:
    """Renders one frame of a `GeomTable` scene; `vmap` it for a batch.

    Args:
        table: the scene (`GeomTable.from_model(model)`).
        height, width: image size in pixels (any size; 84x84 by default).
        fovy: vertical field of view in degrees (MuJoCo's `cam_fovy`; 45 by default).
        grayscale: uint8 `[H, W, 1]` (luminance, ITU-R 601 weights as OpenCV) instead of RGB.
        shadows: hard shadows from the model's first light (one more ray per pixel and geom:
            about twice the work, and a longer compile).
        sky: rgb in [0, 1] of pixels that hit nothing at the top and the bottom of the frame
            (a vertical gradient between them). None (the default): the model's skybox,
            its colours straight up and straight down (`GeomTable.sky`; Gymnasium's Hopper
            blue-grey to black, Ant, HalfCheetah and Swimmer white to black); without a
            skybox, `DEFAULT_SKY`.
        kernel: "auto" (the default: Pallas when JAX's default backend is a GPU, else XLA),
            "xla" (plain JAX, any backend) or "pallas" (the nearest-hit search as one Pallas
            kernel, `pallas_cast.py`: a GPU kernel, interpreted on a CPU). Both render the same
            frames (tests check it on CPU; bench/results/pixel_mujoco.md records the check on
            a GPU).
        floor_filter: how a floor function (`render`'s `floor_rgb` callable) reads its
            texture: "mip" (the default: it is also given each pixel's `floor.Footprint` and
            filters by it, see the module docstring and `floor.texture_mip`) or "nearest" (it
            is given the hit points only and reads the nearest texel).

    Speed: the whole frame is one chain of per-pixel float32 arithmetic ending in the uint8
    image, with no `dot` and no `[..., 3]` vectors in between, so XLA fuses it into a few
    kernels (the Pallas kernel does the geom loop in one). Per frame, the few numbers each geom
    contributes (its position relative to the camera, its axes) are computed once, packed in
    one small array and kept out of the kernel (`optimization_barrier`), so the kernel does not
    redo them per pixel. Spheres and capsules (all of Gymnasium's robots) are intersected in the
    world frame from two dot products per pixel. A camera orientation given as host numbers (a
    tracking camera's never changes) makes the ray directions compile-time constants. The
    normal is computed once per pixel, for the winning geom only (its pose gathered by geom
    index).
    """

    def __init__(self, table: GeomTable, height: int = 84, width: int = 84, fovy: float = 45.0,
                 grayscale: bool = False, shadows: bool = False,
                 sky: tuple | None = None, kernel: str = "auto", floor_filter: str = "mip"):
        if height < 1 or width < 1:
            raise ValueError(f"image size must be positive, got {height}x{width}")
        if kernel not in KERNELS:
            raise ValueError(f"kernel must be one of {KERNELS}, got {kernel!r}")
        if floor_filter not in FLOOR_FILTERS:
            raise ValueError(f"floor_filter must be one of {FLOOR_FILTERS}, got {floor_filter!r}")
        self.kernel = kernel
        self.floor_filter = floor_filter
        self.table = table
        self.height, self.width = int(height), int(width)
        self.fovy = float(fovy)
        self.grayscale = bool(grayscale)
        self.shadows = bool(shadows) and len(table.light_dirs) > 0
        if sky is None:
            sky = table.sky if table.sky is not None else DEFAULT_SKY
        self.sky = np.asarray(sky, np.float32)
        # Camera-frame ray directions, unit, [H, W, 3], row 0 at the top.
        tan_half = math.tan(math.radians(self.fovy) / 2)
        rows = (1 - 2 * (np.arange(self.height) + 0.5) / self.height) * tan_half
        cols = (2 * (np.arange(self.width) + 0.5) / self.width - 1) * tan_half * self.width / self.height
        x, y = np.meshgrid(cols, rows)
        rays = np.stack([x, y, -np.ones_like(x)], axis=-1)
        self._camera_rays = (rays / np.linalg.norm(rays, axis=-1, keepdims=True)).astype(np.float32)
        # The image-plane distance (at unit depth) between neighbouring pixels' rays.
        self._pixel_step = 2 * tan_half / self.height

    @property
    def channels(self) -> int:
        return 1 if self.grayscale else 3

    # --- public API -------------------------------------------------------------------------

    def cast(self, cam_pos, cam_mat, geom_xpos, geom_xmat) -> Hit:
        """Nearest hit per pixel for a camera at `cam_pos [3]` with orientation `cam_mat [3, 3]`
        (columns = camera axes in the world) and geoms at `geom_xpos [ngeom, 3]`, `geom_xmat
        [ngeom, 3, 3]` or `[ngeom, 9]`, indexed like the model (the table picks its geoms)."""
        t, g, normal, point, lit = self._trace(cam_pos, cam_mat, geom_xpos, geom_xmat)
        return Hit(depth=t, geom=g, normal=jnp.stack(normal, -1), point=jnp.stack(point, -1),
                   lit=lit)

    def shade(self, hit: Hit, cam_mat, floor_rgb=None) -> jax.Array:
        """uint8 `[H, W, C]` image of `hit` seen from a camera oriented by `cam_mat` (it aims
        the headlight). `floor_rgb [H, W, 3]` (float in [0, 1]) colours the floor pixels
        (see `floor.py`); without it the floor keeps its geom colour. It may also be a function,
        called as in `render`."""
        normal = tuple(hit.normal[..., i] for i in range(3))
        point = tuple(hit.point[..., i] for i in range(3))
        return self._shade(hit.geom, normal, point, hit.lit, cam_mat, floor_rgb, hit.depth)

    def render(self, cam_pos, cam_mat, geom_xpos, geom_xmat, floor_rgb=None,
               sky_rgb=None) -> jax.Array:
        """`shade(cast(...))` in one pass: one uint8 `[H, W, C]` frame. `floor_rgb` may also be a
        function of the hit points' world `xy [H, W, 2]` returning `[H, W, 3]` (see
        `floor.floor_rgb`): the floor texture is then looked up inside the same kernel. With
        `floor_filter="mip"` it is called as `floor_rgb(xy, footprint)`, `footprint` each
        pixel's `floor.Footprint` (its world x-y step per pixel right and down: `footprint`,
        `floor.texture_mip`). `sky_rgb` (float32 `[H, W, 3]` in [0, 1]) colours the pixels
        that hit nothing in place of the sky gradient (`sky_gradient`)."""
        with jax.named_scope(RENDER_SCOPE):  # names its ops in compiled programs
            depth, g, normal, point, lit = self._trace(cam_pos, cam_mat, geom_xpos, geom_xmat)
            return self._shade(g, normal, point, lit, cam_mat, floor_rgb, depth, sky_rgb)

    # --- the per-pixel work -------------------------------------------------------------------

    def _rays(self, cam_mat):
        """World ray directions, a tuple of three `[H, W]` arrays (host constants when the
        camera orientation is not traced)."""
        rays = self._camera_rays
        cam_mat = _orientation(cam_mat)
        if isinstance(cam_mat, np.ndarray):
            world = rays @ cam_mat.T
            return tuple(world[..., i] for i in range(3))
        return tuple(rays[..., 0] * cam_mat[i, 0] + rays[..., 1] * cam_mat[i, 1]
                     + rays[..., 2] * cam_mat[i, 2] for i in range(3))

    def row_spans(self, cam_pos, cam_mat, geom_xpos, geom_xmat) -> jax.Array:
        """float32 `[G, 2]`: per geom (table order), the first and last image row its bounding
        sphere may cover in this frame. The Pallas kernel skips a geom for the blocks of rows
        outside its span."""
        terms = self._frame_terms(cam_pos, cam_mat, geom_xpos, geom_xmat)
        return terms[:, _ROW_LO:_ROW_HI + 1]

    def _frame_terms(self, cam_pos, cam_mat, geom_xpos, geom_xmat):
        """float32 [G, NUM_TERMS]: per geom, the columns from `_W`, `_XMAT`, `_WW`, `_W_LOCAL`,
        `_ROW_LO`, `_ROW_HI`."""
        ids = self.table.geom_ids
        xpos = jnp.asarray(geom_xpos, jnp.float32)[ids]
        xmat = jnp.asarray(geom_xmat, jnp.float32).reshape(-1, 3, 3)[ids]
        w = jnp.asarray(cam_pos, jnp.float32) - xpos
        ww = jnp.sum(w * w, axis=-1, keepdims=True)
        w_local = jnp.sum(xmat * w[:, :, None], axis=1)  # R^T w, elementwise (no tiny dot)
        rows = self._row_span(w, _orientation(cam_mat))
        terms = jnp.concatenate([w, xmat.reshape(-1, 9), ww, w_local, rows], axis=-1)
        # Computed once per frame, not once per pixel inside the fused kernel.
        return jax.lax.optimization_barrier(terms)

    def _trace(self, cam_pos, cam_mat, geom_xpos, geom_xmat):
        """(depth, geom, normal, point, lit): the nearest hit per pixel, vectors as tuples."""
        d = self._rays(cam_mat)
        terms = self._frame_terms(cam_pos, cam_mat, geom_xpos, geom_xmat)
        if self.kernel == "pallas" or (self.kernel == "auto" and jax.default_backend() == "gpu"):
            from jaxnat.mjx_pixel.pallas_cast import nearest_hit

            best_t, best_g = nearest_hit(self, terms, d)
        else:
            best_t, best_g = self.nearest(lambda g, k: terms[g, k], d)
        t = jnp.where(best_g >= 0, best_t, 0.0)
        cam_pos = jnp.asarray(cam_pos, jnp.float32)
        point = tuple(cam_pos[i] + t * d[i] for i in range(3))
        normal = self._normal(best_g, jnp.maximum(best_g, 0), terms, t, d)
        if self.shadows:
            lit = self._lit(point, best_g, terms, cam_pos)
        else:
            lit = jnp.ones_like(t)
        return best_t, best_g, normal, point, lit

    def nearest(self, term, d, rows=None):
        """(t, geom) of the nearest hit along unit world rays `d` (a tuple of three arrays):
        `term(g, k)` reads column k of geom g's frame terms. Shared by the XLA path and the
        Pallas kernel (`pallas_cast.py`), which reads the terms from its own buffers.

        `rows=(first, last)` (the kernel, where `d` is a block of pixels): the image rows the
        block spans. A geom is then tested only if its bounding sphere may cover one of them
        (`lax.cond` on the block, which a GPU kernel skips as a whole; plain XLA would
        evaluate both sides)."""
        best = (jnp.full(d[0].shape, _MISS, jnp.float32), jnp.full(d[0].shape, -1, jnp.int32))
        for g in range(self.table.num_geoms):  # unrolled: G is small and static
            term_g = lambda k, g=g: term(g, k)  # noqa: E731

            def update(best, g=g, term_g=term_g):
                t = self._intersect(g, term_g, d)
                closer = t < best[0]
                return jnp.where(closer, t, best[0]), jnp.where(closer, g, best[1])

            if rows is not None and self._bounding_radius(g) is not None:
                seen = (term_g(_ROW_LO) <= rows[1]) & (term_g(_ROW_HI) >= rows[0])
                best = jax.lax.cond(seen, update, lambda best: best, best)
            else:
                best = update(best)
        return best

    def _row_span(self, w, cam_mat):
        """float32 [G, 2]: a range of image rows (first, last; may reach past the image) that
        holds every pixel whose ray can meet geom g's bounding sphere, for geoms at `-w` from
        the camera (`w [G, 3]`): one row to spare each side. Empty (first > last) for spheres
        behind the camera; the whole image for planes and spheres across the camera's plane.

        A pixel row's rays all have the slope y / depth = `row_slope` in camera coordinates.
        The planes through the camera's x axis tangent to the sphere bound its slopes:
        (cy + s cz)^2 = R^2 (1 + s^2) for the centre (cx, cy, cz) in camera axes."""
        table = self.table
        radius = np.array([r if r is not None else np.inf
                           for r in map(self._bounding_radius, range(table.num_geoms))], np.float32)
        centre = [-sum(w[:, i] * cam_mat[i, j] for i in range(3)) for j in range(3)]
        cy, cz = centre[1], centre[2]
        r2 = np.where(np.isfinite(radius), radius * radius, 0.0)
        a = cz * cz - r2
        across = (a <= 0) | ~np.isfinite(radius)
        root = jnp.sqrt(jnp.maximum(r2 * (cy * cy + cz * cz - r2), 0.0))
        safe_a = jnp.where(across, 1.0, a)
        slope_lo, slope_hi = (-cy * cz - root) / safe_a, (-cy * cz + root) / safe_a
        tan_half = math.tan(math.radians(self.fovy) / 2)
        row_of = lambda s: (1.0 - s / tan_half) * (self.height / 2) - 0.5  # noqa: E731
        first, last = jnp.floor(row_of(slope_hi)) - 1.0, jnp.ceil(row_of(slope_lo)) + 1.0
        big = float(4 * self.height)
        first = jnp.where(across, -big, jnp.where(cz > 0, big, first))
        last = jnp.where(across, big, jnp.where(cz > 0, -big, last))
        return jnp.stack([first, last], axis=-1)

    def _bounding_radius(self, g: int) -> float | None:
        """Radius of a sphere around geom g's origin that holds it (None: a plane)."""
        size = [float(s) for s in self.table.sizes[g]]
        return {SPHERE: size[0], CAPSULE: size[0] + size[1], ELLIPSOID: max(size),
                CYLINDER: math.hypot(size[0], size[1]),
                BOX: math.sqrt(sum(s * s for s in size))}.get(int(self.table.types[g]))

    def _intersect(self, g: int, term, d):
        """t along the unit world rays `d` to geom `g` (`term(k)`: its frame terms)."""
        geom_type = int(self.table.types[g])
        size = tuple(float(s) for s in self.table.sizes[g])
        w = tuple(term(_W + i) for i in range(3))
        if geom_type == SPHERE:
            return _nearest_root(1.0, _dot(w, d), term(_WW) - size[0] * size[0])
        xmat = _xmat_of(term)
        if geom_type == CAPSULE:
            axis = tuple(xmat[i, 2] for i in range(3))
            return _capsule_from_invariants(_dot(w, d), term(_WW), 1.0, term(_W_LOCAL + 2),
                                            _dot(axis, d), size[0], size[1])
        # Other primitives in their own frame (unused components are dead code to XLA).
        w_local = tuple(term(_W_LOCAL + i) for i in range(3))
        return _INTERSECT[geom_type](w_local, _to_local(d, xmat), size, True)

    def _normal(self, best_g, safe_g, terms, t, d):
        """Unit world normal of the winning geom at each pixel's hit (0 where nothing is hit):
        its pose is gathered by geom index, so the normal is computed once per pixel.

        The winner's whole row of frame terms is gathered once and its columns sliced: one
        gather per pixel. Gathering each column on its own (`terms[:, k][safe_g]`) made XLA
        write the batched gather's indices to memory and cut the terms into a kernel per
        column (the profile: bench/results/pixel_mujoco.md)."""
        table = self.table
        rows = terms[safe_g]  # [..., NUM_TERMS]
        winner = lambda k: rows[..., k]  # noqa: E731
        xmat = _xmat_of(winner)
        rel = tuple(winner(_W + i) + t * d[i] for i in range(3))  # hit point - geom origin
        local = _to_local(rel, xmat)
        sizes = tuple(jnp.asarray(table.sizes[:, i])[safe_g] for i in range(3))
        geom_type = jnp.asarray(table.types)[safe_g]
        normal = None
        for kind in sorted({int(k) for k in table.types}):
            n = _local_normal(kind, sizes, local)
            normal = n if normal is None else tuple(
                jnp.where(geom_type == kind, n[i], normal[i]) for i in range(3))
        world = _to_world(normal, xmat)
        inv = jax.lax.rsqrt(jnp.maximum(_dot(world, world), 1e-24))
        inv = jnp.where(best_g >= 0, inv, 0.0)
        return tuple(n * inv for n in world)

    def _lit(self, point, best_g, terms, cam_pos):
        """1.0 where a ray from the hit point towards the first light hits no geom."""
        to_light = tuple(-float(c) for c in self.table.light_dirs[0])
        blocked = jnp.zeros(point[0].shape, jnp.bool_)
        for g in np.flatnonzero(self.table.cast_shadows):
            xmat = _xmat_of(lambda k, g=g: terms[g, k])
            # point - xpos = point - cam_pos + w
            rel = tuple(point[i] - cam_pos[i] + terms[g, _W + i] for i in range(3))
            d_local = _to_local(tuple(jnp.full((), c, jnp.float32) for c in to_light), xmat)
            t = _INTERSECT[int(self.table.types[g])](_to_local(rel, xmat), d_local,
                                                     tuple(float(s) for s in self.table.sizes[g]), True)
            blocked |= (t < _MISS) & (best_g != g)  # a convex geom never shadows itself
        return jnp.where(blocked | (best_g < 0), 0.0, 1.0)

    def footprint(self, depth, cam_mat, normal):
        """Each pixel's `floor.Footprint`: the world x-y step of its hit point on the plane
        through it with unit normal `normal` (a tuple of three `[H, W]` arrays) when the pixel
        moves one to the right or one down, at distance `depth` along its ray. Exact for a
        plane: a ray `r = x e_x + y e_y - e_z` (camera axes, unit depth) meets it at `P = C + k r`,
        `k = depth (d . forward)`, so a step `dr` moves P by `k (dr - d (n . dr) / (n . d))`
        (d the unit ray), with `|dr|` one pixel's step.

        With a camera orientation given as host numbers (a tracking camera) and a floor fixed
        to the world (`GeomTable.floor_normal`), everything but `depth` is known when tracing:
        the steps per unit depth are host constants, computed with the floor's normal (the
        footprint only matters on floor pixels), and the level of detail costs one log2 per
        pixel (`Footprint.lod`). Otherwise they are computed per pixel from `normal`."""
        from jaxnat.mjx_pixel.floor import Footprint

        axes = _orientation(cam_mat)
        d = self._rays(cam_mat)  # host constants for a host orientation
        xp = jnp
        if isinstance(axes, np.ndarray) and self.table.floor_normal is not None:
            xp, normal = np, tuple(np.float32(c) for c in self.table.floor_normal)
        forward = -(d[0] * axes[0, 2] + d[1] * axes[1, 2] + d[2] * axes[2, 2])
        n_d = _dot(normal, d)
        n_d = xp.where(xp.abs(n_d) > 1e-6, n_d, -1e-6)  # grazing rays (and misses): no blow-up
        scale = forward * self._pixel_step
        steps = []
        for axis, sign in ((0, 1.0), (1, -1.0)):  # right: +e_x; down: -e_y
            step = tuple(sign * axes[i, axis] for i in range(3))
            ratio = _dot(normal, step) / n_d
            steps.append(tuple((scale * (step[j] - d[j] * ratio)).astype(np.float32)
                               for j in range(2)))
        # A miss (infinite depth) reads the last level: in range, and its colour is discarded.
        return Footprint(steps[0], steps[1], depth)

    def _shade(self, g, normal, point, lit, cam_mat, floor_rgb, depth, sky_rgb=None):
        """uint8 `[H, W, C]` from per-pixel geom ids, normals and points (tuples of arrays)."""
        table = self.table
        safe_g = jnp.maximum(g, 0)
        rgb = [jnp.asarray(table.rgb[:, c])[safe_g] for c in range(3)]  # small-table lookups
        on_floor = (g == table.floor) if table.floor >= 0 else None
        if on_floor is not None and floor_rgb is not None:
            if callable(floor_rgb):
                xy = jnp.stack(point[:2], -1)
                if self.floor_filter == "mip":
                    floor_rgb = floor_rgb(xy, self.footprint(depth, cam_mat, normal))
                else:
                    floor_rgb = floor_rgb(xy)
            rgb = [jnp.where(on_floor, floor_rgb[..., c], rgb[c]) for c in range(3)]
        # The headlight shines along the view axis: -(n . forward) = n . cam_mat[:, 2].
        back = _orientation(cam_mat)[:, 2]
        head = jnp.maximum(_dot(normal, back), 0.0)
        cosines = [jnp.maximum(-_dot(normal, table.light_dirs[k]), 0.0)
                   for k in range(len(table.light_dirs))]
        if cosines:
            cosines[0] = cosines[0] * lit
        ambient = table.headlight_ambient + table.light_ambient
        sky = self._sky() if sky_rgb is None else [sky_rgb[..., c] for c in range(3)]
        colour = []
        for c in range(3):
            light = float(ambient[c]) + head * float(table.headlight_diffuse[c])
            for k, cos in enumerate(cosines):
                light = light + cos * float(table.light_diffuse[k][c])
            if on_floor is not None:
                # A lit floor shows its texture unchanged (a video or noise keeps its values);
                # only shadows darken it.
                light = jnp.where(on_floor, jnp.minimum(light, 1.0), light)
            value = jnp.clip(rgb[c] * light, 0.0, 1.0)
            colour.append(jnp.where(g < 0, sky[c], value))
        return self._to_uint8(colour)

    def sky_gradient(self) -> np.ndarray:
        """float32 `[H, 1, 3]` host constants: the sky's colour per row (`_sky`), the background
        a `sky_rgb` replaces or blends over."""
        return np.stack(self._sky(), -1)

    def _sky(self):
        """Per channel, `[H, 1]` host constants: the sky's vertical gradient, from the top
        colour in row 0 to the bottom colour in the last row."""
        top, horizon = self.sky
        rows = np.linspace(1.0, 0.0, self.height, dtype=np.float32)[:, None]
        return [horizon[c] + (top[c] - horizon[c]) * rows for c in range(3)]

    def _to_uint8(self, colour):
        if self.grayscale:
            colour = [0.299 * colour[0] + 0.587 * colour[1] + 0.114 * colour[2]]
        return jnp.stack([jnp.round(c * 255.0).astype(jnp.uint8) for c in colour], axis=-1)
