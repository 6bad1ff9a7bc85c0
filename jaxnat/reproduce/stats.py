"""Statistics of the report: the mean over seeds with a 95% bootstrap confidence interval, and
learning curves binned over env steps.

The interval is the percentile bootstrap of the mean over seeds (resampling seeds with
replacement, a fixed number of resamples from a fixed generator, so a report is reproducible):
with 5 seeds it is narrow where seeds agree and says little otherwise, which is the point.
"""

from __future__ import annotations

import dataclasses

import numpy as np

__all__ = ["Interval", "bootstrap_ci", "bootstrap_band", "binned_curve"]

RESAMPLES = 2000
CONFIDENCE = 0.95


@dataclasses.dataclass(frozen=True)
class Interval:
    """A mean over seeds and its confidence interval (NaN when no seed has a value)."""

    mean: float
    low: float
    high: float
    n: int  # seeds with a finite value

    def contains(self, value: float) -> bool:
        return bool(self.low <= value <= self.high)

    def __str__(self) -> str:
        if not np.isfinite(self.mean):
            return "—"
        return f"{self.mean:.3g} [{self.low:.3g}, {self.high:.3g}]"


def bootstrap_ci(values, *, resamples: int = RESAMPLES, confidence: float = CONFIDENCE, seed: int = 0) -> Interval:
    """The mean of the finite `values` and its percentile-bootstrap interval."""
    values = np.asarray(values, np.float64).ravel()
    values = values[np.isfinite(values)]
    if values.size == 0:
        return Interval(float("nan"), float("nan"), float("nan"), 0)
    rng = np.random.default_rng(seed)
    means = values[rng.integers(0, values.size, (resamples, values.size))].mean(axis=1)
    tail = (1.0 - confidence) / 2.0 * 100.0
    low, high = np.percentile(means, [tail, 100.0 - tail])
    return Interval(float(values.mean()), float(low), float(high), int(values.size))


def bootstrap_band(per_seed, **kwargs) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`per_seed`: `[points, seeds]` -> (mean, low, high) per point, NaN where no seed has a value."""
    per_seed = np.asarray(per_seed, np.float64)
    rows = [bootstrap_ci(row, **kwargs) for row in per_seed]
    return tuple(np.array([getattr(r, name) for r in rows]) for name in ("mean", "low", "high"))


def binned_curve(steps, per_seed, bins: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """A per-seed curve `[points, seeds]` at env steps `steps` -> (bin centres, `[bins, seeds]`):
    each seed's mean of the finite values in each of `bins` equal spans of steps (fewer bins
    when there are fewer points; NaN where a seed has no value in a bin)."""
    steps = np.asarray(steps, np.float64)
    per_seed = np.asarray(per_seed, np.float64)
    if steps.size == 0:
        return steps, per_seed.reshape(0, per_seed.shape[-1] if per_seed.ndim == 2 else 0)
    bins = max(1, min(bins, steps.size))
    edges = np.linspace(steps.min(), steps.max(), bins + 1)
    index = np.clip(np.searchsorted(edges, steps, side="right") - 1, 0, bins - 1)
    finite = np.isfinite(per_seed)
    totals = np.zeros((bins, per_seed.shape[1]))
    counts = np.zeros((bins, per_seed.shape[1]))
    np.add.at(totals, index, np.where(finite, per_seed, 0.0))
    np.add.at(counts, index, finite)
    centres = np.array([steps[index == b].mean() if np.any(index == b) else np.nan for b in range(bins)])
    with np.errstate(invalid="ignore", divide="ignore"):
        values = np.where(counts > 0, totals / np.maximum(counts, 1), np.nan)
    keep = np.isfinite(centres)
    return centres[keep], values[keep]
