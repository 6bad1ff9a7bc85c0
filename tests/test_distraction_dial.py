"""Distraction as a dial, PixelMuJoCo (`PixelParams.distraction`): the video floor's strength
`video_alpha`, its `frame_rate`, the video on the sky `sky_alpha` and the noise's spread
`noise_sigma` as traced params.

What the dial promises: the defaults are the plain env bit for bit; the endpoints are exact
(`video_alpha=0` is floor="checker"'s frames under the same keys, 1 the video floor); the
effect grows with the strength; a vmapped sweep equals separate calls and is traced once.
The physics is `test_pixel_mujoco.Sliding` (a posed HalfCheetah slid along x), which compiles in
seconds where MJX's step takes minutes; the dial lives in the pixel layer only. Its fixtures
(`physics`, `checker`, `video_env`) are test_pixel_mujoco's, imported rather than rebuilt.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

pytest.importorskip("mujoco")

# test_pixel_mujoco's fixtures, shared by import: pytest finds them in this module's namespace,
# and the tests' arguments of the same names are them, not redefinitions (ruff's F811).
# ruff: noqa: F811
from test_pixel_mujoco import (  # noqa: E402,F401
    VIDEO,
    checker,
    floor_mask,
    make_env,
    physics,
    video_env,
)

from jaxnat.mjx_pixel.floor import floor_rgb  # noqa: E402
from jaxnat.mjx_pixel.pixel import Distraction  # noqa: E402


@pytest.fixture(scope="module")
def video(video_env):
    env = video_env
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
    assert params.distraction == Distraction(video_alpha=1.0, frame_rate=1, sky_alpha=0.0,
                                             noise_sigma=50.0)
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
    the call with that strength alone (bit for bit at the endpoints, within the blend's
    rounding elsewhere), and the jitted sweep is traced once, also for other
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
    skies = jnp.array([0.0, 1.0, 0.5, 0.25])
    swept, axes = params.sweep(video_alpha=alphas, frame_rate=jnp.array([1, 0, 2, 1]),
                               sky_alpha=skies)
    sweep = jax.jit(run)
    keys = jax.random.split(jax.random.key(7), 4)
    batched = np.asarray(sweep(keys, swept))
    for i in range(4):
        alone = with_distraction(params, video_alpha=alphas[i], sky_alpha=skies[i],
                                 frame_rate=swept.distraction.frame_rate[i])
        obs, state = reset(keys[i], alone)
        observations = [obs]
        for t in range(2):
            obs, state, *_ = step(jax.random.fold_in(keys[i], t + 1), state, jnp.zeros(6), alone)
            observations.append(obs)
        alone = np.stack(observations)
        if i == 0:  # both strengths at an endpoint: selected, not blended, so exact
            np.testing.assert_array_equal(batched[i], alone)
        else:
            # A blend `a * x + (1 - a) * y` is rounded as the compiler contracts it (a fused
            # multiply-add or not), which XLA decides per program: the vmapped and the single
            # program may put a pixel a level apart, and no more.
            diff = np.abs(batched[i].astype(int) - alone.astype(int))
            assert diff.max() <= 1 and (diff > 0).mean() < 0.005, (i, diff.max(), (diff > 0).mean())
    other, _ = params.sweep(video_alpha=jnp.array([0.1, 0.2, 0.9, 0.5]),
                            frame_rate=jnp.array([3, 1, 0, 1]), sky_alpha=jnp.ones(4))
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
                          (dict(frame_rate=0, floor="noise"), 'need floor="video"'),
                          (dict(sky_alpha=1.5, **VIDEO), r"sky_alpha must lie in \[0, 1\]"),
                          (dict(sky_alpha=0.5), 'need floor="video"'),
                          (dict(noise_sigma=-1.0, floor="noise"), "noise_sigma must be a finite"),
                          (dict(noise_sigma=float("nan"), observation="noise"),
                           "noise_sigma must be a finite"),
                          (dict(noise_sigma=20.0), 'noise_sigma needs observation="noise"')]:
        with pytest.raises(ValueError, match=match):
            make_env(physics, **kwargs)
    env, params, *_ = video
    with pytest.raises(ValueError, match="video_alpha must lie"):
        env.check_params(with_distraction(params, video_alpha=np.array([0.5, 2.0])))
    env.check_params(with_distraction(params, video_alpha=np.array([0.0, 0.5, 1.0])))
    with pytest.raises(ValueError, match="sweep takes Distraction fields"):
        params.sweep(sky=jnp.ones(2))
    with pytest.raises(ValueError, match="sky_alpha must lie"):
        params.sweep(sky_alpha=jnp.array([0.5, -0.5]))
    with pytest.raises(ValueError, match="noise_sigma must be"):
        params.sweep(noise_sigma=jnp.array([0.0, -3.0]))
    with pytest.raises(ValueError, match="frame_rate must be >= 0"):
        params.sweep(frame_rate=jnp.array([1, -2]))
    with pytest.raises(ValueError, match="one leading length"):
        params.sweep(video_alpha=jnp.ones(2), frame_rate=jnp.ones(3, jnp.int32))
    import jaxnat

    with pytest.raises(ValueError, match="video_alpha must lie"):
        jaxnat.make("PixelMuJoCo/Swimmer-v0", floor="video", video_alpha=2.0)
    with pytest.raises(ValueError, match="noise_sigma must be"):
        jaxnat.make("PixelMuJoCo/Swimmer-v0", observation="noise", noise_sigma=-1.0)


def test_constructor_sets_the_defaults(physics):
    env = make_env(physics, **VIDEO, video_alpha=0.25, frame_rate=4, sky_alpha=0.5)
    assert env.default_params.distraction == Distraction(video_alpha=0.25, frame_rate=4,
                                                         sky_alpha=0.5)
    env = make_env(physics, observation="noise", noise="centred", noise_sigma=10.0)
    assert env.default_params.distraction.noise_sigma == 10.0
    assert make_env(physics, floor="noise").default_params.distraction.noise_sigma == 50.0


def sky_mask(env, physics_state):
    """Pixels that hit nothing: the sky."""
    data = physics_state.data
    pos, mat = env.camera.pose(data)
    return np.asarray(env.renderer.cast(pos, mat, data.geom_xpos, data.geom_xmat).geom < 0)


def test_sky_alpha_endpoints_and_growth(video):
    """On a fixed state: sky_alpha=0 is the default frame (the defaults test covers today's
    sky); 1 puts the screen-stretched video frame on every sky pixel and changes nothing else;
    in between every pixel moves away from the plain frame (never back), strictly on average."""
    from jaxnat.mjx_pixel.floor import screen_video
    from jaxnat.natural import cursor_index

    env, params, reset, _ = video
    _, state = reset(jax.random.key(3), params)
    key = jax.random.wrap_key_data(state.key)
    render = jax.jit(lambda p: env.render(key, state.physics, p, state.cursor))
    alphas = np.linspace(0.0, 1.0, 5)
    frames = [np.asarray(render(with_distraction(params, sky_alpha=a)), np.int32) for a in alphas]
    np.testing.assert_array_equal(frames[0], np.asarray(render(params)))
    sky = sky_mask(env, state.physics)
    assert sky.any() and not sky.all()
    np.testing.assert_array_equal(frames[-1][~sky], frames[0][~sky])
    video_rgb = screen_video(params.video.frames, cursor_index(params.video, state.cursor),
                             *frames[0].shape[:2])
    gray = 0.299 * video_rgb[..., 0] + 0.587 * video_rgb[..., 1] + 0.114 * video_rgb[..., 2]
    expected = np.asarray(jnp.round(gray * 255.0).astype(jnp.uint8))
    np.testing.assert_array_equal(frames[-1][..., 0][sky], expected[sky])
    distance = [np.abs(f - frames[0]) for f in frames]
    for near, far in zip(distance, distance[1:]):
        assert np.all(far >= near)
    means = [d.mean() for d in distance]
    assert all(b > a for a, b in zip(means, means[1:])), means


@pytest.fixture(scope="module")
def noise_obs(physics):
    env = make_env(physics, observation="noise")
    return env, env.default_params, jax.jit(env.reset), jax.jit(env.step)


def test_noise_sigma_default_endpoint_growth_and_sweep(noise_obs):
    """observation="noise": the default sigma draws today's values (the law's `sample`, the
    table route, under the state's key) bit for bit; sigma=0 is all black (the authors' law's
    mean); the values grow with sigma under one key; a vmapped sweep over sigma equals separate
    calls and is traced once."""
    env, params, reset, step = noise_obs
    obs, state = reset(jax.random.key(0), params)
    shape = env.observation_space(params).shape
    np.testing.assert_array_equal(obs, env.noise.sample(jax.random.wrap_key_data(state.key), shape))
    obs, state, *_ = step(jax.random.key(1), state, jnp.zeros(6), params)
    np.testing.assert_array_equal(obs, env.noise.sample(jax.random.wrap_key_data(state.key), shape))
    sigmas = jnp.array([0.0, 10.0, 50.0, 120.0])
    draws = [np.asarray(reset(jax.random.key(0), with_distraction(params, noise_sigma=s))[0])
             for s in sigmas]
    assert not draws[0].any()
    for low, high in zip(draws, draws[1:]):
        assert np.all(high >= low) and high.mean() > low.mean()
    traces = []

    def run(keys, swept):
        traces.append(1)  # runs while tracing only
        return jax.vmap(env.reset, in_axes=(0, axes))(keys, swept)[0]

    swept, axes = params.sweep(noise_sigma=sigmas)
    sweep = jax.jit(run)
    keys = jnp.stack([jax.random.key(0)] * 4)
    np.testing.assert_array_equal(np.asarray(sweep(keys, swept)), np.stack(draws))
    sweep(keys, params.sweep(noise_sigma=sigmas[::-1])[0])
    assert len(traces) == 1


def test_noise_floor_sigma(checker):
    """floor="noise": the default sigma renders the floor as before the dial (`floor_rgb`
    without a sigma); sigma=0 blackens every floor pixel and leaves the rest."""
    env, params, reset, _ = checker
    _, state = reset(jax.random.key(3), params)
    noise_env = make_env(env.physics, floor="noise")
    noise_params = noise_env.default_params
    data = state.physics.data
    cam_pos, cam_mat = noise_env.camera.pose(data)
    key = jax.random.key(5)

    def old(key):
        def floor(xy, footprint=None):
            return floor_rgb("noise", noise_env.table, xy, footprint, key=key,
                             channels=noise_env.renderer.channels, noise=noise_env.noise)
        return noise_env.renderer.render(cam_pos, cam_mat, data.geom_xpos, data.geom_xmat, floor)

    render = jax.jit(lambda p: noise_env.render(key, state.physics, p))
    np.testing.assert_array_equal(render(noise_params), jax.jit(old)(key))
    black = np.asarray(render(with_distraction(noise_params, noise_sigma=0.0)))
    floor = floor_mask(env, state.physics)
    assert not black[..., 0][floor].any()
    plain = np.asarray(render(noise_params))
    np.testing.assert_array_equal(black[..., 0][~floor], plain[..., 0][~floor])


def test_num_videos_limits_the_videos_in_play(physics, video):
    """`num_videos=n` draws every reset's and every hand-over's video among the bank's first n:
    1 plays one video only; the bank's count draws exactly as the default (None); a sweep over
    it equals separate calls; out-of-range counts are one-line errors."""
    env, params, reset, step = video
    count = params.video.num_videos
    assert count >= 2, "the test bank should hold several videos"
    keys = jax.random.split(jax.random.key(5), 32)
    vreset = jax.jit(jax.vmap(env.reset, in_axes=(0, None)))
    vstep = jax.jit(jax.vmap(env.step, in_axes=(0, 0, 0, None)))

    def videos(p, steps=4):
        """Each env's video at reset and after each of `steps` steps (a jump of 16 frames per
        step, so the 64-frame bank's videos end and hand over)."""
        p = with_distraction(p, frame_rate=16)
        _, state = vreset(keys, p)
        seen = [np.asarray(state.cursor.video)]
        for t in range(steps):
            step_keys = jax.vmap(lambda k: jax.random.fold_in(k, t + 1))(keys)
            _, state, *_ = vstep(step_keys, state, jnp.zeros((keys.shape[0], 6)), p)
            seen.append(np.asarray(state.cursor.video))
        return np.stack(seen)

    everything = videos(params)
    assert len(np.unique(everything)) == count  # the default plays every video
    np.testing.assert_array_equal(videos(with_distraction(params, num_videos=count)), everything)
    np.testing.assert_array_equal(videos(with_distraction(params, num_videos=1)), 0)
    # One program over the count: each element as its own call.
    swept, axes = params.sweep(num_videos=jnp.array([1, count]), frame_rate=jnp.array([16, 16]))
    batched = jax.jit(jax.vmap(env.reset, in_axes=(None, axes)))(keys[0], swept)[1].cursor.video
    for i, n in enumerate((1, count)):
        assert int(batched[i]) == int(reset(keys[0], with_distraction(params, num_videos=n))[1].cursor.video)
    assert make_env(physics, **VIDEO, num_videos=1).default_params.distraction.num_videos == 1
    for kwargs, match in [(dict(num_videos=0, **VIDEO), "num_videos must be >= 1"),
                          (dict(num_videos=count + 1, **VIDEO), f"exceeds the video bank's {count} videos"),
                          (dict(num_videos=1.5, **VIDEO), "num_videos must be a whole number"),
                          (dict(num_videos=1), 'num_videos needs floor="video"')]:
        with pytest.raises(ValueError, match=match):
            make_env(physics, **kwargs)
    with pytest.raises(ValueError, match="exceeds the video bank"):
        env.check_params(with_distraction(params, num_videos=np.array([1, count + 1])))
    with pytest.raises(ValueError, match="num_videos must be >= 1"):
        params.sweep(num_videos=jnp.array([0, 1]))


def test_the_papers_setting_is_a_named_point(physics):
    """`distraction="paper"`: the authors' video floor advanced 4 frames per agent step; on the
    other floors nothing changes; a field it sets given beside it, or an unknown name, is a
    one-line error."""
    assert make_env(physics, **VIDEO, distraction="paper").default_params.distraction == Distraction(frame_rate=4)
    assert make_env(physics, distraction="paper").default_params.distraction == Distraction()
    assert make_env(physics, **VIDEO).default_params.distraction.frame_rate == 1
    with pytest.raises(ValueError, match="sets frame_rate=4; leave frame_rate out"):
        make_env(physics, **VIDEO, distraction="paper", frame_rate=1)
    with pytest.raises(ValueError, match="distraction must be one of"):
        make_env(physics, distraction="authors")
