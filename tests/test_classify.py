"""Classification-by-navigation semantics (docs/environments.md section 1)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnat.testing import check_env
from jaxnat.vision_envs.classify import (
    DOWN, LEFT, RIGHT, UP, Classify, ClassifyState, pack_mask, unpack_mask,
)

H, W = 12, 10


def start_at(env, params, image_index, row, col):
    """A state on `image_index` with the window at (row, col), only that window revealed."""
    side = int(params.window)
    revealed = np.zeros((H, W), bool)
    revealed[row : row + side, col : col + side] = True
    return ClassifyState(
        time=jnp.int32(0),
        image_index=jnp.int32(image_index),
        label=params.labels[image_index],
        top_left=jnp.array([row, col], jnp.int32),
        revealed=pack_mask(jnp.asarray(revealed)),
    )


def act(move, label):
    return jnp.array([move, label], jnp.int32)


@pytest.fixture
def env(toy_dataset):
    return Classify(toy_dataset, w=3, M=5)


def test_contract(env):
    check_env(env, env.default_params)


def test_spaces(env):
    params = env.default_params
    assert env.observation_space(params).shape == (H, W, 3)
    assert env.observation_space(params).dtype == jnp.uint8
    assert env.action_space(params).nvec.tolist() == [4, 3]


@pytest.mark.parametrize(
    "move, start, expected",
    [
        (UP, (6, 4), (3, 4)),
        (UP, (2, 4), (0, 4)),  # clamped at the top border
        (UP, (0, 4), (0, 4)),
        (DOWN, (3, 4), (6, 4)),
        (DOWN, (8, 4), (9, 4)),  # H - w = 9
        (DOWN, (9, 4), (9, 4)),
        (LEFT, (5, 6), (5, 3)),
        (LEFT, (5, 1), (5, 0)),  # clamped at the left border
        (RIGHT, (5, 3), (5, 6)),
        (RIGHT, (5, 6), (5, 7)),  # W - w = 7
        (RIGHT, (5, 7), (5, 7)),
    ],
)
def test_moves_shift_by_w_and_stay_inside(env, move, start, expected):
    params = env.default_params
    state = start_at(env, params, 0, *start)
    obs, state, *_ = env.step(jax.random.key(0), state, act(move, 1), params)
    assert tuple(np.asarray(state.top_left)) == expected
    window = np.zeros((H, W), bool)
    window[expected[0] : expected[0] + 3, expected[1] : expected[1] + 3] = True
    np.testing.assert_array_equal(np.asarray(obs[..., 2]), window * 255)


def test_observation_reveals_union_of_windows(env, toy_dataset):
    params = env.default_params
    state = start_at(env, params, 1, 0, 0)
    key = jax.random.key(0)
    _, state, *_ = env.step(key, state, act(RIGHT, 0), params)
    obs, state, *_ = env.step(key, state, act(DOWN, 0), params)
    revealed = np.zeros((H, W), bool)
    revealed[0:3, 0:3] = revealed[0:3, 3:6] = revealed[3:6, 3:6] = True
    image = toy_dataset.images[1, ..., 0]
    obs = np.asarray(obs)
    assert obs.dtype == np.uint8
    np.testing.assert_array_equal(obs[..., 0], np.where(revealed, image, 0))
    np.testing.assert_array_equal(obs[..., 1], revealed * 255)
    np.testing.assert_array_equal(obs[..., 2][3:6, 3:6], 255)
    assert obs[..., 2].sum() == 9 * 255


def test_right_label_rewards_and_terminates(env):
    params = env.default_params
    state = start_at(env, params, 2, 0, 0)
    _, state, reward, terminated, truncated, _ = env.step(jax.random.key(0), state, act(UP, 2), params)
    assert float(reward) == 1.0 and bool(terminated) and not bool(truncated)
    assert int(state.time) == 1


def test_wrong_label_costs_and_truncates_at_M(env):
    params = env.default_params  # M = 5
    state = start_at(env, params, 2, 0, 0)
    for t in range(1, 6):
        _, state, reward, terminated, truncated, _ = env.step(
            jax.random.key(t), state, act(RIGHT, 0), params
        )
        assert float(reward) == pytest.approx(-0.1)
        assert not bool(terminated)
        assert bool(truncated) == (t == 5), f"truncated at t={t}"


def test_right_label_on_last_step_is_termination_not_truncation(env):
    params = env.default_params
    state = start_at(env, params, 0, 0, 0).replace(time=jnp.int32(4))
    _, _, reward, terminated, truncated, _ = env.step(jax.random.key(0), state, act(DOWN, 0), params)
    assert float(reward) == 1.0 and bool(terminated) and not bool(truncated)


def test_reset_random_start_is_inside_and_revealed(env, toy_dataset):
    params = env.default_params
    keys = jax.random.split(jax.random.key(0), 64)
    obs, state = jax.vmap(env.reset, in_axes=(0, None))(keys, params)
    top_left = np.asarray(state.top_left)
    assert top_left[:, 0].min() >= 0 and top_left[:, 0].max() <= H - 3
    assert top_left[:, 1].min() >= 0 and top_left[:, 1].max() <= W - 3
    assert len({tuple(t) for t in top_left}) > 10, "random start barely varies"
    assert set(np.asarray(state.image_index).tolist()) == {0, 1, 2}
    obs = np.asarray(obs)
    assert (obs[..., 1] == 255).sum(axis=(1, 2)).tolist() == [9] * 64
    np.testing.assert_array_equal(obs[..., 1], obs[..., 2])
    for o, i in zip(obs, np.asarray(state.image_index)):
        mask = o[..., 1] == 255
        np.testing.assert_array_equal(o[..., 0][mask], toy_dataset.images[i, ..., 0][mask])
        assert (o[..., 0][~mask] == 0).all()


def test_center_start_follows_the_authors(toy_dataset):
    env = Classify(toy_dataset, start="center", w=3)
    _, state = env.reset(jax.random.key(0), env.default_params)
    assert tuple(np.asarray(state.top_left)) == (H // 2 - 3, W // 2 - 3)


def test_window_is_a_traced_param(env):
    """One compiled step serves every window size (vmapped over params)."""
    params = env.default_params
    windows = jnp.array([1, 2, 3, 4])
    batched = jax.vmap(lambda w: params.replace(window=w))(windows)
    keys = jax.random.split(jax.random.key(0), 4)
    obs, _ = jax.vmap(env.reset)(keys, batched)
    assert (np.asarray(obs[..., 2]) == 255).sum(axis=(1, 2)).tolist() == [1, 4, 9, 16]


def test_determinism_for_a_fixed_key(env):
    params = env.default_params
    a = env.reset(jax.random.key(7), params)
    b = env.reset(jax.random.key(7), params)
    jax.tree_util.tree_map(np.testing.assert_array_equal, a, b)


def test_wrong_action_shape_or_dtype_fails_at_trace_time(env):
    params = env.default_params
    _, state = env.reset(jax.random.key(0), params)
    with pytest.raises(ValueError, match="shape"):
        jax.jit(env.step)(jax.random.key(0), state, jnp.array([0, 1, 2]), params)
    with pytest.raises(TypeError, match="int"):
        jax.jit(env.step)(jax.random.key(0), state, jnp.array([0.0, 1.0]), params)


def test_bad_constructor_arguments(toy_dataset):
    with pytest.raises(ValueError, match="start"):
        Classify(toy_dataset, start="middle")
    with pytest.raises(ValueError, match="window"):
        Classify(toy_dataset, w=11)


def test_image_size_resizes(toy_dataset):
    env = Classify(toy_dataset, image_size=(16, 20))
    assert env.observation_space(env.default_params).shape == (16, 20, 3)


@pytest.mark.parametrize("width", [1, 10, 31, 32, 33, 70])
def test_pack_unpack_round_trip(width):
    mask = jax.random.bernoulli(jax.random.key(width), 0.5, (5, width))
    bits = pack_mask(mask)
    assert bits.dtype == jnp.uint32 and bits.shape == (5, -(-width // 32))
    np.testing.assert_array_equal(np.asarray(unpack_mask(bits, width)), np.asarray(mask))


@pytest.mark.parametrize("width", [10, 32, 40, 70])
def test_window_bits_equal_packed_window_mask(width):
    from jaxnat.datasets import ImageDataset
    from jaxnat.vision_envs.classify import window_mask

    images = np.zeros((1, 9, width, 1), np.uint8)
    env = Classify(ImageDataset("blank", "train", images, np.zeros(1, np.int32), ("a",)))
    for side in [1, 3, 9]:
        for row in range(0, 9 - side + 1, 2):
            for col in range(0, width - side + 1, 3):
                top_left = jnp.array([row, col])
                want = pack_mask(window_mask(top_left, side, 9, width))
                np.testing.assert_array_equal(np.asarray(env._window_bits(top_left, side)), np.asarray(want))


def test_out_of_range_actions_are_clipped_per_factor(env):
    """jaxnat's rule for discrete envs (a jitted env cannot raise): each factor is clipped into
    its range, so move 7 acts as RIGHT, -1 as UP, and label 10 (of 3 classes) as label 2."""
    params = env.default_params
    _, state = env.reset(jax.random.key(0), params)

    def outcome(move, label):
        obs, new, reward, terminated, truncated, _ = env.step(jax.random.key(1), state, jnp.array([move, label]),
                                                              params)
        return np.asarray(obs), np.asarray(new.top_left), float(reward), bool(terminated)

    for wild, tame in [((7, 0), (RIGHT, 0)), ((-1, 0), (UP, 0)), ((0, 10), (0, 2)), ((0, -5), (0, 0))]:
        for a, b in zip(outcome(*wild), outcome(*tame)):
            np.testing.assert_array_equal(a, b)

