"""A pure-JAX ray caster for MuJoCo models made of primitive geoms. No OpenGL.

`GeomTable.from_model(model)` reads the static part of a scene once, on the host: each visible
geom's type, size and colour, the floor plane, the lights and the floor's texture. Each frame
then needs only the per-step poses `geom_xpos [G, 3]` / `geom_xmat [G, 3, 3]` (from `mjx.Data`
or `mujoco.MjData`) and a camera pose (see `camera.py`):

    table = GeomTable.from_model(model)
    renderer = Renderer(table, height=84, width=84)
    hit = renderer.cast(cam_pos, cam_mat, geom_xpos, geom_xmat)   # nearest hit per pixel
    image = renderer.shade(hit, floor_rgb)                         # uint8 [H, W, 3 or 1]

Everything is jittable and vmappable. Speed on a GPU comes from the layout, not from clever
culling: the geoms are few and known when tracing, so the geom loop is unrolled in Python and
every pixel's work is straight-line float32 arithmetic over `[..., H, W]` arrays, with no
data-dependent loops and no gathers inside the geom loop. XLA fuses it into a few elementwise
kernels, so nothing of size pixels x geoms is ever written to memory.

Conventions follow MuJoCo: a geom's local frame is `x_world = xpos + xmat @ x_local`; a camera
looks along its local -z with +y up and `fovy` the vertical field of view in degrees; image row
0 is the top (as `mujoco.Renderer` returns it). Shading is Lambertian: MuJoCo's headlight (a
directional light along the view axis) plus the model's lights taken as directional (all
Gymnasium robots have one directional light from above), with optional hard shadows from the
first light. Colours are the geoms' `rgba`; specular terms and floor reflections are omitted.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

__all__ = ["GeomTable", "Renderer", "Hit", "intersect", "PLANE", "SPHERE", "CAPSULE",
           "ELLIPSOID", "CYLINDER", "BOX"]

# mujoco.mjtGeom values, so this module does not need mujoco to render.
PLANE, HFIELD, SPHERE, CAPSULE, ELLIPSOID, CYLINDER, BOX, MESH = range(8)
_SUPPORTED = {PLANE: "plane", SPHERE: "sphere", CAPSULE: "capsule", ELLIPSOID: "ellipsoid",
              CYLINDER: "cylinder", BOX: "box"}
_MISS = jnp.inf
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


def _sphere(o, d, radius, z_offset=0.0, unit=False):
    ox, oy, oz = o[0], o[1], o[2] - z_offset
    a = 1.0 if unit else d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
    b = ox * d[0] + oy * d[1] + oz * d[2]
    c = ox * ox + oy * oy + oz * oz - radius * radius
    return _nearest_root(a, b, c)


def _side(o, d, radius, half):
    """The lateral surface of the z-axis cylinder, |z| <= half."""
    a = d[0] * d[0] + d[1] * d[1]
    b = o[0] * d[0] + o[1] * d[1]
    c = o[0] * o[0] + o[1] * o[1] - radius * radius
    t = _nearest_root(a, b, c)
    return jnp.where(jnp.abs(o[2] + t * d[2]) <= half, t, _MISS)


def _capsule(o, d, size, unit=False):
    """Two square roots, not three: the ray can only enter the capsule through the lateral
    surface, where it enters the infinite cylinder, or else through the end cap on the side
    where it enters that cylinder (or, starting inside it, on its own side)."""
    radius, half = size[0], size[1]
    a = d[0] * d[0] + d[1] * d[1]
    b = o[0] * d[0] + o[1] * d[1]
    c = o[0] * o[0] + o[1] * o[1] - radius * radius
    disc = b * b - a * c
    parallel = a <= 1e-12
    t_side = (-b - jnp.sqrt(jnp.maximum(disc, 0.0))) / jnp.where(parallel, 1.0, a)
    z_side = o[2] + t_side * d[2]
    side = ~parallel & (disc >= 0) & (t_side > _EPS) & (jnp.abs(z_side) <= half)
    inside = parallel | (c < 0)
    cap_z = jnp.where(inside, jnp.sign(o[2]), jnp.sign(z_side)) * half
    t_cap = jnp.where(inside | (disc >= 0), _sphere(o, d, radius, cap_z, unit), _MISS)
    return jnp.where(side, t_side, t_cap)


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
_INTERSECT = {PLANE: _plane, SPHERE: lambda o, d, s, unit=False: _sphere(o, d, s[0], 0.0, unit),
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
    """Unnormalised outward normal at local surface point p (tuple of arrays)."""
    x, y, z = p
    zero = jnp.zeros_like(x)
    if geom_type == PLANE:
        return zero, zero, zero + 1.0
    if geom_type in (SPHERE, CAPSULE):
        half = size[1] if geom_type == CAPSULE else 0.0
        return x, y, z - jnp.clip(z, -half, half)
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


def _to_local(vec, xmat):
    """R^T v for world vectors `vec` (tuple of arrays) and one geom's 3x3 `xmat`."""
    return tuple(vec[0] * xmat[0, j] + vec[1] * xmat[1, j] + vec[2] * xmat[2, j] for j in range(3))


def _to_world(vec, xmat):
    return tuple(xmat[i, 0] * vec[0] + xmat[i, 1] * vec[1] + xmat[i, 2] * vec[2] for i in range(3))


class Renderer:
    """Renders one frame of a `GeomTable` scene; `vmap` it for a batch.

    Args:
        table: the scene (`GeomTable.from_model(model)`).
        height, width: image size in pixels (any size; 84x84 by default).
        fovy: vertical field of view in degrees (MuJoCo's `cam_fovy`; 45 by default).
        grayscale: uint8 `[H, W, 1]` (luminance, ITU-R 601 weights as OpenCV) instead of RGB.
        shadows: hard shadows from the model's first light (one more ray per pixel and geom:
            about twice the work, three times the compile time).
        sky: rgb of pixels that hit nothing, top and horizon (a vertical gradient, as
            Gymnasium's skybox).
    """

    def __init__(self, table: GeomTable, height: int = 84, width: int = 84, fovy: float = 45.0,
                 grayscale: bool = False, shadows: bool = False,
                 sky: tuple = ((0.4, 0.5, 0.6), (0.0, 0.0, 0.0))):
        if height < 1 or width < 1:
            raise ValueError(f"image size must be positive, got {height}x{width}")
        self.table = table
        self.height, self.width = int(height), int(width)
        self.fovy = float(fovy)
        self.grayscale = bool(grayscale)
        self.shadows = bool(shadows) and len(table.light_dirs) > 0
        self.sky = np.asarray(sky, np.float32)
        # Camera-frame ray directions, unit, [H, W, 3], row 0 at the top.
        tan_half = math.tan(math.radians(self.fovy) / 2)
        rows = (1 - 2 * (np.arange(self.height) + 0.5) / self.height) * tan_half
        cols = (2 * (np.arange(self.width) + 0.5) / self.width - 1) * tan_half * self.width / self.height
        x, y = np.meshgrid(cols, rows)
        rays = np.stack([x, y, -np.ones_like(x)], axis=-1)
        self._camera_rays = (rays / np.linalg.norm(rays, axis=-1, keepdims=True)).astype(np.float32)

    @property
    def channels(self) -> int:
        return 1 if self.grayscale else 3

    def cast(self, cam_pos, cam_mat, geom_xpos, geom_xmat) -> Hit:
        """Nearest hit per pixel for a camera at `cam_pos [3]` with orientation `cam_mat [3, 3]`
        (columns = camera axes in the world) and geoms at `geom_xpos [ngeom, 3]`, `geom_xmat
        [ngeom, 3, 3]` or `[ngeom, 9]`, indexed like the model (the table picks its geoms)."""
        table = self.table
        cam_pos = jnp.asarray(cam_pos, jnp.float32)
        cam_mat = jnp.asarray(cam_mat, jnp.float32).reshape(3, 3)
        xpos = jnp.asarray(geom_xpos, jnp.float32)[table.geom_ids]
        xmat = jnp.asarray(geom_xmat, jnp.float32).reshape(-1, 3, 3)[table.geom_ids]
        rays = jnp.asarray(self._camera_rays)
        d = tuple(rays[..., 0] * cam_mat[i, 0] + rays[..., 1] * cam_mat[i, 1]
                  + rays[..., 2] * cam_mat[i, 2] for i in range(3))
        best_t = jnp.full(d[0].shape, _MISS, jnp.float32)
        best_g = jnp.full(d[0].shape, -1, jnp.int32)
        for g in range(table.num_geoms):  # unrolled: G is small and static
            o_local = _to_local(tuple(cam_pos[i] - xpos[g, i] for i in range(3)), xmat[g])
            t = _INTERSECT[int(table.types[g])](o_local, _to_local(d, xmat[g]),
                                                tuple(float(s) for s in table.sizes[g]), True)
            closer = t < best_t
            best_t = jnp.where(closer, t, best_t)
            best_g = jnp.where(closer, g, best_g)
        hit_any = best_g >= 0
        t = jnp.where(hit_any, best_t, 0.0)
        point = tuple(cam_pos[i] + t * d[i] for i in range(3))
        normal = self._normals(point, best_g, xpos, xmat)
        lit = self._lit(point, best_g, xpos, xmat) if self.shadows else jnp.ones_like(t)
        return Hit(depth=best_t, geom=best_g, normal=jnp.stack(normal, -1),
                   point=jnp.stack(point, -1), lit=lit)

    def _normals(self, point, best_g, xpos, xmat):
        normal = (jnp.zeros_like(point[0]),) * 3
        for g in range(self.table.num_geoms):
            local = _to_local(tuple(point[i] - xpos[g, i] for i in range(3)), xmat[g])
            n = _to_world(_local_normal(int(self.table.types[g]),
                                        tuple(float(s) for s in self.table.sizes[g]), local), xmat[g])
            mine = best_g == g
            normal = tuple(jnp.where(mine, n[i], normal[i]) for i in range(3))
        norm = jnp.sqrt(normal[0] ** 2 + normal[1] ** 2 + normal[2] ** 2)
        return tuple(n / jnp.maximum(norm, 1e-12) for n in normal)

    def _lit(self, point, best_g, xpos, xmat):
        """1.0 where a ray from the hit point towards the first light hits no geom."""
        to_light = tuple(-float(c) for c in self.table.light_dirs[0])
        blocked = jnp.zeros(point[0].shape, jnp.bool_)
        for g in np.flatnonzero(self.table.cast_shadows):
            o_local = _to_local(tuple(point[i] - xpos[g, i] for i in range(3)), xmat[g])
            d_local = _to_local(tuple(jnp.full((), c, jnp.float32) for c in to_light), xmat[g])
            t = _INTERSECT[int(self.table.types[g])](o_local, d_local,
                                                     tuple(float(s) for s in self.table.sizes[g]), True)
            blocked |= (t < _MISS) & (best_g != g)  # a convex geom never shadows itself
        return jnp.where(blocked | (best_g < 0), 0.0, 1.0)

    def shade(self, hit: Hit, cam_mat, floor_rgb=None) -> jax.Array:
        """uint8 `[H, W, C]` image of `hit` seen from a camera oriented by `cam_mat` (it aims
        the headlight). `floor_rgb [H, W, 3]` (float in [0, 1]) colours the floor pixels
        (see `floor.py`); without it the floor keeps its geom colour."""
        table = self.table
        g = hit.geom
        rgb = jnp.asarray(table.rgb)[jnp.maximum(g, 0)]  # one small-table lookup per pixel
        if table.floor >= 0 and floor_rgb is not None:
            rgb = jnp.where((g == table.floor)[..., None], floor_rgb, rgb)
        n = hit.normal
        cam_forward = -jnp.asarray(cam_mat, jnp.float32).reshape(3, 3)[:, 2]
        # Elementwise, not `n @ cam_forward`: with an unbatched camera under `vmap` (a tracking
        # camera's orientation is constant) that dot made XLA's CPU program ~150x slower.
        head = jnp.maximum(-(n[..., 0] * cam_forward[0] + n[..., 1] * cam_forward[1]
                             + n[..., 2] * cam_forward[2]), 0.0)
        light = jnp.asarray(table.headlight_ambient + table.light_ambient)
        light = light + head[..., None] * jnp.asarray(table.headlight_diffuse)
        for k in range(len(table.light_dirs)):
            cos = jnp.maximum(-(n @ jnp.asarray(table.light_dirs[k])), 0.0)
            if k == 0:
                cos = cos * hit.lit
            light = light + cos[..., None] * jnp.asarray(table.light_diffuse[k])
        if table.floor >= 0:
            # A lit floor shows its texture unchanged (a video or noise keeps its values);
            # only shadows darken it.
            light = jnp.where((g == table.floor)[..., None], jnp.minimum(light, 1.0), light)
        colour = jnp.clip(rgb * light, 0.0, 1.0)
        colour = jnp.where((g < 0)[..., None], self._sky(), colour)
        return self._to_uint8(colour)

    def render(self, cam_pos, cam_mat, geom_xpos, geom_xmat, floor_rgb=None) -> jax.Array:
        """`shade(cast(...))`: one uint8 `[H, W, C]` frame."""
        hit = self.cast(cam_pos, cam_mat, geom_xpos, geom_xmat)
        return self.shade(hit, cam_mat, floor_rgb)

    def _sky(self):
        top, horizon = jnp.asarray(self.sky[0]), jnp.asarray(self.sky[1])
        rows = jnp.linspace(1.0, 0.0, self.height)[:, None, None]
        return horizon + (top - horizon) * rows * jnp.ones((1, self.width, 1))

    def _to_uint8(self, colour):
        if self.grayscale:
            colour = (colour @ jnp.asarray([0.299, 0.587, 0.114], jnp.float32))[..., None]
        return jnp.round(colour * 255.0).astype(jnp.uint8)
