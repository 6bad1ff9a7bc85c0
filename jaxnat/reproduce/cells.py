"""Training cells in this process, one after another (`train_cells`): each is handed to
`jaxnat.training.train` as its typed arguments (`Cell.train_args`), logged to
`<out>/logs/<cell>.log` and timed by a line of `<out>/timings.jsonl`. On an accelerator each
cell's programs compile while the cell before trains (`CompileAhead`). Every stream of cells
trains this way: the device cells in `jaxnat reproduce`'s process (or, with several GPUs, in one
child process per GPU), the host cells in the host stream's (`cell_stream`)."""

from __future__ import annotations

import datetime
import json
import time
from pathlib import Path

from jaxnat.reproduce.estimates import estimate_seconds
from jaxnat.reproduce.grid import Cell, Plan


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


def timing_row(cell: Cell, plan: Plan, seconds: float, resumed: bool, outcome: str, platform: str,
               started: float, overlapped: bool) -> dict:
    """A line of `<out>/timings.jsonl`: `start` (Unix time) and `overlapped` (run as one of two
    streams at once) let the report tell the elapsed time from the sum of the cells'."""
    return {"cell": cell.name, "experiment": cell.experiment, "seconds": seconds,
            "estimate": estimate_seconds(cell, plan.seeds, platform), "resumed": resumed,
            "outcome": outcome.split(":")[0], "message": outcome, "platform": platform,
            "date": datetime.datetime.now().isoformat(timespec="seconds"), "start": started,
            "overlapped": overlapped}


def runtime_errors() -> tuple[type[Exception], ...]:
    """The exception types of XLA's runtime failures (`jax.errors.JaxRuntimeError`)."""
    import jax

    found = getattr(jax.errors, "JaxRuntimeError", None)
    return (found,) if isinstance(found, type) else ()


def one_line(err: Exception) -> str:
    """`err` as one line: a `TrainError`'s message, or an XLA runtime error's first line with the
    fix for the usual one (out of memory)."""
    text = next((line.strip() for line in str(err).splitlines() if line.strip()), type(err).__name__)
    if "RESOURCE_EXHAUSTED" in str(err):
        text = f"out of device memory ({text[:160]}); give the cell fewer envs per seed (num_envs) or fewer seeds"
    return text


class Claims:
    """Which stream trains a cell when several streams share a pool of cells (`train_cells`'s
    `claim`): the first to create `<folder>/<cell name>`, an exclusive create (one winner on a
    local file system, and on NFS v3 or later), so that a GPU that runs out of its own cells
    takes one another GPU has not started. `folder` is new for each `jaxnat reproduce`, so that
    a cell claimed by a run that was stopped is free again."""

    def __init__(self, folder: Path, stream: str):
        self.folder, self.stream = Path(folder), stream

    def take(self, cell: Cell) -> bool:
        """Claim `cell` for this stream: True once, for the first stream to ask."""
        import os

        try:
            fd = os.open(self.folder / cell.name, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
        except FileExistsError:
            return False
        with os.fdopen(fd, "w") as f:
            f.write(self.stream)
        return True

    @staticmethod
    def holder(folder: Path, name: str) -> str | None:
        """The stream that claimed the cell `name` in `folder` (None: none has)."""
        path = Path(folder) / name
        return path.read_text() or None if path.exists() else None


class CompileAhead:
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

    def start(self, args) -> None:
        """Lower the programs of the run `args` (a `jaxnat.training.TrainArgs`) describes and
        start compiling them (None: nothing to compile)."""
        if not self.enabled or args is None:
            return
        from jaxnat.training import prepare_programs

        try:
            compile_programs = prepare_programs(args, compiler_options=self.compiler_options)
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


def train_cells(cells: list[Cell], plan: Plan, resumed: dict[str, bool], board, *, platform: str,
                compile_ahead: bool, overlapped: bool, claim=None) -> None:
    """Train `cells` one after another (compiling each one's programs while the one before
    trains when `compile_ahead`), each logged to `<out>/logs/<cell>.log` and timed in
    `<out>/timings.jsonl`; `board` (`board.Board`, or a child stream's `Events`) is told of
    each start and outcome. `claim` (a cell -> bool, `Claims.take`; None: every cell is
    this stream's) is asked for each cell just before its programs are first compiled, so that
    streams sharing a pool of cells train each once: a cell it refuses is skipped. A `TrainError` fails its cell and the next one starts, and so does
    an error of XLA's runtime (out of GPU memory, in a compile's autotuning or a step): one cell
    too big for the device must not take the stream's other cells down with it. Anything else
    (Ctrl-C included) propagates."""
    from rich.console import Console

    from jaxnat.training import TrainError, train

    failures = (TrainError, *runtime_errors())

    compiler_options = {"xla_backend_optimization_level": 0} if plan.profile.fast_compile else None
    logs = plan.out / "logs"
    logs.mkdir(exist_ok=True)
    ahead = CompileAhead(compile_ahead, compiler_options)
    mine = (c for c in cells if claim is None or claim(c))  # claimed one at a time, when reached

    runs = {}  # cell name -> its run's arguments, made once (the compile ahead and the training share them)

    def run_of(cell):
        if cell is not None and cell.name not in runs:
            runs[cell.name] = cell.train_args(plan.seeds, plan.out / cell.name, resume=resumed[cell.name])
        return None if cell is None else runs[cell.name]

    try:
        cell = next(mine, None)
        ahead.start(run_of(cell))
        while cell is not None:
            board.start(cell, resumed[cell.name])
            started, start = time.time(), time.perf_counter()
            ahead.wait()  # this cell's programs (their compile time is counted in this cell)
            following = next(mine, None)
            ahead.start(run_of(following))
            with (logs / f"{cell.name}.log").open("a") as log:
                log_console = Console(file=log, width=120, force_terminal=False)
                try:
                    train(run_of(cell), console=log_console, compiler_options=compiler_options)
                    outcome = "finished"
                except failures as err:
                    outcome = f"failed: {one_line(err)}"
            seconds = time.perf_counter() - start
            append_jsonl(plan.out / "timings.jsonl", timing_row(cell, plan, seconds, resumed[cell.name], outcome,
                                                                platform, started, overlapped))
            board.done(cell, outcome, seconds)
            cell = following
    finally:
        ahead.close()
