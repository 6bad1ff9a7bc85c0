"""Shared by the benchmarks: timing, the machine/versions header, and recording results.

Every benchmark prints a table and appends it, with the date, hardware and versions, to
`bench/results/<name>.md` (human-readable) and `bench/results/<name>.jsonl` (one JSON object per
run).
"""

from __future__ import annotations

import datetime
import json
import os
import pathlib
import platform
import statistics
import time

RESULTS = pathlib.Path(__file__).resolve().parent / "results"


def machine() -> dict:
    """Date, hardware and versions of this run."""
    import jax
    import jaxlib
    import numpy

    import jaxnat

    cpu = platform.processor() or platform.machine()
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    device = jax.devices()[0]
    return {
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "backend": device.platform,
        "device": getattr(device, "device_kind", str(device)),
        "num_devices": jax.device_count(),
        "cpu": cpu,
        "cpu_cores": os.cpu_count(),
        "python": platform.python_version(),
        "jax": jax.__version__,
        "jaxlib": jaxlib.__version__,
        "numpy": numpy.__version__,
        "jaxnat": jaxnat.__version__,
    }


def median_seconds(fn, repeats: int = 5) -> float:
    """Median wall time of `fn()` (which must block until its result is ready)."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def markdown_table(rows: list[dict], columns: list[tuple[str, str, str]]) -> str:
    """`columns` = [(key, header, format spec)]."""
    head = "| " + " | ".join(h for _, h, _ in columns) + " |"
    rule = "|" + "|".join("---" for _ in columns) + "|"
    body = [
        "| " + " | ".join(format(r[k], f) if r.get(k) is not None else "-" for k, _, f in columns) + " |"
        for r in rows
    ]
    return "\n".join([head, rule, *body])


def record(name: str, info: dict, table: str, summary: dict, rows: list[dict]) -> pathlib.Path:
    """Print and append one run's results to bench/results/<name>.{md,jsonl}."""
    RESULTS.mkdir(parents=True, exist_ok=True)
    header = (
        f"## {info['date']} | {info['backend']}: {info['device']} | CPU: {info['cpu']} "
        f"({info['cpu_cores']} cores) | python {info['python']}, jax {info['jax']}, "
        f"jaxlib {info['jaxlib']}, numpy {info['numpy']}, jaxnat {info['jaxnat']}"
    )
    lines = [header, "", table, ""]
    lines += [f"- {k}: {v}" for k, v in summary.items()]
    text = "\n".join(lines) + "\n\n"
    print(text)
    with open(RESULTS / f"{name}.md", "a") as f:
        f.write(text)
    with open(RESULTS / f"{name}.jsonl", "a") as f:
        f.write(json.dumps({"machine": info, "summary": summary, "rows": rows}) + "\n")
    return RESULTS / f"{name}.md"
