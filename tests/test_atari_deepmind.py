"""Natural Atari's `preprocessing="deepmind"` (the authors' `wrap_deepmind`): agreement with
Gymnasium's `AtariPreprocessing` where the two overlap, FIRE at reset, lost lives ending the
training episode but not the game, sign-clipped rewards, and the errors."""

from __future__ import annotations

import numpy as np
import pytest

ale_py = pytest.importorskip("ale_py")
pytest.importorskip("numba")  # the atari extra's compositing kernel
gym = pytest.importorskip("gymnasium")

import jaxnat  # noqa: E402
from jaxnat.atari.env import PREPROCESSINGS, NaturalAtariVecEnv  # noqa: E402
from jaxnat.atari.wrappers import ClipRewardWrapper  # noqa: E402


@pytest.fixture(autouse=True)
def isolated_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("JAXNAT_CACHE_DIR", str(tmp_path / "cache"))


def _deepmind(game="Breakout", num_envs=1, **kwargs):
    return NaturalAtariVecEnv(game, num_envs, preprocessing="deepmind", num_threads=1, **kwargs)


def _gymnasium_preprocessing(game):
    """Gymnasium's `AtariPreprocessing` on a frame-by-frame v5 env without sticky actions: the
    authors' settings where it has them (no no-ops here, so that both start alike)."""
    from gymnasium.wrappers import AtariPreprocessing

    gym.register_envs(ale_py)
    return AtariPreprocessing(gym.make(f"ALE/{game}-v5", frameskip=1, repeat_action_probability=0.0),
                              noop_max=0, frame_skip=4, screen_size=84, terminal_on_life_loss=True,
                              grayscale_obs=True, scale_obs=False)


@pytest.mark.parametrize("game", ["Breakout", "SpaceInvaders"])
def test_frames_rewards_and_lost_lives_equal_gymnasium_atari_preprocessing(game):
    # Both pool ALE's gray screens of the last two skipped frames and resize with OpenCV's
    # INTER_AREA (ale-py in C++, Gymnasium in Python): the frames are equal, bit for bit, up to
    # the first lost life. At that step Gymnasium stops the frame skip and ends the game; here
    # the skip runs on and the game goes on (baselines' MaxAndSkipEnv and EpisodicLifeEnv), so
    # from there on the two differ by design. ALE's seeds differ (Gymnasium hashes its seed)
    # but without sticky actions or no-ops nothing random is left.
    ours = _deepmind(game, noop_max=0)
    ours.reset(seed=0)
    ref = _gymnasium_preprocessing(game)
    ref.reset(seed=0)
    ref.unwrapped.ale.act(ale_py.Action.FIRE)  # ale-py's FIRE at reset: one frame
    rng = np.random.default_rng(0)
    scores = []
    for t in range(300):
        action = int(rng.integers(ours.single_action_space.n))
        obs, reward, terminated, truncated, info = ours.step(np.array([action]))
        ref_obs, ref_reward, ref_terminated, ref_truncated, _ = ref.step(action)
        assert terminated[0] == ref_terminated and not truncated[0] and not ref_truncated
        if ref_terminated:  # the first lost life
            assert info["life_lost"][0] and not info["returned_episode"][0]
            break
        np.testing.assert_array_equal(obs[0, ..., -1], ref_obs)
        assert info["unclipped_reward"][0] == ref_reward and reward[0] == np.sign(ref_reward)
        scores.append(ref_reward)
    else:
        pytest.fail(f"no life lost in {game} within 300 steps")
    assert t > 10
    if game == "SpaceInvaders":  # scores of 5 and more: the clipping shows
        assert max(scores) > 1
    ours.close()
    ref.close()


def test_fire_at_reset_and_a_lost_life_ends_the_training_episode_not_the_game():
    # Breakout serves the ball on FIRE only: with NOOPs alone the standard env never loses a
    # life, the deepmind one loses one to the ball its reset served.
    standard = NaturalAtariVecEnv("Breakout", 1, sticky_actions=0.0, noop_max=0, num_threads=1)
    ours = _deepmind(noop_max=0)
    standard.reset(seed=0)
    obs, info = ours.reset(seed=0)
    assert info["lives"][0] == 5
    noop = np.zeros(1, np.int64)
    for t in range(100):
        *_, info_standard = standard.step(noop)
        assert info_standard["lives"][0] == 5 and "life_lost" not in info_standard
        obs, reward, terminated, truncated, info = ours.step(noop)
        if terminated[0]:
            break
    assert info["life_lost"][0] and info["lives"][0] == 4 and not truncated[0]
    assert not info["returned_episode"][0]  # the game goes on
    assert (obs[..., :3] == 0).all() and (obs[..., 3] > 0).any()  # a new frame stack
    final = info["final_observation"]
    assert (final[..., :3] > 0).any() and np.array_equal(final[..., 3], obs[..., 3])
    lost_at = t + 1
    for t in range(20):  # no reset: the lives stay 4, the steps and the score keep counting
        obs, reward, terminated, truncated, info = ours.step(noop)
        assert info["lives"][0] == 4 and not (terminated | truncated | info["life_lost"]).any()
    assert (obs[..., 0] > 0).any()
    assert lost_at > 5


def test_episode_statistics_are_whole_games_with_unclipped_scores():
    env = _deepmind("SpaceInvaders")
    env.reset(seed=1)
    unclipped, clipped, life_losses = 0.0, 0.0, 0
    for t in range(3000):
        _, reward, terminated, truncated, info = env.step(np.array([1]))  # FIRE, standing still
        unclipped += info["unclipped_reward"][0]
        clipped += reward[0]
        assert reward[0] == np.sign(info["unclipped_reward"][0])
        life_losses += int(info["life_lost"][0])
        assert not (info["life_lost"][0] and info["returned_episode"][0])
        if info["returned_episode"][0]:
            break
    assert terminated[0] and not info["life_lost"][0]  # game over
    assert life_losses == 2 and info["lives"][0] == 3  # the next game's lives (same-step reset)
    assert info["returned_episode_lengths"][0] == t + 1
    assert info["returned_episode_returns"][0] == unclipped > clipped > 0  # scores of 5 and more


def test_next_step_autoreset_resets_a_lost_life_with_a_noop_and_no_reward():
    env = _deepmind(autoreset_mode="next_step", noop_max=0)
    env.reset(seed=0)
    noop = np.zeros(1, np.int64)
    for t in range(100):
        obs, reward, terminated, truncated, info = env.step(noop)
        if terminated[0]:
            break
    assert info["life_lost"][0] and (obs[..., :3] > 0).any()  # the final observation itself
    obs, reward, terminated, truncated, info = env.step(np.array([1]))  # FIRE, ignored
    assert reward[0] == 0 and not (terminated | truncated | info["life_lost"]).any()
    assert (obs[..., :3] == 0).all() and info["lives"][0] == 4
    for t in range(60):  # the FIRE was not pressed: nothing serves the ball, no life is lost
        *_, terminated, _, info = env.step(noop)
        assert not terminated[0] and info["lives"][0] == 4


def test_gymnasium_adapter_takes_the_deepmind_preprocessing():
    from jaxnat.compat.gymnasium import make_gymnasium_vec

    vec = make_gymnasium_vec("NaturalAtari/Breakout-v0", 2, preprocessing="deepmind", noop_max=0,
                             seed=0, num_threads=1)
    vec.reset(seed=0)
    for _ in range(100):
        obs, reward, terminated, truncated, info = vec.step(np.zeros(2, np.int64))
        if terminated.any():
            break
    assert terminated.all() and info["life_lost"].all() and info["_life_lost"].all()
    assert not info["_returned_episode_returns"].any()
    vec.close()


def test_games_without_fire_start_as_without_the_preset():
    # Freeway's action set has no FIRE: the deepmind reset presses nothing.
    assert not any(a == ale_py.Action.FIRE for a in _minimal_actions("freeway"))
    standard = NaturalAtariVecEnv("Freeway", 1, sticky_actions=0.0, noop_max=0, num_threads=1)
    ours = _deepmind("Freeway", noop_max=0)
    np.testing.assert_array_equal(ours.reset(seed=0)[0], standard.reset(seed=0)[0])
    for t in range(5):
        np.testing.assert_array_equal(ours.step(np.ones(1, np.int64))[0], standard.step(np.ones(1, np.int64))[0])


def _minimal_actions(rom):
    ale = ale_py.ALEInterface()
    ale.setLoggerMode(ale_py.LoggerMode.Error)
    ale.loadROM(ale_py.roms.get_rom_path(rom))
    return ale.getMinimalActionSet()


def test_sticky_actions_follow_the_preset_unless_stated():
    assert PREPROCESSINGS["deepmind"][0] == 0.0 and PREPROCESSINGS["standard"][0] == 0.25
    for preprocessing, sticky, expected in (("standard", None, 0.25), ("deepmind", None, 0.0),
                                            ("deepmind", 0.25, 0.25), ("standard", 0.0, 0.0)):
        env = jaxnat.make_vec("NaturalAtari/Breakout-v0", 1, preprocessing=preprocessing,
                              sticky_actions=sticky, num_threads=1)
        assert env.sticky_actions == expected and env.preprocessing == preprocessing
        env.close()


def test_unknown_preprocessing_is_a_one_line_error():
    with pytest.raises(ValueError, match=r"preprocessing must be one of \('standard', 'deepmind'\), "
                                         r"got 'nature'") as error:
        jaxnat.make_vec("NaturalAtari/Breakout-v0", 1, preprocessing="nature")
    assert "\n" not in str(error.value)


def test_clip_reward_wrapper_keeps_the_envs_unclipped_reward():
    env = ClipRewardWrapper(_deepmind("SpaceInvaders"))
    env.reset(seed=0)
    seen = []
    for t in range(150):
        _, reward, *_, info = env.step(np.array([t % 2]))  # NOOP and FIRE: SpaceInvaders scores
        np.testing.assert_array_equal(reward, np.sign(info["unclipped_reward"]))
        seen.append(info["unclipped_reward"][0])
    assert max(seen) > 1


def _write_video(path, video: int, num_frames: int):
    """Uniform gray frames of level 20 + 40 * video + 2 * frame, lossless (FFV1)."""
    import cv2

    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"FFV1"), 10, (40, 30))
    assert writer.isOpened()
    for f in range(num_frames):
        writer.write(np.full((30, 40, 3), 20 + 40 * video + 2 * f, np.uint8))
    writer.release()


def test_a_lost_life_keeps_its_video_while_a_game_over_beside_it_starts_a_new_one(tmp_path):
    # Env 1 FIREs at every step and loses its last life at step 121; env 0 serves once, at step
    # 97, and loses a life at the same step: one final observation of each kind in one batch.
    for v in range(4):
        _write_video(tmp_path / f"clip{v}.avi", v, 12 + v)
    env = _deepmind(num_envs=2, noop_max=0, background="video", split="all", video_sources=str(tmp_path))
    bank = env.background_bank
    levels = bank.frames[:, 0, 0, 0].astype(int)
    assert len(set(levels)) == len(levels)  # every bank frame is recognisable
    index = {level: i for i, level in enumerate(levels)}
    starts = set(np.asarray(bank.starts).tolist())

    def position(frame):  # the background's bank frame: most of Breakout's field is black
        return index[int(np.bincount(frame.ravel()).argmax())]

    def follows(before, after):  # one video frame on, or a new video's first at a video's end
        return after in starts if before + 1 in starts or before + 1 == len(levels) else after == before + 1

    obs, _ = env.reset(seed=0)
    for t in range(121):
        previous = obs
        obs, _, terminated, _, info = env.step(np.array([1 if t == 96 else 0, 1]))
        assert terminated[0] == (t in (23, 120))
    np.testing.assert_array_equal(info["life_lost"], [True, False])
    np.testing.assert_array_equal(info["returned_episode"], [False, True])
    final = info["final_observation"]
    assert (obs[..., :3] == 0).all()  # both start a frame stack
    np.testing.assert_array_equal(final[..., :3], previous[..., 1:])
    # the lost life: the game's own screen on the video it kept
    np.testing.assert_array_equal(final[0, ..., 3], obs[0, ..., 3])
    assert follows(position(previous[0, ..., 3]), position(obs[0, ..., 3]))
    # the game over: its last frame on the old video's next frame, then a new video
    assert follows(position(previous[1, ..., 3]), position(final[1, ..., 3]))
    assert not np.array_equal(final[1, ..., 3], obs[1, ..., 3])
    env.close()
