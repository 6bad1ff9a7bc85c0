"""The pure-JAX ray caster (jaxnat/mjx_pixel/render.py), its camera and floor textures.

Ray-primitive intersections against closed forms; the tracking camera against MuJoCo's own
`mj_camlight`; silhouettes and floor masks against MuJoCo's renderer (segmentation mode, exact
geom ids; OSMesa on CPU) for Gymnasium's four robots in random poses.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")

from jaxnat.mjx_pixel import render  # noqa: E402
from jaxnat.mjx_pixel.camera import TrackingCamera  # noqa: E402
from jaxnat.mjx_pixel.floor import floor_rgb, texture_at  # noqa: E402
from jaxnat.mjx_pixel.render import GeomTable, Renderer, intersect  # noqa: E402

ROBOTS = ("ant", "half_cheetah", "hopper", "swimmer")


def gym_model(robot):
    import importlib.resources

    path = importlib.resources.files("gymnasium") / "envs" / "mujoco" / "assets" / f"{robot}.xml"
    return mujoco.MjModel.from_xml_path(str(path))


def posed(model, seed, scale=0.3):
    """MjData in a random pose (free/slide root coordinates kept, joints perturbed), placed by
    MuJoCo's mj_forward."""
    data = mujoco.MjData(model)
    rng = np.random.default_rng(seed)
    qpos = model.qpos0.copy()
    qpos[2:] += rng.normal(0.0, scale, model.nq - 2)
    data.qpos[:] = qpos
    mujoco.mj_forward(model, data)
    return data


# --- intersections -----------------------------------------------------------------------------

def t_of(geom_type, size, origin, direction):
    return float(intersect(geom_type, size, np.asarray(origin, float), np.asarray(direction, float)))


@pytest.mark.parametrize("geom_type, size, origin, direction, expected", [
    # sphere r=0.5 from 3 m along -z: hits at 3 - 0.5
    (render.SPHERE, (0.5, 0, 0), (0, 0, 3), (0, 0, -1), 2.5),
    # grazing miss just outside the radius
    (render.SPHERE, (0.5, 0, 0), (0.51, 0, 3), (0, 0, -1), math.inf),
    # a non-unit direction: t is in units of |direction|
    (render.SPHERE, (1.0, 0, 0), (0, 0, 5), (0, 0, -2), 2.0),
    # capsule r=0.1, half-length 0.4 along z: side hit from x = 2
    (render.CAPSULE, (0.1, 0.4, 0), (2, 0, 0.3), (-1, 0, 0), 1.9),
    # capsule end cap: from above, hits the sphere at z = 0.4 + 0.1
    (render.CAPSULE, (0.1, 0.4, 0), (0, 0, 2), (0, 0, -1), 1.5),
    # capsule: passes beside the cap sphere (x = 0.09 at z = 0.45 is inside the cap's radius)
    (render.CAPSULE, (0.1, 0.4, 0), (0.06, 0, 2), (0, 0, -1), 2 - (0.4 + math.sqrt(0.01 - 0.0036))),
    # box half-sizes (1, 2, 3): faces at x = 1, y = 2, z = 3
    (render.BOX, (1, 2, 3), (5, 0, 0), (-1, 0, 0), 4.0),
    (render.BOX, (1, 2, 3), (0, -7, 0), (0, 1, 0), 5.0),
    (render.BOX, (1, 2, 3), (0, 0, 10), (0, 0, -1), 7.0),
    (render.BOX, (1, 2, 3), (1.5, 0, 10), (0, 0, -1), math.inf),
    # box corner-on diagonal: enters at the vertex (1, 2, 3) of the (1, 2, 3) box
    (render.BOX, (1, 2, 3), (2, 4, 6), (-1, -2, -3), 1.0),
    # ellipsoid semi-axes (1, 2, 3) along each axis
    (render.ELLIPSOID, (1, 2, 3), (4, 0, 0), (-1, 0, 0), 3.0),
    (render.ELLIPSOID, (1, 2, 3), (0, 5, 0), (0, -1, 0), 3.0),
    (render.ELLIPSOID, (1, 2, 3), (0, 0, 9), (0, 0, -1), 6.0),
    # cylinder r=0.5, half-height 1: side, flat cap, and a miss past the rim of the cap
    (render.CYLINDER, (0.5, 1.0, 0), (3, 0, 0.9), (-1, 0, 0), 2.5),
    (render.CYLINDER, (0.5, 1.0, 0), (0.4, 0, 3), (0, 0, -1), 2.0),
    (render.CYLINDER, (0.5, 1.0, 0), (0.6, 0, 3), (0, 0, -1), math.inf),
    # infinite plane (size 0): from above at 45 degrees; from below it is not drawn
    (render.PLANE, (0, 0, 1), (0, 0, 2), (1, 0, -1), 2.0),
    (render.PLANE, (0, 0, 1), (0, 0, -2), (0, 0, 1), math.inf),
    (render.PLANE, (0, 0, 1), (0, 0, 2), (0, 0, 1), math.inf),
    # bounded plane 1 x 1: a hit at x = 3 is off the plane
    (render.PLANE, (1, 1, 1), (0, 0, 2), (1.5, 0, -1), math.inf),
])
def test_intersection_closed_forms(geom_type, size, origin, direction, expected):
    t = t_of(geom_type, size, origin, direction)
    if math.isinf(expected):
        assert math.isinf(t)
    else:
        assert t == pytest.approx(expected, rel=1e-5, abs=1e-5)


IMPLICIT = {  # surface equation f(p) = 0 in the local frame, size (a, b, c)
    render.SPHERE: lambda p, s: np.linalg.norm(p, axis=-1) - s[0],
    render.ELLIPSOID: lambda p, s: np.linalg.norm(p / s, axis=-1) - 1.0,
    render.CAPSULE: lambda p, s: np.linalg.norm(
        p - np.stack([0 * p[..., 0], 0 * p[..., 0], np.clip(p[..., 2], -s[1], s[1])], -1), axis=-1) - s[0],
    render.BOX: lambda p, s: np.max(np.abs(p) / s, axis=-1) - 1.0,
}


@pytest.mark.parametrize("geom_type", sorted(IMPLICIT))
def test_random_rays_land_on_the_surface_and_nothing_is_nearer(geom_type):
    """Random rays from outside: hits satisfy the surface equation, and sampling the ray before
    the hit never finds a point inside (so the nearest root was taken)."""
    rng = np.random.default_rng(geom_type)
    size = np.array([0.5, 0.8, 0.3])
    origin = rng.normal(0, 1, (2000, 3))
    origin = 4 * origin / np.linalg.norm(origin, axis=1, keepdims=True)
    target = rng.uniform(-0.6, 0.6, (2000, 3))
    direction = target - origin
    t = np.asarray(intersect(geom_type, size, origin, direction), np.float64)
    f = IMPLICIT[geom_type]
    hit = np.isfinite(t)
    assert 0.2 < hit.mean() < 1.0, "the rays should both hit and miss"
    points = origin + t[:, None] * direction
    np.testing.assert_allclose(f(points[hit], size), 0.0, atol=2e-4)
    before = origin[:, None] + np.linspace(0, 1, 50)[None, :, None] * (
        np.where(hit, t, 1.0)[:, None, None] * direction[:, None]) * 0.999
    assert np.all(f(before, size) > -1e-4), "a point before the reported hit is inside the geom"
    # Misses: no sample along the whole segment to the target region is inside.
    along = origin[~hit][:, None] + np.linspace(0, 2, 200)[None, :, None] * direction[~hit][:, None]
    assert np.all(f(along, size) > -1e-3)


# --- camera ---------------------------------------------------------------------------------

@pytest.mark.parametrize("robot", ROBOTS)
def test_tracking_camera_matches_mujoco(robot):
    model = gym_model(robot)
    camera = TrackingCamera.from_model(model)
    assert camera.mode == 2 and model.body(camera.body).name == "torso"  # trackcom on the torso
    for seed in range(3):
        data = posed(model, seed)
        data.qpos[0] += 7.0 * seed  # far away along x: the camera follows
        mujoco.mj_forward(model, data)
        pos, mat = camera.pose(data)
        np.testing.assert_allclose(pos, data.cam_xpos[0], atol=1e-5)
        np.testing.assert_allclose(np.asarray(mat).ravel(), data.cam_xmat[0], atol=1e-6)


def test_track_and_fixed_camera_modes_match_mujoco():
    xml = """<mujoco><worldbody><geom type="plane" size="5 5 .1"/>
      <body name="b" pos="0 0 1"><freejoint/><geom type="box" size=".1 .2 .3"/>
        <camera name="follow" mode="track" pos="0 -2 1" xyaxes="1 0 0 0 1 2"/>
        <camera name="onboard" mode="fixed" pos=".1 .2 .3" euler="10 20 30"/>
      </body></worldbody></mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    data.qpos[:7] = [1.0, -2.0, 1.5, 0.9, 0.1, 0.3, 0.2]
    mujoco.mj_forward(model, data)
    for cam, name in enumerate(["follow", "onboard"]):
        pos, mat = TrackingCamera.from_model(model, name).pose(data)
        np.testing.assert_allclose(pos, data.cam_xpos[cam], atol=1e-5)
        np.testing.assert_allclose(np.asarray(mat).ravel(), data.cam_xmat[cam], atol=1e-5)
    with pytest.raises(ValueError, match="no camera named 'track'.*follow"):
        TrackingCamera.from_model(model)


def test_camera_keeps_the_torso_in_view_as_it_moves():
    model = gym_model("half_cheetah")
    table, camera = GeomTable.from_model(model), TrackingCamera.from_model(model)
    renderer = Renderer(table, 48, 48, fovy=camera.fovy, shadows=False)
    masks = []
    for x in (0.0, 25.0, -40.0):
        data = posed(model, 1)
        data.qpos[0] = x
        mujoco.mj_forward(model, data)
        pos, mat = camera.pose(data)
        hit = renderer.cast(pos, mat, data.geom_xpos, data.geom_xmat)
        masks.append(np.asarray((hit.geom >= 0) & (hit.geom != table.floor)))
    assert masks[0].sum() > 30
    # The robot moved 65 m but occupies the same pixels: only the floor slides under it.
    for m in masks[1:]:
        np.testing.assert_array_equal(m, masks[0])


# --- against MuJoCo's renderer -------------------------------------------------------------------

def mujoco_segmentation(model, data, height, width):
    try:
        renderer = mujoco.Renderer(model, height, width)
    except Exception as err:  # no GL: setup installs libosmesa6 (scripts/install_data.sh)
        pytest.skip(f"mujoco.Renderer unavailable (MUJOCO_GL={__import__('os').environ.get('MUJOCO_GL')}): {err}")
    try:
        renderer.enable_segmentation_rendering()
        renderer.update_scene(data, camera="track")
        seg = renderer.render().copy()
    finally:
        renderer.close()
    return np.where(seg[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM), seg[..., 0], -1)


def iou(a, b):
    return (a & b).sum() / max((a | b).sum(), 1)


@pytest.mark.parametrize("robot", ROBOTS)
def test_silhouette_and_floor_agree_with_mujoco_renderer(robot):
    model = gym_model(robot)
    table, camera = GeomTable.from_model(model), TrackingCamera.from_model(model)
    renderer = Renderer(table, 84, 84, fovy=camera.fovy)
    cast = jax.jit(renderer.cast)
    floor_id = table.geom_ids[table.floor]
    for seed in range(3):
        data = posed(model, seed)
        pos, mat = camera.pose(data)
        hit = cast(pos, mat, data.geom_xpos, data.geom_xmat)
        ours = np.where(hit.geom >= 0, table.geom_ids[np.maximum(hit.geom, 0)], -1)
        theirs = mujoco_segmentation(model, data, 84, 84)
        robot_ours, robot_theirs = (ours >= 0) & (ours != floor_id), (theirs >= 0) & (theirs != floor_id)
        assert robot_theirs.sum() > 50, "the robot should be in view"
        assert iou(robot_ours, robot_theirs) >= 0.95, f"{robot} seed {seed}: silhouette IoU"
        assert iou(ours == floor_id, theirs == floor_id) >= 0.95, f"{robot} seed {seed}: floor IoU"
        # Per-geom agreement too: the nearest geom, not just "some robot part".
        assert (ours == theirs).mean() >= 0.97


# --- renderer behaviour -------------------------------------------------------------------------

@pytest.fixture(scope="module")
def cheetah():
    model = gym_model("half_cheetah")
    return model, GeomTable.from_model(model), TrackingCamera.from_model(model)


def test_any_size_rgb_and_grayscale(cheetah):
    model, table, camera = cheetah
    data = posed(model, 0)
    pos, mat = camera.pose(data)
    rgb = Renderer(table, 30, 50, fovy=camera.fovy, shadows=False).render(
        pos, mat, data.geom_xpos, data.geom_xmat)
    gray = Renderer(table, 30, 50, fovy=camera.fovy, grayscale=True, shadows=False).render(
        pos, mat, data.geom_xpos, data.geom_xmat)
    assert rgb.shape == (30, 50, 3) and rgb.dtype == jnp.uint8
    assert gray.shape == (30, 50, 1) and gray.dtype == jnp.uint8
    luminance = np.asarray(rgb, np.float64) @ [0.299, 0.587, 0.114]
    np.testing.assert_allclose(np.asarray(gray)[..., 0], luminance, atol=1.0)
    with pytest.raises(ValueError, match="positive"):
        Renderer(table, 0, 50)


def skybox_texels(model):
    """uint8 [2, 3]: the skybox texture's texels straight up and straight down, read from the
    compiled texture (six square faces, the third up and the fourth down)."""
    tex = int(np.flatnonzero(np.asarray(model.tex_type) == mujoco.mjtTexture.mjTEXTURE_SKYBOX)[0])
    w, c, adr = int(model.tex_width[tex]), int(model.tex_nchannel[tex]), int(model.tex_adr[tex])
    faces = np.asarray(model.tex_data[adr:adr + 6 * w * w * c]).reshape(6, w, w, c)
    return faces[[2, 3], w // 2, w // 2, :3]


@pytest.mark.parametrize("robot", ROBOTS)
def test_sky_is_the_models_own_skybox(robot):
    """The sky runs from the skybox's zenith colour in the top row to its nadir colour in the
    bottom row: white to black for Ant, HalfCheetah and Swimmer, blue-grey to black for
    Hopper (as before, to within the one level MuJoCo's 8-bit texture takes off)."""
    model = gym_model(robot)
    table = GeomTable.from_model(model)
    zenith, nadir = skybox_texels(model).astype(int)
    camera = TrackingCamera.from_model(model)
    renderer = Renderer(table, 24, 24, fovy=camera.fovy, shadows=False)
    sky = np.stack([np.asarray(c)[:, 0] for c in renderer._sky()], -1) * 255  # [H, 3]
    np.testing.assert_allclose(sky[0], zenith, atol=1)
    np.testing.assert_allclose(sky[-1], nadir, atol=1)
    # In a rendered frame, every sky pixel shows its row's colour (Swimmer's camera looks
    # down at the floor and sees no sky; the others see it in the top row).
    data = posed(model, 0, scale=0.0)
    pos, mat = camera.pose(data)
    frame = np.asarray(renderer.render(pos, mat, data.geom_xpos, data.geom_xmat)).astype(int)
    is_sky = np.asarray(renderer.cast(pos, mat, data.geom_xpos, data.geom_xmat).geom) < 0
    assert robot == "swimmer" or is_sky[0].any(), f"{robot}: the top row shows no sky"
    rows = np.nonzero(is_sky)[0]
    np.testing.assert_allclose(frame[is_sky], sky[rows], atol=1)
    if robot == "hopper":  # Hopper's MJCF declares rgb1=".4 .5 .6" rgb2="0 0 0"
        np.testing.assert_allclose(sky / 255, np.linspace([0.4, 0.5, 0.6], [0.0, 0.0, 0.0], 24),
                                   atol=1 / 255)
    else:  # Gymnasium's white-to-black skybox, not Hopper's
        assert zenith.min() >= 250 and nadir.max() <= 2


def test_vmap_gives_each_env_its_own_frame_deterministically(cheetah):
    """One compiled batched render: permuting the batch permutes the frames (no cross-talk),
    the same input gives the same bytes, and each frame is the unbatched render's."""
    model, table, camera = cheetah
    renderer = Renderer(table, 40, 40, fovy=camera.fovy, shadows=False)
    datas = [posed(model, s) for s in range(3)]
    poses = [camera.pose(d) for d in datas]
    args = [jnp.stack([jnp.asarray(x) for x in xs]) for xs in zip(
        *[(p, m, d.geom_xpos, d.geom_xmat) for (p, m), d in zip(poses, datas)])]
    batched = jax.jit(jax.vmap(renderer.render))
    frames = np.asarray(batched(*args))
    order = np.array([2, 0, 1])
    np.testing.assert_array_equal(batched(*[a[order] for a in args]), frames[order])
    np.testing.assert_array_equal(batched(*args), frames)
    assert not np.array_equal(frames[0], frames[1])
    (p, m), d = poses[1], datas[1]
    # Eager (op by op) against compiled: float rounding may move a value by one level.
    np.testing.assert_allclose(renderer.render(p, m, d.geom_xpos, d.geom_xmat), frames[1], atol=1)


def test_pallas_kernel_gives_the_xla_frames(cheetah):
    """The Pallas nearest-hit kernel (interpreted on a CPU) renders the XLA path's frames
    exactly, batched, at a size that is no multiple of its pixel block."""
    model, table, camera = cheetah
    datas = [posed(model, s) for s in range(2)]
    pos = jnp.stack([jnp.asarray(camera.pose(d)[0]) for d in datas])
    xpos = jnp.stack([jnp.asarray(d.geom_xpos) for d in datas])
    xmat = jnp.stack([jnp.asarray(d.geom_xmat) for d in datas])
    frames = []
    for kernel in ("xla", "pallas"):
        renderer = Renderer(table, 24, 40, fovy=camera.fovy, grayscale=True, kernel=kernel)
        render = jax.jit(jax.vmap(lambda p, x, m, r=renderer: r.render(p, camera.mat, x, m)))
        frames.append(np.asarray(render(pos, xpos, xmat)))
    from jaxnat.mjx_pixel.pallas_cast import BLOCK

    assert 24 * 40 % BLOCK != 0
    np.testing.assert_array_equal(frames[1], frames[0])
    assert len(np.unique(frames[0])) > 5
    with pytest.raises(ValueError, match="kernel must be one of"):
        Renderer(table, kernel="cuda")


@pytest.mark.parametrize("robot", ROBOTS)
def test_row_spans_hold_every_pixel_of_their_geom(robot):
    """The Pallas kernel skips a geom for blocks of rows outside its bounding sphere's row span
    (computed per frame): each span must hold every pixel the geom is nearest at, and leave
    out most rows (else culling saves nothing)."""
    model = gym_model(robot)
    table, camera = GeomTable.from_model(model), TrackingCamera.from_model(model)
    renderer = Renderer(table, 84, 84, fovy=camera.fovy)
    covered = []
    for seed in range(4):
        data = posed(model, seed)
        pos, mat = camera.pose(data)
        spans = np.asarray(renderer.row_spans(pos, mat, data.geom_xpos, data.geom_xmat))
        geom = np.asarray(renderer.cast(pos, mat, data.geom_xpos, data.geom_xmat).geom)
        for g in range(table.num_geoms):
            first, last = spans[g]
            rows = np.flatnonzero(np.any(geom == g, axis=1))
            assert np.all((rows >= first) & (rows <= last)), f"geom {g}: rows {rows} vs {first}..{last}"
            if g != table.floor:
                covered.append(np.clip(min(last, 83) - max(first, 0) + 1, 0, 84) / 84)
    assert np.mean(covered) < 0.5


def test_shading_normals_and_shadows(cheetah):
    model, table, camera = cheetah
    data = posed(model, 0)
    pos, mat = camera.pose(data)
    hit = Renderer(table, 84, 84, fovy=camera.fovy, shadows=True).cast(
        pos, mat, data.geom_xpos, data.geom_xmat)
    normal = np.asarray(hit.normal)
    hits = np.asarray(hit.geom) >= 0
    np.testing.assert_allclose(np.linalg.norm(normal[hits], axis=-1), 1.0, atol=1e-4)
    floor = np.asarray(hit.geom) == table.floor
    np.testing.assert_allclose(normal[floor], np.broadcast_to([0.0, 0.0, 1.0], normal[floor].shape), atol=1e-6)
    # Normals face the camera.
    rays = np.asarray(hit.point) - np.asarray(pos)
    assert np.all(np.sum(normal[hits] * rays[hits], -1) < 1e-4)
    # The light is straight above: the floor under the body is in shadow, the far floor is not.
    lit = np.asarray(hit.lit)
    assert 0 < (floor & (lit == 0)).sum() < 0.2 * floor.sum()
    no_shadow = Renderer(table, 84, 84, fovy=camera.fovy, shadows=False).cast(
        pos, mat, data.geom_xpos, data.geom_xmat)
    assert np.all(np.asarray(no_shadow.lit) == 1)
    np.testing.assert_array_equal(no_shadow.geom, hit.geom)


def test_unsupported_geoms_are_a_clear_error():
    xml = """<mujoco><asset><mesh name="m" vertex="0 0 0 1 0 0 0 1 0 0 0 1"/></asset>
      <worldbody><geom type="mesh" mesh="m"/></worldbody></mujoco>"""
    with pytest.raises(ValueError, match="mesh=7"):
        GeomTable.from_model(mujoco.MjModel.from_xml_string(xml))


# --- floor textures -------------------------------------------------------------------------

def test_texture_is_fixed_to_the_world_and_upright():
    texture = jnp.arange(4 * 6, dtype=jnp.uint8).reshape(4, 6, 1)
    tile = jnp.array([3.0, 2.0])  # 6 columns over 3 m: 0.5 m each; 4 rows over 2 m
    xy = jnp.array([[0.25, 1.99], [0.25, 0.01], [2.9, 1.0], [0.25 + 3.0, 0.01 - 2.0], [-0.25, 0.01]])
    got = np.asarray(texture_at(texture, xy, tile))[:, 0]
    # (x=0.25, y near the tile's top) -> row 0, col 0; y near 0 -> last row; periodic in both.
    assert got.tolist() == [0, 18, 6 * 2 + 5, 18, 23]


def test_checker_floor_is_the_models_texture(cheetah):
    model, table, _ = cheetah
    # Gymnasium: 100x100 checker, 60 copies over the 80 m plane -> 4/3 m per copy.
    np.testing.assert_allclose(table.floor_tile, [80 / 60, 80 / 60], rtol=1e-6)
    squares = np.asarray(floor_rgb("checker", table, jnp.array([[0.1, 0.1], [0.1 + 2 / 3, 0.1]])))
    assert not np.allclose(squares[0], squares[1]), "adjacent checker squares differ"
    with pytest.raises(ValueError, match="floor must be one of"):
        floor_rgb("carpet", table, jnp.zeros((1, 2)))


# --- floor filtering (issue #21: the far floor was read at the nearest texel) -------------------

def test_mip_levels_average_down_to_the_mean():
    from jaxnat.mjx_pixel.floor import mip_levels

    texture = np.random.default_rng(0).uniform(size=(100, 36, 3)).astype(np.float32)
    levels = mip_levels(texture)
    # OpenGL's sizes: halved and floored, to 1x1 (100 -> 50 -> 25 -> 12 -> 6 -> 3 -> 1).
    assert [lv.shape[:2] for lv in levels] == [(100, 36), (50, 18), (25, 9), (12, 4), (6, 2),
                                               (3, 1), (1, 1)]
    np.testing.assert_allclose(levels[1][0, 0], texture[:2, :2].mean((0, 1)), rtol=1e-5)
    for level in levels:  # every level, odd sizes included, keeps the texture's mean
        np.testing.assert_allclose(level.mean((0, 1)), texture.mean((0, 1)), rtol=1e-4)
    # The same chain on the device (the video floor builds it per frame).
    device = mip_levels(jnp.asarray(texture))
    for a, b in zip(levels, device):
        np.testing.assert_allclose(np.asarray(b), a, rtol=1e-5, atol=1e-6)


def test_mip_texture_is_nearest_texel_up_close_and_the_mean_far_away():
    from jaxnat.mjx_pixel.floor import mip_levels, texture_mip

    texture = np.random.default_rng(1).uniform(size=(16, 16, 1)).astype(np.float32)
    levels, tile = mip_levels(texture), np.array([2.0, 2.0])
    xy = jnp.asarray(np.random.default_rng(2).uniform(-5, 5, size=(200, 2)), jnp.float32)
    near = np.asarray(texture_at(jnp.asarray(texture), xy, tile))

    def footprint(metres):  # a pixel step of `metres` along x (right) and y (down)
        step, zero = jnp.full(200, metres, jnp.float32), jnp.zeros(200, jnp.float32)
        return (step, zero), (zero, step)

    # At most one texel per pixel (a texel is 1/8 m): exactly the nearest texel, as before.
    for metres in (0.0, 0.01, 0.125):
        np.testing.assert_array_equal(np.asarray(texture_mip(levels, xy, tile, footprint(metres))), near)
    # Two texels per pixel: level 1 exactly; 16 or more: the texture's mean.
    level1 = np.asarray(texture_at(jnp.asarray(levels[1]), xy, tile))
    np.testing.assert_allclose(np.asarray(texture_mip(levels, xy, tile, footprint(0.25))), level1, rtol=1e-6)
    np.testing.assert_allclose(np.asarray(texture_mip(levels, xy, tile, footprint(3.0))),
                               np.full((200, 1), texture.mean()), rtol=1e-5)
    # The nearest level (no blend): level 0 up to sqrt(2) texels per pixel, level 1 past it.
    below, above = (np.asarray(texture_mip(levels, xy, tile, footprint(0.125 * math.sqrt(2) * f)))
                    for f in (0.99, 1.01))
    np.testing.assert_array_equal(below, near)
    np.testing.assert_allclose(above, level1, rtol=1e-6)
    # The packed chain of a uint8 bank, read by frame index: the same texels, rounded to 8 bits.
    from jaxnat.mjx_pixel.floor import pack_mips

    bank = np.random.default_rng(3).integers(0, 256, (3, 16, 16, 1), np.uint8)
    chains = pack_mips(jnp.asarray(bank))
    assert chains.dtype == jnp.uint8 and chains.shape == (3, 16 * 16 + 8 * 8 + 4 * 4 + 2 * 2 + 1, 1)
    for metres in (0.0, 0.25, 0.6, 3.0):
        ours = texture_mip(chains, xy, tile, footprint(metres), shape=(16, 16), index=1)
        exact = texture_mip(mip_levels(bank[1].astype(np.float32)), xy, tile, footprint(metres))
        np.testing.assert_allclose(np.asarray(ours, float), np.asarray(exact), atol=0.5)


def test_footprint_of_a_tracking_camera_is_host_constants_times_depth(cheetah):
    """With the tracking camera's constant orientation and the world-fixed floor, the footprint
    is known per pixel up to the depth (host constants); it matches the general per-pixel
    formula (traced orientation, per-pixel normals) on the floor."""
    model, table, camera = cheetah
    data = posed(model, 0)
    pos, mat = camera.pose(data)
    renderer = Renderer(table, 84, 84, fovy=camera.fovy)
    np.testing.assert_allclose(table.floor_normal, [0, 0, 1], atol=1e-6)
    hit = renderer.cast(pos, mat, data.geom_xpos, data.geom_xmat)
    normal = tuple(hit.normal[..., i] for i in range(3))
    static = renderer.footprint(hit.depth, mat, normal)
    traced = jax.jit(lambda m: renderer.footprint(hit.depth, m, normal).lod(8.0))(jnp.asarray(mat))
    assert all(isinstance(a, np.ndarray) for a in static.right + static.down)
    floor = np.asarray(hit.geom) == table.floor
    np.testing.assert_allclose(np.asarray(static.lod(8.0))[floor], np.asarray(traced)[floor],
                               atol=1e-4)


def test_checker_box_is_the_nearest_texel_up_close_a_tent_average_beyond_and_the_mean_far():
    """The closed-form checker (MuJoCo's builtin 2x2 checker, `floor.checker_box`): under
    sqrt(2) texels per pixel along an axis it reads that axis exactly as the nearest texel;
    past it, each axis is the square wave's average under a tent of half-width the footprint's
    extent (checked against numerical integration); a footprint of whole periods gives the
    two colours' mean. The checker's mip chain is not needed for it."""
    from jaxnat.mjx_pixel.floor import checker_box

    texels = 100
    texture = np.full((texels, texels, 1), 0.2, np.float32)
    texture[:50, :50] = texture[50:, 50:] = 0.9  # a top-left, b the other two blocks
    tile = np.array([2.0, 2.0])
    xy = jnp.asarray(np.random.default_rng(2).uniform(-5, 5, size=(300, 2)), jnp.float32)
    near = np.asarray(texture_at(jnp.asarray(texture), xy, tile))

    def footprint(metres_x, metres_y):  # a pixel step right along x and down along y
        zero = jnp.zeros(300, jnp.float32)
        return (jnp.full(300, metres_x, jnp.float32), zero), (zero, jnp.full(300, metres_y, jnp.float32))

    texel = 2.0 / texels
    for metres in (0.0, 0.5 * texel, 1.4 * texel):
        np.testing.assert_array_equal(np.asarray(checker_box((0.9, 0.2), xy, tile, footprint(metres, metres),
                                                             texels=texels)), near)
    np.testing.assert_allclose(np.asarray(checker_box((0.9, 0.2), xy, tile, footprint(0.0, 4.0), texels=texels)),
                               0.55, atol=1e-6)  # whole periods along y: the mean, whatever x
    width_x = 0.3  # metres: a tent of half-width 0.15 copies along x, exact along y
    ours = np.asarray(checker_box((0.9, 0.2), xy, tile, footprint(width_x, 0.0), texels=texels))[:, 0]
    t = np.linspace(-1.0, 1.0, 4001)
    wave = lambda x: np.where(x - np.floor(x) < 0.5, 1.0, -1.0)  # noqa: E731
    u, v = np.asarray(xy[:, 0], float) / 2.0, -np.asarray(xy[:, 1], float) / 2.0
    tent_u = np.array([np.trapezoid(wave(x + (width_x / 2.0) * t) * (1 - np.abs(t)), t) for x in u])
    np.testing.assert_allclose(ours, 0.55 + 0.35 * tent_u * wave(v), atol=2e-3)


def far_and_near_floor_rows(renderer, table, pos, mat, data):
    """(far, near): the floor mask restricted to the 8 rows below the horizon and to the
    bottom 12 rows."""
    floor = np.asarray(renderer.cast(pos, mat, data.geom_xpos, data.geom_xmat).geom) == table.floor
    first = int(np.flatnonzero(floor.any(axis=1))[0])
    far, near = floor.copy(), floor.copy()
    far[first + 8:] = False
    near[:-12] = False
    return far, near


def render_floor(renderer, pos, mat, data, floor):
    """uint8 [H, W, 3]: `renderer`'s frame with the floor function `floor(xy, footprint)`."""
    fn = floor if renderer.floor_filter == "mip" else (lambda xy: floor(xy, None))
    return np.asarray(jax.jit(lambda p, x, m: renderer.render(p, mat, x, m, fn))(
        pos, data.geom_xpos, data.geom_xmat)).astype(float)


def test_far_checker_fades_to_its_mean_as_in_mujoco(cheetah):
    """Near the horizon a pixel covers many checker squares. Read at the nearest texel (the
    renderer before mip filtering) those rows are black-and-grey noise (moire); filtered by
    the footprint they are the checker's mean colour, smooth as MuJoCo's mipmapped floor. The
    near floor, a few texels per pixel, keeps its squares: only their edges soften."""
    model, table, camera = cheetah
    data = posed(model, 0, scale=0.0)
    pos, mat = camera.pose(data)
    checker = lambda xy, fp: floor_rgb("checker", table, xy, fp)  # noqa: E731
    mean_colour = jnp.asarray(table.floor_texture.mean((0, 1)))
    frames = {f: render_floor(Renderer(table, 84, 84, fovy=camera.fovy, floor_filter=f), pos, mat,
                              data, checker) for f in ("nearest", "mip")}
    flat = render_floor(Renderer(table, 84, 84, fovy=camera.fovy), pos, mat, data,
                        lambda xy, fp: jnp.broadcast_to(mean_colour, xy.shape[:-1] + (3,)))
    far, near = far_and_near_floor_rows(Renderer(table, 84, 84, fovy=camera.fovy), table, pos, mat, data)
    assert far.sum() > 300 and near.sum() > 800
    row_std = lambda frame: np.array([frame[r][far[r]].std(0).max() for r in np.flatnonzero(far.any(1))])  # noqa: E731
    assert row_std(frames["nearest"]).min() > 40, "nearest texel: the far rows are moire"
    assert row_std(frames["mip"]).max() < 3, "filtered: the far rows are smooth"
    np.testing.assert_allclose(frames["mip"][far], flat[far], atol=4)  # the checker's mean
    same = np.all(frames["mip"][near] == frames["nearest"][near], axis=-1)
    assert same.mean() > 0.7, "the near floor keeps its squares"
    np.testing.assert_allclose(frames["mip"][near].mean(0), frames["nearest"][near].mean(0), atol=4)
    # MuJoCo's far floor is as smooth in the 5 rows below the horizon (it shows squares from
    # the 7th on), on the pixels that are floor in both renders (its lighting, with specular,
    # is a few levels brighter). Skipped without OpenGL.
    far &= mujoco_segmentation(model, data, 84, 84) == table.geom_ids[table.floor]
    far[np.flatnonzero(far.any(axis=1))[0] + 5:] = False
    renderer = mujoco.Renderer(model, 84, 84)
    try:
        renderer.update_scene(data, camera="track")
        theirs = renderer.render().astype(float)
    finally:
        renderer.close()
    assert row_std(theirs).max() < 8 and row_std(frames["mip"]).max() < 3
    assert abs(theirs[far].mean() - frames["mip"][far].mean()) < 15
    # Over the whole floor the filtered checker is closer to MuJoCo's (trilinear, lit with
    # specular) than the nearest texel: 13 grey levels off on average, against 43 unfiltered
    # and 20 for the nearest mip level (the filter before the closed-form checker).
    floor = mujoco_segmentation(model, data, 84, 84) == table.geom_ids[table.floor]
    floor &= np.asarray(Renderer(table, 84, 84, fovy=camera.fovy).cast(
        pos, mat, data.geom_xpos, data.geom_xmat).geom) == table.floor
    off = {f: np.abs(frames[f] - theirs)[floor].mean() for f in frames}
    assert off["mip"] < 15 and off["nearest"] > 35, off


def test_far_video_floor_is_filtered(cheetah):
    """The video floor, mip-filtered, read from a bank by index (its chains packed once, as the
    env does, or built per frame on the device): a white-noise frame averages to grey far away
    instead of staying noise."""
    model, table, camera = cheetah
    data = posed(model, 0, scale=0.0)
    pos, mat = camera.pose(data)
    bank = jnp.asarray(np.random.default_rng(0).integers(0, 256, (3, 64, 64, 1), np.uint8))
    video = lambda xy, fp: floor_rgb("video", table, xy, fp, frame=bank, frame_index=jnp.int32(1),  # noqa: E731
                                     tile=(4.0, 4.0))
    far, near = far_and_near_floor_rows(Renderer(table, 84, 84, fovy=camera.fovy), table, pos, mat, data)
    frames = {f: render_floor(Renderer(table, 84, 84, fovy=camera.fovy, floor_filter=f), pos, mat,
                              data, video) for f in ("nearest", "mip")}
    from jaxnat.mjx_pixel.floor import pack_mips

    chains = pack_mips(bank)
    packed = render_floor(Renderer(table, 84, 84, fovy=camera.fovy), pos, mat, data,
                          lambda xy, fp: floor_rgb("video", table, xy, fp, frame=bank, mips=chains,
                                                   frame_index=jnp.int32(1), tile=4.0))
    assert np.abs(packed - frames["mip"]).max() <= 1  # the same levels, rounded to 8 bits
    assert frames["nearest"][far].std() > 30
    assert frames["mip"][far].std() < 0.25 * frames["nearest"][far].std()
    assert frames["mip"][far].std() < 8
    with pytest.raises(ValueError, match="floor_filter must be one of"):
        Renderer(table, floor_filter="linear")
