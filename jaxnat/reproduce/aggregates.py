"""Aggregate scores over cells and seeds, computed with rliable (Agarwal et al. 2021,
https://github.com/google-research/rliable): the interquartile mean (IQM, `metrics.aggregate_iqm`)
and the mean (`metrics.aggregate_mean`) of a group's `[seeds, cells]` scores, each with a 95%
stratified bootstrap interval (`library.get_interval_estimates`: seeds resampled within each
cell, percentile intervals, a fixed number of resamples from a fixed generator so a report is
reproducible). The IQM drops the best and the worst quarter of the runs: one seed that diverged
or one lucky seed moves it less than the mean, which is why rliable recommends it for the few
seeds RL can afford. The report shows it beside each cell's own mean and 95% interval.

**The score** is a seed's final training return, the quantity the findings compare
(`report.CellResult.train_per_seed`: its mean over the last 10% of its updates in which an
episode ended).

- *Classification and localisation*: normalised between the cell's untrained policy and the
  task's best return, `(return - u) / (1 - u)`, `u` the mean over seeds of the untrained
  policy's sampled test return (update 0, `CellResult.untrained`). 1 is each env's maximum
  return: a correct label at the first step (`Classify/*`, +1) or the object found at the first
  move (`Localize/*`, +1). So 0 is "no better than untrained" and 1 "perfect", on every dataset
  and trunk, and cells of different datasets and trunks can be pooled. A group is one experiment
  and algorithm over the cells of the paper's figures (both trunks, every dataset); the
  difficulty sweep (PPO alone, its cells differ in the difficulty it studies) and the noise
  control (not in the paper) are left out. A cell without an untrained policy, or whose
  untrained policy is already at the maximum, cannot be normalised and is left out, with why.
- *Natural Atari and PixelMuJoCo*: no maximum return is known (and Natural Atari's host runs
  record no untrained policy), and the scale of a return is a game's or a robot's. So the
  score is the raw return, and a group is one cell (game or robot, background or observation,
  algorithm): the IQM over its seeds, a robust companion to the cell's mean.

A group needs the same number of seeds in every cell (rliable's `[runs, tasks]` matrix); a cell
with another number, or a seed without a training return, is left out, with why. Only finished
cells are aggregated: a partial cell's return is at a smaller budget.
"""

from __future__ import annotations

import dataclasses
import warnings
import zlib
from collections import Counter

import numpy as np

from jaxnat.reproduce.labels import dataset_label
from jaxnat.reproduce.stats import CONFIDENCE, RESAMPLES, Interval

__all__ = ["MAX_RETURNS", "POOLED_FIGURES", "Aggregate", "bootstrap_seed", "interval_estimates", "rliable_modules", "aggregate",
           "aggregates_section"]

MAX_RETURNS = {"classify": 1.0, "localize": 1.0}  # the best episode return of each env family (docstring)
POOLED_FIGURES = ("classify-cnn", "classify-resnet18", "localize-cnn", "localize-resnet18")


@dataclasses.dataclass(frozen=True)
class Aggregate:
    """One group's IQM and mean over its `[seeds, cells]` scores, with 95% stratified bootstrap
    intervals (`Interval.n`: the runs, seeds x cells)."""

    experiment: str
    group: str  # what the cells share, as printed
    algo: str
    score: str  # "normalised" or "raw return"
    cells: tuple[str, ...]
    seeds: int  # per cell
    iqm: Interval
    mean: Interval
    left_out: tuple[tuple[str, str], ...] = ()  # (cell, why) of the group's cells not aggregated


def bootstrap_seed(seed: int, key: str) -> int:
    """The seed of `key`'s resamples: `seed` and the key's CRC-32, so that a group's interval
    depends on its own scores only, not on which other groups a report has (a cell finished in a
    later sitting leaves the intervals already reported as they were)."""
    return (seed * 0x9E3779B1 + zlib.crc32(key.encode())) % 2**32


def rliable_modules():
    """rliable's `(library, metrics)`, imported on first use (the report's only import of it;
    `jaxnat reproduce` calls this before training to refuse a broken install early)."""
    from rliable import library, metrics
    return library, metrics


def interval_estimates(scores: dict[str, np.ndarray], *, reps: int = RESAMPLES, seed: int = 0
                       ) -> dict[str, tuple[Interval, Interval]]:
    """`{key: [runs, tasks] scores}` -> `{key: (IQM, mean)}`, the point estimates of
    `rliable.metrics.aggregate_iqm` and `aggregate_mean` with their 95% stratified bootstrap
    intervals (`rliable.library.get_interval_estimates`, `reps` resamples from NumPy's global
    generator seeded with `bootstrap_seed(seed, key)` for each key; its state is restored after)."""
    if not scores:
        return {}
    library, metrics = rliable_modules()

    def both(values):
        return np.array([metrics.aggregate_iqm(values), metrics.aggregate_mean(values)])

    # rliable 1.2's StratifiedBootstrap draws its resamples from NumPy's global generator
    # (`update_indices` calls `np.random.choice`), whatever `random_state` says: seeded here for
    # each key, and given back as it was.
    saved = np.random.get_state()
    estimates = {}
    try:
        for key, values in scores.items():
            key_seed = bootstrap_seed(seed, key)
            np.random.seed(key_seed)
            with warnings.catch_warnings():  # arch's notice that it will take a Generator instead of a RandomState
                warnings.simplefilter("ignore", FutureWarning)
                points, intervals = library.get_interval_estimates(
                    {key: np.asarray(values, np.float64)}, both, reps=reps,
                    confidence_interval_size=CONFIDENCE, random_state=np.random.RandomState(key_seed))
            estimates[key] = tuple(Interval(float(points[key][i]), float(intervals[key][0, i]),
                                            float(intervals[key][1, i]), int(np.size(values))) for i in range(2))
    finally:
        np.random.set_state(saved)
    return estimates


def _normalised(result) -> tuple[np.ndarray | None, str]:
    """The cell's per-seed normalised scores, or None and why not."""
    untrained = result.untrained
    if untrained is None:
        return None, "no untrained policy recorded"
    top = MAX_RETURNS[result.cell.experiment]
    if not untrained.mean < top:
        return None, f"its untrained policy ({untrained}) is at the maximum return {top:g}"
    return (result.train_per_seed() - untrained.mean) / (top - untrained.mean), ""


def _group(result) -> tuple[str, str, str] | None:
    """`(experiment, group label, algo)` of a finished cell, None when it is not aggregated."""
    cell = result.cell
    if cell.experiment in MAX_RETURNS:
        return (cell.experiment, "the paper's figure cells", cell.algo) if cell.figure in POOLED_FIGURES else None
    if cell.experiment == "atari":
        return cell.experiment, f"{cell.labels.get('game')}, background {cell.labels.get('background')}", cell.algo
    if cell.experiment == "mujoco":
        return cell.experiment, f"{cell.labels.get('robot')}, {cell.labels.get('observation')} observation", cell.algo
    return None


def aggregate(finished) -> list[Aggregate]:
    """The aggregates of the finished results (`report.CellResult`s), in the order of their groups'
    first cells (see the module docstring for the groups and scores)."""
    groups: dict[tuple[str, str, str], list] = {}
    for result in finished:
        key = _group(result)
        if key is not None:
            groups.setdefault(key, []).append(result)
    kept: dict[tuple, tuple[list, list, list]] = {}
    for key, results in groups.items():
        scored, left_out = [], []
        for result in results:
            values, why = _normalised(result) if key[0] in MAX_RETURNS else (result.train_per_seed(), "")
            if values is None:
                left_out.append((result.cell.name, why))
            elif not np.all(np.isfinite(values)):
                left_out.append((result.cell.name, "a seed has no training return"))
            else:
                scored.append((result, values))
        if scored:
            runs = Counter(len(v) for _, v in scored).most_common(1)[0][0]
            left_out += [(r.cell.name, f"{len(v)} seeds, the group's other cells {runs}") for r, v in scored
                         if len(v) != runs]
            scored = [(r, v) for r, v in scored if len(v) == runs]
        kept[key] = (scored, left_out, results)
    estimates = interval_estimates({"|".join(key): np.stack([v for _, v in scored], axis=1)
                                    for key, (scored, _, _) in kept.items() if scored})
    rows = []
    for key, (scored, left_out, results) in kept.items():
        experiment, group, algo = key
        nan = Interval(float("nan"), float("nan"), float("nan"), 0)
        iqm, mean = estimates.get("|".join(key), (nan, nan))
        rows.append(Aggregate(experiment, group, algo, "normalised" if experiment in MAX_RETURNS else "raw return",
                              tuple(r.cell.name for r, _ in scored), len(scored[0][1]) if scored else 0, iqm, mean,
                              tuple(left_out)))
    return rows


def _datasets(aggregate_row: Aggregate, finished) -> str:
    """The datasets and trunks a pooled group covers, as printed (stand-ins named as such)."""
    by_name = {r.cell.name: r.cell for r in finished}
    parts = dict.fromkeys(f"{dataset_label(by_name[n])} {by_name[n].labels.get('trunk', '')}".strip()
                          for n in aggregate_row.cells)
    return "; ".join(parts)


def aggregates_section(rows: list[Aggregate], finished) -> list[str]:
    """The report's lines for the aggregates (none when there is no finished cell to aggregate)."""
    if not rows:
        return []
    lines = ["## Aggregate scores (IQM and mean over cells x seeds, rliable)", "",
             "The interquartile mean (IQM) and the mean of each group's final training returns, with 95% stratified "
             "bootstrap intervals (seeds resampled within each cell), computed with rliable "
             "(`jaxnat/reproduce/aggregates.py` says why these groups and scores). Classification and localisation: "
             "the return normalised between the cell's untrained policy (0) and the task's maximum return (1), "
             "pooled over the cells of the paper's figures per algorithm. Natural Atari and PixelMuJoCo: the raw "
             "return (no maximum is known), one cell per group: its mean is the cell's own, and its interval "
             "comes from rliable's resamples, not the final table's, so the two may differ in the last digits.", "",
             "| experiment | group | algorithm | score | cells x seeds | IQM [95% CI] | mean [95% CI] |",
             "|---|---|---|---|---|---|---|"]
    for row in (r for r in rows if r.cells):  # a group whose cells were all left out: listed below
        group = row.group + (f" ({_datasets(row, finished)})" if row.score == "normalised" and row.cells else "")
        lines.append(f"| {row.experiment} | {group} | {row.algo.upper()} | {row.score} | {len(row.cells)} x "
                     f"{row.seeds} | {row.iqm} | {row.mean} |")
    left_out = [(name, why) for row in rows for name, why in row.left_out]
    if left_out:
        lines += ["", "Left out of the aggregates: " + "; ".join(f"`{name}` ({why})" for name, why in left_out) + "."]
    return lines + [""]
