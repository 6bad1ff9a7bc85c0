"""Natural Atari: compositor semantics, agreement with ale-py's own preprocessing, backgrounds,
resets, splits, errors, and the adapters.

Background videos for the video tests are written here (lossless FFV1, uniform frames whose
gray level says which video and frame they are), so the tests do not need opencv-doc.
"""

from __future__ import annotations

import threading
from pathlib import Path

import cv2
import jax
import numpy as np
import pytest

ale_py = pytest.importorskip("ale_py")
pytest.importorskip("numba")  # the atari extra's compositing kernel

import jaxnat  # noqa: E402
from jaxnat.atari import AUTHORS_GAMES, GAMES, RomNotFoundError  # noqa: E402
from jaxnat.atari.compositor import (  # noqa: E402
    FrameStack,
    GrayNoiseSampler,
    background_mask,
    composite,
    composite_gray,
    composite_pooled_gray,
    grayscale,
    resize_area,
)
from jaxnat.atari.env import NaturalAtariVecEnv  # noqa: E402
from jaxnat.atari.games import MULTIPLAYER_ONLY, ROM_IDS  # noqa: E402


@pytest.fixture(autouse=True)
def isolated_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("JAXNAT_CACHE_DIR", str(tmp_path / "cache"))


# -- compositor ----------------------------------------------------------------------------
def test_mask_is_all_three_channels_zero():
    frames = np.zeros((2, 3, 4, 3), np.uint8)
    frames[0, 0, 0] = (200, 0, 0)  # the authors' per-channel test replaced two of its channels
    frames[0, 0, 1] = (0, 200, 0)
    frames[0, 0, 2] = (0, 0, 1)
    frames[1, 2, 3] = (1, 1, 1)
    expected = np.ones((2, 3, 4), bool)
    expected[0, 0, :3] = False
    expected[1, 2, 3] = False
    np.testing.assert_array_equal(background_mask(frames), expected)
    backgrounds = np.full_like(frames, 77)
    out = composite(frames, backgrounds)
    np.testing.assert_array_equal(out[0, 0, 0], (200, 0, 0))  # never replaced
    np.testing.assert_array_equal(out[0, 0, 1], (0, 200, 0))
    np.testing.assert_array_equal(out[0, 0, 2], (0, 0, 1))
    np.testing.assert_array_equal(out[expected], 77)


def test_compositing_is_exact_in_rgb_and_gray():
    rng = np.random.default_rng(0)
    # Sparse random colours (half the pixels black, some with only one channel set).
    frames = rng.integers(0, 256, (3, 210, 160, 3), dtype=np.uint8)
    frames[rng.random((3, 210, 160)) < 0.5] = 0
    frames[rng.random((3, 210, 160, 3)) < 0.3] = 0
    backgrounds = rng.integers(0, 256, frames.shape, dtype=np.uint8)
    mask = (frames == 0).all(axis=-1)
    by_hand = np.where(mask[..., None], backgrounds, frames)
    np.testing.assert_array_equal(composite(frames, backgrounds), by_hand)
    expected_gray = grayscale(by_hand)
    # Gray compositing of pre-grayed backgrounds equals RGB compositing then grayscale.
    np.testing.assert_array_equal(composite_gray(frames, grayscale(backgrounds)), expected_gray)
    np.testing.assert_array_equal(composite_gray(frames), grayscale(frames))
    # Pooled gray screens: level 0 is exactly the mask on ALE screens (palette test below); these
    # random colours include dark ones that round to 0, so lift those to 1 first.
    gray = grayscale(frames)
    gray[~mask & (gray == 0)] = 1
    out = composite_pooled_gray(gray.copy(), grayscale(backgrounds))
    np.testing.assert_array_equal(out, np.where(mask, grayscale(backgrounds), gray))


def test_grayscale_follows_ales_law_within_one_level():
    rng = np.random.default_rng(1)
    colours = rng.integers(0, 256, (1, 200_000, 1, 3), dtype=np.uint8)
    rgb = colours.astype(np.float64)
    law = np.floor(rgb[..., 0] * 0.2989 + rgb[..., 1] * 0.5870 + rgb[..., 2] * 0.1140 + 0.5)
    diff = np.abs(grayscale(colours).astype(int) - law)
    assert diff.max() <= 1 and (diff > 0).mean() < 1e-3


def test_batched_resize_equals_per_image_resize():
    rng = np.random.default_rng(2)
    gray = rng.integers(0, 256, (5, 210, 160), dtype=np.uint8)
    per_image = np.stack([cv2.resize(g, (84, 84), interpolation=cv2.INTER_AREA) for g in gray])
    np.testing.assert_array_equal(resize_area(gray, (84, 84)), per_image)


def test_frame_stack_order_and_reset():
    stack = FrameStack(3)
    stack.allocate(2, (2, 2))
    for value in (1, 2):
        stack.rotate()[:] = value
    np.testing.assert_array_equal(stack.observation()[:, 0, 0], [(0, 1, 2), (0, 1, 2)])
    stack.rotate()[:] = 3
    final = stack.with_newest([1], np.full((1, 2, 2), 9, np.uint8))
    np.testing.assert_array_equal(final[0, 0, 0], (1, 2, 9))  # the frames before, then its own
    stack.clear_older(np.array([False, True]))  # env 1 starts a new episode with frame 3
    obs = stack.observation()
    np.testing.assert_array_equal(obs[0, 0, 0], (1, 2, 3))
    np.testing.assert_array_equal(obs[1, 0, 0], (0, 0, 3))  # zeros, then its first frame
    assert obs.shape == (2, 2, 2, 3) and obs.flags.c_contiguous


def test_only_black_has_gray_level_zero_on_real_screens():
    """The gray-pooled mask (`gray == 0`) is the RGB mask (all three channels 0) on ALE screens:
    the same seeds and actions, screens pooled in RGB and in gray."""
    kwargs = dict(img_height=210, img_width=160, stack_num=1, repeat_action_probability=0.0,
                  use_fire_reset=False, num_threads=1)
    for game in ("alien", "space_invaders", "pong"):
        rgb_env = ale_py.vector_env.AtariVectorEnv(game, 2, grayscale=False, **kwargs)
        gray_env = ale_py.vector_env.AtariVectorEnv(game, 2, grayscale=True, **kwargs)
        rgb, _ = rgb_env.reset(seed=0)
        gray, _ = gray_env.reset(seed=0)
        rng = np.random.default_rng(0)
        for _ in range(30):
            rgb_mask = background_mask(rgb[:, 0])
            np.testing.assert_array_equal(gray[:, 0] == 0, rgb_mask)
            assert rgb_mask.any() and not rgb_mask.all()
            actions = rng.integers(0, rgb_env.single_action_space.n, 2)
            rgb, *_ = rgb_env.step(actions)
            gray, *_ = gray_env.step(actions)


def test_gray_noise_is_the_gray_level_of_the_papers_rgb_noise():
    from jaxnat.natural import gaussian_noise_np

    channel = GrayNoiseSampler.channel_probabilities(50.0)
    rgb_noise = gaussian_noise_np(np.random.default_rng(4), (1, 400_000, 1, 3))
    freq = np.bincount(rgb_noise.ravel(), minlength=256) / rgb_noise.size
    assert abs(channel.sum() - 1) < 1e-12 and abs(freq[0] - channel[0]) < 0.005  # half black
    np.testing.assert_allclose(freq[1:120], channel[1:120], atol=0.0015)
    # Our gray draws and the gray levels of the paper's RGB noise follow one law.
    law = GrayNoiseSampler.law_probabilities(50.0)
    sampler = GrayNoiseSampler(np.random.default_rng(5), scale=50.0)
    for sample in (sampler.sample((400_000,)), grayscale(rgb_noise).ravel()):
        freq = np.bincount(sample, minlength=256) / sample.size
        np.testing.assert_allclose(freq, law, atol=0.0015)
    assert sampler.sample((2, 3)).dtype == np.uint8
    assert not np.array_equal(sampler.sample((64,)), sampler.sample((64,)))  # fresh every call


# -- agreement with ale-py -----------------------------------------------------------------
def _run_both(game, maxpool, steps, pool="gray", seed=3, episode_steps=27_000):
    """(ours, ale-py's) observation pairs of the same run, and then final observation pairs
    of the steps where an episode ended."""
    ours = NaturalAtariVecEnv(game, 2, sticky_actions=0.0, maxpool=maxpool, pool=pool,
                              num_threads=1, seed=seed, max_episode_steps=episode_steps)
    ref = ale_py.vector_env.AtariVectorEnv(
        GAMES[game], 2, maxpool=maxpool, use_fire_reset=False, reward_clipping=False,
        repeat_action_probability=0.0, num_threads=1, autoreset_mode="SameStep",
        max_num_frames_per_episode=4 * episode_steps,
    )
    obs, _ = ours.reset(seed=seed)
    ref_obs, _ = ref.reset(seed=seed)
    pairs = [(obs, ref_obs.transpose(0, 2, 3, 1))]  # ale-py stacks channels-first
    finals = []
    rng = np.random.default_rng(0)
    for _ in range(steps):
        actions = rng.integers(0, ours.single_action_space.n, 2)
        obs, reward, terminated, truncated, info = ours.step(actions)
        ref_obs, ref_reward, ref_terminated, ref_truncated, ref_info = ref.step(actions)
        np.testing.assert_array_equal(reward, ref_reward)
        np.testing.assert_array_equal(terminated, ref_terminated)
        np.testing.assert_array_equal(truncated, ref_truncated)
        pairs.append((obs, ref_obs.transpose(0, 2, 3, 1)))
        if (terminated | truncated).any():
            finals.append((info["final_observation"], ref_info["final_obs"].transpose(0, 2, 3, 1)))
    ours.close()
    ref.close()
    return pairs, finals


@pytest.mark.parametrize("game", ["Breakout", "SpaceInvaders", "Alien"])
def test_background_none_equals_ale_py_preprocessing(game):
    pairs, finals = _run_both(game, maxpool=True, steps=60, episode_steps=25)
    assert len(finals) == 2  # time limits at steps 25 and 50
    for obs, ref_obs in pairs + finals:
        np.testing.assert_array_equal(obs, ref_obs)


@pytest.mark.parametrize("game", ["Breakout", "Alien"])
def test_rgb_pooling_equals_ale_py_without_pooling_and_differs_only_by_flicker(game):
    # Without max-pool both orders are one frame: bit-identical.
    for obs, ref_obs in _run_both(game, maxpool=False, steps=40, pool="rgb")[0]:
        np.testing.assert_array_equal(obs, ref_obs)
    # With it, gray(max(a, b)) >= max(gray(a), gray(b)): equal on Breakout (nothing flickers),
    # brighter on Alien's flickering sprites.
    pairs, _ = _run_both(game, maxpool=True, steps=40, pool="rgb")
    diffs = np.array([np.mean(obs != ref) for obs, ref in pairs])
    assert all((obs >= ref).all() for obs, ref in pairs)
    assert (diffs == 0).all() if game == "Breakout" else 0 < diffs.max() < 0.05


# -- episodes, resets, determinism ---------------------------------------------------------
def test_time_limit_reset_and_whole_game_statistics():
    env = NaturalAtariVecEnv("Breakout", 2, max_episode_steps=5, num_threads=1)
    obs, info = env.reset(seed=0)
    assert obs.shape == (2, 84, 84, 4) and obs.dtype == np.uint8
    assert (obs[..., :3] == 0).all() and (obs[..., 3] > 0).any()
    total = np.zeros(2, np.float32)
    for t in range(5):
        obs, reward, terminated, truncated, info = env.step(np.array([1, 3]))
        total += reward
        assert reward.dtype == np.float32
    assert truncated.all() and not terminated.any() and info["returned_episode"].all()
    np.testing.assert_array_equal(info["returned_episode_lengths"], [5, 5])
    np.testing.assert_array_equal(info["returned_episode_returns"], total)
    assert (obs[..., :3] == 0).all()  # the next episode's first observation
    final = info["final_observation"]
    assert (final[..., :3] > 0).any() and not np.array_equal(final, obs)
    obs, *_, info = env.step(np.array([0, 0]))
    assert not info["returned_episode"].any() and (obs[..., :2] == 0).all()


def test_episodes_are_whole_games_not_lives():
    env = NaturalAtariVecEnv("Breakout", 1, num_threads=1, sticky_actions=0.0)
    env.reset(seed=1)
    lives_seen = set()
    for _ in range(3000):
        *_, terminated, truncated, info = env.step(np.array([1]))  # FIRE, then play badly
        lives_seen.add(int(info["lives"][0]))
        if info["returned_episode"][0]:
            break
    assert terminated[0] and len(lives_seen) >= 3  # several lives lost within one episode
    assert info["returned_episode_lengths"][0] > 100


def _observations(env, steps, seed=None):
    """The observations of a reset and `steps` steps with fixed actions, stacked."""
    out = [env.reset(seed=seed)[0]]
    for t in range(steps):
        out.append(env.step(np.full(env.num_envs, t % 4))[0])
    return np.stack(out)


def test_same_seed_same_run_with_sticky_actions():
    def run(seed):
        env = NaturalAtariVecEnv("Breakout", 2, background="noise", num_threads=1, seed=seed)
        return _observations(env, 20)

    a, b, c = run(5), run(5), run(6)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_reset_with_a_seed_repeats_the_run(clips):
    env = NaturalAtariVecEnv("Breakout", 2, background="video", split="all",
                             video_sources=str(clips), num_threads=1, seed=0)
    first, other, again = (_observations(env, 10, seed) for seed in (7, 8, 7))
    np.testing.assert_array_equal(first, again)
    assert not np.array_equal(first, other)


@pytest.mark.parametrize("pool", ["gray", "rgb"])
def test_noise_replaces_exactly_the_black_pixels(pool):
    # Full-resolution screens, no stack: the observation is the composited screen itself.
    kwargs = dict(sticky_actions=0.0, obs_size=(210, 160), stack=1, pool=pool, num_threads=1)
    plain = NaturalAtariVecEnv("Breakout", 2, **kwargs)
    noisy = NaturalAtariVecEnv("Breakout", 2, background="noise", **kwargs)
    a, _ = plain.reset(seed=0)
    b, _ = noisy.reset(seed=0)
    previous = None
    for t in range(12):
        black = a[..., 0] == 0
        np.testing.assert_array_equal(b[~black], a[~black])  # the game's pixels are kept
        assert 0.8 < (b[black] > 0).mean() < 0.9  # P(gray noise level 0) = 0.14
        if previous is not None:
            assert not np.array_equal(b, previous)  # fresh noise every step
        previous = b
        actions = np.full(2, t % 4)
        a, *_ = plain.step(actions)
        b, *_ = noisy.step(actions)


@pytest.mark.parametrize("noise", [None, "centred"])
def test_noise_background_follows_the_named_law(noise):
    """The background's gray levels are those of RGB noise of the named pixel-noise law; None
    (no `noise=`) is `DEFAULT_NOISE`, the law of every family's noise control."""
    from jaxnat.natural import DEFAULT_NOISE, noise_law
    from jaxnat.testing import check_noise_law

    kwargs = dict(sticky_actions=0.0, obs_size=(210, 160), stack=1, num_threads=1)
    plain = NaturalAtariVecEnv("Breakout", 2, **kwargs)
    noisy = NaturalAtariVecEnv("Breakout", 2, background="noise", **kwargs,
                               **({} if noise is None else {"noise": noise}))
    a, _ = plain.reset(seed=0)
    b, _ = noisy.reset(seed=0)
    draws = []
    for t in range(8):
        draws.append(b[a[..., 0] == 0])
        actions = np.full(2, t % 4)
        a, *_ = plain.step(actions)
        b, *_ = noisy.step(actions)
    law = noise_law(DEFAULT_NOISE if noise is None else noise)
    check_noise_law(np.concatenate(draws), GrayNoiseSampler.law_probabilities(law.scale, law.mean),
                    f"NaturalAtari background='noise', noise={noise!r}")


# -- video backgrounds ---------------------------------------------------------------------
def _write_video(path: Path, video: int, num_frames: int) -> Path:
    """Uniform gray frames of level 20 + 40 * video + 2 * frame, lossless (FFV1)."""
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"FFV1"), 10, (40, 30))
    assert writer.isOpened()
    for f in range(num_frames):
        writer.write(np.full((30, 40, 3), 20 + 40 * video + 2 * f, np.uint8))
    writer.release()
    return path


@pytest.fixture
def clips(tmp_path):
    folder = tmp_path / "clips"
    folder.mkdir()
    for v in range(4):
        _write_video(folder / f"clip{v}.avi", v, 12 + v)
    return folder


def _background_level(obs):
    """The background's gray level in each env's newest frame (most of Pong's screen is not
    black, so use Breakout: its black field is most of the frame)."""
    newest = obs[..., -1].reshape(len(obs), -1)
    return np.array([np.bincount(row).argmax() for row in newest])


def test_video_background_one_frame_per_step_and_new_video_at_reset(clips):
    env = NaturalAtariVecEnv(
        "Breakout", 3, background="video", split="all", video_sources=str(clips),
        max_episode_steps=8, num_threads=1, seed=0,
    )
    bank_levels = env.background_bank.frames[:, 0, 0, 0].astype(int)  # one level per frame
    assert len(set(bank_levels)) == len(bank_levels)  # every bank frame is recognisable
    index = {level: i for i, level in enumerate(bank_levels)}
    obs, _ = env.reset()
    positions = [[index[v] for v in _background_level(obs)]]
    for _ in range(20):
        obs, *_, info = env.step(np.zeros(3, np.int64))
        positions.append([index[v] for v in _background_level(obs)])
    positions = np.array(positions)
    starts = np.asarray(env.background_bank.starts)
    lengths = np.asarray(env.background_bank.lengths)
    video_of = np.searchsorted(starts, np.arange(len(bank_levels)), side="right") - 1
    for t in range(1, len(positions)):
        for e in range(3):
            prev, cur = positions[t - 1, e], positions[t, e]
            if t % 8 == 0:  # a reset: a new video at a random offset (any frame)
                continue
            last = starts[video_of[prev]] + lengths[video_of[prev]] - 1
            # One video frame per step; after a video's last frame, a new video's first frame.
            assert cur == prev + 1 or (prev == last and cur == starts[video_of[cur]])
    # Resets draw new offsets: not every env restarts where it would have continued.
    assert any(positions[8, e] != positions[7, e] + 1 for e in range(3))


def test_video_background_dial_per_env(clips):
    """The dial, one value per env in one batch: `video_alpha` scales an env's background to
    round(alpha * level) of the same draws (1: the plain env's; 0: black), `frame_rate=0`
    freezes an env's video, `num_videos=1` keeps an env on the bank's first video; a value
    the background would ignore, or out of range, is a one-line error."""
    kwargs = dict(background="video", split="all", video_sources=str(clips), max_episode_steps=50, num_threads=1,
                  seed=0)
    plain = NaturalAtariVecEnv("Breakout", 3, **kwargs)
    dialled = NaturalAtariVecEnv("Breakout", 3, video_alpha=[1.0, 0.5, 0.0], **kwargs)
    frozen = NaturalAtariVecEnv("Breakout", 3, frame_rate=[0, 0, 1], num_videos=1, **kwargs)
    starts = np.asarray(frozen.background_bank.starts)
    first_video = set(frozen.background_bank.frames[starts[0]:starts[1], 0, 0, 0].astype(int))
    a, _ = plain.reset()
    b, _ = dialled.reset()
    c, _ = frozen.reset()
    first = _background_level(c)
    for _ in range(6):
        levels, dimmed = _background_level(a), _background_level(b)
        assert dimmed[0] == levels[0] and dimmed[1] == np.rint(0.5 * levels[1]) and dimmed[2] == 0
        now = _background_level(c)
        assert now[0] == first[0] and now[1] == first[1] and set(now.tolist()) <= first_video
        a, *_ = plain.step(np.zeros(3, np.int64))
        b, *_ = dialled.step(np.zeros(3, np.int64))
        c, *_ = frozen.step(np.zeros(3, np.int64))
    for env in (plain, dialled, frozen):
        env.close()
    for bad, match in [(dict(video_alpha=1.5), r"video_alpha must lie in \[0, 1\]"),
                       (dict(video_alpha=[1.0, 0.5]), r"one number or one per env \(3\)"),
                       (dict(frame_rate=-1), "frame_rate must be >= 0"),
                       (dict(num_videos=9), r"num_videos must be in \[1, 4\]"),
                       (dict(frame_rate=2, background="image"), "frame_rate needs background='video'"),
                       (dict(video_alpha=0.5, background="noise"), "video_alpha needs background='video' or 'image'"),
                       (dict(num_videos=1, background="none"), "num_videos needs background='video' or 'image'")]:
        with pytest.raises(ValueError, match=match):
            NaturalAtariVecEnv("Breakout", 3, **{**kwargs, **bad})


def test_noise_spread_per_env():
    """`noise_sigma` one per env: spread 0 is the law's constant floor(mean) (black for the
    authors' law); each env draws from its own generator, so env 1 is the same as in a batch
    built with its spread for every env."""
    kwargs = dict(background="noise", max_episode_steps=50, num_threads=1, seed=3)
    mixed = NaturalAtariVecEnv("Breakout", 2, noise_sigma=[0.0, 50.0], **kwargs)
    same = NaturalAtariVecEnv("Breakout", 2, noise_sigma=50.0, **kwargs)
    a, _ = mixed.reset()
    b, _ = same.reset()
    for _ in range(3):
        np.testing.assert_array_equal(a[1], b[1])
        assert _background_level(a)[0] == 0 and _background_level(b)[0] != 0
        a, *_ = mixed.step(np.zeros(2, np.int64))
        b, *_ = same.step(np.zeros(2, np.int64))
    for env in (mixed, same):
        env.close()
    for bad, match in [(dict(noise_sigma=-1.0), "noise_sigma must be a finite number >= 0"),
                       (dict(noise_sigma=[1.0, 2.0, 3.0]), r"one number or one per env \(2\)"),
                       (dict(noise_sigma=10.0, background="none"), "noise_sigma needs background='noise'")]:
        with pytest.raises(ValueError, match=match):
            NaturalAtariVecEnv("Breakout", 2, **{**kwargs, **bad})


def test_video_split_is_disjoint(clips):
    names = {}
    for split in ("train", "test", "all"):
        env = NaturalAtariVecEnv("Breakout", 1, background="video", split=split,
                                 video_sources=str(clips), num_threads=1)
        names[split] = set(env.background_bank.names)
    assert names["train"] and names["test"]
    assert not names["train"] & names["test"]
    assert names["train"] | names["test"] == names["all"]


# -- registry, games, errors ---------------------------------------------------------------
def test_every_ale_game_is_registered():
    assert set(ROM_IDS) == set(ale_py.roms.get_all_rom_ids())
    ids = {i for i in jaxnat.registered_envs() if i.startswith("NaturalAtari/")}
    assert ids == {f"NaturalAtari/{g}-v0" for g in GAMES}
    assert len(GAMES) == len(ROM_IDS) - len(MULTIPLAYER_ONLY)
    assert set(AUTHORS_GAMES) <= set(GAMES) and len(AUTHORS_GAMES) == 16


def test_every_registered_game_builds_and_steps():
    """In a subprocess: ALE ends the whole process (exit code 1, no exception) for a ROM it will
    not run single-player, so a registered id that does so must fail this test, not the suite."""
    import subprocess
    import sys

    code = (
        "import numpy as np, jaxnat\n"
        "for i in jaxnat.registered_envs():\n"
        "    if i.startswith('NaturalAtari/'):\n"
        "        env = jaxnat.make_vec(i, 1, background='none', num_threads=1, obs_size=36)\n"
        "        env.reset(seed=0); env.step(np.zeros(1, np.int64)); env.close()\n"
        "print('all built')\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0 and "all built" in out.stdout, out.stderr[-2000:]


@pytest.mark.parametrize("game", ["Combat", "joust", "MazeCraze", "warlords"])
def test_multiplayer_only_roms_are_a_python_error(game):
    with pytest.raises(ValueError, match="multiplayer-only ROM"):
        NaturalAtariVecEnv(game, 1, background="none", num_threads=1)


@pytest.mark.parametrize("game", AUTHORS_GAMES)
def test_authors_games_construct_and_step(game):
    env = jaxnat.make_vec(f"NaturalAtari/{game}-v0", 2, background="noise", num_threads=1)
    obs, _ = env.reset(seed=0)
    obs, reward, terminated, truncated, _ = env.step(np.zeros(2, np.int64))
    assert obs.shape == (2, 84, 84, 4) and reward.shape == (2,)
    env.close()


def test_full_action_set_is_optional():
    minimal = NaturalAtariVecEnv("Breakout", 1, num_threads=1)
    full = NaturalAtariVecEnv("Breakout", 1, full_action_space=True, num_threads=1)
    assert (minimal.single_action_space.n, full.single_action_space.n) == (4, 18)
    full.reset(seed=0)
    assert full.step(np.array([17]))[0].shape == (1, 84, 84, 4)


def test_bad_game_id_lists_close_matches():
    with pytest.raises(jaxnat.UnknownEnvError, match="NaturalAtari/Breakout-v0"):
        jaxnat.make_vec("NaturalAtari/Breakot-v0", 2)
    with pytest.raises(ValueError, match="Did you mean: SpaceInvaders"):
        NaturalAtariVecEnv("SpaceInvader", 1)
    with pytest.raises(TypeError, match="make_vec"):
        jaxnat.make("NaturalAtari/Breakout-v0")


def test_missing_rom_is_a_clear_error(tmp_path, monkeypatch):
    monkeypatch.setenv("ALE_ROMS_DIR", str(tmp_path))
    with pytest.raises(RomNotFoundError, match=r"breakout\.bin.*ALE_ROMS_DIR"):
        NaturalAtariVecEnv("Breakout", 1)


def test_bad_arguments_are_clear_errors():
    with pytest.raises(ValueError, match="background must be one of"):
        NaturalAtariVecEnv("Breakout", 1, background="fog")
    with pytest.raises(ValueError, match="split"):
        NaturalAtariVecEnv("Breakout", 1, split="val")
    env = NaturalAtariVecEnv("Breakout", 2, num_threads=1)
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(2, np.int64))
    env.reset()
    with pytest.raises(ValueError, match=r"shape \(2,\)"):
        env.step(np.zeros(3, np.int64))
    with pytest.raises(ValueError, match=r"\[0, 4\)"):
        env.step(np.array([0, 9]))


# -- adapters ------------------------------------------------------------------------------
def test_gymnasium_adapter_next_step_autoreset():
    from jaxnat.compat.gymnasium import make_gymnasium_vec

    vec = make_gymnasium_vec("NaturalAtari/Breakout-v0", 2, seed=0, max_episode_steps=3, num_threads=1)
    obs, _ = vec.reset(seed=0)
    assert vec.observation_space.contains(obs)
    for _ in range(3):
        obs, reward, terminated, truncated, info = vec.step(vec.action_space.sample())
    assert truncated.all() and (obs[..., :3] > 0).any()  # the final observation itself
    np.testing.assert_array_equal(info["returned_episode_lengths"], [3, 3])
    assert info["_returned_episode_lengths"].all()
    obs, reward, terminated, truncated, info = vec.step(vec.action_space.sample())
    assert (reward == 0).all() and not (terminated | truncated).any()
    assert (obs[..., :3] == 0).all() and not info["_returned_episode_lengths"].any()
    vec.close()


def test_clip_reward_and_device_arrays_wrappers():
    import jax

    from jaxnat.atari.wrappers import ClipRewardWrapper, DeviceArraysWrapper

    env = DeviceArraysWrapper(ClipRewardWrapper(NaturalAtariVecEnv("Breakout", 2, num_threads=1)))
    obs, _ = env.reset(seed=0)
    assert isinstance(obs, jax.Array) and obs.shape == (2, 84, 84, 4)
    for _ in range(40):
        obs, reward, terminated, truncated, info = env.step(jax.numpy.ones(2, jax.numpy.int32))
        assert isinstance(reward, jax.Array)
        assert (np.abs(np.asarray(reward)) <= 1).all()
        np.testing.assert_array_equal(np.clip(info["unclipped_reward"], -1, 1), reward)
    assert env.num_envs == 2  # attributes pass through


def test_step_in_two_halves_is_step_and_wrappers_keep_their_work():
    """`step_async` + `step_wait` is `step` bit for bit (with an env of the batch in between,
    as the pipelined host driver does), a second `step_async` before the wait is an error, and
    the reward-clipping wrapper clips `step_wait`'s rewards; a `PipelinedVecEnv` of two
    halves seeds emulator j with seed + j, as one batch does."""
    from jaxnat.atari.wrappers import ClipRewardWrapper, PipelinedVecEnv

    def make(n=2):
        return NaturalAtariVecEnv("Breakout", n, background="noise", num_threads=1, seed=3)

    whole, halves, other = make(), ClipRewardWrapper(make()), make(1)
    actions = np.random.default_rng(0).integers(0, 4, (30, 2))
    np.testing.assert_array_equal(whole.reset(seed=3)[0], halves.reset(seed=3)[0])
    other.reset(seed=9)
    for a in actions:
        expected = whole.step(a)
        halves.step_async(a)
        other.step(a[:1])
        got = halves.step_wait()
        np.testing.assert_array_equal(expected[0], got[0])
        np.testing.assert_array_equal(np.clip(expected[1], -1, 1), got[1])
        np.testing.assert_array_equal(expected[4]["final_observation"], got[4]["final_observation"])
    halves.step_async(actions[0])
    with pytest.raises(RuntimeError, match="twice"):
        halves.step_async(actions[0])
    for env in (whole, halves, other):
        env.close()

    ale = lambda n: NaturalAtariVecEnv("Breakout", n, num_threads=1)  # noqa: E731 (ALE resizes: no noise)
    one, split = ale(4), PipelinedVecEnv([ale(2), ale(2)])
    assert split.num_envs == 4
    np.testing.assert_array_equal(one.reset(seed=5)[0], split.reset(seed=5)[0])
    for a in actions[:20]:
        a = np.concatenate([a, a[::-1]])
        for x, y in zip(one.step(a)[:4], split.step(a)[:4]):
            np.testing.assert_array_equal(x, y)
    one.close()
    split.close()


def test_pipelined_parts_reset_with_their_own_seeds_replay_lone_batches():
    """`PipelinedVecEnv.reset(seeds=...)` resets each part as a batch of its own (the seeds of a
    run side by side): with the same actions every part replays the lone batch reset with its
    seed, noise background included, while `step` emulates the parts at once."""
    from jaxnat.atari.wrappers import PipelinedVecEnv

    def make():
        return NaturalAtariVecEnv("Breakout", 2, background="noise", num_threads=1)

    lone, side = [make(), make()], PipelinedVecEnv([make(), make()])
    first = side.reset(seeds=[7, 11])[0]
    np.testing.assert_array_equal(first, np.concatenate([lone[0].reset(seed=7)[0], lone[1].reset(seed=11)[0]]))
    for a in np.random.default_rng(2).integers(0, 4, (25, 4)):
        got = side.step(a)
        expected = [env.step(part) for env, part in zip(lone, np.split(a, 2))]
        for i in range(4):
            np.testing.assert_array_equal(got[i], np.concatenate([out[i] for out in expected]))
    with pytest.raises(ValueError, match="one per part"):
        side.reset(seeds=[1])
    with pytest.raises(ValueError, match="not both"):
        side.reset(seed=1, seeds=[1, 2])
    for env in (*lone, side):
        env.close()


def test_pipelined_parts_of_groups_replay_each_group_s_batch_in_parts():
    """`PipelinedVecEnv(parts, groups=G)` (seeds side by side in pipelined parts): each part
    holds an equal slice of every group; `reset(seeds=...)` and the same actions replay, for
    group `g`, the lone batch in the same parts reset with `seed=seeds[g]`."""
    from jaxnat.atari.wrappers import PipelinedVecEnv

    def make(n):
        return NaturalAtariVecEnv("Breakout", n, background="noise", num_threads=1, obs_size=36)

    seeds = [7, 11]
    side = PipelinedVecEnv([make(4), make(4)], groups=2)  # part p: envs p*2, p*2+1 of each group
    lone = [PipelinedVecEnv([make(2), make(2)]) for _ in seeds]

    def regroup(outs):  # each group's envs, part after part, from the lone batches
        return np.concatenate([x[lo:lo + 2] for lo in (0, 2) for x in outs])

    first = side.reset(seeds=seeds)[0]
    np.testing.assert_array_equal(first, regroup([env.reset(seed=s)[0] for env, s in zip(lone, seeds)]))
    for a in np.random.default_rng(2).integers(0, 4, (15, 8)):
        got = side.step(a)
        parts = a.reshape(2, 2, 2)  # part, group, env
        expected = [env.step(parts[:, g].reshape(-1)) for g, env in enumerate(lone)]
        for i in range(4):
            np.testing.assert_array_equal(got[i], regroup([out[i] for out in expected]))
    with pytest.raises(ValueError, match=r"one per group \(2\), got 3"):
        side.reset(seeds=[1, 2, 3])
    with pytest.raises(ValueError, match=r"groups=2: every part must hold an equal slice of each group; .* \[4, 3\]"):
        PipelinedVecEnv([make(4), make(3)], groups=2)
    for env in (*lone, side):
        env.close()


@pytest.mark.parametrize("background", ["none", "noise", "video"])
def test_one_batch_reset_with_seeds_per_group_replays_lone_batches(clips, background):
    """`NaturalAtariVecEnv.reset(seeds=...)` (the seeds of a run side by side on one ALE batch):
    group `g`'s envs replay the lone batch reset with `seed=seeds[g]` under the same actions,
    their games, games ending one env at a time (the backgrounds of those envs alone redrawn)
    and backgrounds included, and a later `reset()` without a seed continues each group's
    streams as the lone batches' do."""
    kwargs = dict(background=background, split="all", video_sources=str(clips), num_threads=2, obs_size=36)
    seeds, size = [7, 11, 30], 2
    actions = np.random.default_rng(2).integers(0, 4, (250, len(seeds) * size))
    lone = [NaturalAtariVecEnv("Breakout", size, **kwargs) for _ in seeds]
    side = NaturalAtariVecEnv("Breakout", len(seeds) * size, **kwargs)
    got = [side.reset(seeds=seeds)]
    expected = [[env.reset(seed=seed) for env, seed in zip(lone, seeds)]]
    for t, a in enumerate(actions):
        if t == 230:
            got.append(side.reset())
            expected.append([env.reset() for env in lone])
        got.append(side.step(a))
        expected.append([env.step(part) for env, part in zip(lone, np.split(a, len(seeds)))])
    for whole, parts in zip(got, expected):
        for x, *ys in zip(jax.tree.leaves(whole), *(jax.tree.leaves(p) for p in parts)):
            np.testing.assert_array_equal(x, np.concatenate(ys))
    ended = [int(np.sum(step[2] | step[3])) for step in got if len(step) == 5]
    assert any(0 < n < len(seeds) * size for n in ended)  # some games ended while others went on
    with pytest.raises(ValueError, match="4 groups do not divide num_envs=6"):
        side.reset(seeds=[1, 2, 3, 4])
    with pytest.raises(ValueError, match="not both"):
        side.reset(seed=1, seeds=[1, 2, 3])
    for env in (*lone, side):
        env.close()


# -- threaded host work --------------------------------------------------------------------
def _trajectory(env, steps, seed=0):
    """Observations, final observations, rewards and episode statistics of a reset and `steps`
    steps with seeded random actions."""
    rng = np.random.default_rng(1)
    out = [env.reset(seed=seed)[0]]
    for _ in range(steps):
        obs, reward, terminated, truncated, info = env.step(
            rng.integers(0, env.single_action_space.n, env.num_envs))
        out += [obs, reward, terminated | truncated, info["returned_episode_returns"]]
        out.append(info.get("final_observation", obs))
    env.close()
    return out


@pytest.mark.parametrize("background", ["none", "noise", "video"])
@pytest.mark.parametrize("autoreset_mode", ["same_step", "next_step"])
def test_threaded_host_work_equals_serial(clips, background, autoreset_mode):
    def run(host_threads):
        env = NaturalAtariVecEnv(
            "Breakout", 5, background=background, split="all", video_sources=str(clips),
            max_episode_steps=7, autoreset_mode=autoreset_mode, num_threads=2,
            host_threads=host_threads, seed=4,
        )
        assert env.host_threads == min(host_threads, 5)
        return _trajectory(env, 16)

    serial = run(1)
    assert any(x.dtype == bool and x.any() for x in serial)  # episodes ended (time limit)
    for threads in (3, 9):  # uneven chunks; more threads than envs: one env per chunk
        threaded = run(threads)
        for a, b in zip(serial, threaded, strict=True):
            np.testing.assert_array_equal(a, b)


class PerEnvReference(NaturalAtariVecEnv):
    """The host work one env at a time in plain numpy, from the definitions: composite with
    `np.where` on the gray screen, resize each image, stack in a deque per env. Same emulator
    and background draws as the env; only the host path differs."""

    def __init__(self, *args, **kwargs):
        self.history = None  # per env: a deque of its last frames
        super().__init__(*args, **kwargs)
        self.history = [None] * self.num_envs

    def _observe(self, screens, new_episode, final_backgrounds=None, ended=None,
                 final_screens=None, alongside=None):
        from collections import deque

        if alongside is not None:
            alongside()

        def frame(screen, background):
            composited = np.where(screen == 0, background, screen)
            return cv2.resize(composited, self.obs_size[::-1], interpolation=cv2.INTER_AREA)

        backgrounds = self._background.frames()
        frames = [frame(s, b) for s, b in zip(screens, backgrounds, strict=True)]
        finals = {}
        for k, e in enumerate([] if ended is None else ended):
            background = backgrounds[e] if final_backgrounds is None else final_backgrounds[k]
            older = list(self.history[e])[1:]
            finals[e] = np.stack([*older, frame(final_screens[k], background)], axis=-1)
        depth = self._stack.depth
        for e, new in enumerate(new_episode):
            if new:
                self.history[e] = deque([np.zeros_like(frames[e])] * depth, maxlen=depth)
            self.history[e].append(frames[e])
        obs = np.stack([np.stack(list(h), axis=-1) for h in self.history])
        final = obs.copy()
        for e, stack in finals.items():
            final[e] = stack
        return obs, final


@pytest.mark.parametrize("background", ["noise", "video"])
@pytest.mark.parametrize("autoreset_mode", ["same_step", "next_step"])
@pytest.mark.parametrize("obs_size", [84, (105, 80)])  # numba's parallel pass; the Python pool
def test_whole_batch_host_work_equals_the_per_env_definition(clips, background, autoreset_mode,
                                                             obs_size):
    def run(cls, host_threads):
        env = cls("Breakout", 5, background=background, split="all", video_sources=str(clips),
                  max_episode_steps=6, autoreset_mode=autoreset_mode, num_threads=2,
                  host_threads=host_threads, seed=9, obs_size=obs_size)
        assert (env.host_pass == "numba") == (obs_size == 84)
        return _trajectory(env, 14)

    reference = run(PerEnvReference, 1)
    assert any(x.dtype == bool and x.any() for x in reference)  # episodes ended (time limit)
    for host_threads in (1, 2):
        for a, b in zip(reference, run(NaturalAtariVecEnv, host_threads), strict=True):
            np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("background", ["none", "video"])
def test_python_pool_host_pass_gives_the_same_trajectory(clips, background):
    """`host_pass="pool"` runs the host work on the Python thread pool where numba's single
    call would apply (84x84 gray): same observations."""
    def run(host_pass):
        env = NaturalAtariVecEnv(
            "Breakout", 5, background=background, split="all", video_sources=str(clips),
            max_episode_steps=6, num_threads=2, host_threads=2, host_pass=host_pass, seed=3)
        chosen = env.host_pass
        return chosen, _trajectory(env, 12)

    (auto_pass, auto), (pool_pass, pool) = run("auto"), run("pool")
    assert pool_pass == ("inline" if background == "none" else "pool")
    assert auto_pass in (("inline",) if background == "none" else ("numba", "pool"))
    for a, b in zip(auto, pool, strict=True):
        np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="host_pass must be one of"):
        NaturalAtariVecEnv("Breakout", 2, host_pass="numba")


def test_step_timings_add_up():
    env = NaturalAtariVecEnv("Breakout", 2, num_threads=1, host_threads=2)
    env.reset(seed=0)
    for _ in range(3):
        env.step(np.zeros(2, np.int64))
    timings = env.step_timings
    assert timings["steps"] == 3 and timings["ale_s"] > 0 and timings["host_s"] > 0
    assert timings["ahead_s"] >= 0
    env.close()


@pytest.mark.parametrize("name", ["num_threads", "host_threads"])
@pytest.mark.parametrize("value", [-1, 1.5, "4", True])
def test_thread_counts_are_validated(name, value):
    with pytest.raises(ValueError, match=f"{name} must be an integer >= 0"):
        NaturalAtariVecEnv("Breakout", 2, **{name: value})


def test_chunk_runner_covers_every_row_once_and_reraises():
    from jaxnat.atari.chunks import ChunkRunner

    runner = ChunkRunner(10, 4)
    seen = np.zeros(10, int)

    def mark(lo, hi):
        seen[lo:hi] += 1

    runner.run(mark)
    np.testing.assert_array_equal(seen, 1)
    assert sorted(hi - lo for lo, hi in runner.chunks) == [2, 2, 3, 3]  # near-equal

    def fail_late(lo, hi):
        if hi == 10:
            raise KeyError("chunk error")

    with pytest.raises(KeyError, match="chunk error"):
        runner.run(fail_late)
    calls = []  # `alongside` runs once on the calling thread, the chunks still all run
    runner.run(mark, alongside=lambda: calls.append(threading.get_ident()))
    assert calls == [threading.get_ident()]
    np.testing.assert_array_equal(seen, 2)
    with pytest.raises(KeyError, match="bookkeeping"):  # its error, once the pool is done
        runner.run(mark, alongside=lambda: {}["bookkeeping"])
    np.testing.assert_array_equal(seen[runner.chunks[1][0]:], 3)
    runner.close()
    with pytest.raises(ValueError, match="threads must be an integer >= 1"):
        ChunkRunner(4, 0)


def test_outputs_written_in_place_must_be_contiguous():
    gray = np.zeros((2, 210, 160), np.uint8)
    out = np.zeros((2, 84, 84, 2), np.uint8)
    assert resize_area(gray, (84, 84), out=np.zeros((2, 84, 84), np.uint8)).shape == (2, 84, 84)
    with pytest.raises(ValueError, match="C-contiguous uint8"):
        resize_area(gray, (84, 84), out=out[..., 0])  # a strided view: OpenCV would copy it
