"""`jaxnat play`: a video of a trained run's episodes, read back with PyAV.

The contract: the video is `--episodes` episodes one after another, episode `i` being
`length_i + 1` frames (its reset, then one per step, cut at `--max-steps`), the episodes
`trained.play_episodes` plays with the same key on the test split; a frame is
`compat.frames.Frames`' view, each pixel a `scale`-square block; the fps is the env's
simulated time (MuJoCo) or `STEP_FPS`. Bad command lines are refused in one line before the
policy is loaded.

The Classify run is test_trained's tiny run (trained once for this module). The PixelMuJoCo
video is drawn by `play` with a random-action stand-in for the loaded policy: training and
loading an MJX run takes minutes on a small CPU, and loading is test_trained's contract; what
is play's own (the chase camera from the recorded states, drawn in chunks) is all exercised.
"""

import types

import jax
import numpy as np
import pytest

from jaxnat import cli, play_run
from jaxnat.compat.frames import Frames
from jaxnat.trained import load_policy, play_episodes

from test_trained import FAST, needs_digits, tiny_run  # noqa: F401 (the module-scoped fixture)

av = pytest.importorskip("av")


def _decode(path):
    """(frames as uint8 [n, H, W, 3], the stream's average rate)."""
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        frames = [frame.to_ndarray(format="rgb24") for frame in container.decode(stream)]
        return np.stack(frames), stream.average_rate


@needs_digits
def test_mp4_shows_the_eval_episodes_one_after_another(tiny_run, capsys, monkeypatch):  # noqa: F811
    run_dir = tiny_run[0]
    assert cli.COMMANDS["play"][0] == "jaxnat.play_run"
    loaded = []
    monkeypatch.setattr(play_run, "load_policy", lambda *a, **k: loaded.append(load_policy(*a, **k)) or loaded[-1])
    assert play_run.main([str(run_dir), "--episodes", "2", "--greedy", "--key", "3"], compiler_options=FAST) == 0
    path = run_dir / "videos" / "test-seed0-update2-greedy-key3.mp4"
    assert capsys.readouterr().out.splitlines()[-1] == str(path)  # the path, last, on its own line
    frames, rate = _decode(path)
    policy, = loaded
    assert (policy.seed_index, policy.split) == (0, "test")
    lengths = play_episodes(policy, jax.random.key(3), 2, greedy=True)["length"]  # jaxnat eval's episodes
    assert len(frames) == sum(int(n) + 1 for n in lengths)
    assert frames.shape[1:] == (280, 280, 3)  # 28x28 digits, scale 10: a short side of at least 256
    assert rate == play_run.STEP_FPS  # Classify has no physical time step
    # The first frame is the reset's view (the window in red), up to H.264's loss.
    obs, _ = policy.env.reset(jax.random.split(jax.random.split(jax.random.key(3), 2)[0])[0], policy.env_params)
    expected = np.repeat(np.repeat(Frames(policy.env, policy.env_params)(obs, None), 10, 0), 10, 1)
    assert np.abs(frames[0].astype(int) - expected).mean() < 4


@needs_digits
def test_gif_with_max_steps_scale_and_fps(tiny_run, tmp_path, capsys):  # noqa: F811
    out = tmp_path / "look" / "digits.gif"  # --format from the suffix; the folder is created
    argv = [str(tiny_run[0]), "--out", str(out), "--episodes", "3", "--max-steps", "2", "--scale", "3",
            "--fps", "4", "--split", "train", "--seed-index", "1"]
    result = play_run.play(play_run.tyro.cli(play_run.PlayArgs, args=argv), compiler_options=FAST)
    assert result["path"] == out and result["format"] == "gif" and result["fps"] == 4
    lengths = result["episodes"]["length"]
    assert lengths.shape == (3,) and (lengths <= 2).all()
    frames, _ = _decode(out)
    assert len(frames) == result["frames"] == sum(int(n) + 1 for n in lengths)
    assert frames.shape[1:] == (84, 84, 3) and result["size"] == (84, 84)
    assert not list(out.parent.glob("*.partial*"))  # written whole, then renamed


def test_pixel_mujoco_video_is_the_chase_camera_at_the_physics_rate(tmp_path, monkeypatch):
    """A state-observation PixelMuJoCo env: frames are drawn from the recorded states (in
    chunks, the last one padded), at the env's simulated time."""
    pytest.importorskip("mujoco.mjx")
    import jaxnat

    env, params = jaxnat.make("PixelMuJoCo/Swimmer-v0", autoreset=False, observation="state", height=16, width=16)
    space = env.action_space(params)
    stand_in = types.SimpleNamespace(
        env=env, env_params=params, params=None, normalization=None, algo="random", env_id=env.name,
        seed_value=0, update=0, apply=lambda params, normalizer, obs, key, greedy: space.sample(key))
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / "config.json").write_text("{}")
    monkeypatch.setattr(play_run, "check_args", lambda args: "mp4")  # the stand-in run has no spec
    monkeypatch.setattr(play_run, "load_policy", lambda *args, **kwargs: stand_in)
    monkeypatch.setattr(play_run, "CHUNK", 4)  # 2 x 6 frames: chunks of 4 and a padded 2
    args = play_run.PlayArgs(run_dir=run_dir, max_steps=5)
    result = play_run.play(args)
    assert result["path"] == run_dir / "videos" / "test-seed0-update0-key0.mp4"
    assert (result["episodes"]["length"] == 5).all() and result["episodes"]["unfinished"].all()
    frames, rate = _decode(result["path"])
    assert len(frames) == result["frames"] == 2 * (5 + 1)
    assert frames.shape[1:] == (256, 256, 3)  # the 16x16 camera, scale 16
    frames_of = Frames(env, params)
    assert frames_of.timed and rate == frames_of.fps == result["fps"]  # steps per simulated second
    # The first frame is the chase camera on the reset state.
    first_key = jax.random.split(jax.random.split(jax.random.key(0), 2)[0])[0]
    _, state = env.reset(first_key, params)
    camera = frames_of(None, state)
    assert camera.std() > 0
    expected = np.repeat(np.repeat(camera, 16, 0), 16, 1)
    assert np.abs(frames[0].astype(int) - expected).mean() < 4


def _refused(argv, capsys) -> str:
    assert cli.main(["play", *argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith("jaxnat play: error: ") and err.count("\n") == 1, err
    return err


def test_bad_command_lines_are_refused_in_one_line_before_loading(tmp_path, capsys, monkeypatch):
    def no_loading(*args, **kwargs):
        raise AssertionError("loaded a policy for a bad command line")

    monkeypatch.setattr(play_run, "load_policy", no_loading)
    assert "no such folder" in _refused([str(tmp_path / "missing")], capsys)
    assert "no config.json there" in _refused([str(tmp_path)], capsys)
    err = _refused([str(tmp_path), "--format", "avi"], capsys)
    assert "unknown format 'avi': --format takes mp4 or gif" in err
    err = _refused([str(tmp_path), "--out", str(tmp_path / "v.webm")], capsys)
    assert "--out" in err and "does not end in .mp4: name the file .mp4 or pass --format" in err
    assert "must be at least 1 (got 0)" in _refused([str(tmp_path), "--episodes", "0"], capsys)


@needs_digits
def test_an_unwritable_out_is_refused_before_loading(tiny_run, tmp_path, capsys, monkeypatch):  # noqa: F811
    def no_loading(*args, **kwargs):
        raise AssertionError("loaded a policy for a bad command line")

    monkeypatch.setattr(play_run, "load_policy", no_loading)
    run_dir = tiny_run[0]
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    err = _refused([str(run_dir), "--out", str(blocker / "v.mp4")], capsys)
    assert "cannot write the video in" in err and "pass --out with a writable path" in err
    assert "is a folder: name a file in it" in _refused([str(run_dir), "--out", str(tmp_path)], capsys)
