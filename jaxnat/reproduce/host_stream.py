"""The host stream of `jaxnat reproduce`: on an accelerator the host cells (Natural Atari: ALE on
the host's cores, a small policy on the accelerator) train in a child process,
`python -m jaxnat.reproduce.hoststream`, while the device cells train in the parent, both
writing to the same `--out` (`docs/design.md` says why a process and not a thread).

The parent's side is `HostStream` (start the child, show its events on the board, report the
cells it did not finish, stop it); the child's is `host_stream_main` (train the cells with
`cells.train_cells`, sending each start and end as `Events`, one JSON line each, on a pipe).
Only the child's command line (`child_argv`) is argv; its cells are named, not described."""

from __future__ import annotations

import datetime
import json
import sys
import time
from pathlib import Path

from jaxnat.reproduce.board import Board
from jaxnat.reproduce.cells import append_jsonl, timing_row, train_cells
from jaxnat.reproduce.estimates import detect_platform
from jaxnat.reproduce.grid import PROFILES, Cell, Plan, build_grid

# The host stream's scheduling priority: below the device stream's, whose XLA compiles would
# otherwise wait behind ALE's threads on a fully used host. The device stream is the longer one
# in `quick`, so it is the one to keep moving; the host cells only need the cores it leaves.
HOST_STREAM_NICE = 5
HOST_STREAM_LOG = "host-stream.log"  # in <out>/logs/: the child's own output (a crash's traceback)


def child_argv(plan: Plan, cells: list[Cell], events_fd: int) -> list[str]:
    """The child's command line: the grid's cells by name, and the pipe for its events."""
    return [sys.executable, "-m", "jaxnat.reproduce.hoststream", "--profile", plan.profile.name,
            "--seeds", str(plan.seeds), "--out", str(plan.out), "--cells", ",".join(c.name for c in cells),
            "--events-fd", str(events_fd)]


class HostStream:
    """The host cells trained by a child process (`python -m jaxnat.reproduce.hoststream`,
    `host_stream_main`) while this one trains the device cells. The child writes the cells'
    folders, logs and timing lines as this process would; its start and end events come back
    on a pipe to `board`. Its output goes to `<out>/logs/host-stream.log`. It is in a session of
    its own, so a Ctrl-C reaches it once, from `stop`; it stops by itself when this process
    dies (its stdin, a pipe from here, closes)."""

    def __init__(self, cells: list[Cell], plan: Plan, board: Board, platform: str):
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
                self.proc = subprocess.Popen(child_argv(plan, cells, write_end), stdin=subprocess.PIPE, stdout=log,
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
                                 timing_row(cell, self.plan, seconds, self.board.resumed.get(cell.name, False),
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


class Events:
    """The host stream's side of `Board`: each cell's start and end as one JSON line on the
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


def host_stream_main(argv=None) -> int:
    """The host stream's process (`python -m jaxnat.reproduce.hoststream`, started by
    `command.run_cells`, not by hand): train the named cells of the grid into `--out` as
    `run_cells` would, telling the parent of each start and end on the pipe `--events-fd`; no
    report. Stops as after a Ctrl-C when its stdin closes (the parent is gone). Exit status 0,
    130 when interrupted."""
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
        train_cells(cells, plan, resumed, Events(args.events_fd, console), platform=detect_platform(),
                    compile_ahead=False, overlapped=True)
    except KeyboardInterrupt:
        console.print("interrupted (checkpointed)")
        return 130
    # An interrupt the trainer took itself (it checkpoints and stops the cell) still ends the
    # stream as interrupted: the parent is gone, so nothing more may be trained or reported.
    return 130 if parent_gone.is_set() else 0
