"""Natural signal sources: how fast frames are decoded, and what a background frame costs per step.

Measures, in one run:
- decoding: frames/s of OpenCV decoding + resizing for each default video (opencv-doc), no cache;
  and the time to load the whole bank from the disk cache (a second start);
- per agent step, for `--envs` envs (default 4,096), on the default JAX backend: the jitted,
  vmapped `cursor_step` + `cursor_frame` under `lax.scan`, each step's frames in the carry (an
  env writes its observation every step), against the same scan writing a constant frame (the
  write alone), and against fresh Gaussian noise (`gaussian_noise`); and on the host,
  `HostVideoSampler.step(out=...)` (one gather of B frames into a reused buffer).

Frame shapes: 84x84x1 (an Atari observation), 84x84x3 (a PixelMuJoCo floor texture) and
210x160x3 (Atari's RGB screen, where natural Atari composites).

    python bench/natural_sources.py [--envs 4096] [--quick] [--sources DIR] [--no-record]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
import warnings
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import common  # noqa: E402

from jaxnat import natural  # noqa: E402
from jaxnat.natural import decode  # noqa: E402
from jaxnat.natural.sources import VIDEO_EXTENSIONS, resolve  # noqa: E402

SHAPES = [((84, 84), True), ((84, 84), False), ((210, 160), False)]


def video_paths(sources) -> list[Path]:
    if sources is None:
        return natural.default_video_paths()
    return resolve(sources, VIDEO_EXTENSIONS)


def decode_rates(sources, shape: tuple[int, int], grayscale: bool) -> list[dict]:
    rows = []
    for path in video_paths(sources):
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", natural.VideoDecodeWarning)
            frames = decode.decode_video(path, shape, grayscale)
        seconds = time.perf_counter() - t0
        rows.append({"video": path.name, "frames": len(frames), "seconds": seconds,
                     "fps": len(frames) / seconds})
    return rows


def second_start_seconds(sources) -> float:
    """Seconds to load the 84x84 RGB bank of all default videos from a warm disk cache."""
    previous = os.environ.get("JAXNAT_CACHE_DIR")
    with tempfile.TemporaryDirectory() as cache, warnings.catch_warnings():
        warnings.simplefilter("ignore", natural.VideoDecodeWarning)
        os.environ["JAXNAT_CACHE_DIR"] = cache
        try:
            natural.load_videos(sources, split="all")
            t0 = time.perf_counter()
            natural.load_videos(sources, split="all")
            return time.perf_counter() - t0
        finally:
            if previous is None:
                del os.environ["JAXNAT_CACHE_DIR"]
            else:
                os.environ["JAXNAT_CACHE_DIR"] = previous


def scan_fetch(bank, num_envs: int, num_steps: int, mode: str):
    """jit(run(key)): `num_steps` steps of `num_envs` envs, each step's frames in the carry."""
    h, w, c = bank.frame_shape
    reset = jax.vmap(natural.cursor_reset, in_axes=(0, None))
    step = jax.vmap(natural.cursor_step, in_axes=(0, 0, None))
    frame = jax.vmap(natural.cursor_frame, in_axes=(None, 0))

    def run(key, bank):
        cursors = reset(jax.random.split(key, num_envs), bank)
        frames = jnp.zeros((num_envs, h, w, c), jnp.uint8)

        def body(carry, key):
            cursors, frames = carry
            if mode == "video":
                cursors = step(jax.random.split(key, num_envs), cursors, bank)
                frames = frame(bank, cursors)
            elif mode == "noise":
                frames = natural.gaussian_noise(key, (num_envs, h, w, c))
            else:  # "write": the same carry write with a frame that needs no fetch
                frames = jnp.broadcast_to(jax.random.bits(key, (), jnp.uint8),
                                          (num_envs, h, w, c))
            return (cursors, frames), None

        return jax.lax.scan(body, (cursors, frames), jax.random.split(key, num_steps))[0]

    return jax.jit(run)


def step_costs(bank_host, num_envs: int, num_steps: int, noise: bool) -> dict:
    bank = bank_host.to_device()
    row = {}
    key = jax.random.key(0)
    for mode in ("video", "write", "noise") if noise else ("video", "write"):
        run = scan_fetch(bank, num_envs, num_steps, mode)
        jax.block_until_ready(run(key, bank))
        seconds = common.median_seconds(lambda: jax.block_until_ready(run(key, bank)), 5)
        row[f"{mode}_us"] = seconds / num_steps * 1e6
    sampler = natural.HostVideoSampler(bank_host, num_envs, seed=0)
    out = np.empty((num_envs, *bank_host.frame_shape), np.uint8)
    host_steps = max(10, num_steps // 4)
    seconds = common.median_seconds(lambda: [sampler.step(out=out) for _ in range(host_steps)], 3)
    row["host_us"] = seconds / host_steps * 1e6
    return row


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", type=int, default=4096)
    parser.add_argument("--steps", type=int, default=None,
                        help="scan steps per timing (default 200 on GPU, 20 on CPU)")
    parser.add_argument("--quick", action="store_true", help="decode at one shape only")
    parser.add_argument("--noise", action=argparse.BooleanOptionalAction, default=None,
                        help="also time Gaussian noise (default: on GPU only; on a CPU it takes "
                             "seconds per step at 4,096 envs)")
    parser.add_argument("--sources", default=None,
                        help="videos to use (folder or glob; default: opencv-doc's five, which "
                             "must be installed)")
    parser.add_argument("--no-record", action="store_true")
    args = parser.parse_args(argv)

    info = common.machine()
    on_gpu = info["backend"] != "cpu"
    num_steps = args.steps or (200 if on_gpu else 20)
    noise = on_gpu if args.noise is None else args.noise

    decode_rows = decode_rates(args.sources, (84, 84), False)
    total = sum(r["frames"] for r in decode_rows)
    decode_seconds = sum(r["seconds"] for r in decode_rows)
    cached_seconds = second_start_seconds(args.sources)
    gray_rate = None
    if not args.quick:
        gray = decode_rates(args.sources, (84, 84), True)
        gray_rate = sum(r["frames"] for r in gray) / sum(r["seconds"] for r in gray)

    rows = []
    for shape, grayscale in SHAPES:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", natural.VideoDecodeWarning)
            bank = natural.load_videos(args.sources, shape=shape, grayscale=grayscale,
                                       split="all")
        row = {"frame": "x".join(map(str, bank.frame_shape)), "envs": args.envs,
               "steps": num_steps, "bank_mib": bank.nbytes / 2**20}
        row |= step_costs(bank, args.envs, num_steps, noise)
        row["fetch_us"] = row["video_us"] - row["write_us"]
        rows.append(row)
        print(f"  {row['frame']}: video {row['video_us']:.1f} us/step, write only "
              f"{row['write_us']:.1f}, noise {row.get('noise_us', float('nan')):.1f}, "
              f"host {row['host_us']:.1f}", flush=True)

    decode_table = common.markdown_table(decode_rows, [
        ("video", "video (84x84 RGB)", "s"), ("frames", "frames", ","),
        ("seconds", "decode s", ".2f"), ("fps", "frames/s", ",.0f")])
    step_table = common.markdown_table(rows, [
        ("frame", "frame", "s"), ("envs", "envs", ","), ("steps", "scan steps", ","),
        ("bank_mib", "bank MiB (all videos)", ".1f"),
        ("video_us", "video frame: cursor step + fetch, us/step", ".1f"),
        ("write_us", "constant frame (write only), us/step", ".1f"),
        ("fetch_us", "fetch cost over write, us/step", ".1f"),
        ("noise_us", "Gaussian noise, us/step", ".1f"),
        ("host_us", "host sampler step (numpy), us/step", ".1f")])
    summary = {
        "decode (OpenCV, resize to 84x84 RGB), all videos":
            f"{total:,} frames in {decode_seconds:.2f} s = {total / decode_seconds:,.0f} frames/s",
        "decode to 84x84 gray": f"{gray_rate:,.0f} frames/s" if gray_rate else "not run (--quick)",
        "second start (bank of all videos at 84x84 RGB from the disk cache)":
            f"{cached_seconds:.3f} s",
        f"per-step video frame cost at {args.envs:,} envs (84x84x3)":
            f"{rows[1]['video_us']:.1f} us per step ({rows[1]['video_us'] / args.envs * 1e3:.2f} "
            "ns per env)",
    }
    table = decode_table + "\n\n" + step_table
    common.record("natural_sources", info, table, summary,
                  {"decode": decode_rows, "steps": rows}, save=not args.no_record)


if __name__ == "__main__":
    main()
