"""`jaxnat.trained.sweep_episodes` and `jaxnat sweep`: a generalisation curve in one program.

The contract: `sweep_episodes(policy, key, n, **values)` traces the episode once for the whole
grid, and its row `i` is, exactly, `play_episodes` on the policy's env params with the dial set
to strength `i`, with the same key (common random numbers); at the run's own strength it is
`jaxnat eval`'s episodes. Bad command lines are refused in one line; all but a value out of
range before the policy is loaded, that one before the sweep compiles.

The run is test_trained's tiny Classify/Digits-v0 PPO run (trained once for this module).
"""

import dataclasses
import json
import re

import jax
import numpy as np
import pytest

from jaxnat import cli, eval_run, sweep_run
from jaxnat.trained import load_policy, play_episodes, sweep_episodes

from test_trained import FAST, needs_digits, tiny_run  # noqa: F401 (the module-scoped fixture)

SIGMAS = np.array([0.0, 32.0, 96.0], np.float32)


@pytest.fixture(scope="module")
def policy(tiny_run):  # noqa: F811
    return load_policy(tiny_run[0], compiler_options=FAST)


def _counting_reset(monkeypatch, policy):
    traces = []
    reset = type(policy.env).reset
    monkeypatch.setattr(type(policy.env), "reset", lambda self, *a, **k: traces.append(1) or reset(self, *a, **k))
    return traces


@needs_digits
def test_one_trace_and_each_strength_is_its_own_evaluation(policy, monkeypatch):
    traces = _counting_reset(monkeypatch, policy)
    curve = sweep_episodes(policy, jax.random.key(4), 6, greedy=True, noise_sigma=SIGMAS)
    assert len(traces) == 1  # the whole grid: one trace of the episode
    assert curve["return"].shape == curve["terminated"].shape == (3, 6)
    for i, sigma in enumerate(SIGMAS):
        params = policy.env_params.replace(distraction=policy.env_params.distraction.replace(noise_sigma=sigma))
        alone = play_episodes(dataclasses.replace(policy, env_params=params), jax.random.key(4), 6, greedy=True)
        for name in ("return", "length", "terminated", "unfinished"):
            np.testing.assert_array_equal(curve[name][i], alone[name], err_msg=f"{name} at sigma {sigma}")
    # Sampled actions too: the same keys at every strength, so sigma 0 is the plain evaluation.
    sampled = sweep_episodes(policy, jax.random.key(5), 6, noise_sigma=SIGMAS[:1])
    plain = play_episodes(policy, jax.random.key(5), 6)
    for name in ("return", "length", "terminated"):
        np.testing.assert_array_equal(sampled[name][0], plain[name])


@needs_digits
def test_bad_sweeps_are_one_line_value_errors(policy):
    with pytest.raises(ValueError, match=r"dial has no 'video_alpha'; its fields: noise_sigma, background_alpha$"):
        sweep_episodes(policy, jax.random.key(0), 2, video_alpha=np.array([0.5]))
    with pytest.raises(ValueError, match=r"noise_sigma must be a finite number >= 0"):
        sweep_episodes(policy, jax.random.key(0), 2, noise_sigma=np.array([0.0, -1.0]))


@needs_digits
def test_jaxnat_sweep_prints_the_curve_and_writes_json(tiny_run, capsys):  # noqa: F811
    run_dir = tiny_run[0]
    assert cli.COMMANDS["sweep"][0] == "jaxnat.sweep_run"
    argv = [str(run_dir), "--param", "noise_sigma", "--values", "0", "32", "96", "--episodes", "8", "--greedy",
            "--key", "2"]
    assert sweep_run.main(argv, compiler_options=FAST) == 0
    out = capsys.readouterr().out
    path = run_dir / "sweeps" / "noise_sigma-test-seed0-update2-greedy-key2.json"
    assert out.splitlines()[-1] == str(path)
    assert "trained at noise_sigma off (the plain env)" in out
    assert re.search(r"\n +96  [-+]\d\.\d{4} \[[-+]\d\.\d{4}, [-+]\d\.\d{4}\]  \d+\.\d% \[", out), out
    saved = json.loads(path.read_text())
    assert saved["values"] == [0.0, 32.0, 96.0] and saved["common_random_numbers"] and saved["trained_at"] is None
    assert [len(row["episode_returns"]) for row in saved["rows"]] == [8, 8, 8]
    # At strength 0 the observations are the plain env's (the run's), so the row is jaxnat
    # eval's, with the same key and episodes.
    ours = eval_run.evaluate(eval_run.tyro.cli(eval_run.EvalArgs, args=[str(run_dir), "--episodes", "8", "--greedy",
                                                                          "--key", "2"]), compiler_options=FAST)
    row = saved["rows"][0]
    assert row["return"] == dataclasses.asdict(ours["return"])
    assert row["accuracy"] == dataclasses.asdict(ours["accuracy"]) and row["length"] == ours["length"]


@needs_digits
def test_bad_command_lines_are_refused_in_one_line(tiny_run, tmp_path, monkeypatch, capsys):  # noqa: F811
    run_dir = str(tiny_run[0])
    loaded = []
    monkeypatch.setattr(sweep_run, "load_policy", lambda *a, **k: loaded.append(1) or load_policy(*a, **k))
    cases = [
        ([str(tmp_path / "missing"), "--param", "noise_sigma", "--values", "0"], r"is not a run directory: no such folder", 0),
        ([run_dir, "--param", "video_alpha", "--values", "0"],
         r"Classify/Digits-v0's distraction dial has no 'video_alpha'; its fields: noise_sigma, background_alpha$", 0),
        ([run_dir, "--param", "noise_sigma", "--values", "0", "nan"], r"--values must be finite numbers", 0),
        ([run_dir, "--param", "noise_sigma", "--values", "0", "-4"],
         r"--values: noise_sigma must be a finite number >= 0, got \[ 0. -4.\]$", 1),
    ]
    for argv, message, loads in cases:
        loaded.clear()
        assert sweep_run.main(argv, compiler_options=FAST) == 2
        err = capsys.readouterr().err
        assert err.startswith("jaxnat sweep: error: ") and err.count("\n") == 1, err
        assert re.search(message, err.strip()), err
        assert len(loaded) == loads


@needs_digits
def test_a_run_on_an_env_without_a_dial_is_refused(tiny_run, tmp_path, capsys):  # noqa: F811
    config = json.loads((tiny_run[0] / "config.json").read_text())
    config["spec"]["env_id"] = "MuJoCo/HalfCheetah-v0"  # state observations: no distraction to dial
    (tmp_path / "config.json").write_text(json.dumps(config))
    assert sweep_run.main([str(tmp_path), "--param", "noise_sigma", "--values", "0"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("jaxnat sweep: error: "), err
    assert "trained on MuJoCo/HalfCheetah-v0, which has no distraction dial" in err
    assert sweep_run._dial_of("PixelMuJoCo/HalfCheetah-v0") == ("video_alpha", "frame_rate", "sky_alpha", "noise_sigma",
                                                              "num_videos")


def test_the_env_refuses_a_strength_it_would_ignore():
    """`sweep_params` checks the swept params with the env too: PixelMuJoCo's checker floor has no
    video to blend (a stand-in policy: the check needs only the env and its params)."""
    import types

    import jaxnat
    from jaxnat.trained import sweep_params

    env, params = jaxnat.make("PixelMuJoCo/HalfCheetah-v0", autoreset=False)
    stand_in = types.SimpleNamespace(env=env, env_params=params, env_id="PixelMuJoCo/HalfCheetah-v0")
    with pytest.raises(ValueError, match=r'video_alpha, frame_rate and sky_alpha need floor="video"'):
        sweep_params(stand_in, video_alpha=np.array([0.0, 0.5]))
    with pytest.raises(ValueError, match=r"frame_rate must be a whole number"):
        sweep_params(stand_in, frame_rate=np.array([0.0, 1.5]))


@needs_digits
def test_out_names_the_json_and_a_folder_is_refused(tiny_run, policy, tmp_path, monkeypatch, capsys):  # noqa: F811
    monkeypatch.setattr(sweep_run, "load_policy", lambda *a, **k: policy)  # this module's, loaded once
    argv = [str(tiny_run[0]), "--param", "noise_sigma", "--values", "8", "--episodes", "2"]
    assert sweep_run.main([*argv, "--out", str(tmp_path)]) == 2
    assert "is a folder: name a file in it" in capsys.readouterr().err
    out = tmp_path / "curves" / "digits.json"
    assert sweep_run.main([*argv, "--out", str(out)]) == 0
    assert capsys.readouterr().out.splitlines()[-1] == str(out)
    assert json.loads(out.read_text())["values"] == [8.0]
