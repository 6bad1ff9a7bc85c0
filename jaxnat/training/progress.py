"""The live progress bar, fed once per update and seed (from inside the compiled chunks by a host
callback, or by the host backend's loop)."""

from __future__ import annotations

import collections
import math
import threading
import time

import numpy as np

from jaxnat.training.spec import RunSpec


class Progress:
    """A rich progress bar over one group of `seeds` seeds trained together, advanced once per
    update and seed (`progress(update, metrics)`). The bar's columns put speed and ETA first,
    so a narrow (80-column) terminal crops the train/test fields rather than them. When the
    output is not a terminal (a log file, CI), a plain line with the same figures is printed at
    least every `interval` seconds instead."""

    def __init__(self, console, spec: RunSpec, seeds: int, start_update: int, interval: float = 15.0):
        from rich.progress import (BarColumn, MofNCompleteColumn, Progress, ProgressColumn,
                                   TextColumn, TimeRemainingColumn)
        from rich.table import Column
        from rich.text import Text

        self.seeds = seeds
        # Calls per update: one per seed, and per device when each seed's envs are split over
        # devices (every device runs the callback of its shard).
        self._per_update = seeds * (spec.devices if spec.shard == "envs" else 1)

        class SpeedColumn(ProgressColumn):
            def render(self, task):
                speed = task.finished_speed or task.speed
                return Text("— steps/s" if speed is None else f"{speed * seeds:,.0f} steps/s")

        self.spec = spec
        self.console = console
        self.live = console.is_terminal or console.is_jupyter
        self.interval = interval
        keep = lambda: Column(no_wrap=True)  # noqa: E731
        self.progress = Progress(
            BarColumn(bar_width=8), MofNCompleteColumn(table_column=keep()),  # env steps per seed
            TextColumn("·", table_column=keep()), SpeedColumn(table_column=keep()),
            TextColumn("· eta", table_column=keep()), TimeRemainingColumn(table_column=keep()),
            TextColumn("· train {task.fields[train]} · test {task.fields[test]}",
                       table_column=Column(no_wrap=True, overflow="ellipsis")),
            console=console, speed_estimate_period=10, disable=not self.live,
        )
        self.task = self.progress.add_task(
            "training", total=spec.num_updates * spec.steps_per_update,
            completed=start_update * spec.steps_per_update, train="—", test="—")
        self._lock = threading.Lock()
        self._calls = 0
        self._start = start_update
        self._returns = collections.deque(maxlen=seeds)
        self._started = self._last_line = time.monotonic()

    def __call__(self, update, metrics) -> None:
        value = float(np.asarray(metrics["episode_return"]))
        with self._lock:
            self._calls += 1
            if math.isfinite(value):
                self._returns.append(value)
            if self._calls % self._per_update == 0:
                done = self._start + self._calls // self._per_update
                train = f"{np.mean(self._returns):+.3f}" if self._returns else "—"
                self.progress.update(self.task, completed=done * self.spec.steps_per_update, train=train)
                if not self.live and time.monotonic() - self._last_line >= self.interval:
                    self._line(done, train)

    def _line(self, done: int, train: str) -> None:
        """The plain progress line (no terminal): updates, steps/s over this session, ETA."""
        now = time.monotonic()
        self._last_line = now
        per_update = (now - self._started) / max(done - self._start, 1)
        eta = int(per_update * (self.spec.num_updates - done))
        speed = self.spec.steps_per_update * self.seeds / per_update
        self.console.print(f"update {done}/{self.spec.num_updates} · {speed:,.0f} steps/s · "
                           f"eta {eta // 60}:{eta % 60:02d} · train return {train}", highlight=False)

    def sync(self, update: int, test: str | None = None) -> None:
        with self._lock:
            self._calls = (update - self._start) * self._per_update
            fields = {} if test is None else {"test": test}
            self.progress.update(self.task, completed=update * self.spec.steps_per_update, **fields)


class EvalProgress:
    """What the run is doing while the test split is scored (an evaluation, or the chance score):
    `what` (which policy, how many episodes of what length), steps done and an estimate of the
    time left.

    An evaluation is one compiled program per call (every seed vmapped, each episode a lane of
    one scan over the episode's time limit), so it cannot be cut into per-seed or per-episode
    calls without changing the keys, and with them the scores. It reports from inside instead:
    `__call__(pass_index, steps_done)`, from the program's host callback
    (`rollout.evaluate._report_steps`), about 20 times per pass. The scan runs its full length
    whatever the episodes do, so steps done over `passes x steps` is the fraction done and a
    linear estimate of the time left is a fair one.

    On a terminal: while training, the training bar's test field shows the percentage (one live
    display at a time); before it, a transient bar of its own. Elsewhere (a log file, CI): a
    plain line every `interval` seconds from a thread, so an evaluation that takes minutes
    says so, and one of a few seconds prints nothing. `steps` None (a host backend's games,
    whose length nobody knows before they end): elapsed time only."""

    def __init__(self, console, what: str, passes: int, steps: int | None, bar: Progress | None = None,
                 interval: float = 15.0):
        self.console, self.what, self.bar, self.interval = console, what, bar, interval
        self.steps = steps
        self.total = None if steps is None else passes * steps
        self.done = 0
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._own = None
        self._ticker = None

    def __enter__(self):
        self._start = time.monotonic()
        live = self.console.is_terminal or self.console.is_jupyter
        if live and self.bar is not None and self.bar.live:
            self.bar.progress.update(self.bar.task, test="evaluating")
        elif live:
            from rich.progress import (BarColumn, MofNCompleteColumn, Progress as RichProgress, SpinnerColumn,
                                       TextColumn, TimeElapsedColumn, TimeRemainingColumn)

            columns = [SpinnerColumn(), TextColumn(self.what)]
            if self.total is not None:
                columns += [BarColumn(bar_width=8), MofNCompleteColumn(), TextColumn("steps · eta"),
                            TimeRemainingColumn()]
            self._own = RichProgress(*columns, TextColumn("·"), TimeElapsedColumn(), console=self.console,
                                     transient=True)
            self._task = self._own.add_task("evaluating", total=self.total)
            self._own.start()
        else:
            self._ticker = threading.Thread(target=self._tick, daemon=True)
            self._ticker.start()
        return self

    def __call__(self, pass_index, steps_done) -> None:
        if self.steps is None:
            return
        done = int(pass_index) * self.steps + int(steps_done)
        with self._lock:
            if done <= self.done:  # several devices report the same step
                return
            self.done = done
        if self._own is not None:
            self._own.update(self._task, completed=done)
        elif self.bar is not None and self.bar.live:
            self.bar.progress.update(self.bar.task, test=f"evaluating {done / self.total:.0%}")

    def line(self) -> str:
        """The plain progress line: what, steps done, elapsed, the estimate of the time left."""
        elapsed = time.monotonic() - self._start
        with self._lock:
            done = self.done
        parts = [self.what]
        if self.total is not None:
            parts.append(f"step {done:,}/{self.total:,}")
        parts.append(f"{_clock(elapsed)} elapsed")
        if self.total is not None and done:
            parts.append(f"eta {_clock(elapsed * (self.total - done) / done)}")
        return " · ".join(parts)

    def _tick(self) -> None:
        while not self._stop.wait(self.interval):
            self.console.print(self.line(), highlight=False)

    def __exit__(self, *exc) -> None:
        self._stop.set()
        if self._ticker is not None:
            self._ticker.join()
        if self._own is not None:
            self._own.stop()


def _clock(seconds: float) -> str:
    seconds = int(seconds)
    return f"{seconds // 60}:{seconds % 60:02d}"
