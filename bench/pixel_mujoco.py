"""PixelMuJoCo throughput: the pure-JAX renderer, physics only, and the full pixel env.

Measures, in one run on the default JAX backend, for each robot and batch size:
- renderer only: frames/s of `jit(vmap(Renderer.render))` at 84x84 grayscale (the env's
  observation frame) from stored poses (MuJoCo C, random joint angles), called as the env calls
  it (the tracking camera's constant orientation); `--kernels xla pallas` times both kernels;
- renderer with a floor texture: the same, the floor drawn with the checker and with a video
  frame (a stand-in bank of random frames, one per env), each read at the nearest texel
  (`floor_filter="nearest"`, the renderer before mip filtering) and mip-filtered by the pixel's
  footprint (`"mip"`, the default; the video's mip chains built once with the bank, as the
  env builds them), and the ratio mip / nearest (target >= 90%);
- physics only: agent steps/s of `PixelMuJoCo(observation="state")` (MJX, frame skip 4, no
  rendering), autoreset, random actions, `lax.scan` inside one jit;
- full env: agent steps/s of `PixelMuJoCo(observation="pixels")` (physics + one render per
  agent step + floor + frame stack), same loop, per floor (video at every size; checker, noise
  and the noise observation at the largest, or at every size with `--every-size`);
- MuJoCo's own renderer (`mujoco.Renderer`, OpenGL: MUJOCO_GL=egl on a GPU machine, osmesa on a
  CPU one), one context, frames/s at the same size and camera;
and prints the ratios against the targets (one H100: renderer >= 2M frames/s; full step >= 50%
of physics only; renderer >= 100x MuJoCo's). Results go to bench/results/pixel_mujoco.{md,jsonl}.
All programs are traced first and compiled on a thread pool (MJX compiles slowly), then timed.

    python bench/pixel_mujoco.py                      # sizes by backend (GPU: 1024 16384)
    python bench/pixel_mujoco.py --robots hopper --sizes 1024 4096 --floors video
    python bench/pixel_mujoco.py --no-env --kernels xla pallas   # renderer kernels only
    python bench/pixel_mujoco.py --no-env --no-mujoco  # renderers only: floor filters too
    python bench/pixel_mujoco.py --physics fast       # the robots' physics="fast" setting
    python bench/pixel_mujoco.py --strip-only         # PNG strip of observations per floor
"""

from __future__ import annotations

import argparse
import os
import pathlib
import re
import sys
import time
from concurrent.futures import ThreadPoolExecutor

# MuJoCo's renderer: EGL where there is an NVIDIA GPU, OSMesa (software) elsewhere.
# Without libEGL (a bare GPU machine: see the device notes on .gl) `import mujoco` itself fails
# under MUJOCO_GL=egl, so it is set only where EGL is found; mujoco.Renderer is then skipped.
if os.path.exists("/dev/nvidia0"):
    import ctypes.util

    if ctypes.util.find_library("EGL"):
        os.environ.setdefault("MUJOCO_GL", "egl")
else:
    os.environ.setdefault("MUJOCO_GL", "osmesa")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
sys.path.insert(1, str(pathlib.Path(__file__).resolve().parents[1]))  # this checkout's jaxnat
import common  # noqa: E402
from jaxnat.mjx_pixel.render import KERNELS  # noqa: E402

ROBOTS = ("ant", "half_cheetah", "hopper", "swimmer")
IDS = {"ant": "Ant", "half_cheetah": "HalfCheetah", "hopper": "Hopper", "swimmer": "Swimmer"}
FLOORS = ("video", "checker", "noise")
TEXTURED = ("checker", "video")  # the floors the renderer filters (render_*_{nearest,mip}_fps)


def stored_poses(model, count: int, seed: int = 0):
    """`count` MjData snapshots in random poses (MuJoCo C): camera pose and geom poses."""
    import mujoco

    from jaxnat.mjx_pixel.camera import TrackingCamera

    camera = TrackingCamera.from_model(model)
    data = mujoco.MjData(model)
    rng = np.random.default_rng(seed)
    out = {"cam_pos": [], "cam_mat": [], "geom_xpos": [], "geom_xmat": [], "qpos": []}
    for _ in range(count):
        qpos = model.qpos0.copy()
        qpos[0] += rng.uniform(-5, 5)
        qpos[2:] += rng.normal(0.0, 0.3, model.nq - 2)
        data.qpos[:] = qpos
        mujoco.mj_forward(model, data)
        pos, mat = camera.pose(data)
        for k, v in [("cam_pos", pos), ("cam_mat", mat), ("geom_xpos", data.geom_xpos),
                     ("geom_xmat", data.geom_xmat), ("qpos", qpos)]:
            out[k].append(np.array(v, np.float32))
    return {k: np.stack(v) for k, v in out.items()}


class Job:
    """One measurement: programs traced and lowered now (Python, sequential), compiled on a
    thread pool (XLA releases the GIL, so MJX's long compiles overlap), timed later in turn."""

    def __init__(self, lowered: list, measure, pool):
        def compile_timed(low):
            t0 = time.perf_counter()
            compiled = low.compile()
            return compiled, time.perf_counter() - t0

        self.futures = [pool.submit(compile_timed, low) for low in lowered]
        self.measure = measure

    def wait(self):
        for future in self.futures:
            future.result()

    def result(self) -> tuple[float, float, dict]:
        """(rate, compile s of its programs, extras)."""
        done = [f.result() for f in self.futures]
        rate, extras = self.measure(*[c for c, _ in done])
        return rate, sum(s for _, s in done), extras


def kernel_count(compiled) -> int:
    """Kernels (fusions, custom calls) the compiled program launches at its top level."""
    text = compiled.as_text()
    entry = text[text.index("ENTRY"):]
    return len(re.findall(r" (?:fusion|custom-call)\(", entry))


# The renderer's video floor in the bench: random frames at the env's default video size.
BENCH_BANK_FRAMES, BENCH_VIDEO_SHAPE, BENCH_VIDEO_TILE = 256, (128, 128), 4.0


def renderer_job(env, poses, num_envs: int, pool, kernel: str | None = None,
                 floor: str | None = None, floor_filter: str = "mip") -> Job:
    """frames/s of the env's renderer (or one with another `kernel`) at `num_envs` stored poses,
    as the env calls it: the tracking camera's constant orientation. The floor keeps its geom
    colour, or with `floor` ("checker" or "video") shows that texture read with `floor_filter`
    ("video": env i shows frame i of a stand-in bank of random frames)."""
    from jaxnat.mjx_pixel.floor import floor_rgb
    from jaxnat.mjx_pixel.render import Renderer

    renderer = env.renderer
    kernel = kernel or renderer.kernel
    if kernel != renderer.kernel or floor_filter != renderer.floor_filter:
        renderer = Renderer(env.table, renderer.height, renderer.width, fovy=renderer.fovy,
                            grayscale=renderer.grayscale, shadows=renderer.shadows, kernel=kernel,
                            floor_filter=floor_filter)
    reps = -(-num_envs // len(poses["qpos"]))
    args = [jnp.asarray(np.concatenate([poses[k]] * reps)[:num_envs])
            for k in ("cam_pos", "geom_xpos", "geom_xmat")]
    args.append(jnp.arange(num_envs, dtype=jnp.int32) % BENCH_BANK_FRAMES)
    cam_mat = env.camera.mat
    bank = mips = None
    if floor == "video":
        from jaxnat.mjx_pixel.floor import pack_mips

        rng = np.random.default_rng(0)
        bank = jnp.asarray(rng.integers(0, 256, (BENCH_BANK_FRAMES, *BENCH_VIDEO_SHAPE,
                                                 renderer.channels), np.uint8))
        if floor_filter == "mip":  # as the env: the chains built once, with the bank
            mips = jax.block_until_ready(pack_mips(bank))

    def one(pos, xpos, xmat, index):
        if floor is None:
            return renderer.render(pos, cam_mat, xpos, xmat)

        def texture(xy, footprint=None):
            return floor_rgb(floor, env.table, xy, footprint, frame=bank, frame_index=index,
                             tile=BENCH_VIDEO_TILE, mips=mips)

        return renderer.render(pos, cam_mat, xpos, xmat, texture)

    render = jax.jit(jax.vmap(one))

    def measure(compiled):
        jax.block_until_ready(compiled(*args))
        seconds = common.throughput_seconds(lambda: compiled(*args))
        return num_envs / seconds, {"kernels": kernel_count(compiled)}

    return Job([render.lower(*args)], measure, pool)


def rollout_job(env, params, num_envs: int, num_steps: int, pool) -> Job:
    """agent steps/s: `num_steps` vmapped autoreset steps with random actions in one jit."""
    space = env.action_space(params)
    low, high = jnp.asarray(space.low), jnp.asarray(space.high)
    step = jax.vmap(env.step, in_axes=(0, 0, 0, None))
    reset = jax.jit(jax.vmap(env.reset, in_axes=(0, None)))

    def run(key, state):
        def body(state, key):
            key_act, key_step = jax.random.split(key)
            actions = jax.random.uniform(key_act, (num_envs, *low.shape), minval=low, maxval=high)
            obs, state, reward, *_ = step(jax.random.split(key_step, num_envs), state, actions, params)
            # The observation must be computed: fold one byte of it into the carry-out.
            return state, (reward, obs.reshape(num_envs, -1)[:, 0])
        return jax.lax.scan(body, state, jax.random.split(key, num_steps))

    keys = jax.random.split(jax.random.key(0), num_envs)
    state_shape = jax.eval_shape(reset, keys, params)[1]

    def measure(reset_c, run_c):
        state = reset_c(keys, params)[1]
        state, _ = jax.block_until_ready(run_c(jax.random.key(1), state))
        seconds = common.median_seconds(
            lambda: jax.block_until_ready(run_c(jax.random.key(2), state)), repeats=2)
        return num_envs * num_steps / seconds, {}

    return Job([reset.lower(keys, params), jax.jit(run).lower(jax.random.key(1), state_shape)],
               measure, pool)


def mujoco_renderer_fps(model, poses, height: int, width: int, seconds: float = 2.0):
    """Frames/s of MuJoCo's own renderer (one OpenGL context), None if it cannot start."""
    import mujoco

    try:
        renderer = mujoco.Renderer(model, height, width)
    except Exception as err:  # no OpenGL here
        print(f"  mujoco.Renderer unavailable: {err}")
        return None
    data = mujoco.MjData(model)
    frames, t0 = 0, time.perf_counter()
    try:
        while time.perf_counter() - t0 < seconds:
            data.qpos[:] = poses["qpos"][frames % len(poses["qpos"])]
            mujoco.mj_forward(model, data)
            renderer.update_scene(data, camera="track")
            renderer.render()
            frames += 1
    finally:
        renderer.close()
    return frames / (time.perf_counter() - t0)


def save_strip(path: pathlib.Path, size: int = 84) -> None:
    """A PNG: one row per floor mode (checker, video, noise), one column per robot, RGB frames
    from stored poses, then the grayscale observation frame next to each."""
    import cv2

    from jaxnat import natural
    from jaxnat.mjx_pixel.floor import floor_rgb
    from jaxnat.mjx_pixel.models import load_model
    from jaxnat.mjx_pixel.camera import TrackingCamera
    from jaxnat.mjx_pixel.render import GeomTable, Renderer

    bank = natural.load_videos(shape=(128, 128), split="train", max_frames=200)
    rows = []
    for mode in ("checker", "video", "noise"):
        tiles = []
        for i, robot in enumerate(ROBOTS):
            model = load_model(robot)
            table, camera = GeomTable.from_model(model), TrackingCamera.from_model(model)
            poses = stored_poses(model, 1, seed=i)
            for grayscale in (False, True):
                renderer = Renderer(table, size, size, fovy=camera.fovy, grayscale=grayscale,
                                    shadows=True)
                args = [poses[k][0] for k in ("cam_pos", "cam_mat", "geom_xpos", "geom_xmat")]
                hit = renderer.cast(*args)
                colour = floor_rgb(mode, table, hit.point[..., :2], frame=jnp.asarray(bank.frames[50 * i]),
                                   tile=(4.0, 4.0), key=jax.random.key(i), channels=renderer.channels)
                image = np.asarray(renderer.shade(hit, args[1], colour))
                tiles.append(np.repeat(image, 3, axis=-1) if grayscale else image)
        rows.append(np.concatenate(tiles, axis=1))
    strip = np.concatenate(rows, axis=0)
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), cv2.cvtColor(strip, cv2.COLOR_RGB2BGR))
    print(f"wrote {path} (rows: checker, video, noise floors; columns: robot RGB, gray)")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", nargs="+", default=list(ROBOTS), choices=ROBOTS)
    parser.add_argument("--sizes", nargs="+", type=int, default=None,
                        help="batch sizes (default: GPU 1024 16384; CPU 16 64)")
    parser.add_argument("--floors", nargs="+", default=None, choices=FLOORS,
                        help="full-env floors at every size (default: video at every size; "
                             "checker, noise and the noise observation at the largest)")
    parser.add_argument("--every-size", action="store_true",
                        help="all floors and the noise observation at every size")
    parser.add_argument("--steps", type=int, default=None, help="scan steps per timed rollout")
    parser.add_argument("--no-env", action="store_true", help="renderer and MuJoCo only")
    parser.add_argument("--no-mujoco", action="store_true", help="skip mujoco.Renderer")
    parser.add_argument("--shadows", action="store_true", help="render shadows (env default: off)")
    parser.add_argument("--render-kernel", default="auto", choices=KERNELS,
                        help="the envs' renderer kernel (auto: Pallas on a GPU, else XLA)")
    parser.add_argument("--kernels", nargs="+", default=[], choices=KERNELS,
                        help="also time the renderer alone with these kernels")
    parser.add_argument("--videos", default=None,
                        help="video files, a directory or a glob for the video floor (default: "
                             "opencv-doc's)")
    parser.add_argument("--compile-workers", type=int, default=min(16, os.cpu_count() or 1))
    parser.add_argument("--strip-only", action="store_true")
    parser.add_argument("--physics", default="default", choices=["default", "fast"],
                        help="the robots' physics= setting (mjx_pixel/base.py)")
    parser.add_argument("--no-record", action="store_true")
    args = parser.parse_args(argv)

    strip_path = common.RESULTS / "pixel_mujoco_floors.png"
    if args.strip_only:
        save_strip(strip_path)
        return
    import jaxnat

    started = time.perf_counter()
    info = common.machine()
    on_gpu = info["backend"] != "cpu"
    sizes = args.sizes or ([1024, 16384] if on_gpu else [16, 64])
    # 10 steps a timed scan on a GPU: long enough to time at 16,384 envs, short enough to run
    # all four robots in every mode in one sitting (each run's "bench_seconds" is recorded in
    # bench/results/pixel_mujoco.md).
    steps = args.steps or (10 if on_gpu else 4)
    print(f"{info['backend']}: {info['device']}; sizes {sizes}, {steps} scan steps", flush=True)
    pool = ThreadPoolExecutor(max(1, args.compile_workers))
    common_kwargs = {"shadows": args.shadows, "render_kernel": args.render_kernel,
                     "physics": args.physics}
    plans = []  # (row, {column: Job}) in measuring order
    mujoco_fps = {}
    for robot in args.robots:
        env_id = f"PixelMuJoCo/{IDS[robot]}-v0"
        envs = {}
        try:
            if not args.no_env:
                envs["video"] = jaxnat.make(env_id, floor="video", video_max_frames=2000,
                                            videos=args.videos, **common_kwargs)
        except Exception as err:  # no natural videos on this machine (opencv-doc)
            print(f"  no video floor ({type(err).__name__}: {str(err).splitlines()[0]})")
        envs["checker"] = jaxnat.make(env_id, floor="checker", **common_kwargs)
        model = envs["checker"][0].unwrapped.physics.model
        poses = stored_poses(model, 64)
        if not args.no_mujoco:
            mujoco_fps[robot] = mujoco_renderer_fps(model, poses, 84, 84)
        for num_envs in sizes:
            row = {"robot": robot, "envs": num_envs, "mujoco_fps": mujoco_fps.get(robot)}
            jobs = {"render_fps": renderer_job(envs["checker"][0].unwrapped, poses, num_envs, pool)}
            for kernel in args.kernels:
                jobs[f"render_{kernel}_fps"] = renderer_job(
                    envs["checker"][0].unwrapped, poses, num_envs, pool, kernel)
            for floor in TEXTURED:
                for floor_filter in ("nearest", "mip"):  # the renderer before filtering, then now
                    jobs[f"render_{floor}_{floor_filter}_fps"] = renderer_job(
                        envs["checker"][0].unwrapped, poses, num_envs, pool, floor=floor,
                        floor_filter=floor_filter)
            if not args.no_env:
                largest = num_envs == sizes[-1] or args.every_size
                floors = args.floors or (list(FLOORS) if largest else ["video"])
                modes = [("physics", {"observation": "state"})]
                modes += [(floor, {"floor": floor}) for floor in floors]
                if largest:
                    modes.append(("noise_obs", {"observation": "noise"}))
                for name, kwargs in modes:
                    if name == "video" and "video" not in envs:
                        continue
                    if name not in envs:
                        envs[name] = jaxnat.make(env_id, **kwargs, **common_kwargs)
                    jobs[f"{name}_sps"] = rollout_job(*envs[name], num_envs, steps, pool)
            plans.append((row, jobs))
        print(f"{robot}: traced ({time.perf_counter() - started:.0f} s); mujoco.Renderer "
              f"{mujoco_fps.get(robot) or float('nan'):.1f} frames/s", flush=True)

    for _, jobs in plans:  # every compile done before timing: no contention for the host
        for job in jobs.values():
            job.wait()
    print(f"compiled ({time.perf_counter() - started:.0f} s)", flush=True)
    rows = []
    for row, jobs in plans:
        for column, job in jobs.items():
            rate, compile_s, extras = job.result()
            row[column] = rate
            row[column.rsplit("_", 1)[0] + "_compile_s"] = compile_s
            row.update({f"{column.rsplit('_', 1)[0]}_{k}": v for k, v in extras.items()})
        for name in ("video", "checker", "noise", "noise_obs"):
            if f"{name}_sps" in row:
                row[f"{name}_vs_physics"] = row[f"{name}_sps"] / row["physics_sps"]
        for floor in TEXTURED:
            row[f"{floor}_mip_vs_nearest"] = (row[f"render_{floor}_mip_fps"]
                                              / row[f"render_{floor}_nearest_fps"])
        if row["mujoco_fps"]:
            row["render_vs_mujoco"] = row["render_fps"] / row["mujoco_fps"]
        rows.append(row)
        print("  " + ", ".join(f"{k} {v:.3g}" for k, v in row.items()
                               if isinstance(v, (float, int)) and k != "envs")
              + f" ({row['envs']} envs, {time.perf_counter() - started:.0f} s)", flush=True)
    pool.shutdown()

    columns = [("robot", "robot", ""), ("envs", "envs", ","),
               ("render_fps", "renderer frames/s", ".3e")]
    columns += [(f"render_{k}_fps", f"renderer ({k}) frames/s", ".3e") for k in args.kernels]
    for floor in TEXTURED:
        columns += [(f"render_{floor}_nearest_fps", f"renderer {floor} nearest frames/s", ".3e"),
                    (f"render_{floor}_mip_fps", f"renderer {floor} mip frames/s", ".3e"),
                    (f"{floor}_mip_vs_nearest", f"{floor} mip / nearest", ".1%")]
    columns += [("physics_sps", "physics-only steps/s", ".3e")]
    for name in ("video", "checker", "noise", "noise_obs"):
        label = "noise observation" if name == "noise_obs" else f"full ({name})"
        columns += [(f"{name}_sps", f"{label} steps/s", ".3e"),
                    (f"{name}_vs_physics", f"{name} / physics", ".1%")]
    columns += [("mujoco_fps", "mujoco.Renderer frames/s", ".1f"),
                ("render_vs_mujoco", "renderer / mujoco", ".0f"),
                ("render_kernels", "render kernels", "d"),
                ("render_compile_s", "render compile s", ".1f")]
    table = common.markdown_table(rows, columns)
    best = {robot: max((r for r in rows if r["robot"] == robot), key=lambda r: r["render_fps"])
            for robot in args.robots}
    summary = {
        "frame": f"84x84 grayscale, shadows {'on' if args.shadows else 'off (env default)'}, "
                 f"renderer kernel {args.render_kernel}, physics={args.physics!r}, frame skip 4, "
                 f"stack 4, autoreset, "
                 f"{steps} steps per timed scan",
        "renderer_peak_frames_per_s": {r: f"{b['render_fps']:.3e} at {b['envs']} envs"
                                       for r, b in best.items()},
        "renderer_vs_2M_target": {r: f"{b['render_fps'] / 2e6:.2f}" for r, b in best.items()},
    }
    largest = [r for r in rows if r["envs"] == sizes[-1]]
    for floor in TEXTURED:
        summary[f"{floor}_mip_vs_nearest_at_largest (target >= 90%)"] = {
            r["robot"]: f"{r[f'{floor}_mip_vs_nearest']:.1%}" for r in largest}
    for name in ("video", "checker", "noise", "noise_obs"):
        key = f"{name}_vs_physics"
        if largest and all(key in r for r in largest):
            summary[f"{key}_at_largest (target >= 50%)"] = {r["robot"]: f"{r[key]:.1%}"
                                                            for r in largest}
    if largest and all(r.get("render_vs_mujoco") for r in largest):
        summary["renderer_over_mujoco_at_largest (target >= 100x)"] = {
            r["robot"]: f"{r['render_vs_mujoco']:.0f}x" for r in largest}
    summary["bench_seconds"] = round(time.perf_counter() - started)
    common.record("pixel_mujoco", info, table, summary, rows, save=not args.no_record)


if __name__ == "__main__":
    main()
