"""The streams of cells `jaxnat reproduce` trains in child processes, each
`python -m jaxnat.reproduce.cellstream` training a named list of the grid's cells into the same
`--out` as its parent: the host stream (Natural Atari: ALE on the host's cores, a small policy on
the accelerator) beside the device cells on an accelerator, and with two or more GPUs one device
stream per GPU (`docs/design.md` says why processes and not threads).

A stream is a `StreamSpec` (a name, its cells, the variables set in its environment, its
scheduling priority, whether it compiles ahead; `child_streams` makes them). The parent's side is
`CellStream` (start the child, show its events on the board, report the cells it did not finish,
stop it); the child's is `cell_stream_main` (train the cells with `cells.train_cells`, sending
each start and end as `Events`, one JSON line each, on a pipe). Only the child's command line
(`child_argv`) is argv; its cells are named, not described."""

from __future__ import annotations

import dataclasses
import datetime
import json
import sys
import time
from pathlib import Path

from jaxnat.reproduce.board import Board
from jaxnat.reproduce.cells import Claims, append_jsonl, timing_row, train_cells
from jaxnat.reproduce.estimates import detect_platform, stream_gpu
from jaxnat.reproduce.grid import ONLY_NAMES, PROFILES, Cell, Plan, build_grid

ENTRY = "jaxnat.reproduce.cellstream"  # the module `python -m` runs in a stream's child
# The host stream's scheduling priority: below the device streams', whose XLA compiles would
# otherwise wait behind ALE's threads on a fully used host. The device cells are the longer
# stream in `quick`, so they are the ones to keep moving; the host cells only need the cores left.
HOST_STREAM_NICE = 5
PREALLOCATED = 0.75  # JAX's default share of a GPU's memory preallocated by a process


def stream_log(name: str) -> str:
    """The stream's log in `<out>/logs/`: the child's own output (a crash's traceback)."""
    return f"{name}-stream.log"


@dataclasses.dataclass(frozen=True)
class StreamSpec:
    """A stream of cells trained by a child process: its `name` (`host`, `gpu0`, ...), its
    `cells` (in grid order), the variables `env` set in its environment on top of this
    process's, its scheduling priority `nice` (added to this process's), and whether it compiles
    each cell's programs while the one before trains (`compile_ahead`)."""

    name: str
    cells: list[Cell]
    env: dict[str, str]
    nice: int = 0
    compile_ahead: bool = False
    # Pooled streams (several on GPUs of one kind, `pool_streams`): the pool's other cells, which
    # this stream takes once its own are done and another has not started them (`cells.Claims`
    # in the folder `claims`), so that no GPU idles while another still has cells to start.
    then: list[Cell] = dataclasses.field(default_factory=list)
    claims: str | None = None


def pool_streams(streams: dict[str, list[Cell]]) -> dict[str, list[Cell]]:
    """For each GPU stream that shares a pool with others (the `gpu<i>` streams of large cells,
    or the packed `gpu<i>-<j>` streams of small ones, two or more of a kind), the pool's cells
    it may take after its own: the others' cells, each stream's from its end (the cells its own
    stream would start last), taken in turn from each."""
    pools: dict[bool, list[str]] = {}
    for name in streams:
        if stream_gpu(name) is not None:
            pools.setdefault("-" in name, []).append(name)
    then = {}
    for names in pools.values():
        if len(names) < 2:
            continue
        for name in names:
            tails = [list(reversed(streams[other])) for other in names if other != name]
            then[name] = [tail[i] for i in range(max(map(len, tails))) for tail in tails if i < len(tail)]
    return then


def child_streams(streams: dict[str, list[Cell]], gpus: tuple[str, ...], seconds: dict[str, float],
                  compile_ahead: bool, claims: Path | None = None) -> list[StreamSpec]:
    """The streams of `estimates.split_streams` that train in child processes. `gpu<i>` (and,
    packed, `gpu<i>-<j>`) sees only the GPU `gpus[i]` (its `CUDA_VISIBLE_DEVICES` id) and
    preallocates it as a one-GPU run would, or, with n streams on that GPU, an n-th of that
    (`XLA_PYTHON_CLIENT_MEM_FRACTION`: `PREALLOCATED`, or the fraction this process was given,
    over n); with a `claims` folder, pooled GPU streams (`pool_streams`) also take their pool's
    other cells when their own are done. `host` allocates accelerator memory as it needs it
    (its GPU's memory is mostly preallocated by a device stream: the parent's with one GPU,
    else that of the GPU whose streams have the least estimated work, by `seconds`) and runs at
    `HOST_STREAM_NICE`."""
    import os

    on = {i: [name for name in streams if stream_gpu(name) == i] for i in range(len(gpus))}
    load = {gpu: sum(seconds[c.name] for name in on[i] for c in streams[name]) for i, gpu in enumerate(gpus)}
    share = float(os.environ.get("XLA_PYTHON_CLIENT_MEM_FRACTION", PREALLOCATED))
    then = pool_streams(streams) if claims is not None else {}
    specs = []
    for name, cells in streams.items():
        index = stream_gpu(name)
        if index is not None:
            env = {"CUDA_VISIBLE_DEVICES": gpus[index]}
            if len(on[index]) > 1:
                env["XLA_PYTHON_CLIENT_MEM_FRACTION"] = f"{share / len(on[index]):.3f}"
            pooled = name in then
            specs.append(StreamSpec(name, cells, env, 0, compile_ahead, then.get(name, []),
                                    str(claims) if pooled else None))
        elif name == "host":
            env = {"XLA_PYTHON_CLIENT_PREALLOCATE": "false"}
            if gpus:
                env["CUDA_VISIBLE_DEVICES"] = min(load, key=load.get)
            specs.append(StreamSpec(name, cells, env, HOST_STREAM_NICE, False))
    return specs


def child_argv(plan: Plan, spec: StreamSpec, events_fd: int) -> list[str]:
    """The child's command line: the stream's name, the grid's cells by name, its priority, and
    the pipe for its events."""
    return [sys.executable, "-m", ENTRY, "--name", spec.name, "--profile", plan.profile.name,
            "--seeds", str(plan.seeds), "--out", str(plan.out), "--cells", ",".join(c.name for c in spec.cells),
            "--events-fd", str(events_fd), "--nice", str(spec.nice), *(["--compile-ahead"] * spec.compile_ahead),
            *(["--then", ",".join(c.name for c in spec.then), "--claims", spec.claims] if spec.claims else [])]


def child_env(spec: StreamSpec) -> dict[str, str]:
    """The child's environment: this process's, running this process's jaxnat, with `spec.env`."""
    import os

    import jaxnat

    env = dict(os.environ)
    source = str(Path(jaxnat.__file__).resolve().parents[1])
    env["PYTHONPATH"] = os.pathsep.join([source, *filter(None, [env.get("PYTHONPATH")])])
    return {**env, **spec.env}


class CellStream:
    """A stream of cells trained by a child process (`python -m jaxnat.reproduce.cellstream`,
    `cell_stream_main`). The child writes the cells' folders, logs and timing lines as this
    process would; its start and end events come back on a pipe to `board`, and when it ends
    before its cells do, they are reported failed at once. Its output goes to
    `<out>/logs/<name>-stream.log`. It is in a session of its own, so a Ctrl-C reaches it once,
    from `interrupt`; it stops by itself when this process dies (its stdin, a pipe from here,
    closes)."""

    def __init__(self, spec: StreamSpec, plan: Plan, board: Board, platform: str):
        import os
        import subprocess
        import threading

        self.spec, self.plan, self.board, self.platform = spec, plan, board, platform
        self.by_name = {c.name: c for c in [*spec.cells, *spec.then]}
        self.started: set[str] = set()  # the cells this stream started
        self.stopped = False  # by `interrupt`: its end is not a failure
        self.log = plan.out / "logs" / stream_log(spec.name)
        self.log.parent.mkdir(exist_ok=True)
        read_end, write_end = os.pipe()
        try:
            with self.log.open("a") as log:
                log.write(f"--- {datetime.datetime.now().isoformat(timespec='seconds')}: "
                          f"{' '.join(f'{k}={v}' for k, v in spec.env.items())} {', '.join(c.name for c in spec.cells)}"
                          + (f" | then, unless started: {', '.join(c.name for c in spec.then)}" if spec.then else "")
                          + "\n")
                log.flush()
                self.proc = subprocess.Popen(child_argv(plan, spec, write_end), stdin=subprocess.PIPE, stdout=log,
                                             stderr=subprocess.STDOUT, pass_fds=(write_end,), env=child_env(spec),
                                             start_new_session=True)
        finally:
            os.close(write_end)
        self.reader = threading.Thread(target=self._read, args=(read_end,), name=f"{spec.name}-stream-events",
                                       daemon=True)
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
                    self.started.add(cell.name)
                    self.board.start(cell, bool(event.get("resumed")), self.spec.name)
                elif event.get("event") == "done":
                    self.board.done(cell, str(event.get("outcome")), float(event.get("seconds", 0.0)))
        self._ended(self.proc.wait())  # the pipe closes when the child ends

    def _ended(self, status: int) -> None:
        """Unless stopped from here, report every cell the child did not finish as failed (the
        one it was in also gets its timing line, which the child had no time to write); a pooled
        stream only the cell it was in (another stream may still take the others:
        `command.run_cells` reports those no stream took)."""
        if self.stopped:
            return
        why = self.failure(status)
        for cell in [*self.spec.cells, *self.spec.then]:  # (`then` is empty unless pooled)
            if cell.name in self.board.outcomes or (self.spec.claims and cell.name not in self.started):
                continue
            started = self.board.running.get(cell.name)
            seconds = 0.0 if started is None else time.time() - started
            if started is not None:
                append_jsonl(self.plan.out / "timings.jsonl",
                             timing_row(cell, self.plan, seconds, self.board.resumed.get(cell.name, False),
                                        f"failed: {why}", self.platform, started, True))
            self.board.done(cell, f"failed: {why}", seconds)

    def failure(self, status: int) -> str:
        """Why a cell of this stream did not finish when the child ended with `status`."""
        import signal

        ended = "was interrupted" if status in (130, -signal.SIGINT) else f"exited with status {status}"
        return f"the {self.spec.name} stream ({sys.executable} -m {ENTRY}) {ended} before this cell finished; " \
               f"its output: {self.log}"

    def wait(self) -> int:
        """Wait for the child to end and its cells to be reported; returns its exit status."""
        status = self.proc.wait()
        self.reader.join()
        self.proc.stdin.close()
        return status

    def interrupt(self) -> None:
        """Ask the child to stop (it checkpoints its cell, as after a Ctrl-C); `stop` waits."""
        import signal

        self.stopped = True
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)


def stop_streams(streams: list[CellStream]) -> None:
    """Interrupt every stream's child, then wait for them all; a second Ctrl-C while waiting
    kills those still running."""
    for stream in streams:
        stream.interrupt()
    try:
        for stream in streams:
            stream.proc.wait()
    except KeyboardInterrupt:
        for stream in streams:
            stream.proc.kill()
            stream.proc.wait()
        raise
    finally:
        for stream in streams:
            stream.reader.join(timeout=5)
            stream.proc.stdin.close()


class Events:
    """A stream's side of `Board`: each cell's start and end as one JSON line on the pipe `fd`
    to the parent `jaxnat reproduce` (which shows them; nothing is sent when it is gone), and as
    a line on `console` (the stream's log)."""

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


def cell_stream_main(argv=None) -> int:
    """A stream's process (`python -m jaxnat.reproduce.cellstream`, started by
    `command.run_cells`, not by hand): train the named cells of the grid into `--out` as
    `run_cells` would, telling the parent of each start and end on the pipe `--events-fd`; no
    report. Stops as after a Ctrl-C when its stdin closes (the parent is gone). Exit status 0,
    130 when interrupted."""
    import argparse
    import os
    import signal
    import threading

    from rich.console import Console

    parser = argparse.ArgumentParser(prog=f"python -m {ENTRY}")
    parser.add_argument("--name", required=True)
    parser.add_argument("--profile", required=True, choices=list(PROFILES))
    parser.add_argument("--seeds", required=True, type=int)
    parser.add_argument("--out", required=True, type=Path)
    parser.add_argument("--cells", required=True)
    parser.add_argument("--events-fd", required=True, type=int)
    parser.add_argument("--nice", type=int, default=0)
    parser.add_argument("--compile-ahead", action="store_true")
    parser.add_argument("--then", default="", help="the pool's other cells, taken when claimed (with --claims)")
    parser.add_argument("--claims", type=Path, default=None, help="the pool's claims folder (cells.Claims)")
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    # The parent stops this stream with SIGINT: take it as a Ctrl-C even when started with
    # SIGINT ignored (what a non-interactive shell's background job, `jaxnat reproduce ... &`,
    # hands its children).
    signal.signal(signal.SIGINT, signal.default_int_handler)

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
        if args.nice and hasattr(os, "nice"):
            os.nice(args.nice)
        profile = PROFILES[args.profile]
        grid = {c.name: c for c in build_grid(profile, ONLY_NAMES)}
        names = [name for name in [*args.cells.split(","), *args.then.split(",")] if name]
        unknown = [name for name in names if name not in grid]
        if unknown:
            parser.error(f"no cell {unknown[0]!r} in the {args.profile} grid")
        cells = [grid[name] for name in names]
        plan = Plan(profile, tuple(dict.fromkeys(c.experiment for c in cells)), args.seeds, args.out, cells)
        from jaxnat.training import run_status

        resumed = {c.name: run_status(args.out / c.name) == "partial" for c in cells}
        claim = None if args.claims is None else Claims(args.claims, args.name).take
        train_cells(cells, plan, resumed, Events(args.events_fd, console), platform=detect_platform(),
                    compile_ahead=args.compile_ahead, overlapped=True, claim=claim)
    except KeyboardInterrupt:
        console.print("interrupted (checkpointed)")
        return 130
    # An interrupt the trainer took itself (it checkpoints and stops the cell) still ends the
    # stream as interrupted: the parent is gone, so nothing more may be trained or reported.
    return 130 if parent_gone.is_set() else 0
