"""The `jaxnat reproduce` command: check the arguments, estimate, run the grid's cells (skipping
finished ones, resuming interrupted ones), then write the report.

On an accelerator the cells run as two streams at once: the device cells (seeds vmapped on the
accelerator) in this process, one after another, and the host cells (Natural Atari: ALE on the
host's cores, a small policy on the accelerator) in a child process,
`python -m jaxnat.reproduce.hoststream`, writing to the same `--out` (`docs/design.md` says why
a process and not a thread). On a CPU, or with `--sequential`, every cell runs in turn here."""

from __future__ import annotations

import dataclasses
import datetime
import difflib
import inspect
import json
import sys
import time
from pathlib import Path
from typing import Annotated, Optional

import tyro

from jaxnat.cli import exit_status
from jaxnat.reproduce.grid import EXPERIMENTS, PROFILES, RUN_SETTINGS, Cell, Profile, build_grid

PROG = "jaxnat reproduce"

# Rough env steps/s (all seeds of a cell together) and the seconds a cell spends besides
# training (compiling, where it is not hidden behind the cell before, evaluating, test play),
# per experiment, for the estimate printed before starting (with host cells alongside, that of
# the longer stream: `estimate_total`); the progress bar's ETA then follows the measured pace. The GPU figures follow the quick profile's cells (bench/reproduce_cost.py;
# Atari: 256 envs in two parts, the seeds one after another).
RATES = {"cpu": {"classify": 2e3, "localize": 3e2, "atari": 1e3, "mujoco": 2e2},
         "gpu": {"classify": 3.2e4, "localize": 1.5e4, "atari": 1e4, "mujoco": 2.5e4}}
COMPILE_S = {"cpu": {"classify": 15, "localize": 45, "atari": 15, "mujoco": 60},
             "gpu": {"classify": 8, "localize": 23, "atari": 106, "mujoco": 35}}


class ReproduceError(Exception):
    """A user error: printed as one line `jaxnat reproduce: error: <message>`, exit status 2."""


@dataclasses.dataclass
class ReproduceArgs:
    """Run the paper's experiments (a grid of `jaxnat train` runs) and write a findings report.
    Rerunning the same command skips finished cells and resumes an interrupted one."""

    profile: Annotated[str, tyro.conf.arg(metavar="{" + ",".join(PROFILES) + "}")] = "quick"
    """smoke: every cell type, tiny budgets, minutes on a CPU; quick: every finding, reduced budgets (one sitting on one GPU); paper: the paper's budgets (run piecewise with --only)."""
    only: Annotated[str, tyro.conf.arg(metavar=",".join(EXPERIMENTS))] = ",".join(EXPERIMENTS)
    """Comma-separated experiments to run and report."""
    seeds: Annotated[Optional[int], tyro.conf.arg(metavar="INT", help_behavior_hint="")] = None
    """Seeds per cell (unset: the profile's, 5 for quick and paper)."""
    out: Annotated[Optional[Path], tyro.conf.arg(metavar="DIR", help_behavior_hint="")] = None
    """Where the cells and the report go (unset: runs/reproduce-<profile>)."""
    report_only: bool = False
    """Write the report from the cells already in --out without training."""
    sequential: bool = False
    """Run every cell in turn, also on an accelerator (by default there the Natural Atari cells, which run on the host's cores, train in a second process alongside the others)."""


@dataclasses.dataclass(frozen=True)
class Plan:
    profile: Profile
    only: tuple[str, ...]
    seeds: int
    out: Path
    cells: list[Cell]


def parse_args(argv=None) -> ReproduceArgs:
    argv = sys.argv[1:] if argv is None else list(argv)
    return tyro.cli(ReproduceArgs, args=argv, prog=PROG, description=inspect.cleandoc(ReproduceArgs.__doc__))


def make_plan(args: ReproduceArgs) -> Plan:
    """Check the arguments (one-line `ReproduceError`s) and build the grid."""
    if args.profile not in PROFILES:
        close = difflib.get_close_matches(args.profile, PROFILES, n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise ReproduceError(f"unknown --profile {args.profile!r}{hint}; profiles: {', '.join(PROFILES)}")
    profile = PROFILES[args.profile]
    only = tuple(name.strip() for name in args.only.split(",") if name.strip())
    unknown = [name for name in only if name not in EXPERIMENTS]
    if unknown or not only:
        close = difflib.get_close_matches(unknown[0], EXPERIMENTS, n=1) if unknown else []
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        what = f"unknown --only name {unknown[0]!r}{hint}" if unknown else "--only names no experiment"
        raise ReproduceError(f"{what}; experiments: {', '.join(EXPERIMENTS)}")
    seeds = profile.seeds if args.seeds is None else args.seeds
    if seeds < 1:
        raise ReproduceError("--seeds must be at least 1")
    out = Path(args.out) if args.out is not None else Path("runs") / f"reproduce-{profile.name}"
    _check_writable(out)
    return Plan(profile, only, seeds, out, build_grid(profile, only))


def _check_writable(out: Path) -> None:
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = out / ".write-test"
        probe.write_text("")
        probe.unlink()
    except OSError as err:
        raise ReproduceError(f"--out {out} is not writable ({err.strerror or err}); choose another folder") from None


def _platform() -> str:
    import jax

    return "cpu" if jax.default_backend() == "cpu" else "gpu"


def estimate_seconds(cell: Cell, seeds: int, platform: str) -> float:
    """A rough wall time of `cell` (compile + training + evaluation), for the ETA."""
    steps = cell.budget.total_timesteps * seeds
    return COMPILE_S[platform][cell.experiment] + steps / RATES[platform][cell.experiment]


def split_streams(cells: list[Cell], overlap: bool) -> dict[str, list[Cell]]:
    """The cells as the streams that run at the same time, each in grid order: `{"device": ...,
    "host": ...}` when `overlap` and both kinds have cells, else `{"all": cells}` (one after
    another)."""
    device, host = [c for c in cells if not c.host], [c for c in cells if c.host]
    return {"device": device, "host": host} if overlap and device and host else {"all": list(cells)}


def estimate_total(streams: dict[str, list[Cell]], seeds: int, platform: str) -> float:
    """The estimated wall time of `streams` (`split_streams`): the longest stream, as they run at
    the same time (the sum of its cells' `estimate_seconds`). Contention between the streams
    (the accelerator's time, the host's cores while compiling) is not counted."""
    return max((sum(estimate_seconds(c, seeds, platform) for c in cells) for cells in streams.values()), default=0.0)


def _train_argv(cell: Cell, plan: Plan, resume: bool) -> list[str]:
    """The `jaxnat train` arguments of `cell`: a new run, or `--resume` of its folder."""
    run_dir = plan.out / cell.name
    argv = cell.train_argv(plan.seeds, run_dir)
    if resume:
        cut = argv.index("--run-dir")
        argv = ["--resume", str(run_dir), *argv[:cut], *argv[cut + 2:]]
    return argv


def append_jsonl(path: Path, row: dict) -> None:
    """Append `row` to `path` as one JSON line, in one `write` to a file opened for appending and
    under an exclusive lock where the OS has one: two processes appending at once (the streams
    of cells) never interleave their lines."""
    import os

    data = (json.dumps(row) + "\n").encode()
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        try:
            import fcntl
        except ImportError:  # no POSIX locks (Windows): O_APPEND alone places each write at the end
            fcntl = None
        if fcntl is not None:
            fcntl.flock(fd, fcntl.LOCK_EX)
        view = memoryview(data)
        while view:
            view = view[os.write(fd, view):]
    finally:
        os.close(fd)  # releases the lock


class _CompileAhead:
    """Compiles the next cell's programs on a worker thread while the current cell trains: XLA
    compiles on the host's cores while the run keeps the accelerator busy, so a grid of short
    cells is not paced by its compiles. The programs are traced and lowered on the calling
    thread first (`jaxnat.training.prepare_programs`; JAX's tracing is not shared across
    threads), then `train` finds them compiled in the process's cache. A failure here is left
    for `train` to report."""

    def __init__(self, enabled: bool, compiler_options: dict | None):
        from concurrent.futures import ThreadPoolExecutor

        self.enabled, self.compiler_options = enabled, compiler_options
        self.pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="compile-ahead") if enabled else None
        self.pending = None

    def start(self, argv: list[str] | None) -> None:
        """Lower the programs of the run `argv` describes and start compiling them (None:
        nothing to compile)."""
        if not self.enabled or argv is None:
            return
        from jaxnat.training import parse_args as parse_train_args, prepare_programs

        try:
            compile_programs = prepare_programs(parse_train_args(argv), compiler_options=self.compiler_options)
        except Exception:  # noqa: BLE001 (train reports it, in its own words, when the cell runs)
            return
        self.pending = self.pool.submit(compile_programs)

    def wait(self) -> None:
        """Block until the compile started last is done (its errors are left for `train`)."""
        if self.pending is not None:
            self.pending.exception()
            self.pending = None

    def close(self) -> None:
        if self.pool is not None:
            self.pool.shutdown(wait=False, cancel_futures=True)


class _Board:
    """What the user sees of the cells of both streams: the progress bar (cells done of all, and
    an ETA over the estimate of the longest stream still running), one line per cell start and
    end without a terminal, failures in red, and each cell's outcome. Thread-safe: the host
    stream's events arrive on a reader thread."""

    def __init__(self, console, streams: dict[str, list[Cell]], estimates: dict[str, float]):
        import threading

        from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

        self.console, self.estimates, self.lock = console, estimates, threading.Lock()
        self.stream_of = {c.name: stream for stream, cells in streams.items() for c in cells}
        self.cells = {c.name: c for cells in streams.values() for c in cells}
        self.overlapped = len(streams) > 1
        self.left = {stream: sum(estimates[c.name] for c in cells) for stream, cells in streams.items()}
        self.total = max(self.left.values(), default=0.0)
        self.count = sum(len(cells) for cells in streams.values())
        self.started, self.finished = 0, 0
        self.number: dict[str, int] = {}
        self.running: dict[str, float] = {}  # cell name -> when it started (time.time())
        self.resumed: dict[str, bool] = {}
        self.outcomes: dict[str, str] = {}
        self.live = console.is_terminal
        self.progress = Progress(TextColumn("{task.description}"), BarColumn(bar_width=20),
                                 TextColumn("{task.fields[cells]}"), TimeElapsedColumn(), TextColumn("eta"),
                                 TimeRemainingColumn(), console=console, disable=not self.live)
        self.task = self.progress.add_task("cells", total=max(self.total, 1e-9), cells=f"0/{self.count}")

    def _label(self, name: str) -> str:
        tags = [tag for tag, on in (("resumed", self.resumed.get(name)),
                                    ("alongside", self.overlapped and self.cells[name].host)) if on]
        return f"{name} ({', '.join(tags)})" if tags else name

    def _running(self) -> str:
        return ", ".join(map(self._label, self.running)) or "cells"

    def start(self, cell: Cell, resumed: bool) -> None:
        with self.lock:
            self.started += 1
            self.number[cell.name] = self.started
            self.running[cell.name] = time.time()
            self.resumed[cell.name] = resumed
            self.progress.update(self.task, description=self._running())
            if not self.live:
                self.console.print(f"[{self.started}/{self.count}] {self._label(cell.name)} ...", highlight=False)

    def done(self, cell: Cell, outcome: str, seconds: float) -> None:
        with self.lock:
            self.running.pop(cell.name, None)
            self.outcomes[cell.name] = outcome
            self.finished += 1
            self.left[self.stream_of[cell.name]] -= self.estimates[cell.name]
            # Done is the estimate of all streams less that of the longest one still to run.
            completed = self.total - max(max(self.left.values(), default=0.0), 0.0)
            self.progress.update(self.task, completed=completed, cells=f"{self.finished}/{self.count}",
                                 description=self._running())
            if outcome.startswith("failed"):
                self.console.print(f"{cell.name}: {outcome.removeprefix('failed: ')}", style="red", highlight=False)
            if not self.live:
                self.console.print(f"[{self.number.get(cell.name, '?')}/{self.count}] {cell.name}: {outcome} in "
                                   f"{seconds:.0f} s", highlight=False)


class _Events:
    """The host stream's side of `_Board`: each cell's start and end as one JSON line on the
    pipe `fd` to the parent `jaxnat reproduce` (which shows them; nothing is sent when it is
    gone), and as a line on `console` (the stream's log)."""

    def __init__(self, fd: int, console):
        self.fd, self.console, self.outcomes = fd, console, {}

    def _send(self, event: dict) -> None:
        import os

        try:
            os.write(self.fd, (json.dumps(event) + "\n").encode())
        except OSError:  # the parent is gone; its watcher stops this process
            pass

    def start(self, cell: Cell, resumed: bool) -> None:
        self.console.print(f"{cell.name}{' (resumed)' if resumed else ''} ...", highlight=False)
        self._send({"event": "start", "cell": cell.name, "resumed": resumed})

    def done(self, cell: Cell, outcome: str, seconds: float) -> None:
        self.outcomes[cell.name] = outcome
        self.console.print(f"{cell.name}: {outcome} in {seconds:.0f} s", highlight=False)
        self._send({"event": "done", "cell": cell.name, "outcome": outcome, "seconds": seconds})


def _train_cells(cells: list[Cell], plan: Plan, resumed: dict[str, bool], board, *, platform: str,
                 compile_ahead: bool, overlapped: bool) -> None:
    """Train `cells` one after another (compiling each one's programs while the one before
    trains when `compile_ahead`), each logged to `<out>/logs/<cell>.log` and timed in
    `<out>/timings.jsonl`; `board` is told of each start and outcome. A `TrainError` fails its
    cell and the next one starts; anything else (Ctrl-C included) propagates."""
    from rich.console import Console

    from jaxnat.training import TrainError, parse_args as parse_train_args, train

    compiler_options = {"xla_backend_optimization_level": 0} if plan.profile.fast_compile else None
    logs = plan.out / "logs"
    logs.mkdir(exist_ok=True)
    ahead = _CompileAhead(compile_ahead, compiler_options)
    argvs = [_train_argv(c, plan, resumed[c.name]) for c in cells]
    try:
        ahead.start(argvs[0] if argvs else None)
        for index, cell in enumerate(cells):
            board.start(cell, resumed[cell.name])
            started, start = time.time(), time.perf_counter()
            ahead.wait()  # this cell's programs (their compile time is counted in this cell)
            ahead.start(argvs[index + 1] if index + 1 < len(cells) else None)
            with (logs / f"{cell.name}.log").open("a") as log:
                log_console = Console(file=log, width=120, force_terminal=False)
                try:
                    train(parse_train_args(argvs[index]), console=log_console, compiler_options=compiler_options)
                    outcome = "finished"
                except TrainError as err:
                    outcome = f"failed: {err}"
            seconds = time.perf_counter() - start
            append_jsonl(plan.out / "timings.jsonl", _timing_row(cell, plan, seconds, resumed[cell.name], outcome,
                                                                 platform, started, overlapped))
            board.done(cell, outcome, seconds)
    finally:
        ahead.close()


def _timing_row(cell: Cell, plan: Plan, seconds: float, resumed: bool, outcome: str, platform: str,
                started: float, overlapped: bool) -> dict:
    """A line of `<out>/timings.jsonl`: `start` (Unix time) and `overlapped` (run as one of two
    streams at once) let the report tell the elapsed time from the sum of the cells'."""
    return {"cell": cell.name, "experiment": cell.experiment, "seconds": seconds,
            "estimate": estimate_seconds(cell, plan.seeds, platform), "resumed": resumed,
            "outcome": outcome.split(":")[0], "message": outcome, "platform": platform,
            "date": datetime.datetime.now().isoformat(timespec="seconds"), "start": started,
            "overlapped": overlapped}


# The host stream's scheduling priority: below the device stream's, whose XLA compiles would
# otherwise wait behind ALE's threads on a fully used host. The device stream is the longer one
# in `quick`, so it is the one to keep moving; the host cells only need the cores it leaves.
HOST_STREAM_NICE = 5
HOST_STREAM_LOG = "host-stream.log"  # in <out>/logs/: the child's own output (a crash's traceback)


def _child_argv(plan: Plan, cells: list[Cell], events_fd: int) -> list[str]:
    return [sys.executable, "-m", "jaxnat.reproduce.hoststream", "--profile", plan.profile.name,
            "--seeds", str(plan.seeds), "--out", str(plan.out), "--cells", ",".join(c.name for c in cells),
            "--events-fd", str(events_fd)]


class _HostStream:
    """The host cells trained by a child process (`python -m jaxnat.reproduce.hoststream`,
    `host_stream_main`) while this one trains the device cells. The child writes the cells'
    folders, logs and timing lines as this process would; its start and end events come back
    on a pipe to `board`. Its output goes to `<out>/logs/host-stream.log`. It is in a session of
    its own, so a Ctrl-C reaches it once, from `stop`; it stops by itself when this process
    dies (its stdin, a pipe from here, closes)."""

    def __init__(self, cells: list[Cell], plan: Plan, board: _Board, platform: str):
        import os
        import subprocess
        import threading

        import jaxnat

        self.cells, self.plan, self.board, self.platform = cells, plan, board, platform
        self.by_name = {c.name: c for c in cells}
        self.stopped = False  # by `stop`: its end is not a failure
        self.log = plan.out / "logs" / HOST_STREAM_LOG
        self.log.parent.mkdir(exist_ok=True)
        read_end, write_end = os.pipe()
        env = dict(os.environ)
        # The child runs this process's jaxnat, and allocates accelerator memory as it needs it:
        # this process has already reserved most of it (JAX preallocates), the policy needs little.
        source = str(Path(jaxnat.__file__).resolve().parents[1])
        env["PYTHONPATH"] = os.pathsep.join([source, *filter(None, [env.get("PYTHONPATH")])])
        env["XLA_PYTHON_CLIENT_PREALLOCATE"] = "false"
        try:
            with self.log.open("a") as log:
                log.write(f"--- {datetime.datetime.now().isoformat(timespec='seconds')}: "
                          f"{', '.join(c.name for c in cells)}\n")
                log.flush()
                self.proc = subprocess.Popen(_child_argv(plan, cells, write_end), stdin=subprocess.PIPE, stdout=log,
                                             stderr=subprocess.STDOUT, pass_fds=(write_end,), env=env,
                                             start_new_session=True)
        finally:
            os.close(write_end)
        self.reader = threading.Thread(target=self._read, args=(read_end,), name="host-stream-events", daemon=True)
        self.reader.start()

    def _read(self, fd: int) -> None:
        import os

        with os.fdopen(fd, "rb") as pipe:
            for line in pipe:
                try:
                    event = json.loads(line)
                    cell = self.by_name[event["cell"]]
                except (ValueError, KeyError, TypeError):
                    continue
                if event.get("event") == "start":
                    self.board.start(cell, bool(event.get("resumed")))
                elif event.get("event") == "done":
                    self.board.done(cell, str(event.get("outcome")), float(event.get("seconds", 0.0)))

    def wait(self) -> int:
        """Wait for the child to end; every host cell it did not finish is reported failed (the
        one it was in also gets its timing line, which the child had no time to write).
        Returns the child's exit status."""
        import signal

        status = self.proc.wait()
        self.reader.join()
        self.proc.stdin.close()
        if not self.stopped:
            ended = "was interrupted" if status in (130, -signal.SIGINT) else f"exited with status {status}"
            why = f"the host stream ({sys.executable} -m jaxnat.reproduce.hoststream) {ended} before this " \
                  f"cell finished; its output: {self.log}"
            for cell in self.cells:
                if cell.name in self.board.outcomes:
                    continue
                started = self.board.running.get(cell.name)
                seconds = 0.0 if started is None else time.time() - started
                if started is not None:
                    append_jsonl(self.plan.out / "timings.jsonl",
                                 _timing_row(cell, self.plan, seconds, self.board.resumed.get(cell.name, False),
                                             f"failed: {why}", self.platform, started, True))
                self.board.done(cell, f"failed: {why}", seconds)
        return status

    def stop(self) -> None:
        """Interrupt the child (it checkpoints its cell, as a Ctrl-C would) and wait for it; a
        second Ctrl-C while waiting kills it."""
        import signal

        self.stopped = True
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
        try:
            self.proc.wait()
        except KeyboardInterrupt:
            self.proc.kill()
            self.proc.wait()
            raise
        finally:
            self.reader.join(timeout=5)
            self.proc.stdin.close()


def _default_overlap(platform: str) -> bool:
    import os

    return platform != "cpu" and os.name == "posix"


def run_cells(plan: Plan, console, *, compile_ahead: bool | None = None, overlap: bool | None = None) -> dict:
    """Train every runnable, unfinished cell of `plan`; returns `{cell name: outcome}` where an
    outcome is "finished before", "finished", or "failed: <one line>".

    `compile_ahead`: compile each device cell's programs while the one before trains (None: on an
    accelerator, not on a CPU, where compiling would take the cores the training uses).
    `overlap`: train the host cells (`Cell.host`) in a child process while the device cells
    train here (None: on an accelerator under POSIX; a CPU's cores are the training's). With
    both kinds to run, the estimate and the ETA are the longer stream's, the child's failures
    (a cell's, or its own death) are reported as the cells', and a Ctrl-C stops both (each
    checkpoints its cell) before `KeyboardInterrupt` propagates."""
    from jaxnat.training import read_run, run_status

    platform = _platform()
    runnable = [c for c in plan.cells if not c.skip]
    status = {c.name: run_status(plan.out / c.name) for c in runnable}
    for cell in runnable:
        if status[cell.name] != "new":
            _check_same_run(cell, plan, read_run(plan.out / cell.name).config)
    todo = [c for c in runnable if status[c.name] != "finished"]
    streams = split_streams(todo, _default_overlap(platform) if overlap is None else overlap)
    estimates = {c.name: estimate_seconds(c, plan.seeds, platform) for c in todo}
    total = estimate_total(streams, plan.seeds, platform)
    alongside = ""
    if "host" in streams:
        device, host = (sum(estimates[c.name] for c in streams[k]) for k in ("device", "host"))
        alongside = (f" (host cells {_duration(host)} alongside device cells {_duration(device)})")
    console.print(f"{PROG}: profile {plan.profile.name} · {len(plan.cells)} cells ({len(runnable) - len(todo)} "
                  f"finished before, {len(plan.cells) - len(runnable)} not runnable here) · {plan.seeds} seeds · "
                  f"estimated {_duration(total)} on this {platform.upper()}{alongside} · {plan.out}", highlight=False)
    board = _Board(console, streams, estimates)
    board.outcomes.update({c.name: "finished before" for c in runnable if status[c.name] == "finished"})
    resumed = {c.name: status[c.name] == "partial" for c in todo}
    ahead = platform != "cpu" if compile_ahead is None else compile_ahead
    host = None
    try:
        with board.progress:
            if "host" in streams:
                host = _HostStream(streams["host"], plan, board, platform)
            _train_cells(streams.get("device", streams.get("all")), plan, resumed, board, platform=platform,
                         compile_ahead=ahead, overlapped=host is not None)
            if host is not None:
                host.wait()
    except BaseException as err:
        if host is not None:
            host.stop()
        if isinstance(err, KeyboardInterrupt):
            where = " and ".join(board.running) or "between cells"
            console.print(f"interrupted in {where} (checkpointed); rerun the same command to continue")
        raise
    return board.outcomes


def host_stream_main(argv=None) -> int:
    """The host stream's process (`python -m jaxnat.reproduce.hoststream`, started by `run_cells`,
    not by hand): train the named cells of the grid into `--out` as `run_cells` would, telling
    the parent of each start and end on the pipe `--events-fd`; no report. Stops as after a
    Ctrl-C when its stdin closes (the parent is gone). Exit status 0, 130 when interrupted."""
    import argparse
    import os
    import signal
    import threading

    from rich.console import Console

    parser = argparse.ArgumentParser(prog="python -m jaxnat.reproduce.hoststream")
    parser.add_argument("--profile", required=True, choices=list(PROFILES))
    parser.add_argument("--seeds", required=True, type=int)
    parser.add_argument("--out", required=True, type=Path)
    parser.add_argument("--cells", required=True)
    parser.add_argument("--events-fd", required=True, type=int)
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)

    parent_gone = threading.Event()

    def watch_parent() -> None:
        # The raw descriptor, not sys.stdin: a daemon thread blocked in a buffered read holds
        # its lock, which the interpreter's shutdown then cannot take.
        while os.read(0, 4096):  # b"": the parent closed the pipe or died
            pass
        parent_gone.set()
        os.kill(os.getpid(), signal.SIGINT)

    console = Console()
    threading.Thread(target=watch_parent, name="parent-watch", daemon=True).start()
    try:  # from here: an interrupt may come at any point, setup included
        os.set_inheritable(args.events_fd, False)  # the pipe ends with this process, not a child of it
        if hasattr(os, "nice"):
            os.nice(HOST_STREAM_NICE)
        profile = PROFILES[args.profile]
        grid = {c.name: c for c in build_grid(profile)}
        names = args.cells.split(",")
        unknown = [name for name in names if name not in grid]
        if unknown:
            parser.error(f"no cell {unknown[0]!r} in the {args.profile} grid")
        cells = [grid[name] for name in names]
        plan = Plan(profile, tuple(dict.fromkeys(c.experiment for c in cells)), args.seeds, args.out, cells)
        from jaxnat.training import run_status

        resumed = {c.name: run_status(args.out / c.name) == "partial" for c in cells}
        _train_cells(cells, plan, resumed, _Events(args.events_fd, console), platform=_platform(), compile_ahead=False,
                     overlapped=True)
    except KeyboardInterrupt:
        console.print("interrupted (checkpointed)")
        return 130
    # An interrupt the trainer took itself (it checkpoints and stops the cell) still ends the
    # stream as interrupted: the parent is gone, so nothing more may be trained or reported.
    return 130 if parent_gone.is_set() else 0


def _check_same_run(cell: Cell, plan: Plan, config: dict) -> None:
    """A cell folder written with other seeds or budgets is not silently mixed into this grid."""
    spec = config.get("spec", {})
    from jaxnat.training import parse_env_kwargs

    saved = (spec.get("env_id"), spec.get("env_kwargs"), spec.get("algo"), spec.get("seeds"),
             spec.get("config", {}).get("total_timesteps"), spec.get("env_parts", RUN_SETTINGS["env_parts"]))
    wanted = (cell.env_id, parse_env_kwargs({k: str(v) for k, v in cell.env_kwargs.items()}, cell.env_id), cell.algo, plan.seeds,
              cell.budget.total_timesteps, cell.overrides.get("env_parts", RUN_SETTINGS["env_parts"]))
    if saved != wanted:
        raise ReproduceError(f"{plan.out / cell.name} holds a run with other settings (env, kwargs, algo, seeds, "
                             f"steps, env parts {saved}; this grid wants {wanted}); use another --out, or the same "
                             "--profile and --seeds")


def _duration(seconds: float) -> str:
    seconds = int(round(seconds))
    return f"{seconds // 3600}h{seconds % 3600 // 60:02d}m" if seconds >= 3600 else f"{seconds // 60}m{seconds % 60:02d}s"


def reproduce(args: ReproduceArgs, *, console=None, overlap: bool | None = None) -> Path:
    """Run (or continue) the grid and write the report once every cell has ended; returns the
    report's path. `overlap`: `run_cells`'s (None: its default, unless `args.sequential`)."""
    from rich.console import Console

    from jaxnat.reproduce.report import write_report

    console = console or Console()
    plan = make_plan(args)
    if args.sequential:
        overlap = False
    outcomes = {} if args.report_only else run_cells(plan, console, overlap=overlap)
    path = write_report(plan, outcomes)
    console.print(f"report: {path}", highlight=False)
    return path


def main(argv=None) -> int:
    """`jaxnat reproduce` with `argv` (default: sys.argv[1:]); returns the exit status."""
    args = parse_args(argv)
    return exit_status(lambda: reproduce(args), ReproduceError, PROG)
