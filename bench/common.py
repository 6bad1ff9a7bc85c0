"""Shared by the benchmarks: timing, the machine/versions header, and recording results.

Also the two measurements the env throughput benchmarks share: the device's copy bandwidth and
a timed `lax.scan` rollout of a vmapped env under random actions.

Every benchmark prints a table and appends it, with the date, hardware and versions, to
`bench/results/<name>.md` (human-readable) and `bench/results/<name>.jsonl` (one JSON object per
run).
"""

from __future__ import annotations

import datetime
import json
import math
import os
import pathlib
import platform
import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np

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


def t_half_width(std: float, n: int) -> float:
    """Half-width of the 95% Student's t interval of a mean over `n` values with sample std `std`."""
    from scipy import stats

    return float(stats.t.ppf(0.975, n - 1) * std / np.sqrt(n)) if n >= 2 else float("nan")


def mean_ci(values) -> tuple[float, float]:
    """Mean of the finite values and the half-width of its 95% t-interval (NaN for one value)."""
    values = np.asarray(values, np.float64)
    values = values[np.isfinite(values)]
    if len(values) == 0:
        return float("nan"), float("nan")
    return float(values.mean()), t_half_width(float(values.std(ddof=1)) if len(values) > 1 else 0.0, len(values))


def median_seconds(fn, repeats: int = 5) -> float:
    """Median wall time of `fn()` (which must block until its result is ready)."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def throughput_seconds(call, repeats: int = 7, min_seconds: float = 0.05, max_calls: int = 256) -> float:
    """Seconds per `call()` (an async JAX dispatch returning arrays): the median over `repeats`
    timings of back-to-back calls blocked once. A call shorter than its launch latency (a small
    batch on an accelerator) timed alone measures the launch, not the work, and varies with
    it; enough calls per timing to fill `min_seconds` measure the work."""
    one = median_seconds(lambda: jax.block_until_ready(call()), repeats=3)
    calls = int(min(max_calls, max(1, math.ceil(min_seconds / max(one, 1e-9)))))
    return median_seconds(lambda: jax.block_until_ready([call() for _ in range(calls)]), repeats) / calls


def markdown_table(rows: list[dict], columns: list[tuple[str, str, str]]) -> str:
    """`columns` = [(key, header, format spec)]."""
    head = "| " + " | ".join(h for _, h, _ in columns) + " |"
    rule = "|" + "|".join("---" for _ in columns) + "|"
    body = [
        "| " + " | ".join(format(r[k], f) if r.get(k) is not None else "-" for k, _, f in columns) + " |"
        for r in rows
    ]
    return "\n".join([head, rule, *body])


def record(name: str, info: dict, table: str, summary: dict, rows: list[dict],
           save: bool = True) -> pathlib.Path | None:
    """Print one run's results and (unless `save` is False, e.g. `--no-record`) append them to
    bench/results/<name>.{md,jsonl}."""
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
    if not save:
        return None
    with open(RESULTS / f"{name}.md", "a") as f:
        f.write(text)
    with open(RESULTS / f"{name}.jsonl", "a") as f:
        f.write(json.dumps({"machine": info, "summary": summary, "rows": rows}) + "\n")
    return RESULTS / f"{name}.md"


def copy_bandwidths(num_bytes: int) -> dict[str, float]:
    """Bytes read + written per second when XLA copies `num_bytes` on the device, two ways:
    an elementwise kernel (`x ^ 1` on uint32) and a plain copy (`jnp.copy`, a device memcpy).
    The larger is "the device's copy bandwidth"."""
    x = jnp.zeros((num_bytes // 4,), jnp.uint32)
    result = {}
    for name, fn in [("xor_u32", lambda x: x ^ jnp.uint32(1)), ("copy", jnp.copy)]:
        f = jax.jit(fn)
        jax.block_until_ready(f(x))
        seconds = median_seconds(lambda: jax.block_until_ready(f(x)), repeats=10)
        result[name] = 2 * num_bytes / seconds
    return result


def scan_rollout(env, params, num_envs: int, num_steps: int, trajectory: bool):
    """A jitted `run(key, params)`: `num_steps` vmapped steps with uniformly random actions.

    `trajectory=False`: each step's observation is the scan carry (the next policy input), so
    every step writes it to the carry buffer: the env-step metric. `trajectory=True`: every
    observation is also a scan output (a rollout buffer, as a learner keeps). The scan is not
    unrolled: unrolled, XLA may drop observations that no later step reads.
    """
    space = env.action_space(params)
    high = jnp.asarray(space.nvec if hasattr(space, "nvec") else space.n)
    step = jax.vmap(env.step, in_axes=(0, 0, 0, None))
    reset = jax.vmap(env.reset, in_axes=(0, None))

    def run(key, params):
        obs, state = reset(jax.random.split(key, num_envs), params)

        def body(carry, key):
            obs, state = carry
            key_act, key_step = jax.random.split(key)
            actions = jax.random.randint(key_act, (num_envs, *space.shape), 0, high)
            obs, state, reward, *_ = step(jax.random.split(key_step, num_envs), state, actions, params)
            return (obs, state), ((obs, reward) if trajectory else reward)

        return jax.lax.scan(body, (obs, state), jax.random.split(key, num_steps))

    return jax.jit(run)


def device_kernels(trace_dir: str, calls: int = 1) -> list:
    """Every device kernel of a `jax.profiler` trace (its Perfetto JSON), by total time:
    `[name, ms per call, share of device time]` (every stream of every GPU counted), for a
    trace of `calls` calls of the program."""
    import collections
    import glob
    import gzip

    paths = sorted(glob.glob(f"{trace_dir}/**/perfetto_trace.json.gz", recursive=True))
    if not paths:
        return []
    with gzip.open(paths[-1]) as f:
        trace = json.load(f)
    events = trace["traceEvents"] if isinstance(trace, dict) else trace
    devices = {e["pid"] for e in events if e.get("ph") == "M" and e.get("name") == "process_name"
               and "GPU" in str(e.get("args", {}).get("name", ""))}
    totals = collections.Counter()
    for e in events:
        if e.get("ph") == "X" and e.get("pid") in devices:
            totals[e["name"]] += e.get("dur", 0.0)
    whole = sum(totals.values()) or 1.0
    return [[name, us / 1e3 / calls, us / whole] for name, us in totals.most_common()]


# Kernel classes of a GPU trace, by name (first match wins): copies the program makes, XLA's
# own fused kernels (Triton GEMMs among them), then cuDNN's and cuBLAS's library kernels.
KERNEL_CLASSES = (("copies (MemcpyD2D, Memset)", ("memcpy", "memset")),
                  ("XLA GEMM fusions", ("gemm_fusion", "triton_gemm", "__triton_gemm")),
                  ("XLA fusions", ("fusion", "triton", "copy", "transpose", "reduce", "slice", "gather", "scatter")),
                  ("convolutions (cuDNN)", ("conv", "cudnn", "xmma", "implicit", "wgrad", "dgrad", "fprop",
                                            "cutlass", "nhwc", "kernel_")),
                  ("GEMMs (cuBLAS)", ("gemm", "cublas", "sm90", "sm80", "ampere", "hopper")))


def kernel_classes(kernels: list) -> dict:
    """`device_kernels` summed by `KERNEL_CLASSES` (the rest "other"): {class: [ms, share]}."""
    sums: dict = {}
    for name, ms, share in kernels:
        lower = name.lower()
        group = next((cls for cls, words in KERNEL_CLASSES if any(w in lower for w in words)), "other")
        total = sums.setdefault(group, [0.0, 0.0])
        total[0] += ms
        total[1] += share
    return dict(sorted(sums.items(), key=lambda kv: -kv[1][0]))


def forward_mflop(network, params, observation_space) -> float:
    """MFLOP of one sample's forward pass of `network` (unbatched `params`), from XLA:CPU's cost
    analysis of XLA's own convolutions: on a GPU the convolutions are cuDNN calls, which its
    cost analysis leaves out."""
    obs = jax.ShapeDtypeStruct((1, *observation_space.shape), observation_space.dtype)
    with jax.default_device(jax.devices("cpu")[0]):
        analysis = jax.jit(network.clone(conv="native").apply).lower(params, obs).compile().cost_analysis()
    analysis = analysis[0] if isinstance(analysis, (list, tuple)) else analysis
    return float(analysis.get("flops", float("nan"))) / 1e6
