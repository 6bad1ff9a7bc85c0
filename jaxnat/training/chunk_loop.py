"""The one training loop of `jaxnat train`: the run directory, chunks of updates, evaluation,
checkpoints, resume, the curve and the summary, over a `Backend` that trains the seeds.

Two backends: `device_backend.DeviceBackend` (pure-JAX envs: every seed in one compiled, vmapped
program; the test split is scored after every chunk) and `host_backend.HostBackend` (host-batched
envs, Natural Atari: from a Python loop, every seed side by side or one seed after another; the
test split is scored before a group's first update and when it ends). Both score the untrained
policy at update 0. A backend trains *groups* of seeds (the device backend one group of all
seeds, the host backend one group of all seeds side by side, or one group per seed); the loop
here is the same for both:

    for each group: restore its latest checkpoint (if any), drop the records written after it,
        then chunk by chunk: train `eval_every` updates, append `metrics.jsonl` rows, evaluate
        (every chunk or at the group's end) into `eval.jsonl`, checkpoint, redraw `curve.png`
        (at most every `PLOT_EVERY_S`, and after the last chunk)
    write `summary.json` (also for a run stopped early, marked incomplete)

Checkpoints live in `checkpoints/` (device) or `checkpoints/seed_<s>/` (host: a group of one
seed, or with `checkpoints_per_seed` each seed's slice of the group's stacked state,
`checkpoints.SeedCheckpoints`); each holds the backend's state pytree and `{"chunk", "update",
"env_steps", "wall_time_s"}`.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any, Protocol, Sequence

import numpy as np

from jaxnat.training.args import TrainError
from jaxnat.training.checkpoints import Checkpoints, SeedCheckpoints, damaged
from jaxnat.training.progress import EvalProgress, Progress
from jaxnat.training.records import (History, json_value, mean_std, nanmean, plot, print_summary, read_jsonl,
                                     run_summary, shows_first_guess, Sink, terminated_label, write_jsonl, FIRST_GUESS)
from jaxnat.training.spec import RunSpec

# `curve.png` is redrawn after a chunk at most this often (and always after the last one): a
# short run's chunks take a second or two, and drawing the figure costs a good part of one.
PLOT_EVERY_S = 10.0

__all__ = ["Backend", "run_training"]


class Backend(Protocol):
    """What trains the seeds of a run; `run_training` does everything else."""

    groups: list[list[int]]  # seed values trained together, in order
    evaluates_each_chunk: bool  # score the test split after every chunk (else at a group's end)
    # The group's state stacks its seeds along a leading axis and each seed's slice is saved in
    # a folder of its own (`checkpoint_dir([seed])`); False: the state is one checkpoint.
    checkpoints_per_seed: bool
    # Steps of one evaluation pass (a scan over a test episode's time limit), reported to the
    # `progress.EvalProgress` that `evaluate` and `chance` are handed; None: not known ahead.
    eval_steps: int | None

    def checkpoint_dir(self, group: list[int]) -> str:
        """The group's checkpoint folder, relative to the run directory (with
        `checkpoints_per_seed`, asked for each seed's own: `[seed]`)."""

    def init(self, group: list[int]) -> Any:
        """The group's state at update 0 (the structure a checkpoint restores into)."""

    def update_of(self, state) -> int:
        """Updates the state has done."""

    def begin(self, group: list[int], state) -> None:
        """Get ready to train `state` from its update on (the host backend starts new games)."""

    def chunk(self, state, num_updates: int, progress: Progress) -> tuple[Any, dict]:
        """`(state, metrics)`: `num_updates` more updates; metrics `{name: [len(group), n]}`."""

    def evaluate(self, group: list[int], state, progress: EvalProgress) -> dict:
        """Test-split scores `{name: [len(group)]}` (`greedy_return`, `sampled_return`, ...),
        greedy then sampled (two passes)."""

    def chance(self, progress: EvalProgress) -> dict | None:
        """The uniform random policy's test scores `{return, terminated_fraction, ...}`, or None
        (one pass)."""


def run_training(spec: RunSpec, run_dir: Path, backend: Backend, *, console, new_run: dict | None,
                 stop_after_chunks: int | None = None, sinks: Sequence[Sink] = ()) -> tuple[Any, dict, bool]:
    """Train (or resume) `spec` in `run_dir`; `new_run`: the `config.json` to write for a new
    run (None when resuming); `sinks`: where the metric and evaluation rows are mirrored once
    they are in the JSONL (`records.Sink`). Returns `(state of the last group, summary, complete)`; raises
    `KeyboardInterrupt` after saving the summary when interrupted."""
    session_start = time.perf_counter()
    run_dir.mkdir(parents=True, exist_ok=True)
    metrics_path, eval_path = run_dir / "metrics.jsonl", run_dir / "eval.jsonl"
    if new_run is not None:
        (run_dir / "config.json").write_text(json.dumps(new_run, indent=2, default=str) + "\n")
        metrics_path.write_text("")
        eval_path.write_text("")
    metrics_rows, eval_rows = read_jsonl(metrics_path), read_jsonl(eval_path)
    what = f"scoring the uniform random policy on the test split ({_episodes_field(spec, spec.seeds, backend)})"
    with EvalProgress(console, what, 1, backend.eval_steps) as shown:
        chance = backend.chance(shown)
    if chance is not None:
        accuracy, first = chance.get("terminated_fraction"), chance.get("first_step_terminated")
        console.print(f"chance (uniform random policy on the test split): return {chance['return']:+.3f}"
                      + ("" if accuracy is None else f" · {terminated_label(spec.env_id)} {accuracy:.1%}")
                      + (f" · {FIRST_GUESS} {first:.1%}" if shows_first_guess(spec.env_id) and first is not None
                         else ""))
    prior_wall, chunks_done, interrupted, stopped = 0.0, 0, False, False
    last_plot = -float("inf")
    num_chunks = -(-spec.num_updates // spec.eval_every)
    state = None

    def evaluate(group, state, update: int, chunk_seconds: float | None, bar: Progress | None = None) -> dict:
        seeds = "" if len(group) == len(spec.seed_values) else f"seed {', '.join(map(str, group))}, "
        what = (f"evaluating {seeds}update {update} on the test split ({_episodes_field(spec, len(group), backend)}, "
                "greedy then sampled)")
        with EvalProgress(console, what, 2, backend.eval_steps, bar) as shown:
            scores = backend.evaluate(group, state, shown)
        sps = None if chunk_seconds is None else last_chunk_steps * len(group) / chunk_seconds
        rows = [{"chunk": -(-update // spec.eval_every), "update": update,
                 "env_steps": update * spec.steps_per_update, "seed": seed,
                 **{k: json_value(v[i]) for k, v in scores.items()},
                 "chunk_seconds": chunk_seconds, "steps_per_second": sps}
                for i, seed in enumerate(group)]
        write_jsonl(eval_path, rows)
        eval_rows.extend(rows)
        for sink in sinks:
            sink.write("eval", rows)
        return scores

    try:
        for group in backend.groups:
            label = "" if len(group) == len(spec.seed_values) else f"seed {', '.join(map(str, group))} · "
            checkpoints = _open_checkpoints(backend, run_dir, group)
            try:
                state = backend.init(group)
                if checkpoints.latest_step() is not None:
                    state, meta = _restore(checkpoints, state)
                    prior_wall = max(prior_wall, float(meta.get("wall_time_s", 0.0)))
                    console.print(f"{label}resumed from checkpoint at update {meta['update']}")
                elif new_run is None:
                    # Rows past the first chunk mean a checkpoint was written and is gone.
                    recorded = max((r["update"] for r in metrics_rows if r["seed"] in group), default=0)
                    if recorded > spec.eval_every:
                        raise TrainError(
                            f"cannot resume {run_dir}: its metrics go to update {recorded} but "
                            f"{_checkpoint_folders(checkpoints)} holds no checkpoint; restore that "
                            "folder, or start a new run (nothing was changed)")
                update = backend.update_of(state)
                # Drop the group's records written after its checkpoint (a run stopped between
                # writing and saving); other groups' rows stay.
                keep = lambda r: r["seed"] not in group or r["update"] <= update  # noqa: E731
                metrics_rows[:] = [r for r in metrics_rows if keep(r)]
                eval_rows[:] = [r for r in eval_rows if keep(r)]
                write_jsonl(metrics_path, metrics_rows, "w")
                write_jsonl(eval_path, eval_rows, "w")
                evaluated = {r["update"] for r in eval_rows if r["seed"] in group}
                if update >= spec.num_updates and update in evaluated:
                    console.print(f"{label}finished before")
                    continue
                last_chunk_steps = 0
                # The untrained policy (update 0), for every backend: the reproduction's verdicts
                # ask whether a cell learned beyond it. A device run resumed at a state never
                # scored is scored too.
                if update not in evaluated and (backend.evaluates_each_chunk or update == 0):
                    evaluate(group, state, update, None)
                backend.begin(group, state)
                progress = Progress(console, spec, len(group), update)
                with progress.progress:
                    progress.sync(update)
                    while update < spec.num_updates:
                        if stop_after_chunks is not None and chunks_done >= stop_after_chunks:
                            stopped = True
                            break
                        # Chunks end at multiples of eval_every (and at the run's end): a run
                        # extended after a short last chunk first completes that chunk.
                        n = min(spec.eval_every - update % spec.eval_every, spec.num_updates - update)
                        start = time.perf_counter()
                        state, metrics = backend.chunk(state, n, progress)
                        seconds = time.perf_counter() - start
                        first, update = update, update + n
                        last_chunk_steps = n * spec.steps_per_update
                        rows = [{"update": first + j + 1, "env_steps": (first + j + 1) * spec.steps_per_update,
                                 "seed": seed, **{k: json_value(v[i, j]) for k, v in metrics.items()}}
                                for j in range(n) for i, seed in enumerate(group)]
                        write_jsonl(metrics_path, rows)
                        metrics_rows.extend(rows)
                        for sink in sinks:
                            sink.write("train", rows)
                        scores = None
                        if backend.evaluates_each_chunk or update == spec.num_updates:
                            scores = evaluate(group, state, update, seconds, progress)
                        chunk_index = -(-update // spec.eval_every)
                        checkpoints.save(state, {"chunk": chunk_index, "update": update,
                                                 "env_steps": update * spec.steps_per_update,
                                                 "wall_time_s": prior_wall + time.perf_counter() - session_start})
                        if update >= spec.num_updates or time.perf_counter() - last_plot >= PLOT_EVERY_S:
                            plot(run_dir / "curve.png", spec, History.load(spec, metrics_rows, eval_rows), chance)
                            last_plot = time.perf_counter()
                        chunks_done += 1
                        progress.sync(update, None if scores is None else f"{mean_std(scores['greedy_return'])[0]:+.3f}")
                        console.print(f"{label}chunk {chunk_index}/{num_chunks} · update {update}/{spec.num_updates}"
                                      f" · {update * spec.steps_per_update:,} env steps/seed · "
                                      f"{_train_field(metrics)}{_scores_field(scores, spec.env_id)} · "
                                      f"{n * spec.steps_per_update * len(group) / seconds:,.0f} steps/s")
                if stopped:
                    break
                if update >= spec.num_updates and update not in {r["update"] for r in eval_rows if r["seed"] in group}:
                    evaluate(group, state, update, None)  # resumed from the group's last checkpoint
            finally:
                checkpoints.close()
    except KeyboardInterrupt:
        interrupted = True

    finished = {r["seed"] for r in eval_rows if r["update"] == spec.num_updates}
    complete = finished >= set(spec.seed_values)
    history = History.load(spec, metrics_rows, eval_rows)
    if not (run_dir / "curve.png").exists() or not complete:
        plot(run_dir / "curve.png", spec, history, chance)
    summary = run_summary(spec, history, prior_wall + time.perf_counter() - session_start, complete, chance)
    (run_dir / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    print_summary(console, summary)
    if not complete:
        why = "interrupted" if interrupted else "stopped"
        console.print(f"{why}; continue with: jaxnat train --resume {run_dir}")
    else:
        console.print(f"run directory: {run_dir}\nlearning curve: {run_dir / 'curve.png'}")
    if interrupted:
        raise KeyboardInterrupt
    return state, summary, complete


def _open_checkpoints(backend: Backend, run_dir: Path, group: list[int]):
    """The group's checkpoints: one folder, or one per seed (`Backend.checkpoints_per_seed`)."""
    if backend.checkpoints_per_seed:
        return SeedCheckpoints([run_dir / backend.checkpoint_dir([seed]) for seed in group])
    return Checkpoints(run_dir / backend.checkpoint_dir(group))


def _checkpoint_folders(checkpoints) -> str:
    """The folder, or the seeds' folders (`{a,b}`), the group's checkpoints are in."""
    if isinstance(checkpoints, SeedCheckpoints):
        names = ",".join(c.directory.name for c in checkpoints.seeds)
        return str(checkpoints.directory / f"{{{names}}}")
    return str(checkpoints.directory)


def _restore(checkpoints, state):
    """`checkpoints.restore(state)`, with a damaged checkpoint reported in one line."""
    step = checkpoints.latest_step()
    try:
        return checkpoints.restore(state)
    except TrainError:
        raise
    except Exception as err:  # noqa: BLE001 (orbax and tensorstore raise many kinds for bad bytes)
        raise damaged(step, checkpoints.directory, err) from None


def _episodes_field(spec: RunSpec, seeds: int, backend: Backend) -> str:
    """How much one pass of an evaluation plays: "5 seeds x 1,000 episodes of up to 20 steps"."""
    steps = backend.eval_steps
    seeds = f"{seeds} seed{'s' * (seeds != 1)} x "
    length = "whole games" if steps is None else f"episodes of up to {steps:,} steps"
    return f"{seeds}{spec.eval_episodes:,} {length}"


def _train_field(metrics: dict) -> str:
    mean, std = mean_std(nanmean(metrics["episode_return"], 1))
    return "no episode ended yet" if np.isnan(mean) else f"train return {mean:+.3f} ± {std:.3f}"


def _scores_field(scores: dict | None, env_id: str) -> str:
    """The test scores of a progress line: returns, and the greedy policy's terminated fraction
    (`records.terminated_label`) and, for Classify, its first-guess accuracy."""
    if scores is None:
        return ""
    greedy, greedy_std = mean_std(scores["greedy_return"])
    sampled, _ = mean_std(scores["sampled_return"])
    accuracy = ""
    if "greedy_terminated_fraction" in scores:
        fields = [f"{terminated_label(env_id)} {mean_std(scores['greedy_terminated_fraction'])[0]:.1%}"]
        if shows_first_guess(env_id) and "greedy_first_step_terminated" in scores:
            fields.insert(0, f"{FIRST_GUESS} {mean_std(scores['greedy_first_step_terminated'])[0]:.1%}")
        accuracy = f" ({', '.join(fields)})"
    return f" · test greedy {greedy:+.3f} ± {greedy_std:.3f}{accuracy} · sampled {sampled:+.3f}"
