"""The progress board of `jaxnat reproduce` (`Board`): the cells of every stream as they start
and end. A child stream's cells reach it as events from that process (`cell_stream.Events`
sends them, `cell_stream.CellStream` reads them)."""

from __future__ import annotations

import time

from jaxnat.reproduce.grid import Cell


class Board:
    """What the user sees of the cells of every stream: the progress bar (cells done of all, and
    an ETA over the estimate of the longest stream still running), one line per cell start and
    end without a terminal (a child stream's cells tagged: "alongside" for the host stream's,
    the GPU stream's name, e.g. "gpu1", for a device stream's), failures in red, and each cell's
    outcome. Thread-safe: a child stream's events arrive on a reader thread."""

    def __init__(self, console, streams: dict[str, list[Cell]], estimates: dict[str, float]):
        import threading

        from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

        self.console, self.estimates, self.lock = console, estimates, threading.Lock()
        self.stream_of = {c.name: stream for stream, cells in streams.items() for c in cells}  # as planned
        self.trained_on: dict[str, str] = {}  # where a cell started, when told
        self.cells = {c.name: c for cells in streams.values() for c in cells}
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
        stream = self.trained_on.get(name, self.stream_of[name])
        tags = [tag for tag, on in (("resumed", self.resumed.get(name)), ("alongside", stream == "host"),
                                    (stream, stream.startswith("gpu"))) if on]
        return f"{name} ({', '.join(tags)})" if tags else name

    def _running(self) -> str:
        return ", ".join(map(self._label, self.running)) or "cells"

    def start(self, cell: Cell, resumed: bool, stream: str | None = None) -> None:
        """`cell` started, on `stream` (None: the stream planned for it; a pooled GPU stream
        may take another's cell)."""
        with self.lock:
            if stream is not None:
                self.trained_on[cell.name] = stream
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
