"""Natural Atari throughput: our env (background none / noise / video) against ale-py's own vector
env with the same preprocessing and threads, side by side in one run, and thread scaling.

For each thread count, every contender steps `--num-envs` envs of `--game` with the same random
actions (sticky actions 0.25, up to 30 no-ops at reset, frame skip 4 with max-pool, 84x84 gray,
stack 4, no FIRE at reset, unclipped rewards); ale-py does all preprocessing in its C++ threads,
with a background we ask it for the max-pooled 210x160 gray screen and composite, resize (one
fused pass, jaxnat.atari.area) and stack on the host (background none: ALE resizes, we stack).
Also timed at the largest thread count: ale-py returning that screen alone (the emulation share
of our step), our env with `pool="rgb"` (RGB screens, the spec's literal pooling order) with the
video background, the video and noise backgrounds with other host-thread counts (the
compositing, resizing and stacking after ALE, and the noise draws, are split over `host_threads`
chunks of envs; 1 = the calling thread alone), and the video background with that host pass on
the Python thread pool that jaxnat.atari.hostpass's single numba call replaced (with the
default's chunk count).
Contenders are timed in interleaved rounds (median), so load from other processes hits them
alike. For our env the table also splits a batched step into the wait for ALE's emulation and
the background work done while ALE emulates (next video frames, noise draws) and the host work
after it (ms per batched step, from `env.step_timings`; host us/env = that host work per env).
Target: video >= 90% of ale-py's own throughput (the "target" line of each run in
bench/results/natural_atari.md).

Also writes bench/results/natural_atari_frames.png: one row per background, the agent's newest
84x84 frame at a few steps, then the next RGB screen composited at full resolution with a
frame of that background's source (the env itself composites in gray).

    python bench/natural_atari.py                 # sizes from the CPU count
    python bench/natural_atari.py --quick         # a smoke run
    python bench/natural_atari.py --threads 1 4 8 16 --num-envs 64 --steps 100
    python bench/natural_atari.py --video-sources out/videos   # a folder of your own clips

On a 16-core host this sweeps 1, 4, 8 and 16 threads with 64 envs (how long a run takes: the
"bench seconds" line of each run in bench/results/natural_atari.md). A host without Debian's
opencv-doc needs videos: copy some there (e.g. opencv-doc's vtest.avi, tree.avi and
Megamind.avi into out/videos/) and pass --video-sources out/videos.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import common  # noqa: E402

from jaxnat.atari import GAMES  # noqa: E402
from jaxnat.atari.compositor import composite  # noqa: E402
from jaxnat.atari.env import NaturalAtariVecEnv  # noqa: E402

SETTINGS = dict(sticky_actions=0.25, noop_max=30, frame_skip=4, maxpool=True)


def ale_py_env(game: str, num_envs: int, threads: int, screen: bool, seed: int):
    """ale-py's own vector env with our settings: 84x84 gray stack 4, or the 210x160 screen."""
    from ale_py.vector_env import AtariVectorEnv

    shape = dict(img_height=210, img_width=160, stack_num=1) if screen else {}
    env = AtariVectorEnv(
        GAMES[game], num_envs, num_threads=threads, repeat_action_probability=0.25,
        noop_max=30, frameskip=4, maxpool=True, use_fire_reset=False, reward_clipping=False,
        autoreset_mode="SameStep", **shape,
    )
    env.reset(seed=seed)
    return env


def steps_per_second(env, actions: np.ndarray) -> float:
    t0 = time.perf_counter()
    for a in actions:
        env.step(a)
    return actions.size / (time.perf_counter() - t0)


def contenders(game, num_envs, threads, backgrounds, seed, video_sources, rgb_pool, host_threads,
               extras):
    """name -> env: ale-py's own env and ours with each background; with `extras` (the largest
    thread count: constructing 64 emulators takes seconds, so the sweep keeps to the essentials)
    also ale-py's bare screen, the video and noise backgrounds with `host_threads` host threads,
    and video with `pool="rgb"`."""
    envs = {"ale-py (gray 84x84x4)": ale_py_env(game, num_envs, threads, screen=False, seed=seed)}
    if extras:
        envs["ale-py 210x160 screen only"] = ale_py_env(game, num_envs, threads, screen=True,
                                                        seed=seed)
    variants = [(bg, "gray", 0) for bg in backgrounds]
    if "video" in backgrounds and extras and rgb_pool:
        variants.append(("video", "rgb", 0))
    if extras:  # after the defaults: a count equal to the default's chunks would time it twice
        variants += [(bg, "gray", h) for bg in ("video", "noise") if bg in backgrounds
                     for h in host_threads]
    for bg, pool, host in variants:
        name = f"jaxnat {bg}" + (" (pool=rgb)" if pool == "rgb" else "")
        if host and host == envs[name].host_threads:
            continue
        env = NaturalAtariVecEnv(game, num_envs, background=bg, num_threads=threads, seed=seed,
                                 video_sources=video_sources, pool=pool, host_threads=host,
                                 **SETTINGS)
        env.reset()
        envs[name + (f" (host_threads={host})" if host else "")] = env
    if extras and "video" in backgrounds:  # the host pass before jaxnat.atari.hostpass, to compare
        env = NaturalAtariVecEnv(game, num_envs, background="video", num_threads=threads,
                                 seed=seed, video_sources=video_sources, host_pass="pool",
                                 host_threads=envs["jaxnat video"].host_threads, **SETTINGS)
        env.reset()
        envs["jaxnat video (Python thread-pool chunks)"] = env
    return envs


def rgb_twin(game: str, seed: int):
    """ale-py's own vector env emulating exactly what `frame_strip`'s one-env
    `NaturalAtariVecEnv(..., pool="rgb", num_threads=1, seed=seed, **SETTINGS)` emulates (the
    same settings and seed: the same games under the same actions), returning its max-pooled
    210x160 RGB screens."""
    from ale_py.vector_env import AtariVectorEnv

    env = AtariVectorEnv(
        GAMES[game], 1, img_height=210, img_width=160, grayscale=False, stack_num=1,
        frameskip=4, maxpool=True, noop_max=30, use_fire_reset=False, episodic_life=False,
        reward_clipping=False, repeat_action_probability=0.25, full_action_space=False,
        max_num_frames_per_episode=27_000 * 4, num_threads=1, autoreset_mode="SameStep",
    )
    env.reset(seed=seed)
    return env


def frame_strip(game: str, backgrounds, video_sources, path: Path, steps=(0, 40, 80)) -> None:
    """Newest observation frame (84x84, upscaled 2x) per background and step, plus an RGB
    composite at full resolution, one row per background."""
    rows = []
    for bg in backgrounds:
        env = NaturalAtariVecEnv(game, 1, background=bg, num_threads=1, seed=1, pool="rgb",
                                 video_sources=video_sources, **SETTINGS)
        twin = rgb_twin(game, seed=1)
        obs, _ = env.reset()
        tiles = []
        rng = np.random.default_rng(0)
        for t in range(max(steps) + 1):
            if t in steps:
                tiles.append(cv2.resize(obs[0, ..., -1], (168, 168), interpolation=cv2.INTER_NEAREST))
            if t < max(steps):
                actions = rng.integers(0, env.single_action_space.n, 1)
                obs, *_ = env.step(actions)
                twin.step(actions)
        # The next RGB screen, composited in RGB (the env composites in gray).
        rgb = twin.step(np.zeros(1, np.int64))[0][:, 0]
        twin.close()
        background = _rgb_background(env, bg)
        full = composite(rgb, background)[0] if background is not None else rgb[0]
        full = cv2.resize(full, (128, 168), interpolation=cv2.INTER_AREA)
        gray_tiles = [cv2.cvtColor(t, cv2.COLOR_GRAY2RGB) for t in tiles]
        row = np.concatenate([*gray_tiles, full], axis=1)
        cv2.putText(row, bg, (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 64, 64), 1)
        rows.append(row)
        env.close()
    strip = np.concatenate(rows, axis=0)
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), cv2.cvtColor(strip, cv2.COLOR_RGB2BGR))


def _rgb_background(env, bg):
    from jaxnat import natural

    if bg == "none":
        return None
    if bg == "noise":
        return natural.gaussian_noise_np(np.random.default_rng(0), (1, 210, 160, 3))

    load = natural.load_videos if bg == "video" else natural.load_images
    bank = load(env.video_sources, shape=(210, 160), split=env.split)
    return bank.frames[bank.num_frames // 2][None]


def host_pieces(num_envs: int, repeats: int = 20) -> str:
    """Microseconds per env of each piece of the host work, one whole-batch call each, on one
    core (OpenCV limited to 1 thread here): what the host threads have to share out. The env
    composites and resizes in one pass of jaxnat.atari.area's kernel; OpenCV's way of doing
    the same (a masked copy, then cv2.resize: bit-identical output) is timed beside it."""
    from jaxnat.atari.compositor import (
        FrameStack,
        GrayNoiseSampler,
        composite_and_resize,
        composite_pooled_gray,
        resize_area,
    )

    rng = np.random.default_rng(0)
    screens = rng.integers(1, 256, (num_envs, 210, 160), dtype=np.uint8)
    screens[rng.random(screens.shape) < 0.8] = 0  # mostly background, as Breakout
    bank = rng.integers(0, 256, (256, 210, 160), dtype=np.uint8)
    backgrounds = np.empty_like(screens)
    stack = FrameStack(4)
    stack.allocate(num_envs, (84, 84))
    sampler = GrayNoiseSampler(rng)
    rngs = [np.random.default_rng(i) for i in range(num_envs)]
    index = rng.integers(0, len(bank), num_envs)
    work = screens.copy()
    pieces = {
        "video gather": lambda: np.take(bank, index, axis=0, out=backgrounds, mode="clip"),
        "composite+resize (fused kernel)": lambda: composite_and_resize(
            screens, backgrounds, (84, 84), out=stack.rotate()),
        "OpenCV: screen copy+mask+composite": lambda: composite_pooled_gray(
            np.copyto(work, screens) or work, backgrounds),
        "OpenCV: resize": lambda: resize_area(work, (84, 84), out=stack.rotate()),
        "stack merge": stack.observation,
        "noise draws": lambda: [sampler.sample((210, 160), r, out=b) for r, b in zip(rngs, backgrounds)],
    }
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        out = []
        for name, piece in pieces.items():
            piece()
            best = min(_seconds(piece, repeats) for _ in range(3))
            out.append(f"{name} {1e6 * best / num_envs:.1f}")
    finally:
        cv2.setNumThreads(threads)
    return ", ".join(out)


def _seconds(piece, repeats: int) -> float:
    t0 = time.perf_counter()
    for _ in range(repeats):
        piece()
    return (time.perf_counter() - t0) / repeats


def main(argv=None):
    cores = os.cpu_count() or 1
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--game", default="Breakout")
    parser.add_argument("--num-envs", type=int, default=max(8, 4 * cores))
    parser.add_argument("--threads", type=int, nargs="+",
                        default=sorted({1, max(1, cores // 4), max(1, cores // 2), cores}))
    parser.add_argument("--steps", type=int, default=100,
                        help="batched steps per round at the largest thread count (fewer threads: "
                             "proportionally fewer, at least 25; a step is slower there)")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--backgrounds", nargs="+", default=["none", "noise", "video"])
    parser.add_argument("--video-sources", default=None, help="default: opencv-doc's videos")
    parser.add_argument("--no-rgb-pool", action="store_true", help="skip the pool='rgb' variant")
    parser.add_argument("--host-threads", type=int, nargs="*", default=None,
                        help="at the largest thread count, also time the video and noise "
                             "backgrounds with these host-thread counts (default: 1, a quarter and a half of "
                             "the threads)")
    parser.add_argument("--quick", action="store_true", help="few envs and steps, one thread count")
    parser.add_argument("--no-record", action="store_true")
    args = parser.parse_args(argv)
    if args.quick:
        args.num_envs, args.threads, args.steps, args.rounds = 4, [min(2, cores)], 20, 1
    most = max(args.threads)
    if args.host_threads is None:
        args.host_threads = sorted({1, max(1, most // 4), max(1, most // 2)})
    if "video" in args.backgrounds:
        from jaxnat.datasets import DatasetNotFoundError
        from jaxnat.natural import load_videos

        try:
            load_videos(args.video_sources, shape=(210, 160), split="train")
        except DatasetNotFoundError as err:  # e.g. a host without Debian's opencv-doc
            print(f"skipping the video background (pass --video-sources a folder of clips): {err}")
            args.backgrounds = [b for b in args.backgrounds if b != "video"]

    info = common.machine()
    started = time.perf_counter()
    rows = []
    for threads in args.threads:
        envs = contenders(args.game, args.num_envs, threads, args.backgrounds, 0,
                          args.video_sources, not args.no_rgb_pool, args.host_threads,
                          extras=threads == most)
        rng = np.random.default_rng(0)
        n_actions = int(next(iter(envs.values())).single_action_space.n)
        warm = rng.integers(0, n_actions, (10, args.num_envs))
        for env in envs.values():
            steps_per_second(env, warm)
            if hasattr(env, "step_timings"):
                env.step_timings.update(steps=0, ale_s=0.0, ahead_s=0.0, host_s=0.0)
        rates = {name: [] for name in envs}
        for _ in range(args.rounds):
            steps = max(min(args.steps, 25), args.steps * threads // most)
            actions = rng.integers(0, n_actions, (steps, args.num_envs))
            for name, env in envs.items():
                rates[name].append(steps_per_second(env, actions))
        reference = statistics.median(rates["ale-py (gray 84x84x4)"])
        for name, values in rates.items():
            rate = statistics.median(values)
            row = dict(threads=threads, env=name, num_envs=args.num_envs,
                       steps_per_s=rate, vs_ale_py=rate / reference)
            timings = getattr(envs[name], "step_timings", None)
            if timings:
                row["host_threads"] = envs[name].host_threads
                row["ale_wait_ms"] = 1e3 * timings["ale_s"] / timings["steps"]
                row["ahead_ms"] = 1e3 * timings["ahead_s"] / timings["steps"]
                row["host_ms"] = 1e3 * timings["host_s"] / timings["steps"]
                row["host_us_per_env"] = 1e3 * row["host_ms"] / args.num_envs
            rows.append(row)
        for env in envs.values():
            env.close()

    table = common.markdown_table(rows, [
        ("threads", "threads", "d"), ("env", "env", "s"), ("num_envs", "envs", "d"),
        ("steps_per_s", "env steps/s", ",.0f"), ("vs_ale_py", "vs ale-py", ".2f"),
        ("host_threads", "host threads", "d"), ("ale_wait_ms", "ALE wait ms/step", ".2f"),
        ("ahead_ms", "during ALE ms/step", ".2f"), ("host_ms", "host ms/step", ".2f"),
        ("host_us_per_env", "host us/env", ".1f"),
    ])
    video = [r for r in rows if r["env"] == "jaxnat video" and r["threads"] == most]
    summary = {
        "steps x rounds": f"{args.steps} x {args.rounds} batched steps per contender at "
                          f"{most} threads (fewer threads: proportionally fewer, at least 25)",
        "bench seconds": f"{time.perf_counter() - started:.0f} (timing and constructing the envs)",
        "game": args.game,
        "num_envs": args.num_envs,
        "settings": "sticky 0.25, noop 30, frame skip 4 + max-pool, 84x84 gray, stack 4, "
                    "no fire reset",
        "target": "video >= 0.90 of ale-py at the same threads",
        f"video vs ale-py at {most} threads": f"{video[0]['vs_ale_py']:.2f}" if video else "not run",
        "video sources": args.video_sources or "opencv-doc",
        f"host pieces, us/env on one core ({args.num_envs} envs)": host_pieces(args.num_envs),
    }
    if not args.no_record:
        # Photos come from opencv-doc only (--video-sources names videos).
        strip_backgrounds = list(args.backgrounds)
        if "video" in args.backgrounds and args.video_sources is None:
            strip_backgrounds.append("image")
        strip = common.RESULTS / "natural_atari_frames.png"
        frame_strip(args.game, strip_backgrounds, args.video_sources, strip)
        summary["frames"] = str(strip.relative_to(common.RESULTS.parent.parent))
    common.record("natural_atari", info, table, summary, rows, save=not args.no_record)

if __name__ == "__main__":
    main()
