"""The live progress bar, fed once per update and seed (from inside the compiled chunks by a host
callback, or by the host backend's loop)."""

from __future__ import annotations

import collections
import math
import threading

import numpy as np

from jaxnat.training.spec import RunSpec


class Progress:
    """A rich progress bar over one group of `seeds` seeds trained together, advanced once per
    update and seed (`progress(update, metrics)`)."""

    def __init__(self, console, spec: RunSpec, seeds: int, start_update: int):
        from rich.progress import (BarColumn, MofNCompleteColumn, Progress, ProgressColumn,
                                   TextColumn, TimeElapsedColumn, TimeRemainingColumn)
        from rich.text import Text

        self.seeds = seeds

        class SpeedColumn(ProgressColumn):
            def render(self, task):
                speed = task.finished_speed or task.speed
                return Text("— steps/s" if speed is None else f"{speed * seeds:,.0f} steps/s")

        self.spec = spec
        self.progress = Progress(
            TextColumn("[bold]{task.description}"), BarColumn(bar_width=24), MofNCompleteColumn(),
            TextColumn("steps/seed ·"), SpeedColumn(),
            TextColumn("· train {task.fields[train]} · test {task.fields[test]} ·"),
            TimeElapsedColumn(), TextColumn("eta"), TimeRemainingColumn(), console=console,
            speed_estimate_period=10, disable=not (console.is_terminal or console.is_jupyter),
        )
        self.task = self.progress.add_task(
            "training", total=spec.num_updates * spec.steps_per_update,
            completed=start_update * spec.steps_per_update, train="—", test="—")
        self._lock = threading.Lock()
        self._calls = 0
        self._start = start_update
        self._returns = collections.deque(maxlen=seeds)

    def __call__(self, update, metrics) -> None:
        value = float(np.asarray(metrics["episode_return"]))
        with self._lock:
            self._calls += 1
            if math.isfinite(value):
                self._returns.append(value)
            if self._calls % self.seeds == 0:
                done = self._start + self._calls // self.seeds
                train = f"{np.mean(self._returns):+.3f}" if self._returns else "—"
                self.progress.update(self.task, completed=done * self.spec.steps_per_update, train=train)

    def sync(self, update: int, test: str | None = None) -> None:
        with self._lock:
            self._calls = (update - self._start) * self.seeds
            fields = {} if test is None else {"test": test}
            self.progress.update(self.task, completed=update * self.spec.steps_per_update, **fields)
