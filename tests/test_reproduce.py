"""`jaxnat reproduce`: the smoke profile end to end, skipping finished cells on a rerun, resuming
a killed cell, the bootstrap interval on hand-made data, and one-line errors for bad arguments
(the findings' verdicts on hand-made results: test_verdicts.py)."""

import collections
import dataclasses
import json

import numpy as np
import pytest

from jaxnat.reproduce import aggregates, cell_stream, command, estimates, findings, grid, stats
from jaxnat.reproduce.cells import append_jsonl
from jaxnat.training import read_run

pytestmark = pytest.mark.xdist_group("reproduce")


def _report_body(path):
    """The report without its 'Written <time>' line."""
    return [line for line in path.read_text().splitlines() if not line.startswith("- Written")]


@pytest.fixture(scope="session")
def smoke(tmp_path_factory):
    """The smoke profile, run once per test process (9 minutes on CI): this module's tests share
    it in whatever order and company their worker runs them (tests/test_xdist_groups.py checks
    that the module's group keeps them on one worker)."""
    out = tmp_path_factory.mktemp("smoke")
    assert command.main(["--profile", "smoke", "--out", str(out)]) == 0
    return out


def test_smoke_profile_writes_every_cell_figure_and_table(smoke):
    plan = command.make_plan(command.ReproduceArgs(profile="smoke", out=smoke))
    assert {c.experiment for c in plan.cells} == set(grid.EXPERIMENTS)
    report = (smoke / "report.md").read_text()
    for cell in plan.cells:
        assert not cell.skip, cell.skip
        assert (smoke / cell.name / "summary.json").is_file()
        assert f"`{cell.name}`" in report
    for figure in ("classify-cnn", "sweep", "localize", "atari", "mujoco", "noise-control"):
        assert (smoke / f"{figure}.png").stat().st_size > 0
        assert f"({figure}.png)" in report
    assert report.count("| **") == len(findings.FINDINGS)
    # The table's numbers are the runs' own: the sampled test return of the last evaluation.
    cell = plan.cells[0]
    record = read_run(smoke / cell.name)
    last = max(r["update"] for r in record.evals)
    sampled = [r["sampled_return"] for r in record.evals if r["update"] == last]
    row = next(line for line in report.splitlines() if line.startswith(f"| `{cell.name}`"))
    assert str(stats.bootstrap_ci(sampled)) == row.split(" | ")[6]


def test_rerun_skips_finished_cells_and_gives_the_same_report(smoke):
    before = _report_body(smoke / "report.md")
    timings = (smoke / "timings.jsonl").read_text()
    assert command.main(["--profile", "smoke", "--out", str(smoke)]) == 0
    assert (smoke / "timings.jsonl").read_text() == timings  # nothing trained
    assert _report_body(smoke / "report.md") == before


def test_a_killed_cell_resumes_to_the_uninterrupted_result(smoke, tmp_path):
    from rich.console import Console

    from jaxnat.training import train

    plan = command.make_plan(command.ReproduceArgs(profile="smoke", only="classify", out=tmp_path))
    cell = plan.cells[0]
    fast = {"xla_backend_optimization_level": 0}
    stopped = train(cell.train_args(plan.seeds, tmp_path / cell.name), console=Console(quiet=True),
                    compiler_options=fast, stop_after_chunks=1)
    assert not stopped.complete
    assert command.main(["--profile", "smoke", "--only", "classify", "--out", str(tmp_path), "--report-only"]) == 0
    assert "incomplete (interrupted" in (tmp_path / "report.md").read_text()
    assert command.main(["--profile", "smoke", "--only", "classify", "--out", str(tmp_path)]) == 0
    rows = [json.loads(line) for line in (tmp_path / "timings.jsonl").read_text().splitlines()]
    assert rows[0]["cell"] == cell.name and rows[0]["resumed"] and rows[0]["outcome"] == "finished"

    def scores(directory):
        return [{k: v for k, v in r.items() if k not in ("chunk_seconds", "steps_per_second")}
                for r in read_run(directory / cell.name).evals]

    assert scores(tmp_path) == scores(smoke)


def test_bootstrap_interval_on_hand_made_values():
    equal = stats.bootstrap_ci([2.0, 2.0, 2.0])
    assert (equal.mean, equal.low, equal.high, equal.n) == (2.0, 2.0, 2.0, 3)
    values = [0.0, 1.0, 2.0, 3.0, 10.0]
    interval = stats.bootstrap_ci(values)
    assert interval.mean == pytest.approx(3.2) and interval.n == 5
    # The exact bootstrap distribution of the mean of 5 draws: its 2.5% and 97.5% quantiles.
    draws = np.array(np.meshgrid(*[values] * 5)).reshape(5, -1).mean(axis=0)
    low, high = np.percentile(draws, [2.5, 97.5])
    assert interval.low == pytest.approx(low, abs=0.25) and interval.high == pytest.approx(high, abs=0.25)
    assert stats.bootstrap_ci(values) == interval  # a fixed generator: the same report every time
    assert stats.bootstrap_ci([np.nan, 1.0]).n == 1
    assert np.isnan(stats.bootstrap_ci([np.nan]).mean)


def test_binned_curve_means_each_seed_within_each_bin():
    steps = np.array([1.0, 2.0, 3.0, 4.0])
    per_seed = np.array([[1.0, np.nan], [3.0, 5.0], [np.nan, 7.0], [8.0, 9.0]])
    centres, values = stats.binned_curve(steps, per_seed, bins=2)
    np.testing.assert_allclose(centres, [1.5, 3.5])
    np.testing.assert_allclose(values, [[2.0, 5.0], [8.0, 8.0]])


def test_figure_curves_are_drawn_through_steps_without_finished_episodes(tmp_path, monkeypatch):
    """Steps where no seed finished an episode (NaN) leave the curve a line through the others."""
    from matplotlib.figure import Figure

    from jaxnat.reproduce import report
    from jaxnat.reproduce.report import CellResult

    figures = []
    monkeypatch.setattr(Figure, "savefig", lambda figure, *_, **__: figures.append(figure))
    cell = grid.Cell("classify-ppo", "classify", "classify-cnn", "X/Y-v0", {}, "ppo", None, grid.Budget(10), {},
                     {"dataset": "mnist"})
    train = np.tile([1.0, 3.0], (10, 1))
    train[1::2] = np.nan  # steps 2, 4, ..., 10: no episode ended
    empty = np.zeros((0, 2))
    result = CellResult(cell, True, 2, np.arange(1.0, 11.0), train, np.zeros(0), empty, empty, None, 1.0)
    report.plot_figure(tmp_path / "f.png", "title", {"panel": [("ppo", result)]})
    line = figures[0].axes[0].lines[0]
    np.testing.assert_array_equal(line.get_xdata(), [1.0, 3.0, 5.0, 7.0, 9.0])
    np.testing.assert_array_equal(line.get_ydata(), [2.0] * 5)


def test_a_curve_has_one_colour_in_every_panel(tmp_path, monkeypatch):
    """A figure's curve ("noise · PPO") keeps its colour whichever curves each panel has."""
    from matplotlib.colors import to_hex
    from matplotlib.figure import Figure

    from jaxnat.reproduce import report
    from jaxnat.reproduce.report import CellResult

    figures = []
    monkeypatch.setattr(Figure, "savefig", lambda figure, *_, **__: figures.append(figure))
    cell = grid.Cell("mujoco-x", "mujoco", "mujoco", "X/Y-v0", {}, "ppo", None, grid.Budget(10), {}, {})
    empty = np.zeros((0, 2))
    result = CellResult(cell, True, 2, np.arange(1.0, 3.0), np.ones((2, 2)), np.zeros(0), empty, empty, None, 1.0)
    panels = {"Swimmer": [("checker · PPO", result), ("noise · PPO", result)],
              "Hopper": [("noise · PPO", result), ("state · PPO", result)]}
    report.plot_figure(tmp_path / "f.png", "title", panels)
    colours = [{line.get_label(): to_hex(line.get_color()) for line in ax.lines} for ax in figures[0].axes]
    assert colours[0]["noise · PPO (train)"] == colours[1]["noise · PPO (train)"]
    assert len({*colours[0].values(), *colours[1].values()}) == 3  # three curves, three colours


@pytest.mark.parametrize("argv, message", [
    (["--profile", "smok"], "unknown --profile 'smok' (did you mean 'smoke'?)"),
    (["--only", "classify,atary"], "unknown --only name 'atary' (did you mean 'atari'?)"),
    (["--seeds", "0"], "--seeds must be at least 1"),
])
def test_bad_arguments_get_one_line_and_write_nothing(argv, message, tmp_path, capsys):
    out = tmp_path / "out"
    assert command.main([*argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("jaxnat reproduce: error: ") and message in err and "\n" not in err
    assert not (out / "report.md").exists()


@pytest.mark.parametrize("platform, profile", [("cpu", "smoke"), ("gpu", "quick")])
def test_without_profile_a_cpu_runs_smoke_and_says_so(platform, profile, tmp_path, monkeypatch, capsys):
    plans = []
    from jaxnat.reproduce.gpus import Devices

    monkeypatch.setattr(command, "find_devices", lambda: Devices(platform))
    monkeypatch.setattr(command, "run_cells", lambda plan, *_, **__: plans.append(plan) or {})
    monkeypatch.setattr("jaxnat.reproduce.report.write_report", lambda plan, outcomes: plan.out / "report.md")
    assert command.main(["--out", str(tmp_path)]) == 0
    assert [plan.profile.name for plan in plans] == [profile]
    note = "no --profile given: running the smoke profile on this CPU (pass --profile quick or paper to run more)"
    assert (note in capsys.readouterr().out) == (platform == "cpu")


def test_unwritable_out_is_refused(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("")
    assert command.main(["--profile", "smoke", "--out", str(blocker / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert "is not writable" in err and "\n" not in err


def test_a_broken_statistics_install_is_refused_before_any_cell_trains(tmp_path, monkeypatch, capsys):
    # As arch 7 fails to import under pandas 3: an error raised while rliable imports. Patched
    # where the report imports it, since a worker that already imported rliable skips the finders.
    def broken():
        raise TypeError("deprecate_kwarg() missing 1 required positional argument")

    monkeypatch.setattr(aggregates, "rliable_modules", broken)
    assert command.main(["--profile", "smoke", "--only", "classify", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert "need rliable" in err and "TypeError" in err and "pandas below 3" in err and "\n" not in err
    assert not list((tmp_path / "out").glob("classify-*"))  # no cell started


def test_a_folder_of_other_settings_is_refused(smoke, tmp_path, capsys):
    assert command.main(["--profile", "smoke", "--out", str(smoke), "--seeds", "3", "--only", "classify"]) == 2
    assert "holds a run with other settings" in capsys.readouterr().err


def test_a_folder_trained_with_another_batch_is_refused(smoke):
    """A profile whose batch changed must not count a cell trained with the old one as finished."""
    plan = command.make_plan(command.ReproduceArgs(profile="smoke", out=smoke, only="classify"))
    cell = plan.cells[0]
    config = read_run(smoke / cell.name).config
    command._check_same_run(cell, plan, config)  # the same settings pass
    changed = dataclasses.replace(cell, overrides={**cell.overrides, "num_envs": 4})
    with pytest.raises(command.ReproduceError, match=r"other settings: num_envs 2 \(this grid: 4\)"):
        command._check_same_run(changed, plan, config)


def _train_argv(cell, seeds, run_dir, resume):
    """The cell's `jaxnat train` command line, as `jaxnat reproduce` built it to parse back in
    its own process before cells were handed to the trainer as `TrainArgs`."""
    argv = ["--env-id", cell.env_id, "--algo", cell.algo, "--seeds", str(seeds),
            "--total-timesteps", str(cell.budget.total_timesteps),
            "--eval-episodes", str(cell.budget.eval_episodes)]
    argv += ["--resume", str(run_dir)] if resume else ["--run-dir", str(run_dir)]
    if cell.env_kwargs:
        argv += ["--env-kwargs", *(f"{k}={v}" for k, v in cell.env_kwargs.items())]
    if cell.trunk is not None:
        argv += ["--trunk", cell.trunk]
    for key, value in cell.overrides.items():
        argv += [f"--{key.replace('_', '-')}", str(value)]
    return argv


def test_cell_train_args_are_its_parsed_command_line(tmp_path):
    """Every cell of every profile, new or resumed: the typed arguments are what `jaxnat train`
    parses from the cell's command line, to the values' types and the names given."""
    from jaxnat.training import parse_args

    for profile in grid.PROFILES.values():
        for cell in grid.build_grid(profile):
            if cell.env_id is None:  # not runnable here: never trained
                continue
            for resume in (False, True):
                args = cell.train_args(profile.seeds, tmp_path / cell.name, resume=resume)
                parsed = parse_args(_train_argv(cell, profile.seeds, tmp_path / cell.name, resume))
                assert args == parsed and repr(args) == repr(parsed), (profile.name, cell.name, resume)


def test_atari_cells_step_pipelined_parts_in_quick_only():
    for name, parts in (("smoke", 1), ("quick", 2), ("paper", 1)):
        cells = grid.build_grid(grid.PROFILES[name], ("atari",))
        for cell in cells:
            args = cell.train_args(5, "run")
            assert args.env_parts == parts, (name, cell.name)
            if name == "quick":  # two parts of 128 envs, whole updates
                assert args.num_envs == 256 and args.config.num_steps == 32
                assert cell.budget.total_timesteps % (256 * 32) == 0
    plan = command.make_plan(command.ReproduceArgs(profile="quick", only="atari", out="out"))
    cell = plan.cells[0]
    spec = {"env_id": cell.env_id, "env_kwargs": dict(cell.env_kwargs), "algo": cell.algo, "seeds": plan.seeds,
            "config": {"total_timesteps": cell.budget.total_timesteps}, "env_parts": 2}
    command._check_same_run(cell, plan, {"spec": spec})
    with pytest.raises(command.ReproduceError, match="other settings"):  # one batch: written before parts
        command._check_same_run(cell, plan, {"spec": {k: v for k, v in spec.items() if k != "env_parts"}})


def test_cells_compiled_ahead_train_to_the_same_results(smoke, tmp_path, monkeypatch):
    from rich.console import Console

    from jaxnat.training import device_backend as programs

    plan = command.make_plan(command.ReproduceArgs(profile="smoke", only="classify", out=tmp_path))
    built = []
    real_init = programs.DeviceBackend.__init__

    def init(self, spec, *args, **kwargs):  # count the program sets built
        built.append(spec.env_id)
        real_init(self, spec, *args, **kwargs)

    monkeypatch.setattr(programs.DeviceBackend, "__init__", init)
    # An empty program cache: a test before this one in the same process may have left these
    # cells' programs there, and the count below is of programs built.
    monkeypatch.setattr(programs, "_PROGRAMS", collections.OrderedDict())
    outcomes = command.run_cells(plan, Console(quiet=True), compile_ahead=True)
    assert set(outcomes.values()) == {"finished"}
    # Each cell's programs were built once, on the worker, and found there by its run.
    assert len(built) == len(plan.cells)
    for cell in plan.cells:
        def scores(directory):
            return [{k: v for k, v in r.items() if k not in ("chunk_seconds", "steps_per_second")}
                    for r in read_run(directory / cell.name).evals]

        assert scores(tmp_path) == scores(smoke), cell.name


# Host cells alongside device cells: forced on (a CPU runs every cell in turn by default), on the
# smoke grid's classify and Atari cells.
ALONGSIDE = "atari,classify"
ATARI_CELL = "atari-breakout-video-ppo"


def _without_wall_time(path):
    """The report's body without its wall time section (the seconds differ from run to run)."""
    lines, keep = [], True
    for line in _report_body(path):
        if line.startswith("## "):
            keep = line != "## Wall time"
        if keep:
            lines.append(line)
    return lines


def _eval_rows(directory, name):
    return [{k: v for k, v in r.items() if k not in ("chunk_seconds", "steps_per_second")}
            for r in read_run(directory / name).evals]


def _run(out, text=None):
    """`reproduce` of the smoke grid's ALONGSIDE cells with host cells alongside; (report, output)."""
    import io

    from rich.console import Console

    text = io.StringIO() if text is None else text
    args = command.ReproduceArgs(profile="smoke", only=ALONGSIDE, out=out)
    command.reproduce(args, console=Console(file=text, width=300), overlap=True)
    return out / "report.md", text.getvalue()


@pytest.fixture
def device_cells_copied(smoke, monkeypatch):
    """Device cells "trained" by copying the smoke run's folders (this process's `train`; the
    host stream's child process trains for real)."""
    import shutil

    from jaxnat import training

    def copy(args, **_):
        shutil.copytree(smoke / args.run_dir.name, args.run_dir)

    monkeypatch.setattr(training, "train", copy)


def test_host_cells_alongside_train_the_same_cells_and_report(smoke, tmp_path):
    import shutil

    plan = command.make_plan(command.ReproduceArgs(profile="smoke", only=ALONGSIDE, out=tmp_path / "x"))
    names = [c.name for c in plan.cells]
    assert ATARI_CELL in names and {c.host for c in plan.cells} == {True, False}
    out, sequential = tmp_path / "alongside", tmp_path / "sequential"
    for name in names:  # the sequential run's cells: the smoke run's
        shutil.copytree(smoke / name, sequential / name)
    trained = [names[0], ATARI_CELL]  # one classify cell beside the Atari cell; the others finished before
    for name in set(names) - set(trained):
        shutil.copytree(smoke / name, out / name)
    report, output = _run(out)
    assert "(device cells" in output and "host cells" in output and "side by side)" in output
    assert f"{ATARI_CELL} (alongside) ..." in output and "[2/2]" in output
    rows = [json.loads(line) for line in (out / "timings.jsonl").read_text().splitlines()]
    assert sorted(r["cell"] for r in rows) == sorted(trained)
    assert all(r["outcome"] == "finished" and r["overlapped"] for r in rows)
    assert (out / "logs" / cell_stream.stream_log("host")).is_file()
    assert "| elapsed" in report.read_text()
    for name in names:
        assert _eval_rows(out, name) == _eval_rows(smoke, name), name
    command.reproduce(command.ReproduceArgs(profile="smoke", only=ALONGSIDE, out=sequential, report_only=True))
    assert _without_wall_time(report) == _without_wall_time(sequential / "report.md")
    # A rerun trains nothing, with host cells alongside or not.
    timings, before = (out / "timings.jsonl").read_text(), _report_body(report)
    _, output = _run(out)
    assert "4 cells (4 finished before" in output
    assert command.main(["--profile", "smoke", "--only", ALONGSIDE, "--out", str(out), "--sequential"]) == 0
    assert (out / "timings.jsonl").read_text() == timings
    assert _report_body(report) == before


def test_a_failing_host_cell_is_reported(smoke, tmp_path, device_cells_copied):
    import shutil

    out = tmp_path / "out"
    shutil.copytree(smoke / ATARI_CELL, out / ATARI_CELL)
    (out / ATARI_CELL / "summary.json").unlink()  # interrupted, and its checkpoints damaged
    for path in (out / ATARI_CELL / "checkpoints").rglob("*"):
        if path.is_file() and "state" in path.parts:
            path.write_text("damaged")
    report, output = _run(out)
    assert f"{ATARI_CELL}: cannot resume: checkpoint" in output
    assert f"{ATARI_CELL}: failed: cannot resume" in output
    rows = {r["cell"]: r for r in map(json.loads, (out / "timings.jsonl").read_text().splitlines())}
    assert rows[ATARI_CELL]["outcome"] == "failed" and "is damaged" in rows[ATARI_CELL]["message"]
    assert f"| `{ATARI_CELL}` | incomplete (failed: cannot resume" in report.read_text()
    assert sum(r["outcome"] == "finished" for r in rows.values()) == len(rows) - 1


def test_a_host_stream_that_dies_fails_its_cells(tmp_path, monkeypatch, device_cells_copied):
    import sys

    monkeypatch.setattr(cell_stream, "child_argv", lambda *_: [sys.executable, "-c", "raise SystemExit(3)"])
    report, output = _run(tmp_path)
    assert "exited with status 3 before this cell finished" in output
    assert f"| `{ATARI_CELL}` | not run (failed): the host stream" in report.read_text()
    rows = [json.loads(line) for line in (tmp_path / "timings.jsonl").read_text().splitlines()]
    assert {r["cell"] for r in rows} == {c.name for c in grid.build_grid(grid.PROFILES["smoke"], ("classify",))}


def test_ctrl_c_stops_both_streams_and_reports_nothing_unfinished(tmp_path, monkeypatch):
    import io
    import subprocess
    import time

    from jaxnat import training
    from jaxnat.training import run_status

    children = []

    class Spy(subprocess.Popen):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            children.append(self)

    def interrupted(args, **_):  # Ctrl-C once the host stream is in its cell
        deadline = time.monotonic() + 120
        while not (tmp_path / ATARI_CELL / "config.json").is_file() and time.monotonic() < deadline:
            time.sleep(0.2)
        raise KeyboardInterrupt

    monkeypatch.setattr(subprocess, "Popen", Spy)
    monkeypatch.setattr(training, "train", interrupted)
    text = io.StringIO()
    with pytest.raises(KeyboardInterrupt):
        _run(tmp_path, text)
    (child,) = children
    assert child.returncode in (130, 0)  # stopped (or it had just finished): never left running
    status = run_status(tmp_path / ATARI_CELL)
    assert status in ("partial", "finished")
    timings = tmp_path / "timings.jsonl"
    rows = [json.loads(line) for line in timings.read_text().splitlines()] if timings.exists() else []
    assert [r["cell"] for r in rows] == ([ATARI_CELL] if status == "finished" else [])
    stopped = [line for line in text.getvalue().splitlines() if line.startswith("interrupted in")]
    first = f"classify-{grid.data_name('mnist', grid.dataset_choice('mnist')[1])}-cnn-ppo"  # digits: a stand-in
    assert stopped and first in stopped[0]
    assert (ATARI_CELL in stopped[0]) == (status == "partial")


def test_the_host_stream_stops_when_its_parent_is_gone(tmp_path):
    import os
    import subprocess

    plan = command.make_plan(command.ReproduceArgs(profile="smoke", only="atari", out=tmp_path))
    read_end, write_end = os.pipe()
    spec = cell_stream.StreamSpec("host", plan.cells, {})
    child = subprocess.Popen(cell_stream.child_argv(plan, spec, write_end), stdin=subprocess.PIPE,
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, pass_fds=(write_end,))
    os.close(write_end)
    child.stdin.close()  # as when the parent dies
    try:
        assert child.wait(timeout=120) in (130, -2)  # interrupted, wherever it was
    finally:
        child.kill()
        os.close(read_end)


def test_the_estimate_with_host_cells_alongside_is_the_longer_stream():
    from jaxnat.training.host_backend import is_host_env

    cells = grid.build_grid(grid.PROFILES["quick"])
    assert all(c.host == is_host_env(c.env_id) for c in cells if c.env_id)
    streams = estimates.split_streams(cells, overlap=True)
    assert streams["host"] == [c for c in cells if c.experiment == "atari"]
    assert streams["device"] == [c for c in cells if c.experiment != "atari"]
    device, host = (sum(estimates.estimate_seconds(c, 5, "gpu") for c in streams[k]) for k in ("device", "host"))
    assert estimates.estimate_total(streams, 5, "gpu") == pytest.approx(max(device, host))
    assert estimates.estimate_total(estimates.split_streams(cells, overlap=False), 5, "gpu") == pytest.approx(device + host)
    only_device = [c for c in cells if not c.host]
    assert estimates.split_streams(only_device, overlap=True) == {"all": only_device}


def test_concurrent_timing_lines_never_interleave(tmp_path):
    from concurrent.futures import ThreadPoolExecutor

    path = tmp_path / "timings.jsonl"
    rows = [{"cell": f"c{i}", "message": str(i) * 20_000} for i in range(64)]
    with ThreadPoolExecutor(8) as pool:
        list(pool.map(lambda row: append_jsonl(path, row), rows))
    written = [json.loads(line) for line in path.read_text().splitlines()]
    assert sorted(written, key=lambda r: int(r["cell"][1:])) == rows
