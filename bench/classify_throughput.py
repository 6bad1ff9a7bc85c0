"""Classification env throughput: `jit(vmap(step))` under `lax.scan`, 1 ... 65,536 envs.

Measures, in one run on the default JAX backend:
- env steps/s and observation bytes written/s of the raw env and of the autoresetting env
  (what `jaxnat.make` returns), random actions, every step's observation in the scan carry
  (the next policy input: written every step) and, separately, also stored as a trajectory
  output (a rollout buffer);
- the same env with the straightforward byte-wise observation writer (GPU), side by side;
- the device's copy bandwidth (bytes read + written per second by a large elementwise op), and
  the observation bandwidth as a fraction of it (target on one H100: >= 50% at 65,536 envs);
- a plain NumPy single-env implementation of the same task stepped in a Python loop (the
  authors' style), and the speed-up over it.

    python bench/classify_throughput.py [--env-id Classify/FashionMNIST-v0] [--max-envs 65536]
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


class NumpyClassify:
    """The same task for one env in NumPy, stepped from Python (the authors' style)."""

    def __init__(self, images, labels, window=5, max_steps=20, seed=0):
        self.images, self.labels, self.w, self.max_steps = images, labels, window, max_steps
        self.rng = np.random.default_rng(seed)
        self.h, self.width = images.shape[1:3]

    def reset(self):
        self.index = self.rng.integers(len(self.images))
        self.pos = self.rng.integers(0, [self.h - self.w + 1, self.width - self.w + 1])
        self.revealed = np.zeros((self.h, self.width), bool)
        self.t = 0
        return self._reveal()

    def _reveal(self):
        window = np.zeros_like(self.revealed)
        r, c = self.pos
        window[r : r + self.w, c : c + self.w] = True
        self.revealed |= window
        image = self.images[self.index]
        return np.concatenate(
            [np.where(self.revealed[..., None], image, 0), self.revealed[..., None] * 255,
             window[..., None] * 255], axis=-1).astype(np.uint8)

    def step(self, move, label):
        delta = ((-1, 0), (1, 0), (0, -1), (0, 1))[move]
        self.pos = np.clip(self.pos + np.array(delta) * self.w, 0,
                           [self.h - self.w, self.width - self.w])
        obs = self._reveal()
        self.t += 1
        correct = label == self.labels[self.index]
        return obs, (1.0 if correct else -0.1), correct, (self.t >= self.max_steps) and not correct


def numpy_steps_per_second(images, labels, num_classes, seconds: float = 3.0) -> float:
    env = NumpyClassify(images, labels)
    rng = np.random.default_rng(1)
    env.reset()
    steps, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        for _ in range(1000):
            _, _, terminated, truncated = env.step(rng.integers(4), rng.integers(num_classes))
            if terminated or truncated:
                env.reset()
        steps += 1000
    return steps / (time.perf_counter() - t0)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env-id", default=None, help="default: FashionMNIST, else Digits")
    parser.add_argument("--max-envs", type=int, default=65536)
    parser.add_argument("--step-budget", type=float, default=None,
                        help="env steps per timed scan (default: 2^25 on GPU, 2^22 on CPU)")
    parser.add_argument("--no-record", action="store_true")
    args = parser.parse_args(argv)

    info = common.machine()
    on_gpu = info["backend"] != "cpu"
    budget = int(args.step_budget or (2**25 if on_gpu else 2**19))
    max_buffer = 2**32 if on_gpu else 2**29
    env_id = args.env_id
    if env_id is None:
        from jaxnat import datasets

        try:
            datasets.load("fashion_mnist", "train")
            env_id = "Classify/FashionMNIST-v0"
        except datasets.DatasetNotFoundError:
            env_id = "Classify/Digits-v0"
    raw, params = jaxnat.make(env_id, autoreset=False)
    auto, _ = jaxnat.make(env_id)
    # The same env writing its observation byte-wise (the straightforward jnp.concatenate).
    bytewise, _ = jaxnat.make(env_id, autoreset=False, observation_writer="bytewise")
    obs_bytes = int(np.prod(raw.observation_space(params).shape))
    print(f"{env_id}: {params.images.shape[0]} images, observation {obs_bytes} bytes; {info['device']}")

    bandwidths = common.copy_bandwidths(2**31 if on_gpu else 2**28)
    bandwidth = max(bandwidths.values())
    rows = []
    sizes = [4**i for i in range(9) if 4**i <= args.max_envs]
    if args.max_envs not in sizes:
        sizes.append(args.max_envs)
    # (label, env, observations also stored as a trajectory?)
    variants = [("raw", raw, False), ("auto", auto, False), ("rawtraj", raw, True),
                ("autotraj", auto, True)]
    if on_gpu:  # CPUs run the byte-wise writer anyway
        variants.append(("bytewise", bytewise, False))
    for num_envs in sizes:
        # Trajectory runs are bounded by their buffer (at most `max_buffer` bytes of observations).
        num_steps = int(np.clip(budget // num_envs, 8, 2000))
        traj_steps = int(np.clip(max_buffer // (num_envs * obs_bytes), 8, num_steps))
        row = {"envs": num_envs, "steps": num_steps, "traj_steps": traj_steps}
        for label, env, trajectory in variants:
            steps = traj_steps if trajectory else num_steps
            run = common.scan_rollout(env, params, num_envs, steps, trajectory)
            key = jax.random.key(0)
            t0 = time.perf_counter()
            jax.block_until_ready(run(key, params))
            row[f"{label}_compile_s"] = time.perf_counter() - t0
            seconds = common.median_seconds(lambda: jax.block_until_ready(run(key, params)), repeats=5)
            row[f"{label}_sps"] = num_envs * steps / seconds
            row[f"{label}_bw_frac"] = row[f"{label}_sps"] * obs_bytes / bandwidth
        rows.append(row)
        print("  " + ", ".join(f"{label} {row[label + '_sps']:.3e}" for label, *_ in variants)
              + f" steps/s at {num_envs} envs", flush=True)

    images = np.asarray(params.images)
    labels = np.asarray(params.labels)
    numpy_sps = numpy_steps_per_second(images, labels, raw.num_classes)
    names = {"raw": "raw", "auto": "autoreset", "rawtraj": "raw + trajectory",
             "autotraj": "autoreset + trajectory", "bytewise": "raw, byte-wise writer"}
    columns = [("envs", "envs", ","), ("steps", "scan steps", ","),
               ("traj_steps", "trajectory steps", ",")]
    for label, *_ in variants:
        columns += [(f"{label}_sps", f"{names[label]} steps/s", ".3e"),
                    (f"{label}_bw_frac", "obs / copy BW", ".1%")]
    columns.append(("raw_compile_s", "compile s", ".2f"))
    table = common.markdown_table(rows, columns)
    largest = rows[-1]

    (raw_label, raw_sps), (auto_label, auto_sps) = ("raw", largest["raw_sps"]), ("auto", largest["auto_sps"])
    summary = {
        "env": env_id,
        "observation bytes": obs_bytes,
        "copy bandwidth (read+write; xor kernel, memcpy)":
            ", ".join(f"{k} {v / 1e9:.0f} GB/s" for k, v in bandwidths.items()),
        f"obs bytes written / copy bandwidth at {largest['envs']:,} envs (obs in the carry)":
            f"raw {raw_sps * obs_bytes / bandwidth:.1%} ({names[raw_label]}), autoreset "
            f"{auto_sps * obs_bytes / bandwidth:.1%} ({names[auto_label]}); target on one H100: >= 50%",
        "NumPy single env, Python loop": f"{numpy_sps:,.0f} steps/s",
        f"jaxnat at {largest['envs']:,} envs / NumPy loop (raw, autoreset)":
            f"{raw_sps / numpy_sps:,.0f}x, {auto_sps / numpy_sps:,.0f}x",
        f"with a trajectory buffer at {largest['envs']:,} envs (raw, autoreset)":
            f"{largest['rawtraj_sps']:.3e}, {largest['autotraj_sps']:.3e} steps/s",
    }
    if on_gpu:
        summary[f"word-wise / byte-wise observation writer at {largest['envs']:,} envs"] = (
            f"{largest['raw_sps'] / largest['bytewise_sps']:.2f}x")
    common.record("classify_throughput", info | {"env": env_id}, table, summary, rows, save=not args.no_record)


if __name__ == "__main__":
    main()
