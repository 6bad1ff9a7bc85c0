"""`jaxnat reproduce` on 1 GPU against N GPUs: the wall time of the same cells, and the same results.

Runs `jaxnat reproduce --profile P --only X --trunks T --gpus G` once per `--gpus` value, each in a
fresh out folder (nothing finished before), one after another, and records per run: the cells
trained, the wall time of the whole command (compiling included), the sum of the cells' own
times (`<out>/timings.jsonl`), the speedup against the first run (`--gpus 1` by default) and the
efficiency (speedup / G). A cell trained on another GPU must train the same run: each cell's
final train return per seed (last row of `metrics.jsonl`) is compared with the first run's, and
the largest difference is printed (the GPUs are of one kind, so runs under a key are expected
to agree bit for bit; the column shows whether they did).

    python bench/reproduce_scaling.py                          # quick profile's classification cells, 1 vs 2 GPUs
    python bench/reproduce_scaling.py --gpus 1 2 4 --only classify,localize
    python bench/reproduce_scaling.py --profile paper --cells 'classify-sweep-w5-*'   # paper cells, 1 vs 2 GPUs
    JAX_PLATFORMS=cpu python bench/reproduce_scaling.py --profile smoke --gpus 1 --no-record

The paper profile's own cells take GPU-hours each; the quick profile trains the same grid of
cells (same envs, algorithms and seeds, smaller budgets), which is what the scheduler shares
among GPUs, so its ratio is the one the paper profile gets when its cells are as evenly split
(the report of each out folder says how they were split). Records to
`bench/results/reproduce_scaling.{md,jsonl}` unless `--no-record`.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
# This process only reads the machine's description: the GPUs' memory is the children's.
os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")


def final_returns(out: Path) -> dict[tuple[str, int], float]:
    """`{(cell, seed): train return of the cell's last metrics row for that seed}`."""
    result = {}
    for metrics in sorted(out.glob("*/metrics.jsonl")):
        for line in metrics.read_text().splitlines():
            row = json.loads(line)
            if "episode_return" in row and row["episode_return"] is not None:
                result[(metrics.parent.name, int(row.get("seed", 0)))] = float(row["episode_return"])
    return result


def run_reproduce(args, gpus: int, out: Path, gpu_ids: list[str]) -> dict:
    """One `jaxnat reproduce` into the fresh folder `out`, seeing the first `gpus` of `gpu_ids`
    (none: as this process does); its row."""
    argv = [sys.executable, "-m", "jaxnat.cli", "reproduce", "--profile", args.profile, "--only", args.only,
            "--trunks", args.trunks, "--out", str(out), "--gpus", str(gpus)]
    if args.seeds:
        argv += ["--seeds", str(args.seeds)]
    if args.pack_small > 1:
        argv += ["--pack-small", str(args.pack_small)]
    if args.cells:
        argv += ["--cells", args.cells]
    env = {**os.environ, "COLUMNS": "160"}
    env.pop("XLA_PYTHON_CLIENT_PREALLOCATE", None)  # the children run as a user's would
    if gpu_ids:  # a 1-GPU run must not take the others' memory, as JAX in one process would
        env["CUDA_VISIBLE_DEVICES"] = ",".join(gpu_ids[:gpus])
    start = time.perf_counter()
    proc = subprocess.run(argv, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - start
    log = out / "bench.log"
    log.write_text(proc.stdout + proc.stderr)
    timings = [json.loads(line) for line in (out / "timings.jsonl").read_text().splitlines()] \
        if (out / "timings.jsonl").exists() else []
    failed = [t["cell"] for t in timings if t.get("outcome") != "finished"]
    if proc.returncode != 0 or failed:
        tail = (proc.stdout + proc.stderr).strip().splitlines()[-1:] or ["(no output)"]
        print(f"--gpus {gpus}: exit {proc.returncode}, failed cells {failed}: {tail[0]} (log: {log})")
    return {"gpus": gpus, "cells": len(timings), "failed": len(failed), "exit": proc.returncode,
            "wall_s": wall, "cell_s": sum(t["seconds"] for t in timings)}


def main(argv=None) -> int:
    from common import machine, markdown_table, record

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--profile", default="quick", choices=("smoke", "quick", "paper"))
    parser.add_argument("--only", default="classify", help="reproduce's --only (default: classify)")
    parser.add_argument("--trunks", default="cnn", help="reproduce's --trunks (default: cnn)")
    parser.add_argument("--gpus", type=int, nargs="+", default=[1, 2],
                        help="GPU counts, one reproduce each, the first the baseline (default: 1 2)")
    parser.add_argument("--seeds", type=int, default=None, help="seeds per cell (default: the profile's)")
    parser.add_argument("--pack-small", type=int, default=1, help="reproduce's --pack-small (default: 1)")
    parser.add_argument("--cells", default=None,
                        help="reproduce's --cells: only these cells (e.g. the paper profile's 'classify-sweep-*')")
    parser.add_argument("--keep", type=Path, default=None, help="keep the out folders under this folder")
    parser.add_argument("--no-record", action="store_true")
    args = parser.parse_args(argv)
    if any(g < 1 for g in args.gpus):
        parser.error(f"--gpus takes GPU counts of 1 or more, not {args.gpus}")

    info = machine()
    gpu_ids = []
    if info["backend"] == "gpu":
        visible = [v.strip() for v in os.environ.get("CUDA_VISIBLE_DEVICES", "").split(",") if v.strip()]
        gpu_ids = visible or [str(i) for i in range(info["num_devices"])]
        if max(args.gpus) > len(gpu_ids):
            parser.error(f"--gpus {max(args.gpus)}: only {len(gpu_ids)} GPUs are visible here ({','.join(gpu_ids)})")
    root = Path(args.keep or tempfile.mkdtemp(prefix="reproduce-scaling-"))
    outs = [root / f"{i}-gpus-{gpus}" for i, gpus in enumerate(args.gpus)]
    for out in outs:
        if out.exists() and any(out.iterdir()):
            parser.error(f"{out} is not empty: every run starts from nothing; pass another --keep folder")
    rows, base_returns = [], None
    for gpus, out in zip(args.gpus, outs):
        out.mkdir(parents=True, exist_ok=True)
        row = run_reproduce(args, gpus, out, gpu_ids)
        if row["cells"] == 0:  # a speedup of two empty runs measures nothing: record nothing
            sys.exit(f"reproduce_scaling: --gpus {gpus} trained no cell, nothing recorded: no cell matched --cells "
                     f"or none is runnable here (missing data?); {out / 'report.md'} and {out / 'bench.log'} say why")
        returns = final_returns(out)
        if base_returns is None:
            base_returns = returns
        shared = set(returns) & set(base_returns)
        row["max_return_diff"] = max((abs(returns[k] - base_returns[k]) for k in shared), default=None)
        row["compared"] = len(shared)
        rows.append(row)
        print(f"--gpus {gpus}: {row['cells']} cells in {row['wall_s']:.0f} s (cells' own time {row['cell_s']:.0f} s)",
              flush=True)
    base = rows[0]["wall_s"]
    for row in rows:
        row["speedup"] = base / row["wall_s"]
        row["efficiency"] = row["speedup"] * rows[0]["gpus"] / row["gpus"]
    table = markdown_table(rows, [("gpus", "GPUs", "d"), ("cells", "cells", "d"), ("failed", "failed", "d"),
                                  ("wall_s", "wall s", ".0f"), ("cell_s", "cells' own s", ".0f"),
                                  ("speedup", "speedup", ".2f"), ("efficiency", "efficiency", ".0%"),
                                  ("compared", "returns compared", "d"),
                                  ("max_return_diff", "max |return diff|", ".3g")])
    summary = {"command": f"jaxnat reproduce --profile {args.profile} --only {args.only} --trunks {args.trunks}"
                          + (f" --seeds {args.seeds}" if args.seeds else "")
                          + (f" --pack-small {args.pack_small}" if args.pack_small > 1 else "")
                          + (f" --cells '{args.cells}'" if args.cells else "") + " --gpus G",
               "baseline": f"{rows[0]['gpus']} GPU(s), the first row",
               "speedup": "wall(first row) / wall(row), each from nothing, compiling included"}
    record("reproduce_scaling", info, table, summary, rows, save=not args.no_record)
    return 1 if any(r["failed"] or r["exit"] for r in rows) else 0


if __name__ == "__main__":
    sys.exit(main())
