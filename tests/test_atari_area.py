"""jaxnat.atari.area: the fused compositing + INTER_AREA kernel is OpenCV's resize bit for bit."""

import itertools

import cv2
import numpy as np
import pytest

pytest.importorskip("numba")

from jaxnat.atari.area import area_plan, composite_resize
from jaxnat.atari.compositor import composite_and_resize


def _reference(screens, backgrounds, size):
    composited = np.where(screens == 0, backgrounds, screens)
    return np.stack([cv2.resize(c, size[::-1], interpolation=cv2.INTER_AREA) for c in composited])


def _batches(shape, rng, n=6):
    """Random, quantised (flat areas: many ties) and sparse screens over random backgrounds."""
    for kind in range(3):
        screens = rng.integers(0, 256, (n, *shape), dtype=np.uint8)
        if kind == 1:
            screens = screens // 64 * 64
        if kind == 2:
            screens = ((screens > 180) * rng.integers(1, 256, (n, 1, 1))).astype(np.uint8)
        backgrounds = rng.integers(0, 256, (n, *shape), dtype=np.uint8) // (8 * kind + 1)
        yield screens, backgrounds.astype(np.uint8)


@pytest.mark.parametrize("src, dst", [((210, 160), (84, 84)), ((210, 160), (64, 48)),
                                      ((210, 160), (105, 84)), ((100, 77), (40, 35))])
def test_equals_opencv_inter_area_bit_for_bit(src, dst):
    rng = np.random.default_rng(0)
    plan = area_plan(src, dst)
    assert plan is not None
    for screens, backgrounds in _batches(src, rng):
        out = np.full((len(screens), *dst), 7, np.uint8)
        composite_resize(screens, backgrounds, out, plan)
        np.testing.assert_array_equal(out, _reference(screens, backgrounds, dst))
        plain = composite_resize(screens, screens, np.empty_like(out), plan)  # nothing composited
        np.testing.assert_array_equal(plain, _reference(screens, screens, dst))


def test_ties_follow_opencvs_float_rounding():
    """At ~1% of pixels the exact area mean is k + 1/2; OpenCV's float32 sums round those either
    way. The inputs here have such ties, and rounding them half up would differ from OpenCV."""
    rng = np.random.default_rng(1)
    plan = area_plan((210, 160), (84, 84))
    assert plan.denominator == 200 and plan.sum_dtype is np.uint16
    screens, backgrounds = next(_batches((210, 160), rng, n=8))
    reference = _reference(screens, backgrounds, (84, 84))
    composited = np.where(screens == 0, backgrounds, screens).astype(np.int64)
    wy = np.zeros((84, 210), np.int64)
    wx = np.zeros((84, 160), np.int64)
    for r in range(84):
        wy[r, plan.y_first[r]:plan.y_first[r] + plan.y_weights.shape[1]] = plan.y_weights[r]
        wx[r, plan.x_first[r]:plan.x_first[r] + plan.x_weights.shape[1]] = plan.x_weights[r]
    exact = np.einsum("ri,bic,jc->brj", wy, composited, wx)  # 200 x the area mean, exactly
    ties = exact % 200 == 100
    assert ties.mean() > 0.005
    half_up = (exact + 100) // 200
    assert (half_up != reference)[ties].any() and (half_up == reference)[~ties].all()
    out = composite_resize(screens, backgrounds, np.empty_like(reference), plan)
    np.testing.assert_array_equal(out, reference)


def test_every_plan_of_small_images_equals_opencv():
    """Every source up to 10x10, every smaller size with a plan: random and two-level images
    (ties), composited over a background. Small denominators such as 49 (7 -> 2 on both axes)
    are where a rounded 1/D would floor k*D to k - 1."""
    rng = np.random.default_rng(4)
    planned = 0
    for src in itertools.product(range(1, 11), repeat=2):
        screens = rng.integers(0, 256, (4, *src), dtype=np.uint8)
        screens[2:] = screens[2:] // 128 * 255  # two levels: many exact ties
        screens[3, ::2] = 0  # background rows
        backgrounds = rng.integers(0, 256, (4, *src), dtype=np.uint8)
        for dst in itertools.product(range(1, src[0] + 1), range(1, src[1] + 1)):
            plan = area_plan(src, dst)
            if plan is None:
                continue
            planned += 1
            out = composite_resize(screens, backgrounds, np.empty((4, *dst), np.uint8), plan)
            np.testing.assert_array_equal(out, _reference(screens, backgrounds, dst),
                                          err_msg=f"{src} -> {dst}")
    assert planned > 2000


def test_one_pixel_over_49_rounds_like_opencv():
    image = np.zeros((1, 7, 7), np.uint8)
    image[0, 3, 3] = 25  # each output's mean is 25/49 (0.51): rounds to 1
    out = composite_resize(image, image, np.empty((1, 2, 2), np.uint8), area_plan((7, 7), (2, 2)))
    np.testing.assert_array_equal(out[0], cv2.resize(image[0], (2, 2), interpolation=cv2.INTER_AREA))
    assert out.min() == 1


def test_no_plan_where_opencvs_float_error_could_cross_a_rounding_boundary():
    """At 210x160 -> 83x79 (D = 33,600) a mean of 159.49997 is 3e-5 from a half, within
    OpenCV's float32 error: it gives 160 where exact rounding gives 159. No plan there; the
    fallback is OpenCV itself."""
    assert area_plan((210, 160), (83, 79)) is None
    image = np.zeros((1, 210, 160), np.uint8)
    image[0, 88:92, 101:104] = [[238, 47, 198], [25, 253, 2], [187, 200, 170], [233, 167, 226]]
    reference = cv2.resize(image[0], (79, 83), interpolation=cv2.INTER_AREA)
    assert reference[35, 50] == 160
    np.testing.assert_array_equal(composite_and_resize(image, None, (83, 79))[0], reference)
    assert area_plan((2000, 10), (1999, 5)) is None  # output side >= 1,000
    plan = area_plan([210, 160], np.array([84, 84]))  # any sequence of ints
    assert plan is area_plan((210, 160), (84, 84))
    assert not plan.x_weights.flags.writeable  # a cached plan is shared: read-only


@pytest.mark.parametrize("dst", [(105, 80), (210, 160), (300, 200), (100, 170)])
def test_other_sizes_fall_back_to_opencv(dst):
    """Integer factors (OpenCV's fast path rounds differently), the same size and upscaling
    have no plan; `composite_and_resize` then composites and resizes with OpenCV."""
    assert area_plan((210, 160), dst) is None
    rng = np.random.default_rng(2)
    screens, backgrounds = next(_batches((210, 160), rng, n=3))
    kept = screens.copy()
    np.testing.assert_array_equal(composite_and_resize(screens, backgrounds, dst),
                                  _reference(screens, backgrounds, dst))
    np.testing.assert_array_equal(screens, kept)  # the screens are not modified


def test_composite_and_resize_writes_out_and_keeps_the_screens():
    rng = np.random.default_rng(3)
    screens, backgrounds = next(_batches((210, 160), rng, n=3))
    kept = screens.copy()
    out = np.zeros((3, 84, 84), np.uint8)
    assert composite_and_resize(screens, backgrounds, (84, 84), out=out) is out
    np.testing.assert_array_equal(out, _reference(screens, backgrounds, (84, 84)))
    np.testing.assert_array_equal(composite_and_resize(screens, None, (84, 84)),
                                  _reference(screens, screens, (84, 84)))
    np.testing.assert_array_equal(screens, kept)


def test_bad_shapes_are_clear_errors():
    plan = area_plan((210, 160), (84, 84))
    screens = np.zeros((2, 210, 160), np.uint8)
    with pytest.raises(ValueError, match="screens and backgrounds"):
        composite_resize(screens, np.zeros((2, 200, 160), np.uint8), np.zeros((2, 84, 84), np.uint8), plan)
    with pytest.raises(ValueError, match="C-contiguous uint8"):
        composite_resize(screens, screens, np.zeros((2, 84, 84, 2), np.uint8)[..., 0], plan)
