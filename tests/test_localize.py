"""Localization-by-navigation semantics (docs/environments.md section 2)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxnat
from jaxnat.datasets import DatasetNotFoundError
from jaxnat.datasets.segmentation import VOID, SegmentationDataset
from jaxnat.testing import check_env
from jaxnat.wrappers import AutoResetWrapper
from jaxnat.vision_envs.localize import DOWN, LEFT, RIGHT, UP, Localize, LocalizeState

H, W, SIDE = 20, 24, 4
START = ((H - SIDE) // 2, (W - SIDE) // 2)  # (8, 10)


def scene(pixels):
    """A VOID class map with `{(row, col): class}` set."""
    class_map = np.full((H, W), VOID, np.uint8)
    for (r, c), k in pixels.items():
        class_map[r, c] = k
    return class_map


@pytest.fixture
def dataset():
    """Three photos with distinct pixel values; class maps:
    0: class 0 under the start footprint, class 1 at (0, 0), class 2 absent;
    1: class 2 at (19, 23) only;
    2: class 0 only under the start footprint (no valid goal: dropped)."""
    r, c = np.meshgrid(np.arange(H), np.arange(W), indexing="ij")
    images = np.stack([np.stack([r * 10 + i, c * 10, np.full_like(r, 7 + i)], -1)
                       for i in range(3)]).astype(np.uint8)
    maps = np.stack([
        scene({(9, 11): 0, (0, 0): 1}),
        scene({(19, 23): 2}),
        scene({(START[0], START[1]): 0}),
    ])
    return SegmentationDataset("toy", "train", images, maps, ("zero", "one", "two"))


@pytest.fixture
def env(dataset):
    return Localize(dataset, w=SIDE, M=7)


def at(image_index, goal, row, col, time=0):
    return LocalizeState(time=jnp.int32(time), image_index=jnp.int32(image_index),
                         goal=jnp.int32(goal), top_left=jnp.array([row, col], jnp.int32))


def one_goal_env(goal_pixels, goal=1):
    """An env over one photo whose class map has class `goal` at `goal_pixels` and class 0 at
    the centre (so the image has a valid goal), plus a state with that goal."""
    maps = scene({**{p: goal for p in goal_pixels}, START: 0})[None]
    images = np.zeros((1, H, W, 3), np.uint8)
    env = Localize(SegmentationDataset("one", "train", images, maps, ("a", "b")), w=SIDE)
    return env, env.default_params


def test_contract(env):
    check_env(env, env.default_params)
    check_env(AutoResetWrapper(env), env.default_params)


def test_spaces(env):
    params = env.default_params
    space = env.observation_space(params)
    assert space.spaces["pixels"].shape == (H, W, 4)
    assert space.spaces["pixels"].dtype == jnp.uint8
    assert space.spaces["goal"].n == 3
    assert env.action_space(params).n == 4


def test_images_without_a_valid_goal_are_dropped(env, dataset):
    assert env.num_dropped == 1
    assert env.default_params.images.shape[0] == 2
    np.testing.assert_array_equal(np.asarray(env.default_params.class_maps),
                                  dataset.class_maps[:2])


def test_goal_is_present_never_void_and_never_under_the_start(env):
    params = env.default_params
    keys = jax.random.split(jax.random.key(0), 256)
    obs, state = jax.vmap(env.reset, in_axes=(0, None))(keys, params)
    pairs = set(zip(np.asarray(state.image_index).tolist(), np.asarray(state.goal).tolist()))
    # Image 0: class 0 is under the start, class 2 absent -> always 1; image 1: only class 2.
    assert pairs == {(0, 1), (1, 2)}
    np.testing.assert_array_equal(np.asarray(obs["goal"]), np.asarray(state.goal))
    assert (np.asarray(state.top_left) == START).all()


def test_goal_is_uniform_among_valid_classes():
    maps = scene({(0, 0): 0, (0, 5): 1, (0, 9): 2})[None]
    env = Localize(SegmentationDataset("three", "train", np.zeros((1, H, W, 3), np.uint8), maps,
                                       ("a", "b", "c")), w=SIDE)
    keys = jax.random.split(jax.random.key(1), 1200)
    _, state = jax.vmap(env.reset, in_axes=(0, None))(keys, env.default_params)
    counts = np.bincount(np.asarray(state.goal), minlength=3)
    assert counts.min() > 330, counts  # 400 expected, sd 16


def test_class_subset_restricts_goals(dataset):
    env = Localize(dataset, w=SIDE, classes=["two"])
    assert env.num_dropped == 2
    _, state = jax.vmap(env.reset, in_axes=(0, None))(jax.random.split(jax.random.key(0), 32),
                                                      env.default_params)
    assert set(np.asarray(state.goal).tolist()) == {2}
    assert Localize(dataset, w=SIDE, classes=[2]).num_dropped == 2
    with pytest.raises(ValueError, match="unknown class 'three'"):
        Localize(dataset, w=SIDE, classes=["three"])
    with pytest.raises(ValueError, match="no image"):
        Localize(dataset, w=SIDE, classes=["zero"])


@pytest.mark.parametrize("move, start, expected", [
    (UP, (8, 10), (4, 10)), (UP, (2, 10), (0, 10)), (UP, (0, 10), (0, 10)),
    (DOWN, (8, 10), (12, 10)), (DOWN, (14, 10), (16, 10)), (DOWN, (16, 10), (16, 10)),
    (LEFT, (8, 10), (8, 6)), (LEFT, (8, 3), (8, 0)),
    (RIGHT, (8, 10), (8, 14)), (RIGHT, (8, 18), (8, 20)), (RIGHT, (8, 20), (8, 20)),
])
def test_moves_shift_by_w_and_stay_inside(env, move, start, expected):
    params = env.default_params
    obs, state, *_ = env.step(jax.random.key(0), at(1, 2, *start), jnp.int32(move), params)
    assert tuple(np.asarray(state.top_left)) == expected
    footprint = np.zeros((H, W), np.uint8)
    footprint[expected[0]:expected[0] + SIDE, expected[1]:expected[1] + SIDE] = 255
    np.testing.assert_array_equal(np.asarray(obs["pixels"][..., 3]), footprint)


def test_observation_is_the_photo_and_the_footprint(env, dataset):
    obs, _ = env.reset(jax.random.key(3), env.default_params)
    _, state = env.reset(jax.random.key(3), env.default_params)
    pixels = np.asarray(obs["pixels"])
    np.testing.assert_array_equal(pixels[..., :3], dataset.images[int(state.image_index)])
    assert obs["goal"].dtype == jnp.int32 and obs["goal"].shape == ()


@pytest.mark.parametrize("goal_pixel, hit", [
    ((8, 14), True),   # the footprint moves right to (8, 14): its top-left pixel
    ((11, 17), True),  # its bottom-right pixel: a one-pixel overlap counts
    ((12, 18), False),  # diagonal neighbour of that corner: outside
    ((12, 17), False),  # edge neighbour below the footprint: outside
    ((11, 18), False),  # edge neighbour right of it: outside
    ((7, 13), False),  # diagonal neighbour of the top-left corner
])
def test_footprint_overlap_is_exact(goal_pixel, hit):
    env, params = one_goal_env([goal_pixel])
    _, state, reward, terminated, truncated, _ = env.step(
        jax.random.key(0), at(0, 1, *START), jnp.int32(RIGHT), params)
    assert tuple(np.asarray(state.top_left)) == (8, 14)
    assert float(reward) == (1.0 if hit else 0.0)
    assert bool(terminated) == hit and not bool(truncated)


def test_other_classes_under_the_footprint_do_not_count():
    env, params = one_goal_env([(0, 0)])
    # Class 0 fills the start pixel; moving away and back onto it is no success for goal 1.
    state = at(0, 1, START[0], START[1] + SIDE)
    _, _, reward, terminated, *_ = env.step(jax.random.key(0), state, jnp.int32(LEFT), params)
    assert float(reward) == 0.0 and not bool(terminated)


def test_truncated_at_max_steps_default_200(dataset):
    env = Localize(dataset, w=SIDE)
    params = env.default_params
    assert params.max_steps_in_episode == 200

    def body(state, t):
        # Image 1's goal (class 2) sits in the bottom-right corner; UP never reaches it.
        _, state, reward, terminated, truncated, _ = env.step(jax.random.key(0), state,
                                                              jnp.int32(UP), params)
        return state, (reward, terminated, truncated)

    _, (reward, terminated, truncated) = jax.lax.scan(body, at(1, 2, *START), jnp.arange(200))
    assert not np.asarray(terminated).any() and (np.asarray(reward) == 0).all()
    assert np.flatnonzero(np.asarray(truncated)).tolist() == [199]


def test_success_on_the_last_step_is_termination_not_truncation():
    env, params = one_goal_env([(8, 14)])
    state = at(0, 1, *START, time=199)
    _, _, reward, terminated, truncated, _ = env.step(jax.random.key(0), state, jnp.int32(RIGHT),
                                                      params)
    assert float(reward) == 1.0 and bool(terminated) and not bool(truncated)


def test_reaching_the_goal_by_walking(env):
    """Image 1's goal is the bottom-right pixel: only the footprint in the corner covers it."""
    params = env.default_params
    state = at(1, 2, *START)
    moves = [DOWN, RIGHT, RIGHT, DOWN, RIGHT]  # (12, 10) (12, 14) (12, 18) (16, 18) (16, 20)
    done = []
    for move in moves:
        _, state, reward, terminated, *_ = env.step(jax.random.key(0), state, jnp.int32(move), params)
        done.append(bool(terminated))
    assert done == [False] * 4 + [True]
    assert tuple(np.asarray(state.top_left)) == (H - SIDE, W - SIDE)


def test_wrong_action_fails_at_trace_time(env):
    _, state = env.reset(jax.random.key(0), env.default_params)
    with pytest.raises(ValueError, match="shape"):
        jax.jit(env.step)(jax.random.key(0), state, jnp.array([0, 1]), env.default_params)
    with pytest.raises(TypeError, match="int"):
        jax.jit(env.step)(jax.random.key(0), state, jnp.float32(1.0), env.default_params)


def test_bad_constructor_arguments(dataset):
    with pytest.raises(ValueError, match="footprint"):
        Localize(dataset, w=21)
    with pytest.raises(ValueError, match="image_size applies to the named datasets"):
        Localize(dataset, image_size=32)
    with pytest.raises(TypeError, match="SegmentationDataset"):
        Localize(np.zeros((1, 4, 4, 3), np.uint8))
    with pytest.raises(ValueError, match="unknown localization dataset"):
        Localize("kitti")
    with pytest.raises(ValueError, match="options of the clutter"):
        Localize("cityscapes", seed=3)
    with pytest.raises(ValueError, match="options of Cityscapes"):
        Localize("clutter", labels="all")


def test_registered_ids_route_their_arguments(tmp_path, monkeypatch):
    monkeypatch.setenv("JAXNAT_CACHE_DIR", str(tmp_path))
    try:
        env, params = jaxnat.make("Localize/Clutter-v0", autoreset=False, num_images=8,
                                  image_size=64, w=8, M=50, split="test")
    except DatasetNotFoundError as err:
        pytest.skip(f"embedded data not present: {str(err).splitlines()[0]}")
    assert env.split == "test" and env.footprint == 8 and params.max_steps_in_episode == 50
    assert env.observation_space(params).spaces["pixels"].shape == (64, 64, 4)
    assert env.num_classes == 20 and params.images.shape[0] + env.num_dropped == 8


def test_wordwise_writer_gives_the_same_observation(dataset):
    """GPUs take the word-wise writer (CPUs the byte-wise one): same bytes either way."""
    bytewise = Localize(dataset, w=SIDE, M=7, observation_writer="bytewise")
    wordwise = Localize(dataset, w=SIDE, M=7, observation_writer="wordwise")
    params = bytewise.default_params
    keys = jax.random.split(jax.random.key(5), 8)
    _, state = jax.vmap(bytewise.reset, in_axes=(0, None))(keys, params)
    state = state.replace(top_left=jnp.array([[0, 0], [16, 20], [3, 7], [8, 10]] * 2, jnp.int32))
    expected = jax.vmap(bytewise.get_obs, in_axes=(0, None))(state, params)
    got = jax.vmap(wordwise.get_obs, in_axes=(0, None))(state, params)
    jax.tree_util.tree_map(np.testing.assert_array_equal, got, expected)
