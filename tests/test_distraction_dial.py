"""Distraction as a dial, PixelMuJoCo (`PixelParams.distraction`): the video floor's strength
`video_alpha` and its `frame_rate` as traced params.

What the dial promises: the defaults are the plain env bit for bit; the endpoints are exact
(`video_alpha=0` is floor="checker"'s frames under the same keys, 1 the video floor); the
effect grows with the strength; a vmapped sweep equals separate calls and is traced once.
The physics is `test_pixel_mujoco.Sliding` (a posed HalfCheetah slid along x), which compiles in
seconds where MJX's step takes minutes; the dial lives in the pixel layer only.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

pytest.importorskip("mujoco")

from test_pixel_mujoco import Sliding, floor_mask, make_env  # noqa: E402

from jaxnat.mjx_pixel.floor import floor_rgb  # noqa: E402
from jaxnat.mjx_pixel.pixel import Distraction  # noqa: E402

VIDEO = dict(floor="video", video_shape=(32, 32), video_max_frames=64)


@pytest.fixture(scope="module")
def physics():
    return Sliding()


@pytest.fixture(scope="module")
def video(physics):
    natural = pytest.importorskip("jaxnat.natural")
    try:
        natural.default_video_paths()
    except Exception as err:  # opencv-doc missing
        pytest.skip(str(err))
    env = make_env(physics, **VIDEO)
    return env, env.default_params, jax.jit(env.reset), jax.jit(env.step)


@pytest.fixture(scope="module")
def checker(physics):
    env = make_env(physics)
    return env, env.default_params, jax.jit(env.reset), jax.jit(env.step)


def with_distraction(params, **values):
    return params.replace(distraction=params.distraction.replace(**values))


def rollout(reset, step, params, steps=3):
    """Observations and states of a reset and `steps` steps under fixed keys and actions."""
    obs, state = reset(jax.random.key(0), params)
    observations, states = [obs], [state]
    for t in range(steps):
        obs, state, *_ = step(jax.random.key(t + 1), state, jnp.zeros(6), params)
        observations.append(obs)
        states.append(state)
    return np.stack(observations), states


def old_render(env, key, physics_state, params, cursor):
    """A frame as the env rendered it before the dial: the video floor alone, read without
    `video_alpha`."""
    from jaxnat.natural import cursor_index

    data = physics_state.data
    cam_pos, cam_mat = env.camera.pose(data)

    def floor(xy, footprint=None):
        return floor_rgb(env.floor, env.table, xy, footprint, frame=params.video.frames,
                         frame_index=cursor_index(params.video, cursor), tile=params.video_tile,
                         key=key, channels=env.renderer.channels, noise=env.noise,
                         mips=params.video_mips)

    return env.renderer.render(cam_pos, cam_mat, data.geom_xpos, data.geom_xmat, floor)


def test_defaults_are_the_plain_env(video):
    """Default distraction: frames rendered as before the dial, and the cursor moved by
    `cursor_step` itself, step for step (past the end of a video: 64 frames in the bank)."""
    from jaxnat.natural import cursor_step

    env, params, reset, step = video
    assert params.distraction == Distraction(video_alpha=1.0, frame_rate=1)
    render = jax.jit(env.render)
    old = jax.jit(lambda *a: old_render(env, *a))
    _, state = reset(jax.random.key(0), params)
    ended = False
    for t in range(24):
        key = jax.random.key(t + 1)
        key_video = jax.random.split(key, 3)[1]
        expected = cursor_step(key_video, state.cursor, params.video)
        _, state, *_ = step(key, state, jnp.zeros(6), params)
        np.testing.assert_array_equal(state.cursor.video, expected.video)
        np.testing.assert_array_equal(state.cursor.offset, expected.offset)
        ended |= int(state.cursor.offset) == 0
        frame_key = jax.random.wrap_key_data(state.key)
        np.testing.assert_array_equal(render(frame_key, state.physics, params, state.cursor),
                                      old(frame_key, state.physics, params, state.cursor))
    assert ended or int(params.video.lengths.max()) > 24


def test_endpoints_are_exact(video, checker):
    """video_alpha=0: floor="checker"'s observations under the same keys; video_alpha=1: the
    default video floor's."""
    env, params, reset, step = video
    checker_obs, _ = rollout(*checker[2:], checker[1])
    zero_obs, _ = rollout(reset, step, with_distraction(params, video_alpha=0.0))
    np.testing.assert_array_equal(zero_obs, checker_obs)
    video_obs, _ = rollout(reset, step, params)
    one_obs, _ = rollout(reset, step, with_distraction(params, video_alpha=jnp.float32(1.0)))
    np.testing.assert_array_equal(one_obs, video_obs)
    assert np.any(video_obs != checker_obs)


def test_effect_grows_with_alpha(video):
    """On a fixed state, every pixel moves away from the checker frame (never back) as
    video_alpha grows, only floor pixels move, and the mean distance grows strictly."""
    env, params, reset, _ = video
    _, state = reset(jax.random.key(3), params)
    key = jax.random.wrap_key_data(state.key)
    render = jax.jit(lambda p: env.render(key, state.physics, p, state.cursor))
    alphas = np.linspace(0.0, 1.0, 6)
    frames = [np.asarray(render(with_distraction(params, video_alpha=a)), np.int32)
              for a in alphas]
    distance = [np.abs(f - frames[0]) for f in frames]
    for near, far in zip(distance, distance[1:]):
        assert np.all(far >= near)
    means = [d.mean() for d in distance]
    assert all(b > a for a, b in zip(means, means[1:])), means
    floor = floor_mask(env, state.physics)
    assert not distance[-1][..., 0][~floor].any()


def test_vmapped_sweep_equals_separate_calls_in_one_trace(video):
    """jax.vmap over a strength axis (`PixelParams.sweep`): each element's reset and steps equal
    the call with that strength alone, and the jitted sweep is traced once, also for other
    strengths of the same count."""
    env, params, reset, step = video
    traces = []

    def run(keys, swept):
        traces.append(1)  # runs while tracing only
        vreset = jax.vmap(env.reset, in_axes=(0, axes))
        vstep = jax.vmap(env.step, in_axes=(0, 0, 0, axes))
        obs, state = vreset(keys, swept)
        observations = [obs]
        for t in range(2):
            step_keys = jax.vmap(lambda k: jax.random.fold_in(k, t + 1))(keys)
            obs, state, *_ = vstep(step_keys, state, jnp.zeros((keys.shape[0], 6)), swept)
            observations.append(obs)
        return jnp.stack(observations, 1)

    alphas = jnp.array([0.0, 0.3, 0.7, 1.0])
    swept, axes = params.sweep(video_alpha=alphas, frame_rate=jnp.array([1, 0, 2, 1]))
    sweep = jax.jit(run)
    keys = jax.random.split(jax.random.key(7), 4)
    batched = np.asarray(sweep(keys, swept))
    for i in range(4):
        alone = with_distraction(params, video_alpha=alphas[i], frame_rate=swept.distraction.frame_rate[i])
        obs, state = reset(keys[i], alone)
        observations = [obs]
        for t in range(2):
            obs, state, *_ = step(jax.random.fold_in(keys[i], t + 1), state, jnp.zeros(6), alone)
            observations.append(obs)
        np.testing.assert_array_equal(batched[i], np.stack(observations))
    other, _ = params.sweep(video_alpha=jnp.array([0.1, 0.2, 0.9, 0.5]),
                            frame_rate=jnp.array([3, 1, 0, 1]))
    sweep(keys, other)
    assert len(traces) == 1


def test_frame_rate_moves_the_cursor(video):
    """frame_rate=0 freezes the episode's first frame; frame_rate=3 jumps three frames a step
    (until the video ends)."""
    env, params, reset, step = video
    frozen = with_distraction(params, frame_rate=0)
    _, states = rollout(reset, step, frozen, steps=3)
    for state in states[1:]:
        assert int(state.cursor.video) == int(states[0].cursor.video)
        assert int(state.cursor.offset) == int(states[0].cursor.offset)
    _, states = rollout(reset, step, with_distraction(params, frame_rate=3), steps=3)
    offsets = [int(s.cursor.offset) for s in states]
    length = int(params.video.lengths[int(states[0].cursor.video)])
    for before, after in zip(offsets, offsets[1:]):
        assert after == (before + 3 if before + 3 < length else 0)


def test_out_of_range_values_are_clear_errors(physics, video):
    for kwargs, match in [(dict(video_alpha=1.5), r"video_alpha must lie in \[0, 1\]"),
                          (dict(video_alpha=-0.1), r"video_alpha must lie in \[0, 1\]"),
                          (dict(frame_rate=-1), "frame_rate must be >= 0"),
                          (dict(frame_rate=1.5), "frame_rate must be a whole number"),
                          (dict(video_alpha=0.5, floor="checker"), 'need floor="video"'),
                          (dict(frame_rate=0, floor="noise"), 'need floor="video"')]:
        with pytest.raises(ValueError, match=match):
            make_env(physics, **kwargs)
    env, params, *_ = video
    with pytest.raises(ValueError, match="video_alpha must lie"):
        env.check_params(with_distraction(params, video_alpha=np.array([0.5, 2.0])))
    env.check_params(with_distraction(params, video_alpha=np.array([0.0, 0.5, 1.0])))
    with pytest.raises(ValueError, match="sweep takes Distraction fields"):
        params.sweep(sky_alpha=jnp.ones(2))
    with pytest.raises(ValueError, match="frame_rate must be >= 0"):
        params.sweep(frame_rate=jnp.array([1, -2]))
    with pytest.raises(ValueError, match="one leading length"):
        params.sweep(video_alpha=jnp.ones(2), frame_rate=jnp.ones(3, jnp.int32))
    import jaxnat

    with pytest.raises(ValueError, match="video_alpha must lie"):
        jaxnat.make("PixelMuJoCo/Swimmer-v0", floor="video", video_alpha=2.0)


def test_constructor_sets_the_defaults(physics):
    env = make_env(physics, **VIDEO, video_alpha=0.25, frame_rate=4)
    assert env.default_params.distraction == Distraction(video_alpha=0.25, frame_rate=4)
