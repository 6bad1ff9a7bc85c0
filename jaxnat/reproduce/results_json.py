"""`<out>/results.json`: the report's numbers in one machine-readable file, per seed, so that
another analysis (other aggregates, other plots, another verdict rule) starts from what the
report read and not from its rounded tables.

Per finished or partial cell: its grid entry (name, experiment, figure, labels, the dataset as
printed, env id and kwargs, algorithm, trunk, overrides, note), whether it finished, its seeds,
env steps per seed and share of the paper's budget, wall time, the uniform random policy's test
return, and per seed: the final training return (`report.CellResult.train_per_seed`), the
training return at each of `verdicts.SPEED_CHECKPOINTS` the run reached and at its last step,
the untrained policy's sampled test return (update 0; null where not recorded), and the last
evaluation's greedy and sampled test returns. Then the findings' verdict rows, the aggregates
(`aggregates.py`), the departures (`departures.py`) and the cells not finished or not run.
Non-finite numbers (a seed with no finished episode) are written as null: the file is strict
JSON.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from jaxnat.reproduce.labels import dataset_label
from jaxnat.reproduce.verdicts import SPEED_CHECKPOINTS

__all__ = ["SCHEMA", "cell_entry", "results_document", "write_results", "write_text_atomic"]

SCHEMA = 1  # bumped when a key changes meaning


def _plain(value):
    """`value` as strict JSON: numpy scalars and arrays as numbers and lists, NaN and inf as null."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [_plain(v) for v in value]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, Path):
        return str(value)
    return value


def _interval(interval) -> dict:
    return {"mean": interval.mean, "low": interval.low, "high": interval.high, "n": interval.n}


def cell_entry(result) -> dict:
    """One cell's entry (a `report.CellResult`): its grid entry and its per-seed numbers."""
    cell = result.cell
    last = float(result.steps.max()) if result.steps.size else 0.0
    checkpoints = [{"env_steps": c, "per_seed": result.train_per_seed(c)} for c in SPEED_CHECKPOINTS if last >= c]
    if not checkpoints or checkpoints[-1]["env_steps"] != last:
        checkpoints.append({"env_steps": last, "per_seed": result.train_per_seed(None)})
    untrained = result.untrained_per_seed
    final = result.final_eval
    return {
        "name": cell.name, "experiment": cell.experiment, "figure": cell.figure, "labels": cell.labels,
        "dataset": dataset_label(cell) or None, "env_id": cell.env_id, "env_kwargs": cell.env_kwargs,
        "algo": cell.algo, "trunk": cell.trunk, "overrides": cell.overrides, "note": cell.note,
        "complete": result.complete, "seeds": list(result.seed_values) or result.seeds,
        "env_steps_per_seed": last, "budget_share": result.budget_share, "wall_time_s": result.wall_time_s,
        "random_policy_test_return": result.chance, "data": result.data,
        "train_final": {"env_steps": last, "per_seed": result.train_per_seed(None),
                        "interval": _interval(result.final_train)},
        "train_checkpoints": checkpoints,
        "untrained_test_sampled": None if untrained is None else {"env_steps": 0, "per_seed": untrained,
                                                                 "interval": _interval(result.untrained),
                                                                 "computed_after": result.untrained_after},
        "test_final": None if final is None else {
            "env_steps": float(result.eval_steps[final]),
            "greedy": {"per_seed": result.greedy[final], "interval": _interval(result.final_greedy)},
            "sampled": {"per_seed": result.sampled[final], "interval": _interval(result.final_sampled)}},
    }


def _verdict_row(finding, verdict) -> dict:
    return {"claim": finding.claim, "experiments": list(finding.experiments), "verdict": verdict.verdict,
            "budget_share": None if verdict.share is None else list(verdict.share), "comparisons": verdict.numbers}


def _aggregate_row(row) -> dict:
    return {**{k: getattr(row, k) for k in ("experiment", "group", "algo", "score", "cells", "seeds")},
            "iqm": _interval(row.iqm), "mean": _interval(row.mean),
            "left_out": [{"cell": name, "why": why} for name, why in row.left_out]}


def results_document(plan, results, missing: dict[str, str], verdicts, aggregates, departures: list[dict],
                     written: str) -> dict:
    """The document of `results.json` (`verdicts`: `(findings.Finding, verdicts.Verdict)` pairs;
    `aggregates`: `aggregates.Aggregate`s; `departures`: `departures.departures_data`)."""
    return _plain({
        "schema": SCHEMA, "written": written, "profile": plan.profile.name, "only": list(plan.only),
        "seeds": plan.seeds, "cells": [cell_entry(r) for r in results],
        "not_finished": [{"cell": name, "why": why} for name, why in missing.items()],
        "verdicts": [_verdict_row(f, v) for f, v in verdicts],
        "aggregates": [_aggregate_row(a) for a in aggregates],
        "departures": departures,
    })


def write_text_atomic(path: Path, text: str) -> Path:
    """Write `text` to `path` whole or not at all: through a temporary file beside it, renamed
    over it. Shards of one grid (`jaxnat reproduce --shard`) write the report of one folder and
    may finish at the same moment; a reader never sees half a file."""
    import os
    import tempfile

    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    try:
        with os.fdopen(fd, "w") as out:
            out.write(text)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def write_results(path: Path, document: dict) -> Path:
    return write_text_atomic(path, json.dumps(document, indent=1, allow_nan=False) + "\n")
