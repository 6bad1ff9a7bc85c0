"""The single-env Gymnasium adapter (`GymnasiumEnv`): Gymnasium's own `check_env` for one id of
every pure-JAX family, seeding, replay against jaxnat's own step, frames, registration, and the
vector adapter's `render`. Each env is built (and compiled) once per module."""

import warnings

import jax
import numpy as np
import pytest

gymnasium = pytest.importorskip("gymnasium")

from gymnasium.utils.env_checker import check_env  # noqa: E402

import jaxnat  # noqa: E402
from jaxnat.compat import (GymnasiumEnv, GymnasiumVectorEnv, gymnasium_id, make_gymnasium,  # noqa: E402
                           register_gymnasium_envs)
from jaxnat.compat.frames import Frames  # noqa: E402
from jaxnat.datasets import DatasetNotFoundError, ImageDataset  # noqa: E402
from jaxnat.testing import has_dataset  # noqa: E402
from jaxnat.vision_envs.classify import DOWN, Classify  # noqa: E402

M = 5  # time limit of the image envs


def checked(env):
    """Gymnasium's checker, render check included; its warnings are not failures, but a
    warning about our observations or rendering is (only those about spaces are tolerated:
    MuJoCo's unbounded state Box)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped, skip_render_check=False)
    allowed = ("infinity", "precision lowered", "not having a spec")
    bad = [str(w.message) for w in caught if not any(a in str(w.message) for a in allowed)]
    assert not bad, bad


def replay(env: GymnasiumEnv, seed: int, actions):
    """The adapter's episode and jaxnat's own `reset`/`step` under the keys the adapter
    documents: key(seed), split before every call."""
    obs, _ = env.reset(seed=seed)
    ours = [obs]
    rewards = []
    jreset, jstep = jax.jit(env.jax_env.reset), jax.jit(env.jax_env.step)
    key = jax.random.key(seed)
    key, sub = jax.random.split(key)
    jobs, state = jreset(sub, env.params)
    theirs = [jobs]
    their_rewards = []
    for action in actions:
        obs, reward, terminated, truncated, _ = env.step(action)
        ours.append(obs)
        rewards.append(reward)
        key, sub = jax.random.split(key)
        jobs, state, r, t, tr, _ = jstep(sub, state, np.asarray(action, env.action_space.dtype), env.params)
        theirs.append(jobs)
        their_rewards.append(float(r))
        assert (bool(t), bool(tr)) == (terminated, truncated)
        if terminated or truncated:
            break
    for a, b in zip(ours, theirs):
        jax.tree.map(np.testing.assert_array_equal, a, jax.tree.map(np.asarray, b))
    assert rewards == their_rewards and all(type(r) is float for r in rewards)
    return rewards


def same_first_observation(env):
    first = env.reset(seed=11)[0]
    env.step(env.action_space.sample())
    other = env.reset(seed=12)[0]
    again = env.reset(seed=11)[0]
    jax.tree.map(np.testing.assert_array_equal, first, again)
    return first, other


# ---- Classify: a hand-built dataset (always), Digits (when installed) -------------------

@pytest.fixture(scope="module")
def toy():
    """conftest's toy dataset: pixel (r, c) of image i is 1 + 120 i + 10 r + c (never 0)."""
    r, c = np.meshgrid(np.arange(12), np.arange(10), indexing="ij")
    images = np.stack([1 + i * 120 + r * 10 + c for i in range(3)]).astype(np.uint8)[..., None]
    dataset = ImageDataset("toy", "train", images, np.arange(3, dtype=np.int32), ("0", "1", "2"))
    return GymnasiumEnv(Classify(dataset, w=3, M=M), render_mode="rgb_array")


def test_toy_classify_passes_check_env(toy):
    checked(toy)
    assert isinstance(toy, gymnasium.Env) and toy.metadata["render_modes"] == ["rgb_array"]


def test_reset_seed_gives_the_same_first_observation(toy):
    first, other = same_first_observation(toy)
    assert first.dtype == np.uint8 and first.shape == (12, 10, 3)
    # The first unseeded reset draws its key from np_random: seeded, it is reproducible.
    a = GymnasiumEnv(toy.jax_env)
    a.np_random, _ = gymnasium.utils.seeding.np_random(5)
    b = GymnasiumEnv(toy.jax_env)
    b.np_random, _ = gymnasium.utils.seeding.np_random(5)
    np.testing.assert_array_equal(a.reset()[0], b.reset()[0])


def test_episode_matches_jaxnat_step_under_the_adapters_keys(toy):
    rewards = replay(toy, 3, [np.array([DOWN, 1])] * (M + 2))
    assert len(rewards) <= M  # the env's own limit ends the episode


def test_step_returns_host_types_and_checks_actions(toy):
    toy.reset(seed=0)
    obs, reward, terminated, truncated, info = toy.step(np.array([DOWN, 0]))
    assert isinstance(obs, np.ndarray) and obs.flags.writeable
    assert type(reward) is float and type(terminated) is bool and type(truncated) is bool and info == {}
    with pytest.raises(ValueError, match="outside"):
        toy.step(np.array([4, 0]))
    with pytest.raises(ValueError, match="shape"):
        toy.step(np.array([DOWN]))
    with pytest.raises(ValueError, match="reset options"):
        toy.reset(options={"x": 1})


def test_classify_frame_is_the_image_with_the_window_tinted(toy):
    obs, _ = toy.reset(seed=2)
    frame = toy.render()
    assert frame.dtype == np.uint8 and frame.shape == (12, 10, 3)
    image, window = obs[..., 0], obs[..., 2] > 0
    out = ~window
    for ch in range(3):
        np.testing.assert_array_equal(frame[..., ch][out], image[out])  # gray, unrevealed black
    np.testing.assert_array_equal(frame[window][:, 0], (image[window].astype(int) + 255) // 2)
    np.testing.assert_array_equal(frame[window][:, 1], image[window] // 2)


def test_no_render_mode_renders_nothing_and_bad_ones_fail(toy):
    assert GymnasiumEnv(toy.jax_env).render() is None
    with pytest.raises(ValueError, match="render_mode"):
        GymnasiumEnv(toy.jax_env, render_mode="human")


def test_wrappers_of_single_env_gymnasium_work(toy):
    env = gymnasium.wrappers.RecordEpisodeStatistics(toy)
    env.reset(seed=0)
    done = False
    while not done:
        _, _, terminated, truncated, info = env.step(np.array([DOWN, 0]))
        done = terminated or truncated
    assert "episode" in info and info["episode"]["l"] <= M
    frames = gymnasium.wrappers.RenderCollection(toy)
    frames.reset(seed=0)
    frames.step(np.array([DOWN, 0]))
    assert len(frames.render()) == 2


def test_a_natural_atari_game_passes_check_env_and_renders_its_newest_frame():
    pytest.importorskip("ale_py")
    env = make_gymnasium("NaturalAtari/Breakout-v0", render_mode="rgb_array", obs_size=36, num_threads=1,
                         max_episode_steps=20, background="noise")
    checked(env)
    obs, _ = env.reset(seed=3)
    again, _ = env.reset(seed=3)
    np.testing.assert_array_equal(obs, again)
    assert obs.shape == (36, 36, 4) and obs.dtype == np.uint8
    obs, reward, terminated, truncated, info = env.step(1)
    assert isinstance(reward, float) and isinstance(terminated, bool) and isinstance(truncated, bool)
    np.testing.assert_array_equal(env.render(), np.repeat(obs[..., -1:], 3, axis=-1))
    stats = gymnasium.wrappers.RecordEpisodeStatistics(env)
    stats.reset(seed=0)
    done, steps = False, 0
    while not done:
        *_, terminated, truncated, info = stats.step(stats.action_space.sample())
        done, steps = terminated or truncated, steps + 1
    assert steps <= 20 and info["episode"]["l"] == steps  # the env's own limit truncates
    with pytest.raises(ValueError, match="is not in Discrete"):
        env.step(99)
    with pytest.raises(ValueError, match=r"use jaxnat.compat.make_gymnasium\('NaturalAtari/Pong-v0'\) for one game"):
        GymnasiumEnv("NaturalAtari/Pong-v0")
    env.close()


@pytest.mark.skipif(not has_dataset("digits"), reason="Classify/Digits-v0 data not installed")
def test_digits_through_gymnasium_make_passes_check_env():
    """The registered id, through `gymnasium.make` (checker and order wrappers, a spec: the
    checker then also builds fresh envs for the render and close checks)."""
    assert gymnasium_id("Classify/Digits-v0") == "jaxnat/Classify-Digits-v0"
    ids = register_gymnasium_envs()
    assert "jaxnat/Localize-Clutter-v0" in ids and not any("NaturalAtari" in i for i in ids)
    # "module:id" imports jaxnat.compat first, which registers the ids.
    env = gymnasium.make("jaxnat.compat:jaxnat/Classify-Digits-v0", w=4, M=M, render_mode="rgb_array")
    checked(env)
    obs, _ = env.reset(seed=0)
    assert obs.shape == (28, 28, 3) and env.render().shape == (28, 28, 3)
    assert env.unwrapped.params.max_steps_in_episode == M


# ---- Localize ------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def clutter(tmp_path_factory):
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("JAXNAT_CACHE_DIR", str(tmp_path_factory.mktemp("cache")))
        try:
            return make_gymnasium("Localize/Clutter-v0", render_mode="rgb_array", num_images=8,
                                  image_size=32, w=8, M=M)
        except DatasetNotFoundError as err:
            pytest.skip(f"embedded data not present: {str(err).splitlines()[0]}")


def test_clutter_passes_check_env(clutter):
    checked(clutter)


def test_clutter_seeding_replay_and_frame(clutter):
    first, _ = same_first_observation(clutter)
    assert type(first["goal"]) is np.int64 and first["pixels"].shape == (32, 32, 4)
    replay(clutter, 4, [1, 3, 0, 2, 1, 3])
    obs, _ = clutter.reset(seed=1)
    frame = clutter.render()
    footprint = obs["pixels"][..., 3] > 0
    np.testing.assert_array_equal(frame[~footprint], obs["pixels"][..., :3][~footprint])
    np.testing.assert_array_equal(frame[footprint][:, 2], obs["pixels"][..., 2][footprint] // 2)


# ---- MuJoCo and PixelMuJoCo (jaxnat[mujoco]) ------------------------------------------------

mujoco_group = pytest.mark.xdist_group("gymnasium-mujoco")
pixel_group = pytest.mark.xdist_group("gymnasium-pixel")


def _mujoco(env_id, **kwargs):
    pytest.importorskip("mujoco")
    try:
        return make_gymnasium(env_id, render_mode="rgb_array", **kwargs)
    except jaxnat.MissingDependencyError as err:
        pytest.skip(str(err))


@pytest.fixture(scope="module")
def swimmer():
    return _mujoco("MuJoCo/Swimmer-v0")


@pytest.fixture(scope="module")
def pixel_swimmer():
    return _mujoco("PixelMuJoCo/Swimmer-v0", height=16, width=16, frame_stack=2)


@mujoco_group
def test_mujoco_state_env_passes_check_env_and_renders_the_scene(swimmer):
    checked(swimmer)
    same_first_observation(swimmer)
    _, _, _, _, info = swimmer.step(swimmer.action_space.sample())
    assert all(type(v) is float for v in info.values())
    frame = swimmer.render()
    assert frame.shape == (84, 84, 3) and frame.dtype == np.uint8 and frame.std() > 0
    assert swimmer.metadata["render_fps"] == 25  # Swimmer v5: 0.01 s x 4 per step


@pixel_group
def test_pixel_mujoco_passes_check_env_and_renders_the_newest_frame(pixel_swimmer):
    checked(pixel_swimmer)
    same_first_observation(pixel_swimmer)
    obs, *_ = pixel_swimmer.step(pixel_swimmer.action_space.sample())
    frame = pixel_swimmer.render()
    assert obs.shape == (16, 16, 2) and frame.shape == (16, 16, 3)
    np.testing.assert_array_equal(frame, np.repeat(obs[..., -1:], 3, axis=-1))


# ---- The vector adapter renders too ---------------------------------------------------------

def test_vector_adapter_renders_each_env_and_takes_vector_wrappers(toy):
    vec = GymnasiumVectorEnv(toy.jax_env, num_envs=3, seed=0, render_mode="rgb_array")
    assert vec.metadata["render_modes"] == ["rgb_array"]
    obs, _ = vec.reset(seed=0)
    frames = vec.render()
    assert isinstance(frames, tuple) and len(frames) == 3
    frame = Frames(toy.jax_env, toy.params)  # what GymnasiumEnv.render shows
    for o, f in zip(obs, frames):
        np.testing.assert_array_equal(f, frame(o, None))
    stats = gymnasium.wrappers.vector.RecordEpisodeStatistics(vec)
    stats.reset(seed=0)
    for _ in range(M):
        _, _, terminated, truncated, info = stats.step(np.tile([DOWN, 0], (3, 1)))
        if "episode" in info:
            break
    ended = terminated | truncated
    np.testing.assert_array_equal(info["_episode"], ended)
    assert ended.any() and ((info["episode"]["l"][ended] >= 1) & (info["episode"]["l"][ended] <= M)).all()
