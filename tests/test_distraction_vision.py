"""Distraction as a dial, Classify and Localize (`jaxnat.vision_envs.distraction`): additive
pixel noise `noise_sigma` as a traced param.

What the dial promises: the default (0) is the plain env bit for bit; a strength's image is
`clip(round(image + sigma * z), 0, 255)` on the image channels only (hidden pixels and the
binary planes untouched); the effect grows with sigma under one key; a vmapped sweep over
sigma equals separate calls and is traced once. Each test runs on Classify (conftest's
`toy_dataset`, width 10: the byte-wise writer) and on Localize (test_localize's `dataset`,
width 24) with both observation writers, since the noised image reaches the word-wise writer
as a one-image dataset.
"""

# test_localize's `dataset` fixture, shared by import: pytest finds it in this module's
# namespace, and the arguments of that name are it, not redefinitions (ruff's F811).
# ruff: noqa: F811
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_localize import dataset  # noqa: F401

from jaxnat.vision_envs.classify import DOWN, RIGHT, Classify, unpack_mask, window_mask
from jaxnat.vision_envs.distraction import NOISE_STREAM, Distraction
from jaxnat.vision_envs.localize import Localize
from jaxnat.vision_envs.observation import masked_image_observation_reference

CASES = ("classify", "localize-bytewise", "localize-wordwise")


class Case:
    """One env under test, its jitted reset and step, and what differs between the two
    families: the action, where the pixels are, which pixels show the image."""

    def __init__(self, name, toy_dataset, dataset):
        self.classify = name == "classify"
        if self.classify:
            self.env = Classify(toy_dataset, w=3, M=5)
        else:
            self.env = Localize(dataset, w=4, M=7, observation_writer=name.split("-")[1])
        self.params = self.env.default_params
        self.reset, self.step = jax.jit(self.env.reset), jax.jit(self.env.step)

    def action(self, t):
        move = (RIGHT, DOWN)[t % 2]
        return jnp.array([move, 2], jnp.int32) if self.classify else jnp.int32(move)

    def pixels(self, obs):
        return np.asarray(obs if self.classify else obs["pixels"])

    def shown(self, state):
        """bool [H, W]: pixels that show the image, and the binary planes after it."""
        env = self.env
        h, w = env.image_shape[:2]
        if self.classify:
            revealed = unpack_mask(state.revealed, w)
            return revealed, [revealed, window_mask(state.top_left, self.params.window, h, w)]
        return jnp.ones((h, w), bool), [window_mask(state.top_left, env.footprint, h, w)]

    def plain(self, state, params):
        """The observation's pixels as the env wrote them before the dial."""
        shown, planes = self.shown(state)
        return np.asarray(masked_image_observation_reference(params.images, state.image_index,
                                                             shown, planes))

    def rollout(self, params, steps=3, key=0):
        obs, state = self.reset(jax.random.key(key), params)
        observations, states = [self.pixels(obs)], [state]
        for t in range(steps):
            obs, state, *_ = self.step(jax.random.key(key + t + 1), state, self.action(t), params)
            observations.append(self.pixels(obs))
            states.append(state)
        return np.stack(observations), states


_BUILT = {}  # one Case per name for the module: the data are fixed, so reuse its compiled jits


@pytest.fixture(params=CASES)
def case(request, toy_dataset, dataset):
    if request.param not in _BUILT:
        _BUILT[request.param] = Case(request.param, toy_dataset, dataset)
    return _BUILT[request.param]


def with_sigma(params, sigma):
    return params.replace(distraction=params.distraction.replace(noise_sigma=sigma))


def test_default_is_the_plain_env(case):
    assert case.params.distraction == type(case.params.distraction)()  # off: no noise in the program
    assert case.params.distraction.noise_sigma is None and Distraction().noise_sigma is None
    observations, states = case.rollout(case.params)
    for obs, state in zip(observations, states):
        np.testing.assert_array_equal(obs, case.plain(state, case.params))
    zero, _ = case.rollout(with_sigma(case.params, jnp.float32(0.0)))
    np.testing.assert_array_equal(zero, observations)


def test_noise_is_the_stated_formula_on_the_image_only(case):
    """At sigma = 30: the image channels are clip(round(image + 30 z), 0, 255) where shown (z
    from the state's noise key folded with NOISE_STREAM), 0 where hidden; the planes are
    untouched; the noise is fresh every step."""
    params = with_sigma(case.params, 30.0)
    observations, states = case.rollout(params)
    c = case.params.images.shape[-1]
    for obs, state in zip(observations, states):
        plain = case.plain(state, params)
        np.testing.assert_array_equal(obs[..., c:], plain[..., c:])
        key = jax.random.fold_in(jax.random.wrap_key_data(state.noise_key), NOISE_STREAM)
        z = np.asarray(jax.random.normal(key, plain[..., :c].shape, jnp.float32))
        image = np.asarray(params.images[state.image_index], np.float32)
        expected = np.clip(np.round(image + np.float32(30.0) * z), 0, 255)
        shown = np.asarray(case.shown(state)[0])
        expected = np.where(shown[..., None], expected, 0)
        diff = np.abs(obs[..., :c].astype(np.int32) - expected)
        assert diff.max() <= 1 and (diff == 0).mean() > 0.99  # float rounding at .5 only
        assert (obs[..., :c][shown] != plain[..., :c][shown]).mean() > 0.5
    assert np.any(observations[1][..., :c] != observations[2][..., :c])


def test_effect_grows_with_sigma(case):
    """Under one key: no value moves back toward the clean image as sigma grows, the mean
    distance grows strictly, and sigma=0 is the clean image."""
    sigmas = [0.0, 4.0, 16.0, 64.0, 255.0]
    frames = [case.rollout(with_sigma(case.params, s), steps=1)[0].astype(np.int32)
              for s in sigmas]
    distance = [np.abs(f - frames[0]) for f in frames]
    assert not distance[0].any()
    for near, far in zip(distance, distance[1:]):
        assert np.all(far >= near)
    means = [d.mean() for d in distance]
    assert all(b > a for a, b in zip(means, means[1:])), means


def test_vmapped_sweep_equals_separate_calls_in_one_trace(case):
    env, params = case.env, case.params
    traces = []

    def run(keys, swept):
        traces.append(1)  # runs while tracing only
        obs, state = jax.vmap(env.reset, in_axes=(0, axes))(keys, swept)
        observations = [obs]
        for t in range(2):
            step_keys = jax.vmap(lambda k: jax.random.fold_in(k, t + 1))(keys)
            actions = jnp.stack([case.action(t)] * keys.shape[0])
            obs, state, *_ = jax.vmap(env.step, in_axes=(0, 0, 0, axes))(
                step_keys, state, actions, swept)
            observations.append(obs)
        return jax.tree.map(lambda *o: jnp.stack(o, 1), *observations)

    sigmas = jnp.array([0.0, 8.0, 40.0, 0.0])
    swept, axes = params.sweep(noise_sigma=sigmas)
    sweep = jax.jit(run)
    keys = jax.random.split(jax.random.key(7), 4)
    batched = case.pixels(sweep(keys, swept))
    for i in range(4):
        alone = with_sigma(params, sigmas[i])
        obs, state = case.reset(keys[i], alone)
        observations = [case.pixels(obs)]
        for t in range(2):
            obs, state, *_ = case.step(jax.random.fold_in(keys[i], t + 1), state, case.action(t),
                                       alone)
            observations.append(case.pixels(obs))
        np.testing.assert_array_equal(batched[i], np.stack(observations))
    sweep(keys, params.sweep(noise_sigma=jnp.array([1.0, 2.0, 3.0, 4.0]))[0])
    assert len(traces) == 1


def test_out_of_range_values_are_clear_errors(toy_dataset, dataset):
    for build in (lambda **k: Classify(toy_dataset, w=3, **k),
                  lambda **k: Localize(dataset, w=4, **k)):
        for sigma in (-1.0, float("nan"), float("inf")):
            with pytest.raises(ValueError, match="noise_sigma must be a finite number >= 0"):
                build(noise_sigma=sigma)
        env = build(noise_sigma=12.0)
        params = env.default_params
        assert params.distraction == type(params.distraction)(noise_sigma=12.0)
        with pytest.raises(ValueError, match="noise_sigma must be"):
            env.check_params(with_sigma(params, np.array([0.0, -2.0])))
        with pytest.raises(ValueError, match="noise_sigma must be"):
            params.sweep(noise_sigma=jnp.array([1.0, -1.0]))
        with pytest.raises(ValueError, match="sweep takes Distraction fields"):
            params.sweep(video_alpha=jnp.ones(2))
        with pytest.raises(ValueError, match="one leading length"):
            params.sweep(noise_sigma=jnp.float32(1.0))


# Classify's background dial (`ClassifyDistraction.background_alpha`). The frames are a
# stand-in: seeded random 12x10 grey frames (a `FrameBank` given as `backgrounds=`), so the
# tests need no photos; the real frames (opencv-doc's) are loaded in the last test.
def _stand_in_frames(count=4):
    from jaxnat.natural import FrameBank

    frames = np.random.default_rng(7).integers(0, 256, (count, 12, 10, 1), dtype=np.uint8)
    return FrameBank(frames, np.arange(count, dtype=np.int32), np.ones(count, np.int32))


def _with_alpha(params, alpha):
    return params.replace(distraction=params.distraction.replace(background_alpha=alpha))


@pytest.fixture
def behind(toy_dataset):
    if "behind" not in _BUILT:  # the env and its compiled jits, once for the module
        env = Classify(toy_dataset, w=3, M=5, background_alpha=0.0, backgrounds=_stand_in_frames())
        _BUILT["behind"] = env, jax.jit(env.reset), jax.jit(env.step)
    return _BUILT["behind"]


def _classify_rollout(reset, step, params, steps=3):
    obs, state = reset(jax.random.key(3), params)
    observations, states = [np.asarray(obs)], [state]
    for t in range(steps):
        obs, state, *_ = step(jax.random.key(4 + t), state, jnp.array([(RIGHT, DOWN)[t % 2], 2], jnp.int32), params)
        observations.append(np.asarray(obs))
        states.append(state)
    return np.stack(observations), states


def test_background_at_zero_is_the_plain_env_and_off_adds_nothing(toy_dataset, behind):
    env, reset, step = behind
    plain = Classify(toy_dataset, w=3, M=5)
    assert plain.default_params.background is None
    plain_obs, plain_states = _classify_rollout(jax.jit(plain.reset), jax.jit(plain.step), plain.default_params)
    assert plain_states[0].background_index is None  # no leaf: the plain state (and checkpoints) unchanged
    obs, states = _classify_rollout(reset, step, env.default_params)
    np.testing.assert_array_equal(obs, plain_obs)  # same draws: the frame's key is folded apart
    assert [int(s.image_index) for s in states] == [int(s.image_index) for s in plain_states]


def test_background_is_the_stated_composite_on_revealed_pixels(behind):
    env, reset, step = behind
    params = _with_alpha(env.default_params, jnp.float32(0.7))
    obs, states = _classify_rollout(reset, step, params)
    for o, state in zip(obs, states):
        image = np.asarray(params.images[int(state.image_index)], np.float64)
        frame = np.asarray(params.background.frames[int(state.background_index)], np.float64)
        want = np.clip(np.round(image + (1 - image / 255) * np.float32(0.7) * frame), 0, 255)
        revealed = np.asarray(unpack_mask(state.revealed, 10))
        np.testing.assert_array_equal(o[..., 0][revealed], want[..., 0][revealed])
        assert not o[..., 0][~revealed].any()  # hidden pixels stay 0: the photo shows through the window only
    assert len({int(s.background_index) for s in states}) == 1  # one frame per episode


def _grows_and_sweeps_in_one_trace(env, params, alphas, separate, key, pixels):
    """`separate[i]` (int32 observations at `alphas[i]`, the first the plain one) move away
    from the first as `i` grows, and `params.sweep(background_alpha=alphas)` vmapped over the
    reset gives them all in one trace (`pixels`: the image part of an observation)."""
    distance = [np.abs(o - separate[0]).sum() for o in separate]
    assert distance[0] == 0 and all(a <= b for a, b in zip(distance, distance[1:])) and distance[-1] > 0
    swept, axes = params.sweep(background_alpha=alphas)
    traces = []

    def traced_reset(key, p):
        traces.append(1)
        return env.reset(key, p)

    together, _ = jax.jit(jax.vmap(traced_reset, in_axes=(None, axes)))(jax.random.key(key), swept)
    np.testing.assert_array_equal(np.asarray(pixels(together), np.int32), np.stack(separate))
    assert len(traces) == 1


def test_background_effect_grows_with_alpha_and_a_sweep_equals_separate_calls(behind):
    env, reset, _ = behind
    params = env.default_params
    alphas = jnp.array([0.0, 0.25, 0.5, 1.0], jnp.float32)
    separate = [np.asarray(reset(jax.random.key(11), _with_alpha(params, a))[0], np.int32) for a in alphas]
    _grows_and_sweeps_in_one_trace(env, params, alphas, separate, 11, lambda obs: obs)


def test_background_errors_are_one_line(toy_dataset):
    for alpha in (-0.1, 1.5, float("nan")):
        with pytest.raises(ValueError, match=r"background_alpha must be in \[0, 1\]"):
            Classify(toy_dataset, background_alpha=alpha, backgrounds=_stand_in_frames())
    with pytest.raises(ValueError, match="backgrounds= is used by the background dial: pass background_alpha="):
        Classify(toy_dataset, backgrounds=_stand_in_frames())
    from jaxnat.natural import FrameBank

    wrong = FrameBank(np.zeros((2, 28, 28, 1), np.uint8), np.arange(2, dtype=np.int32), np.ones(2, np.int32))
    with pytest.raises(ValueError, match=r"background frames of shape \(28, 28, 1\) for images of \(12, 10, 1\)"):
        Classify(toy_dataset, background_alpha=0.5, backgrounds=wrong)
    plain = Classify(toy_dataset)
    swept, _ = plain.default_params.sweep(background_alpha=jnp.array([0.0, 1.0]))
    with pytest.raises(ValueError, match="background_alpha needs the env's background frames"):
        plain.check_params(swept)
    env = Classify(toy_dataset, background_alpha=0.5, backgrounds=_stand_in_frames())
    with pytest.raises(ValueError, match=r"background_alpha must be in \[0, 1\]"):
        env.default_params.sweep(background_alpha=jnp.array([0.5, 2.0]))


def test_digits_behind_the_splits_own_photos_and_video_frames():
    """The embedded data: the train and test envs' frames come from disjoint files (opencv-doc's
    photos and video frames, split by whole file), grey at the digits' 28x28."""
    from jaxnat.natural.clutter import background_files

    if not background_files():
        pytest.skip("opencv-doc's photos and videos are not installed")
    import jaxnat

    try:
        train, train_params = jaxnat.make("Classify/Digits-v0", background_alpha=0.5)
        _, test_params = jaxnat.make("Classify/Digits-v0", split="test", background_alpha=0.5)
    except jaxnat.datasets.DatasetNotFoundError as err:
        pytest.skip(str(err))
    frames = train_params.background.frames
    assert frames.shape[1:] == (28, 28, 1) and frames.dtype == jnp.uint8
    train_frames = {np.asarray(f).tobytes() for f in frames}
    assert not train_frames & {np.asarray(f).tobytes() for f in test_params.background.frames}
    obs, state = train.reset(jax.random.key(0), train_params)
    assert obs.shape == (28, 28, 3) and 0 <= int(state.background_index) < frames.shape[0]
    # A run records the files behind its frames (`config.json`'s "data"): disjoint by name and hash.
    from jaxnat.natural import bank_manifests

    (train_files,), (test_files,) = bank_manifests(train_params), bank_manifests(test_params)
    assert train_files and test_files and all(len(f["sha256"]) == 64 for f in train_files)
    assert not {f["sha256"] for f in train_files} & {f["sha256"] for f in test_files}


# Localize's background dial (`LocalizeDistraction.background_alpha`): the scene's void pixels
# (test_localize's toy scenes: everything outside the few labelled object pixels) dimmed.
def _localize_pixels(env, params, key=5):
    obs, state = jax.jit(env.reset)(jax.random.key(key), params)
    return np.asarray(obs["pixels"]), state


def test_localize_background_at_one_is_the_plain_scene_and_dims_only_the_void(dataset):
    env = Localize(dataset, w=4, M=7, background_alpha=1.0)
    plain = Localize(dataset, w=4, M=7)
    obs, state = _localize_pixels(env, env.default_params)
    np.testing.assert_array_equal(obs, _localize_pixels(plain, plain.default_params)[0])
    params = env.default_params.replace(distraction=env.default_params.distraction.replace(
        background_alpha=jnp.float32(0.3)))
    dimmed, same_state = _localize_pixels(env, params)
    assert int(same_state.image_index) == int(state.image_index)
    index = int(state.image_index)
    image = np.asarray(params.images[index], np.float64)
    void = np.asarray(params.class_maps[index]) == 255
    assert void.any() and (~void).any()
    np.testing.assert_array_equal(dimmed[..., :3][void], np.round(np.float32(0.3) * image[void]))
    np.testing.assert_array_equal(dimmed[..., :3][~void], image[~void])  # the objects unchanged
    np.testing.assert_array_equal(dimmed[..., 3], obs[..., 3])  # the footprint plane too


def test_localize_background_effect_grows_as_alpha_falls_and_sweeps_in_one_trace(dataset):
    env = Localize(dataset, w=4, M=7, background_alpha=1.0)
    params = env.default_params
    alphas = jnp.array([1.0, 0.75, 0.5, 0.0], jnp.float32)
    separate = [_localize_pixels(env, params.replace(distraction=params.distraction.replace(background_alpha=a)))[0]
                .astype(np.int32) for a in alphas]
    _grows_and_sweeps_in_one_trace(env, params, alphas, separate, 5, lambda obs: obs["pixels"])
    with pytest.raises(ValueError, match=r"background_alpha must be in \[0, 1\]"):
        Localize(dataset, w=4, background_alpha=-0.5)
    with pytest.raises(ValueError, match=r"background_alpha must be in \[0, 1\]"):
        params.sweep(background_alpha=jnp.array([1.0, 1.5]))
