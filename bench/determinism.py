"""Same key, same trajectory: `jaxnat.testing.check_determinism` over every env family, and what
XLA's deterministic GPU ops cost.

For each env: a vmapped rollout of random actions, run three times under one key (twice from
one compiled program, once after compiling again), every output compared bit for bit; the
median wall time of the compiled rollout gives env steps/s. Run once as is and once with
`--deterministic-ops` (sets `XLA_FLAGS=--xla_gpu_deterministic_ops=true` before JAX starts):
the two records side by side give each family's determinism and the flag's throughput cost.

    python bench/determinism.py [--deterministic-ops] [--num-envs 1024] [--steps 8] [--ids ...]
"""

from __future__ import annotations

import argparse
import os
import sys
import time

DEFAULT_IDS = [  # cheapest first, so a run stopped early has the most rows
    "Classify/Digits-v0", "Localize/Clutter-v0",
    "MuJoCo/Swimmer-v0", "MuJoCo/Hopper-v0", "MuJoCo/HalfCheetah-v0", "MuJoCo/Ant-v0",
    "PixelMuJoCo/Hopper-v0", "PixelMuJoCo/Hopper-v0:floor=video", "PixelMuJoCo/Ant-v0",
    "PixelMuJoCo/Ant-v0:floor=video", "PixelMuJoCo/Ant-v0:floor=noise", "PixelMuJoCo/Ant-v0:observation=noise",
    "PixelMuJoCo/Swimmer-v0", "PixelMuJoCo/HalfCheetah-v0",
]


def parse_id(item: str) -> tuple[str, dict]:
    """`PixelMuJoCo/Ant-v0:floor=video,observation=noise` -> (id, kwargs)."""
    env_id, _, rest = item.partition(":")
    kwargs = dict(pair.split("=", 1) for pair in rest.split(",") if pair)
    return env_id, kwargs


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ids", nargs="*", default=DEFAULT_IDS, help="env ids, optionally ID:key=value,...")
    parser.add_argument("--num-envs", type=int, default=1024)
    parser.add_argument("--steps", type=int, default=8)
    parser.add_argument("--deterministic-ops", action="store_true",
                        help="run with XLA_FLAGS=--xla_gpu_deterministic_ops=true")
    parser.add_argument("--budget-seconds", type=float, default=None,
                        help="start no new env after this long; the rest are listed as not run")
    parser.add_argument("--no-record", action="store_true")
    args = parser.parse_args(argv)
    if args.deterministic_ops:  # before JAX starts: XLA reads its flags once
        os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " --xla_gpu_deterministic_ops=true").strip()

    sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parent))
    import common  # noqa: PLC0415

    from jaxnat.datasets import DatasetNotFoundError  # noqa: PLC0415
    from jaxnat.registration import MissingDependencyError  # noqa: PLC0415
    from jaxnat.testing import check_determinism  # noqa: PLC0415

    info = common.machine()
    mode = "xla_gpu_deterministic_ops" if args.deterministic_ops else "default"
    rows, not_run, start = [], [], time.perf_counter()
    for item in args.ids:
        if args.budget_seconds is not None and time.perf_counter() - start > args.budget_seconds:
            not_run.append(item)
            continue
        env_id, kwargs = parse_id(item)
        try:
            report = check_determinism(env_id, args.num_envs, args.steps, **kwargs)
        except (DatasetNotFoundError, MissingDependencyError) as err:
            print(f"{item}: skipped ({err})", flush=True)
            continue
        row = {"env": item, "mode": mode, "identical": report.identical,
               "first_difference": "" if report.identical else str(report).split(": ", 1)[1],
               "steps_per_second": report.steps_per_second}
        rows.append(row)
        print(row, flush=True)
    table = common.markdown_table(rows, [("env", "env", ""), ("mode", "XLA mode", ""),
                                         ("identical", "bitwise identical", ""),
                                         ("first_difference", "first difference", ""),
                                         ("steps_per_second", "env steps/s", ",.0f")])
    summary = {"mode": mode, "num_envs": args.num_envs, "steps": args.steps,
               "identical": f"{sum(r['identical'] for r in rows)} of {len(rows)}",
               **({"not run (time budget)": ", ".join(not_run)} if not_run else {})}
    common.record("determinism", info, table, summary, rows, save=not args.no_record)


if __name__ == "__main__":
    main()
