"""Localization env throughput: `jit(vmap(step))` under `lax.scan` at 256x256, 1 ... 16,384 envs.

Measures, in one run on the default JAX backend, for `Localize/Clutter-v0` (or `--env-id`):
- env steps/s and observation bytes written/s (`pixels` uint8[256, 256, 4] + `goal` int32) of
  the raw env and of the autoresetting env (what `jaxnat.make` returns), random actions, each
  step's observation in the scan carry (written every step);
- on GPU, the same env with the byte-wise observation writer, side by side;
- the device's copy bandwidth (bytes read + written per second) and the observation bandwidth
  as a fraction of it (target on one H100: >= 50% at the largest batch).

    python bench/localize_throughput.py [--max-envs 16384] [--env-id Localize/Clutter-v0]

CPU runs default to `--max-envs 256`.
"""

from __future__ import annotations

import argparse
import sys
import time

import jax
import numpy as np

sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parent))
import common  # noqa: E402

import jaxnat  # noqa: E402


def observation_bytes(space) -> int:
    """Bytes of one observation (all leaves of a Dict space)."""
    spaces = space.spaces.values() if hasattr(space, "spaces") else [space]
    return sum(int(np.prod(s.shape, dtype=np.int64)) * np.dtype(s.dtype).itemsize for s in spaces)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env-id", default="Localize/Clutter-v0")
    parser.add_argument("--max-envs", type=int, default=None, help="default: 16384 on GPU, 256 on CPU")
    parser.add_argument("--step-budget", type=float, default=None,
                        help="env steps per timed scan (default: 2^22 on GPU, 2^13 on CPU)")
    parser.add_argument("--backgrounds", default=None,
                        help="Clutter's photos/videos folder where opencv-doc is not installed "
                             "(scripts/stage_localize_data.py)")
    parser.add_argument("--no-record", action="store_true")
    args = parser.parse_args(argv)

    info = common.machine()
    on_gpu = info["backend"] != "cpu"
    max_envs = args.max_envs or (16384 if on_gpu else 256)
    budget = int(args.step_budget or (2**22 if on_gpu else 2**13))
    kwargs = {"backgrounds": args.backgrounds} if args.backgrounds else {}
    raw, params = jaxnat.make(args.env_id, autoreset=False, **kwargs)
    auto, _ = jaxnat.make(args.env_id, **kwargs)
    variants = [("raw", raw), ("auto", auto)]
    if on_gpu:  # CPUs run the byte-wise writer anyway
        bytewise, _ = jaxnat.make(args.env_id, autoreset=False, observation_writer="bytewise",
                                  **kwargs)
        variants.append(("bytewise", bytewise))
    obs_bytes = observation_bytes(raw.observation_space(params))
    print(f"{args.env_id}: {params.images.shape[0]} images, observation {obs_bytes:,} bytes; "
          f"{info['device']}", flush=True)

    bandwidths = common.copy_bandwidths(2**31 if on_gpu else 2**28)
    bandwidth = max(bandwidths.values())
    sizes = [4**i for i in range(8) if 4**i <= max_envs]
    if max_envs not in sizes:
        sizes.append(max_envs)
    rows = []
    for num_envs in sizes:
        num_steps = int(np.clip(budget // num_envs, 8, 2000))
        row = {"envs": num_envs, "steps": num_steps}
        for label, env in variants:
            run = common.scan_rollout(env, params, num_envs, num_steps, trajectory=False)
            key = jax.random.key(0)
            t0 = time.perf_counter()
            jax.block_until_ready(run(key, params))
            row[f"{label}_compile_s"] = time.perf_counter() - t0
            seconds = common.median_seconds(lambda: jax.block_until_ready(run(key, params)), repeats=5)
            row[f"{label}_sps"] = num_envs * num_steps / seconds
            row[f"{label}_bw_frac"] = row[f"{label}_sps"] * obs_bytes / bandwidth
        rows.append(row)
        print("  " + ", ".join(f"{label} {row[label + '_sps']:.3e}" for label, _ in variants)
              + f" steps/s at {num_envs} envs", flush=True)

    names = {"raw": "raw", "auto": "autoreset", "bytewise": "raw, byte-wise writer"}
    columns = [("envs", "envs", ","), ("steps", "scan steps", ",")]
    for label, _ in variants:
        columns += [(f"{label}_sps", f"{names[label]} steps/s", ".3e"),
                    (f"{label}_bw_frac", "obs / copy BW", ".1%")]
    columns.append(("raw_compile_s", "compile s", ".2f"))
    table = common.markdown_table(rows, columns)
    largest = rows[-1]
    summary = {
        "env": args.env_id,
        "observation bytes": obs_bytes,
        "copy bandwidth (read+write; xor kernel, memcpy)":
            ", ".join(f"{k} {v / 1e9:.0f} GB/s" for k, v in bandwidths.items()),
        f"obs bytes written / copy bandwidth at {largest['envs']:,} envs (obs in the carry)":
            f"raw {largest['raw_bw_frac']:.1%}, autoreset {largest['auto_bw_frac']:.1%}; "
            "target on one H100: >= 50%",
        f"env steps/s at {largest['envs']:,} envs (raw, autoreset)":
            f"{largest['raw_sps']:.3e}, {largest['auto_sps']:.3e}",
    }
    if on_gpu:
        summary[f"word-wise / byte-wise observation writer at {largest['envs']:,} envs"] = (
            f"{largest['raw_sps'] / largest['bytewise_sps']:.2f}x")
    common.record("localize_throughput", info | {"env": args.env_id}, table, summary, rows, save=not args.no_record)


if __name__ == "__main__":
    main()
