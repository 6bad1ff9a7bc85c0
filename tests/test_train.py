"""`jaxnat train`: the run directory, exact resume, and one-line errors.

The runs are tiny (Classify/Digits-v0, 2 seeds x 8 envs x 16 steps, 4 updates in 2 chunks, 16
test episodes). Programs compile with XLA's backend optimisation off, which
compiles about 3x faster on CPU; compiled programs are reused within the process, so the
interrupted and resumed runs of the resume test do not compile again.
"""

import collections
import json
import os

import jax
import numpy as np
import pytest

import dataclasses

from jaxnat import cli, train
from jaxnat.agents import ALGORITHMS
from jaxnat.training import checkpoints
from jaxnat.training import command as train_command
from jaxnat.training import spec as spec_module

FAST = {"xla_backend_optimization_level": 0}
TINY = ["--env-id", "Classify/Digits-v0", "--algo", "ppo", "--seeds", "2", "--num-envs", "8",
        "--num-steps", "16", "--total-timesteps", "512", "--eval-every", "2",
        "--eval-episodes", "16", "--trunk", "mnist"]


def _digits_available() -> bool:
    from jaxnat.datasets import DatasetNotFoundError, load

    try:
        load("digits", "test")
    except DatasetNotFoundError:
        return False
    return True


needs_digits = pytest.mark.skipif(not _digits_available(), reason="Classify/Digits-v0 data not installed")


def _lines(path):
    return [json.loads(line) for line in path.read_text().splitlines()]


def _error(capsys) -> str:
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert err.startswith("jaxnat train: error: "), err
    return err


def _not_reached(*_, **__):
    raise AssertionError("compiled: the error should have come first")


def _check_run_dir(run_dir):
    config = json.loads((run_dir / "config.json").read_text())
    spec = config["spec"]
    assert spec["env_id"] == "Classify/Digits-v0" and spec["algo"] == "ppo"
    assert set(spec["config"]) == {f.name for f in dataclasses.fields(ALGORITHMS["ppo"].config)}
    assert spec["config"]["trunk"] == "mnist" and spec["config"]["num_steps"] == 16
    assert "trunk" in spec["static_fields"] and "lr" not in spec["static_fields"]
    assert spec["num_updates"] == 4 and spec["seed_values"] == [0, 1]
    assert {"jax", "jaxnat"} <= set(config["versions"])

    metrics = _lines(run_dir / "metrics.jsonl")
    assert [(m["update"], m["seed"]) for m in metrics] == [(u, s) for u in range(1, 5) for s in (0, 1)]
    assert metrics[-1]["env_steps"] == 512
    assert {"episode_return", "terminated_fraction", "policy_loss", "value_loss", "entropy"} <= set(metrics[0])

    evals = _lines(run_dir / "eval.jsonl")  # the untrained policy, then after each chunk
    assert [(e["update"], e["seed"]) for e in evals] == [(u, s) for u in (0, 2, 4) for s in (0, 1)]
    assert {"greedy_return", "greedy_terminated_fraction", "sampled_return"} <= set(evals[0])

    assert (run_dir / "curve.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["complete"] and summary["env_steps_per_seed"] == 512
    # The baseline printed and plotted beside the results: 10 labels, a guess until right or M.
    assert 0.0 < summary["chance"]["terminated_fraction"] < 1.0 and summary["chance"]["return"] < 1.0
    for name in ("train_return", "test_greedy_return", "test_greedy_accuracy", "test_sampled_return"):
        assert len(summary["metrics"][name]["per_seed"]) == 2
    assert summary["metrics"]["test_greedy_return"]["per_seed"] == [e["greedy_return"] for e in evals[-2:]]
    steps = sorted(int(p.name) for p in (run_dir / "checkpoints").iterdir() if p.name.isdigit())
    assert steps == [2, 4]  # one per chunk, step = update


@needs_digits
def test_run_and_exact_resume(tmp_path, capsys):
    """One test, so that its three runs share one compilation even under pytest-xdist."""
    full, resumed = tmp_path / "full", tmp_path / "resumed"
    assert train.main([*TINY, "--run-dir", str(full)], compiler_options=FAST) == 0
    _check_run_dir(full)

    # Stop after the first of two chunks, then resume: bit-for-bit the uninterrupted run.
    assert train.main([*TINY, "--run-dir", str(resumed)], compiler_options=FAST, stop_after_chunks=1) == 0
    assert json.loads((resumed / "summary.json").read_text())["complete"] is False
    assert train.main(["--resume", str(resumed)], compiler_options=FAST) == 0
    _check_run_dir(resumed)
    (expected, _), (actual, meta) = (train.load_checkpoint(d, compiler_options=FAST) for d in (full, resumed))
    assert meta["update"] == 4 and meta["chunk"] == 2
    leaves = jax.tree.leaves(expected.train_state.params)
    assert len(leaves) > 0
    for a, b in zip(leaves, jax.tree.leaves(actual.train_state.params), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    for a, b in zip(jax.tree.leaves(checkpoints.to_saveable(expected)),
                    jax.tree.leaves(checkpoints.to_saveable(actual)), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))  # optimizer, env state, keys
    assert (resumed / "metrics.jsonl").read_text() == (full / "metrics.jsonl").read_text()
    timing = ("chunk_seconds", "steps_per_second")
    strip = lambda rows: [{k: v for k, v in r.items() if k not in timing} for r in rows]  # noqa: E731
    assert strip(_lines(resumed / "eval.jsonl")) == strip(_lines(full / "eval.jsonl"))

    # A checkpoint written before RunnerState had its `memory` and `normalizer` fields (None for
    # a feed-forward policy on images) restores into today's runner.
    fields = [name for name in expected._fields if name not in ("memory", "normalizer")]
    OldRunnerState = collections.namedtuple("RunnerState", fields)
    old = checkpoints.Checkpoints(tmp_path / "old")
    old.manager.save(4, args=old.ocp.args.Composite(
        state=old.ocp.args.StandardSave(checkpoints.to_saveable(OldRunnerState(*(getattr(expected, f) for f in fields)))),
        meta=old.ocp.args.JsonSave({"update": 4})))
    old.manager.wait_until_finished()
    restored, _ = old.restore(expected)
    old.close()
    assert restored.memory is None
    for a, b in zip(jax.tree.leaves(checkpoints.to_saveable(expected)),
                    jax.tree.leaves(checkpoints.to_saveable(restored)), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))

    # Arguments that contradict the run's config are refused.
    capsys.readouterr()
    assert train.main(["--resume", str(full), "--lr", "0.1"], compiler_options=FAST) == 2
    assert "--lr" in _error(capsys)


def test_unknown_env_id_names_close_match(tmp_path, capsys):
    assert train.main(["--env-id", "Classify/Digit-v0", "--run-dir", str(tmp_path / "r")]) == 2
    err = _error(capsys)
    assert "Classify/Digits-v0" in err and err.count("\n") == 1
    assert not (tmp_path / "r").exists()


def test_unknown_algo(tmp_path, capsys):
    assert train.main(["--algo", "ppo2", "--run-dir", str(tmp_path / "r")]) == 2
    assert "'ppo'" in _error(capsys)


def test_unknown_trunk_is_refused_before_the_env_is_built(tmp_path, capsys, monkeypatch):
    from jaxnat.training import command as train_command

    monkeypatch.setattr(train_command, "make_envs", lambda spec: pytest.fail("the env was built"))
    assert train.main(["--trunk", "resnet", "--run-dir", str(tmp_path / "r")]) == 2
    err = _error(capsys)
    assert "unknown trunk 'resnet' (did you mean 'resnet18'?)" in err and err.count("\n") == 1


@needs_digits
@pytest.mark.parametrize("argv, message", [
    (["--env-kwargs", "bogus=1"], "bogus"),
    (["--env-kwargs", "split=test"], "split"),
    (["--trunk", "atari"], "atari"),
    (["--algo", "a2c", "--clip-eps", "0.2"], "--clip-eps"),
    (["--env-parts", "2"], "--env-parts applies to host-batched envs (NaturalAtari/*); Classify/Digits-v0 is a JAX env"),
    (["--env-parts", "0"], "--env-parts must be at least 1"),
])
def test_setup_errors(argv, message, tmp_path, capsys):
    assert train.main([*argv, "--run-dir", str(tmp_path / "r")]) == 2
    assert message in _error(capsys)


@needs_digits
@pytest.mark.parametrize("argv, message", [
    (["--num-envs", "0"], "--num-envs must be at least 1"),
    (["--num-envs", "-8"], "--num-envs must be at least 1"),
    (["--num-steps", "0"], "--num-steps must be at least 1"),
    (["--total-timesteps", "0"], "--total-timesteps must be at least 1"),
    (["--total-timesteps", "-512"], "--total-timesteps must be at least 1"),
    (["--seeds", "0"], "--seeds must be at least 1"),
    (["--eval-episodes", "-1"], "--eval-episodes must be at least 1"),
    (["--total-timesteps", "100"], "--total-timesteps 100 is less than one rollout of 128 env steps"),
])
def test_counts_are_refused_in_one_line_before_compiling(argv, message, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(train_command, "compiled_program", _not_reached)
    small = ["--trunk", "mnist", "--num-envs", "8", "--num-steps", "16"]
    assert train.main([*small, *argv, "--run-dir", str(tmp_path / "r")]) == 2
    err = _error(capsys)
    assert message in err and err.count("\n") == 1, err
    assert not (tmp_path / "r").exists()


@needs_digits
@pytest.mark.parametrize("argv, message", [
    (["--lr", "-1"], "lr=-1.0 is out of range: lr must be > 0"),
    (["--gamma", "1.5"], "gamma=1.5 is out of range: gamma must be in (0, 1]"),
    (["--algo", "dqn", "--eps-end", "1.5"], "eps_end=1.5 is out of range: eps_end must be in [0, 1]"),
])
def test_config_values_out_of_range_are_refused_before_compiling(argv, message, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(train_command, "compiled_program", _not_reached)
    assert train.main([*argv, "--run-dir", str(tmp_path / "r")]) == 2
    err = _error(capsys)
    assert message in err and err.count("\n") == 1, err


@pytest.mark.parametrize("env_id", ["Classify/Digits-v0", "NaturalAtari/Breakout-v0"])
def test_an_unwritable_run_dir_is_refused_before_building_anything(env_id, tmp_path, capsys, monkeypatch):
    for name in ("make_envs", "new_host_spec", "compiled_program"):
        monkeypatch.setattr(train_command, name, _not_reached)
    blocker = tmp_path / "file"
    blocker.write_text("")
    for run_dir in (blocker / "run", blocker):  # under a regular file, and the file itself
        assert train.main(["--env-id", env_id, "--run-dir", str(run_dir)]) == 2
        err = _error(capsys)
        assert f"--run-dir {run_dir} is not writable" in err and err.count("\n") == 1, err
    if os.geteuid() != 0:  # (root writes anywhere)
        locked = tmp_path / "locked"
        locked.mkdir(mode=0o500)
        assert train.main(["--env-id", env_id, "--run-dir", str(locked / "run")]) == 2
        assert "is not writable" in _error(capsys)
    assert sorted(p.name for p in tmp_path.iterdir()) in (["file"], ["file", "locked"])


def test_the_curve_is_drawn_through_updates_without_finished_episodes(tmp_path, monkeypatch):
    """Updates in which no episode ended have no train return (NaN): the curve is a line through
    the updates that have one, not isolated (invisible) points between gaps."""
    from matplotlib.figure import Figure

    from jaxnat.training import records

    figures = []
    monkeypatch.setattr(Figure, "savefig", lambda figure, *_, **__: figures.append(figure))
    spec = spec_module.RunSpec("Classify/Digits-v0", {}, "ppo", ALGORITHMS["ppo"].config(num_envs=8, num_steps=16),
                               seeds=2, seed=0, eval_every=2, eval_episodes=16)
    returns = {1: (1.0, 2.0), 2: (None, None), 3: (3.0, None), 4: (None, None), 5: (5.0, 6.0), 6: (None, None)}
    rows = [{"update": u, "seed": s, "episode_return": r[s], "terminated_fraction": r[s]}
            for u, r in returns.items() for s in (0, 1)]
    records.plot(tmp_path / "curve.png", spec, records.History.load(spec, rows, []))
    for ax in figures[0].axes[:2]:
        train = ax.lines[0]
        np.testing.assert_array_equal(train.get_xdata(), [128, 384, 640])  # updates 1, 3, 5 x 128 steps
        np.testing.assert_array_equal(train.get_ydata(), [1.5, 3.0, 5.5])


def test_env_kwargs_with_a_string_default_stay_strings():
    # `background=none` names Natural Atari's "none" background: `none` reads as None only where
    # the constructor's default is not a string.
    assert train.parse_env_kwargs(["start=none", "M=none", "w=3"], "Classify/Digits-v0") == {
        "start": "none", "M": None, "w": 3}
    assert train.parse_env_kwargs(["start=none"]) == {"start": None}


def test_parse_env_kwargs():
    assert train.parse_env_kwargs(["w=3", "correct_reward=0.5", "start=center", "flag=true", "x=none"]) == {
        "w": 3, "correct_reward": 0.5, "start": "center", "flag": True, "x": None}
    with pytest.raises(train.TrainError):
        train.parse_env_kwargs(["w"])


@pytest.mark.parametrize("name", ["split", "video_split"])
def test_split_kwargs_are_refused_on_every_path(name):
    # One check for the device path (`programs.make_envs`) and the host path (`host.py`).
    from jaxnat.training.args import check_split_kwargs
    with pytest.raises(train.TrainError, match=f"env kwarg '{name}' is set by jaxnat train"):
        check_split_kwargs({"w": 3, name: "test"})
    check_split_kwargs({"w": 3, "floor": "video"})


def test_auto_eval_every():
    assert spec_module.auto_eval_every(976) == 61  # PPO defaults: a divisor near 976 / 20
    assert spec_module.auto_eval_every(977) == 49  # prime: one shorter last chunk
    assert spec_module.auto_eval_every(7) == 1


def test_cli_dispatch(capsys):
    assert cli.main(["--help"]) == 0
    assert "train" in capsys.readouterr().out
    assert cli.main(["trian"]) == 2
    assert "'train'" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_:
        cli.main(["train", "--help"])
    assert exit_.value.code == 0
    out = capsys.readouterr().out
    assert "--env-id" in out and "--resume" in out and "--clip-eps" in out


@needs_digits
def test_recurrent_run_resumes_exactly(tmp_path):
    """A recurrent policy's memory (GRU state, previous action and reward per env) is part of
    the checkpoint: the resumed run ends bit-for-bit where the uninterrupted one does."""
    argv = [*TINY, "--memory", "8", "--num-minibatches", "2"]
    full, resumed = tmp_path / "full", tmp_path / "resumed"
    assert train.main([*argv, "--run-dir", str(full)], compiler_options=FAST) == 0
    assert train.main([*argv, "--run-dir", str(resumed)], compiler_options=FAST, stop_after_chunks=1) == 0
    assert train.main(["--resume", str(resumed)], compiler_options=FAST) == 0
    (expected, _), (actual, _) = (train.load_checkpoint(d, compiler_options=FAST) for d in (full, resumed))
    assert len(jax.tree.leaves(expected.memory)) == 4
    for a, b in zip(jax.tree.leaves(checkpoints.to_saveable(expected)),
                    jax.tree.leaves(checkpoints.to_saveable(actual)), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


@needs_digits
def test_damaged_run_directories_are_refused_in_one_line(tmp_path, capsys):
    """Resuming a damaged run never starts over and never prints a traceback: one line says what
    is wrong and what to do, and the run directory is left as it was."""
    import shutil

    run = tmp_path / "run"
    assert train.main([*TINY, "--run-dir", str(run)], compiler_options=FAST) == 0  # checkpoints at 2 and 4

    def damaged(name, damage):
        copy = tmp_path / name
        shutil.copytree(run, copy)
        damage(copy)
        before = {p: p.read_bytes() for p in copy.rglob("*") if p.is_file()}
        capsys.readouterr()
        assert train.main(["--resume", str(copy)], compiler_options=FAST) == 2
        assert {p: p.read_bytes() for p in copy.rglob("*") if p.is_file()} == before
        return _error(capsys)

    assert "config.json is not readable JSON" in damaged(
        "bad_json", lambda d: (d / "config.json").write_text("{not json"))

    def drop_config(d):
        saved = json.loads((d / "config.json").read_text())
        del saved["spec"]["config"]
        (d / "config.json").write_text(json.dumps(saved))

    assert "run spec is damaged" in damaged("no_config", drop_config)
    assert "holds no checkpoint" in damaged("no_checkpoints", lambda d: shutil.rmtree(d / "checkpoints"))
    err = damaged("no_state", lambda d: shutil.rmtree(d / "checkpoints" / "4" / "state"))
    assert "checkpoint 4" in err and "is damaged" in err

    def truncate_largest(d):
        largest = max((p for p in (d / "checkpoints" / "4").rglob("*") if p.is_file()), key=lambda p: p.stat().st_size)
        largest.write_bytes(largest.read_bytes()[: largest.stat().st_size // 2])

    assert "is damaged" in damaged("truncated", truncate_largest)

    # A flag given at its default value still has to match the run's (the run has 2 seeds).
    capsys.readouterr()
    assert train.main(["--resume", str(run), "--seeds", "5"], compiler_options=FAST) == 2
    assert "--seeds" in _error(capsys)


def test_progress_without_a_terminal_prints_plain_lines():
    """Output to a file (CI, a log) gets a plain line with steps/s and the ETA at least every
    `interval` seconds; a terminal gets the live bar only."""
    import io
    import types

    from rich.console import Console

    from jaxnat.training.progress import Progress

    spec = types.SimpleNamespace(num_updates=10, steps_per_update=64, devices=1, shard=None)
    out = io.StringIO()
    progress = Progress(Console(file=out, width=80), spec, seeds=2, start_update=0, interval=0.0)
    for update in range(1, 4):
        for _ in range(2):  # once per seed
            progress(update, {"episode_return": 0.5})
    lines = out.getvalue().splitlines()
    assert len(lines) == 3 and lines[-1].startswith("update 3/10 · ") and "steps/s · eta " in lines[-1]
    assert all(len(line) <= 80 for line in lines)
    quiet = io.StringIO()
    live = Progress(Console(file=quiet, width=80, force_terminal=True), spec, seeds=2, start_update=0, interval=0.0)
    live(1, {"episode_return": 0.5})
    live(1, {"episode_return": 0.5})
    assert "update 1/10" not in quiet.getvalue()


def test_dqn_runs_saved_before_the_loss_option_resume_with_huber():
    from jaxnat.agents import DQNConfig
    from jaxnat.training import RunSpec

    spec = RunSpec("Classify/Digits-v0", {}, "dqn", DQNConfig(trunk="mnist"), 2, 0, 1, 10)
    saved = spec.to_json()
    assert RunSpec.from_json(saved).config.loss == "mse"  # today's default, saved explicitly
    del saved["config"]["loss"]
    assert RunSpec.from_json(saved).config.loss == "huber"  # every DQN before the option


@pytest.mark.skipif(not _digits_available(), reason="Classify/Digits-v0 data not installed")
def test_runs_that_differ_in_traced_params_share_compiled_programs():
    from jaxnat.training import device_backend as programs
    from jaxnat.training.spec import RunSpec

    config = ALGORITHMS["ppo"].config(total_timesteps=256, num_envs=4, num_steps=32, trunk="mnist")

    def spec(**kwargs):
        return RunSpec("Classify/Digits-v0", kwargs, "ppo", config, 2, 0, 1, 8)

    programs._PROGRAMS.clear()

    def scores(backend):  # the untrained policy's test scores: they depend on what it sees
        return jax.tree.map(np.asarray, backend.evaluate(None, backend.init()))

    first = programs.compiled_program(spec(window=5))
    second = programs.compiled_program(spec(window=7))  # a params field: the programs are shared
    assert second is not first and second._compiled is first._compiled and int(second.params.window) == 7
    fresh = programs.DeviceBackend(spec(window=7), None)
    shared = scores(second)
    jax.tree.map(np.testing.assert_array_equal, shared, scores(fresh))  # reads its own params
    assert not np.array_equal(shared["greedy_return"], scores(first)["greedy_return"])
    # A constructor argument (w=) may change the env itself: never shared.
    assert programs.compiled_program(spec(w=7))._compiled is not first._compiled
    # Another time limit bounds evaluation differently: not shared either.
    assert programs.compiled_program(spec(window=5, max_steps_in_episode=10))._compiled is not first._compiled
    # The noise control wraps the env (a `jaxnat.make` argument): it never runs the real one's programs.
    assert programs.compiled_program(spec(window=5, observation_noise=True))._compiled is not first._compiled
    programs._PROGRAMS.clear()


def test_runs_saved_before_env_parts_resume_as_one_batch():
    from jaxnat.agents import PPOConfig
    from jaxnat.training import RunSpec
    from jaxnat.training.rundir import check_resume_args

    saved = RunSpec("NaturalAtari/Breakout-v0", {}, "ppo", PPOConfig(trunk="atari"), 2, 0, 1, 10).to_json()
    assert saved["env_parts"] == 1
    del saved["env_parts"]  # as config.json was written before the setting
    assert RunSpec.from_json(saved).env_parts == 1
    for argv in ([], ["--env-parts", "1"]):
        check_resume_args(train.parse_args(["--resume", "run", *argv]), saved)
    with pytest.raises(train.TrainError, match=r"^--env-parts 2 \(the run: 1\) conflicts with"):
        check_resume_args(train.parse_args(["--resume", "run", "--env-parts", "2"]), saved)
    # Each conflict names the value given and the run's.
    with pytest.raises(train.TrainError, match=r"^--seeds 3 \(the run: 2\), --lr 0.001 \(the run: 0.00025\) conflict"):
        check_resume_args(train.parse_args(["--resume", "run", "--seeds", "3", "--lr", "1e-3"]), saved)


def test_help_lists_the_values_of_text_and_switch_settings(capsys):
    """`--dtype`, `--optimizer`, `--loss` and the normalisation switches name what they take."""
    from jaxnat.agents.dqn import LOSSES, OPTIMIZERS
    from jaxnat.agents.networks import DTYPES

    with pytest.raises(SystemExit):
        train.main(["--help"])
    text = " ".join(capsys.readouterr().out.split())
    for flag, values in (("--dtype", DTYPES), ("--optimizer", OPTIMIZERS), ("--loss", LOSSES)):
        assert f"{flag} {{{','.join(values)}}}" in text
    assert "--normalize-observations {True,False}" in text and "--normalize-rewards {True,False}" in text


def test_settings_table_never_cuts_the_run_directory(tmp_path):
    """On a narrow terminal the table's cells fold or cut; the run directory is a path to copy."""
    import io

    from rich.console import Console

    from jaxnat.training import spec as spec_module
    from jaxnat.training.command import _print_config

    spec = spec_module.RunSpec("Classify/Digits-v0", {}, "ppo", ALGORITHMS["ppo"].config(num_envs=8, num_steps=16),
                               seeds=2, seed=0, eval_every=2, eval_episodes=16)
    run_dir = tmp_path / "runs" / "PixelMuJoCo_Hopper-v0-ppo-20261127-121959-a-long-name"
    out = io.StringIO()
    _print_config(Console(file=out, width=50, force_terminal=False), spec, run_dir)
    assert f"run dir: {run_dir}" in out.getvalue().splitlines()


def test_resume_into_an_unwritable_folder_is_refused_before_building(tmp_path, capsys, monkeypatch):
    """Checkpoints and records go into the resumed run's folder: one that cannot be written is
    refused at once (root ignores permission bits, so the check's answer is stood in for)."""
    from jaxnat.training import command as train_command
    from jaxnat.training import rundir
    from jaxnat.training import spec as spec_module

    spec = spec_module.RunSpec("Classify/Digits-v0", {}, "ppo", ALGORITHMS["ppo"].config(num_envs=2, num_steps=8),
                               seeds=1, seed=0, eval_every=1, eval_episodes=4)
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.json").write_text(json.dumps({"spec": spec.to_json()}))
    monkeypatch.setattr(rundir, "unwritable", lambda folder: "Read-only file system")
    monkeypatch.setattr(train_command, "make_envs", lambda spec: pytest.fail("the env was built"))
    assert train.main(["--resume", str(run)]) == 2
    err = _error(capsys)
    assert f"cannot resume {run}: it is not writable (Read-only file system)" in err and err.count("\n") == 1
