"""What `jaxnat reproduce` costs: the wall time of a profile's run and of each family within it,
and the GPU-hours the `paper` profile would take, extrapolated from the measured cells.

    python bench/reproduce_cost.py runs/repro [--profile quick] [--hardware "H200 host" --cores 16]

The run may have been made elsewhere (its folder copied here): device and versions are the
run's own (`config.json`), the host CPU as `--hardware` says.

Reads the run's `timings.jsonl` (wall time of every cell session) and each cell's
`summary.json` (its training rate, env steps/s over all seeds, compile and evaluation
excluded). The paper profile's cost per cell is its env steps (budget x seeds) over the
measured rate of the same kind of cell (experiment, trunk, algorithm; else the experiment's
median rate), plus the measured compile-and-evaluation overhead of that kind. Cells of a kind
never measured, or measured only with settings that change the rate (`RATE_SETTINGS`, e.g.
the quick profile's Atari envs), are counted as unmeasured.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
import common  # noqa: E402

from jaxnat.reproduce import PROFILES, build_grid  # noqa: E402
from jaxnat.reproduce.grid import EXPERIMENTS  # noqa: E402


# Settings that change a cell's training rate: a measured cell whose profile set one of them
# (e.g. quick's 256 Atari envs, or PixelMuJoCo's fast physics) says nothing about the paper's rate.
RATE_SETTINGS = ("num_envs", "num_steps", "env_parts", "physics")


def kind(cell) -> tuple:
    return (cell.experiment, cell.labels.get("trunk"), cell.algo)


def rate_departures(profile, experiment: str) -> dict:
    """The settings of `profile` for `experiment` that change the training rate from the paper's."""
    settings = {**profile.overrides.get(experiment, {}), **profile.env_kwargs.get(experiment, {})}
    return {k: v for k, v in settings.items() if k in RATE_SETTINGS}


def measure(out: Path):
    """Per measured cell: (cell, seconds of its sessions, rate in env steps/s, overhead seconds)."""
    timings = [json.loads(line) for line in (out / "timings.jsonl").read_text().splitlines() if line.strip()]
    seconds: dict[str, float] = {}
    for row in timings:
        if row["outcome"] == "finished":
            seconds[row["cell"]] = seconds.get(row["cell"], 0.0) + row["seconds"]
    measured = []
    for cell in build_grid(PROFILES["paper"]):  # every kind of cell (names do not depend on the profile)
        summary_path = out / cell.name / "summary.json"
        if cell.name not in seconds or not summary_path.is_file():
            continue
        summary = json.loads(summary_path.read_text())
        rate = summary["steps_per_second"]["mean"]
        if not summary.get("complete") or not rate:
            continue
        steps = summary["env_steps_per_seed"] * len(summary["seeds"])
        measured.append((cell, seconds[cell.name], rate, max(0.0, seconds[cell.name] - steps / rate)))
    return measured


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--profile", default="quick", choices=list(PROFILES))
    parser.add_argument("--hardware", default=None, help="the host CPU of the run (default: this machine's)")
    parser.add_argument("--cores", default=None, help="its core count (with --hardware)")
    args = parser.parse_args(argv)
    measured = measure(args.out)
    if not measured:
        sys.exit(f"no finished cells with timings in {args.out}")
    rows = [{"experiment": e, "cells": sum(1 for m in measured if m[0].experiment == e),
             "seconds": sum(m[1] for m in measured if m[0].experiment == e)} for e in EXPERIMENTS]
    rows.append({"experiment": "total", "cells": len(measured), "seconds": sum(m[1] for m in measured)})

    by_kind: dict[tuple, list] = {}
    by_experiment: dict[str, list] = {}
    departures = {e: rate_departures(PROFILES[args.profile], e) for e in EXPERIMENTS}
    for cell, _, rate, overhead in measured:
        by_kind.setdefault(kind(cell), []).append((rate, overhead))
        if not departures[cell.experiment]:
            by_experiment.setdefault(cell.experiment, []).append((rate, overhead))
    paper = PROFILES["paper"]
    for row in rows[:-1]:
        row["paper_hours"], row["unmeasured"] = 0.0, 0
    for cell in build_grid(paper):
        row = rows[EXPERIMENTS.index(cell.experiment)]
        sample = None if departures[cell.experiment] else by_kind.get(kind(cell)) or by_experiment.get(cell.experiment)
        if not sample or cell.skip:
            row["unmeasured"] += 1
            continue
        rate = statistics.median(r for r, _ in sample)
        overhead = statistics.median(o for _, o in sample)
        row["paper_hours"] += (cell.budget.total_timesteps * paper.seeds / rate + overhead) / 3600
    rows[-1]["paper_hours"] = sum(r["paper_hours"] for r in rows[:-1])
    rows[-1]["unmeasured"] = sum(r["unmeasured"] for r in rows[:-1])
    kinds = [{"kind": " ".join(str(k) for k in key if k), "rate": statistics.median(r for r, _ in v),
              "overhead": statistics.median(o for _, o in v), "cells": len(v)} for key, v in by_kind.items()]

    versions = json.loads((args.out / measured[0][0].name / "config.json").read_text())["versions"]
    info = {**common.machine(), **{k: versions.get(k, "?") for k in ("jax", "jaxlib", "python", "jaxnat")},
            "device": versions.get("device", "?"), "backend": "gpu" if "cpu" not in versions.get("device", "") else "cpu"}
    if args.hardware:
        info["cpu"], info["cpu_cores"] = args.hardware, args.cores or "?"
    table = common.markdown_table(rows, [("experiment", "experiment", "s"), ("cells", f"{args.profile} cells measured", "d"),
                                         ("seconds", "wall s", ".0f"), ("paper_hours", "paper profile, GPU-hours", ".1f"),
                                         ("unmeasured", "paper cells of an unmeasured kind", "d")])
    table += "\n\n" + common.markdown_table(kinds, [("kind", "kind of cell", "s"), ("cells", "cells", "d"),
                                                      ("rate", "training env steps/s (all seeds)", ",.0f"),
                                                      ("overhead", "compile + evaluation s", ".0f")])
    common.record("reproduce_cost", info, table,
                  {"source": f"jaxnat reproduce --profile {args.profile} (timings.jsonl and summaries of {args.out.name})",
                   "paper GPU-hours": f"{rows[-1]['paper_hours']:.0f}, without {rows[-1]['unmeasured']} cells of kinds "
                                      "never measured at the paper's settings",
                   **{f"{e} not extrapolated": f"{args.profile} runs it with {json.dumps(d)}"
                      for e, d in departures.items() if d}},
                  rows + kinds)


if __name__ == "__main__":
    main()
