"""`jaxnat reproduce` on several GPUs: the device cells shared among child streams by their
estimates (LPT), each child's command line and environment, counting the GPUs without starting
JAX, `--gpus` errors, a dead or interrupted stream, and the smoke grid's device cells trained by
two child streams on the CPU (a test names two "GPUs" there: `reproduce(devices=...)`)."""

import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

import jaxnat
from jaxnat.reproduce import cell_stream, command, estimates, gpus, grid
from jaxnat.reproduce.gpus import Devices

pytestmark = pytest.mark.xdist_group("reproduce")

SMOKE = grid.PROFILES["smoke"]
DEVICE_EXPERIMENTS = "classify,localize,mujoco"
TWO = Devices("cpu", ("0", "1"))  # two device streams on this CPU


def _cells(names):
    """Hand-made device cells named `names` (a smoke classify cell under other names)."""
    base = grid.build_grid(SMOKE, ("classify",))[0]
    return [dataclasses.replace(base, name=name) for name in names]


def test_device_cells_are_shared_longest_first_onto_the_least_loaded_stream():
    cells = _cells("eacfbd")  # grid order e, a, c, f, b, d
    seconds = {"a": 5.0, "b": 4.0, "c": 3.0, "d": 3.0, "e": 2.0, "f": 2.0}
    # Longest first: a->0 (5, 0), b->1 (5, 4), c->1 (5, 7), d->0 (8, 7), e->1 (8, 9), f->0 (10, 9);
    # each stream then in grid order.
    parts = estimates.balance(cells, 2, seconds)
    assert [[c.name for c in part] for part in parts] == [["a", "f", "d"], ["e", "c", "b"]]
    parts = estimates.balance(cells, 3, seconds)  # a, b, c; d->2 (5, 4, 6); e->1 (5, 6, 6); f->0
    assert [[c.name for c in part] for part in parts] == [["a", "f"], ["e", "b"], ["c", "d"]]
    atari = grid.build_grid(SMOKE, ("atari",))
    streams = estimates.split_streams([*cells, *atari], overlap=False, gpus=4, seconds=seconds)
    assert {k: [c.name for c in v] for k, v in streams.items()} == {
        "gpu0": ["a"], "gpu1": ["b"], "gpu2": ["e", "c"], "gpu3": ["f", "d"], "host": [c.name for c in atari]}
    # More GPUs than cells: the empty streams are left out; the estimate is the longest stream's.
    streams = estimates.split_streams(cells[:2], overlap=True, gpus=3, seconds=seconds)
    assert {k: [c.name for c in v] for k, v in streams.items()} == {"gpu0": ["a"], "gpu1": ["e"]}
    # The estimate is the longest stream's (every hand-made cell is the same smoke cell: 3 a stream).
    total = estimates.estimate_total(estimates.split_streams(cells, True, 2, seconds), 2, "cpu")
    assert total == pytest.approx(3 * estimates.estimate_seconds(cells[0], 2, "cpu"))


def test_each_stream_child_sees_its_gpu_and_the_host_stream_allocates_as_it_needs(monkeypatch, tmp_path):
    monkeypatch.setenv("CUDA_VISIBLE_DEVICES", "3,5")  # the user's choice: the children get its ids
    monkeypatch.delenv("XLA_PYTHON_CLIENT_PREALLOCATE", raising=False)
    device, host = _cells(["a", "b", "c"]), grid.build_grid(SMOKE, ("atari",))
    seconds = {"a": 1.0, "b": 5.0, "c": 1.0}
    streams = estimates.split_streams([*device, *host], overlap=True, gpus=2, seconds=seconds)
    specs = {s.name: s for s in cell_stream.child_streams(streams, ("3", "5"), seconds, compile_ahead=True)}
    assert list(specs) == ["gpu0", "gpu1", "host"]
    assert [c.name for c in specs["gpu0"].cells] == ["b"] and [c.name for c in specs["gpu1"].cells] == ["a", "c"]
    assert specs["gpu0"].env == {"CUDA_VISIBLE_DEVICES": "3"} and specs["gpu1"].env == {"CUDA_VISIBLE_DEVICES": "5"}
    # The host stream shares the GPU of the device stream with the least work (gpu1: 2 s < 5 s).
    assert specs["host"].env == {"XLA_PYTHON_CLIENT_PREALLOCATE": "false", "CUDA_VISIBLE_DEVICES": "5"}
    for name, gpu in (("gpu0", "3"), ("gpu1", "5")):  # preallocation left to JAX's default (on)
        env = cell_stream.child_env(specs[name])
        assert env["CUDA_VISIBLE_DEVICES"] == gpu and "XLA_PYTHON_CLIENT_PREALLOCATE" not in env
        assert env["PYTHONPATH"].split(os.pathsep)[0] == str(Path(jaxnat.__file__).resolve().parents[1])
    assert cell_stream.child_env(specs["host"])["XLA_PYTHON_CLIENT_PREALLOCATE"] == "false"
    plan = grid.Plan(SMOKE, ("classify",), 2, tmp_path, device)
    argv = cell_stream.child_argv(plan, specs["gpu1"], 7)
    assert argv[:3] == [sys.executable, "-m", "jaxnat.reproduce.cellstream"]
    assert argv[3:] == ["--name", "gpu1", "--profile", "smoke", "--seeds", "2", "--out", str(tmp_path),
                        "--cells", "a,c", "--events-fd", "7", "--nice", "0", "--compile-ahead"]
    host_argv = cell_stream.child_argv(plan, specs["host"], 7)
    assert host_argv[-2:] == ["--nice", str(cell_stream.HOST_STREAM_NICE)] and "--compile-ahead" not in host_argv
    # One GPU: the device cells train in the parent and the host stream is as it always was.
    one = estimates.split_streams([*device, *host], overlap=True)
    (spec,) = cell_stream.child_streams(one, (), seconds, compile_ahead=True)
    assert (spec.name, spec.env, spec.nice, spec.compile_ahead) == (
        "host", {"XLA_PYTHON_CLIENT_PREALLOCATE": "false"}, cell_stream.HOST_STREAM_NICE, False)


def _batch(cell, envs, steps):
    return dataclasses.replace(cell, overrides={**cell.overrides, "num_envs": envs, "num_steps": steps})


def test_small_cells_are_packed_on_gpus_of_their_own(monkeypatch):
    """`--pack-small N`: cells of at most `SMALL_BATCH` env steps per update (all seeds) train N
    to a GPU, the others on GPUs of their own; the GPUs are shared by estimated work."""
    big = [_batch(c, 512, 32) for c in _cells("ab")]  # 512 x 32 x 2 seeds: large
    few = [_batch(c, 16, 5) for c in _cells("wxyz")]  # 16 x 5 x 2 seeds: small (the authors' A2C)
    assert not estimates.small(big[0], 2) and estimates.small(few[0], 2)
    assert not estimates.small(_batch(few[0], 16, 5), estimates.SMALL_BATCH)  # the seeds count
    seconds = dict.fromkeys("abwxyz", 10.0)
    streams = estimates.split_streams([*big, *few], overlap=True, gpus=2, seconds=seconds, pack=2, seeds=2)
    assert {k: [c.name for c in v] for k, v in streams.items()} == {
        "gpu0": ["a", "b"], "gpu1-0": ["w", "y"], "gpu1-1": ["x", "z"]}
    assert [estimates.stream_gpu(name) for name in streams] == [0, 1, 1] and estimates.stream_gpu("host") is None
    # Small work outweighing the large: more GPUs packed (4 GPUs: 1 large, 3 packed).
    seconds.update(w=100.0, x=100.0, y=100.0, z=100.0)
    streams = estimates.split_streams([*big, *few], overlap=True, gpus=4, seconds=seconds, pack=2, seeds=2)
    assert sorted(streams) == ["gpu0", "gpu1-0", "gpu1-1", "gpu2-0", "gpu3-0"]  # a GPU each, then doubled
    # One GPU: the large cells' stream and the packed ones share it; no small cell: one stream.
    streams = estimates.split_streams([*big, *few], overlap=True, gpus=1, seconds=seconds, pack=2, seeds=2)
    assert list(streams) == ["gpu0", "gpu0-0", "gpu0-1"]
    assert list(estimates.split_streams(big, True, 1, seconds, pack=2, seeds=2)) == ["gpu0"]
    # Each packed stream preallocates its share of the GPU's memory; a GPU alone, JAX's default.
    monkeypatch.delenv("XLA_PYTHON_CLIENT_MEM_FRACTION", raising=False)
    specs = {s.name: s.env for s in cell_stream.child_streams(streams, ("7",), seconds, compile_ahead=False)}
    assert specs == {name: {"CUDA_VISIBLE_DEVICES": "7", "XLA_PYTHON_CLIENT_MEM_FRACTION": "0.250"}
                     for name in ("gpu0", "gpu0-0", "gpu0-1")}  # three streams on one GPU: 0.75 / 3
    streams = estimates.split_streams([*big, *few], overlap=True, gpus=2, seconds=seconds, pack=2, seeds=2)
    monkeypatch.setenv("XLA_PYTHON_CLIENT_MEM_FRACTION", "0.9")
    specs = {s.name: s.env for s in cell_stream.child_streams(streams, ("3", "5"), seconds, compile_ahead=False)}
    assert specs["gpu0"] == {"CUDA_VISIBLE_DEVICES": "3"}
    assert specs["gpu1-0"] == specs["gpu1-1"] == {"CUDA_VISIBLE_DEVICES": "5", "XLA_PYTHON_CLIENT_MEM_FRACTION": "0.450"}


def test_the_gpus_are_counted_from_jaxs_probe():
    probe = 'WARNING: a line JAX printed\n{"platform": "gpu", "devices": 2}\n'
    assert gpus.parse_probe(probe, {}) == Devices("gpu", ("0", "1"))
    assert gpus.parse_probe(probe, {"CUDA_VISIBLE_DEVICES": "6,2,7"}) == Devices("gpu", ("6", "2"))
    assert gpus.parse_probe(probe, {"CUDA_VISIBLE_DEVICES": "GPU-1a,GPU-2b"}) == Devices("gpu", ("GPU-1a", "GPU-2b"))
    assert gpus.parse_probe('{"platform": "cpu", "devices": 1}', {}) == Devices("cpu")
    broken = gpus.parse_probe("Traceback ...", {})
    assert broken.platform == "" and broken.gpus == () and "Traceback" in broken.problem


def test_counting_the_gpus_never_starts_jax_in_this_process(tmp_path):
    """In a fresh process with no JAX platform set (as `jaxnat reproduce` starts), the count comes
    from the probe's child and this process's JAX stays unstarted (on a CPU machine: no GPU)."""
    script = ("from jaxnat.reproduce import gpus; found = gpus.find_devices(); "
              "print(found.platform, len(found.gpus), found.problem or '-', gpus.jax_started())")
    env = {k: v for k, v in os.environ.items() if k != "JAX_PLATFORMS"}
    env["PYTHONPATH"] = str(Path(jaxnat.__file__).resolve().parents[1])
    done = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    platform, count, problem, started = done.stdout.split()
    assert problem == "-" and started == "False"
    assert platform in ("cpu", "gpu") and (platform == "gpu") == (int(count) > 0)


@pytest.mark.parametrize("argv, devices, message", [
    (["--gpus", "3"], Devices("gpu", ("0", "1")), "--gpus 3: JAX finds 2 GPUs here"),
    (["--gpus", "2"], Devices("gpu", ("0",)), "--gpus 2: JAX finds 1 GPU here"),
    (["--gpus", "2"], Devices("cpu"), "--gpus 2: JAX finds no GPUs here (platform cpu)"),
    (["--gpus", "2"], Devices("", problem="JAX's probe exited with status 1: boom"),
     "--gpus 2: cannot count its GPUs (JAX's probe exited with status 1: boom)"),
    (["--gpus", "0"], None, "--gpus takes a number of GPUs (1 or more) or 'all', not '0'"),
    (["--gpus", "two"], None, "--gpus takes a number of GPUs (1 or more) or 'all', not 'two'"),
    (["--gpus", "2", "--sequential"], None,
     "--sequential trains every cell in turn on one GPU; it cannot use --gpus 2"),
    (["--pack-small", "0"], None, "--pack-small takes the number of small cells per GPU (1 or more), not 0"),
    (["--pack-small", "4", "--sequential"], None, "--sequential trains every cell in turn; it cannot use --pack-small 4"),
])
def test_bad_gpus_get_one_line_and_train_nothing(argv, devices, message, tmp_path, monkeypatch, capsys):
    def found():
        assert devices is not None, "the GPUs were counted for an argument that needs no count"
        return devices

    monkeypatch.setattr(command, "find_devices", found)
    out = tmp_path / "out"
    assert command.main([*argv, "--profile", "smoke", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("jaxnat reproduce: error: ") and message in err and "\n" not in err
    assert not (out / "report.md").exists() and not (out / "timings.jsonl").exists()


def test_gpus_chosen(monkeypatch):
    four = Devices("gpu", ("0", "1", "2", "3"))

    def choose(value, devices, sequential=False):
        args = command.ReproduceArgs(gpus=value, sequential=sequential)
        return command.choose_gpus(args, devices)

    assert choose("all", four) == ("gpu", ("0", "1", "2", "3"))
    assert choose("2", four) == ("gpu", ("0", "1"))
    assert choose("all", Devices("gpu", ("0",))) == ("gpu", ())  # one GPU: today's single stream here
    assert choose("all", Devices("cpu")) == ("cpu", ())
    assert choose("all", Devices("", problem="no probe")) == (None, ())  # asked in this process, as before
    monkeypatch.setattr(command, "find_devices", lambda: pytest.fail("counted GPUs for one stream"))
    assert choose("1", None) == (None, ()) and choose("all", None, sequential=True) == (None, ())
    # Packing trains in child processes, so one GPU's id is handed on too.
    packed = command.choose_gpus(command.ReproduceArgs(gpus="all", pack_small=4), Devices("gpu", ("0",)))
    assert packed == ("gpu", ("0",))


def test_gpu_streams_of_one_kind_share_their_cells_from_the_far_end():
    a, b, c, d, e, f, g, h, i = _cells("abcdefghi")
    streams = {"gpu0": [a, b, c], "gpu1": [d, e], "gpu2": [f], "gpu3-0": [g], "gpu3-1": [h], "host": [i]}
    assert cell_stream.pool_streams(streams) == {
        "gpu0": [e, f, d], "gpu1": [c, f, b, a], "gpu2": [c, e, b, d, a],  # the others' last cells first, in turn
        "gpu3-0": [h], "gpu3-1": [g]}  # packed small cells pool among themselves; the host stream does not
    assert cell_stream.pool_streams({"gpu0": [a], "gpu1-0": [b], "host": [c]}) == {}  # one of a kind: no pool
    specs = cell_stream.child_streams(streams, ("0", "1", "2", "3"), dict.fromkeys("abcdefghi", 1.0), False,
                                      Path("claims"))
    assert {s.name: (s.then, s.claims) for s in specs}["gpu1"] == ([c, f, b, a], "claims")
    assert {s.name: (s.then, s.claims) for s in specs}["host"] == ([], None)
    assert all(not s.then and s.claims is None for s in cell_stream.child_streams(streams, ("0", "1", "2", "3"),
                                                                                 dict.fromkeys("abcdefghi", 1.0), False))


def test_a_cell_is_claimed_once_and_a_claimed_cell_is_skipped(tmp_path, monkeypatch):
    from jaxnat.reproduce import cells as cells_module

    plan = _smoke_plan(tmp_path / "out", "classify")
    first, second, third = plan.cells[:3]
    claims = tmp_path / "claims"
    claims.mkdir()
    assert cells_module.Claims(claims, "gpu1").take(second)
    assert not cells_module.Claims(claims, "gpu0").take(second)  # one winner
    assert cells_module.Claims.holder(claims, second.name) == "gpu1"
    assert cells_module.Claims.holder(claims, first.name) is None
    trained = []
    monkeypatch.setattr("jaxnat.training.train", lambda args, **_: trained.append(Path(args.run_dir).name))

    class Events:
        def __init__(self):
            self.seen = []

        def start(self, cell, resumed):
            self.seen.append(("start", cell.name))

        def done(self, cell, outcome, seconds):
            self.seen.append((outcome, cell.name))

    events = Events()
    cells_module.train_cells([first, second, third], plan, dict.fromkeys([c.name for c in plan.cells], False),
                             events, platform="cpu", compile_ahead=False, overlapped=True,
                             claim=cells_module.Claims(claims, "gpu0").take)
    assert trained == [first.name, third.name]
    assert events.seen == [("start", first.name), ("finished", first.name), ("start", third.name),
                           ("finished", third.name)]
    assert cells_module.Claims.holder(claims, third.name) == "gpu0"


def _smoke_plan(out, only=DEVICE_EXPERIMENTS):
    return command.make_plan(command.ReproduceArgs(profile="smoke", only=only, out=out))


def test_a_dead_device_stream_fails_its_cells(tmp_path, monkeypatch):
    import io

    from rich.console import Console

    monkeypatch.setattr(cell_stream, "child_argv", lambda *_: [sys.executable, "-c", "raise SystemExit(3)"])
    plan = _smoke_plan(tmp_path, "classify")
    text = io.StringIO()
    outcomes = command.run_cells(plan, Console(file=text, width=300), platform="cpu", gpus=TWO.gpus)
    assert set(outcomes) == {c.name for c in plan.cells}
    streams = {c.name: "gpu0" if "ppo-noise" not in c.name else "gpu1" for c in plan.cells}  # 15 s each: a, c / b
    for name, outcome in outcomes.items():
        assert outcome.startswith(f"failed: the {streams[name]} stream (") and "exited with status 3" in outcome
    assert "on 2 GPUs (gpu0" in text.getvalue()
    assert not (tmp_path / "timings.jsonl").exists()  # no cell had started


def test_ctrl_c_stops_every_stream(tmp_path, monkeypatch):
    import io
    import signal
    import time

    from rich.console import Console

    def child(plan, spec, fd):  # a stream that says it is up, then sleeps until its SIGINT
        up = tmp_path / f"{spec.name}.up"  # (taking SIGINT as `cell_stream_main` does, even if
        # this test runs with SIGINT ignored, as under a non-interactive shell's `&`)
        return [sys.executable, "-c", "import pathlib, signal, time; "
                "signal.signal(signal.SIGINT, signal.default_int_handler); "
                f"pathlib.Path({str(up)!r}).touch(); time.sleep(120)"]

    def interrupted(self):  # Ctrl-C while this process waits for its streams, both up
        deadline = time.monotonic() + 120
        while len(list(tmp_path.glob("*.up"))) < 2 and time.monotonic() < deadline:
            time.sleep(0.1)
        raise KeyboardInterrupt

    stopped = []

    def stop(streams):
        stopped.extend(streams)
        cell_stream.stop_streams(streams)

    monkeypatch.setattr(cell_stream, "child_argv", child)
    monkeypatch.setattr(cell_stream.CellStream, "wait", interrupted)
    monkeypatch.setattr(command, "stop_streams", stop)
    text = io.StringIO()
    with pytest.raises(KeyboardInterrupt):
        command.run_cells(_smoke_plan(tmp_path), Console(file=text, width=300), platform="cpu", gpus=TWO.gpus)
    assert [s.spec.name for s in stopped] == ["gpu0", "gpu1"]
    # Each child stopped by its SIGINT (a cell would checkpoint), never killed, never left running.
    assert [s.proc.returncode for s in stopped] == [-signal.SIGINT] * 2
    assert "interrupted in between cells" in text.getvalue() and "failed" not in text.getvalue()


def _eval_rows(directory, name):
    from jaxnat.training import read_run

    return [{k: v for k, v in r.items() if k not in ("chunk_seconds", "steps_per_second")}
            for r in read_run(directory / name).evals]


E2E = """
import json, sys
from rich.console import Console
from jaxnat.reproduce import command, gpus
args = command.ReproduceArgs(profile="smoke", only=sys.argv[2], out=sys.argv[1], gpus="2")
command.reproduce(args, console=Console(width=300), devices=gpus.Devices("cpu", ("0", "1")))
print(json.dumps({"jax started": gpus.jax_started()}))
"""


def test_smoke_device_cells_train_in_two_streams_and_report(tmp_path):
    """Every device cell of the smoke grid, in two child streams (one resuming an interrupted
    cell), from a fresh `jaxnat reproduce` process that never starts JAX itself: the same results
    as training in this process, each stream's log, and the report."""
    from rich.console import Console

    from jaxnat.training import run_status, train

    out, alone = tmp_path / "out", tmp_path / "alone"
    plan = _smoke_plan(out)
    first = plan.cells[0]
    fast = {"xla_backend_optimization_level": 0}
    train(first.train_args(plan.seeds, alone / first.name), console=Console(quiet=True), compiler_options=fast)
    stopped = train(first.train_args(plan.seeds, out / first.name), console=Console(quiet=True),
                    compiler_options=fast, stop_after_chunks=1)
    assert not stopped.complete and run_status(out / first.name) == "partial"

    env = {**os.environ, "PYTHONPATH": str(Path(jaxnat.__file__).resolve().parents[1])}
    done = subprocess.run([sys.executable, "-c", E2E, str(out), DEVICE_EXPERIMENTS], env=env, capture_output=True,
                          text=True, timeout=1800)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert json.loads(done.stdout.splitlines()[-1]) == {"jax started": False}
    assert "on 2 GPUs (gpu0" in done.stdout and "gpu1" in done.stdout
    seconds = {c.name: estimates.estimate_seconds(c, plan.seeds, "cpu") for c in plan.cells}
    streams = estimates.split_streams(plan.cells, overlap=True, gpus=2, seconds=seconds)
    assert list(streams) == ["gpu0", "gpu1"]
    then = cell_stream.pool_streams(streams)  # each GPU may take the other's cells it has not started
    for name, cells in streams.items():
        header = (out / "logs" / cell_stream.stream_log(name)).read_text().splitlines()[0]
        assert header.endswith(f"CUDA_VISIBLE_DEVICES={name[3:]} {', '.join(c.name for c in cells)} | then, unless "
                               f"started: {', '.join(c.name for c in then[name])}")
    rows = [json.loads(line) for line in (out / "timings.jsonl").read_text().splitlines()]
    assert sorted(r["cell"] for r in rows) == sorted(c.name for c in plan.cells)  # each cell trained once
    assert not any((out / "logs" / "claims").iterdir())  # the run's claims go with it
    assert all(r["outcome"] == "finished" and r["overlapped"] for r in rows)
    assert [r["resumed"] for r in rows if r["cell"] == first.name] == [True]
    assert _eval_rows(out, first.name) == _eval_rows(alone, first.name)
    report = (out / "report.md").read_text()
    assert f"Cells: {len(plan.cells)} in the grid, {len(plan.cells)} finished" in report
    assert "| elapsed (streams of cells side by side" in report
    # A rerun trains nothing and starts no stream.
    timings = (out / "timings.jsonl").read_text()
    command.reproduce(command.ReproduceArgs(profile="smoke", only=DEVICE_EXPERIMENTS, out=out, gpus="2"),
                      console=Console(quiet=True), devices=TWO)
    assert (out / "timings.jsonl").read_text() == timings
    starts = (out / "logs" / cell_stream.stream_log("gpu0")).read_text().splitlines()
    assert sum(line.startswith("--- ") for line in starts) == 1
