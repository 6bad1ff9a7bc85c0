"""jaxnat.atari.area: the fused compositing + INTER_AREA kernel is OpenCV's resize bit for bit."""

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
                                      ((210, 160), (105, 84)), ((100, 77), (33, 20))])
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
