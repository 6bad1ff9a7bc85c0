"""PixelMuJoCo throughput: the pure-JAX renderer, physics only, and the full pixel env.

Measures, in one run on the default JAX backend, for each robot and batch size:
- renderer only: frames/s of `jit(vmap(Renderer.render))` at 84x84 grayscale (the env's
  observation frame) from stored poses (MuJoCo C, random joint angles);
- physics only: agent steps/s of `PixelMuJoCo(observation="state")` (MJX, frame skip 4, no
  rendering), autoreset, random actions, `lax.scan` inside one jit;
- full env: agent steps/s of `PixelMuJoCo(observation="pixels")` (physics + one render per
  agent step + floor + frame stack), same loop, for the floors asked for;
- MuJoCo's own renderer (`mujoco.Renderer`, OpenGL: MUJOCO_GL=egl on a GPU machine, osmesa on a
  CPU one), one context, frames/s at the same size and camera;
and prints the ratios against the targets (one H100: renderer >= 2M frames/s; full step >= 50%
of physics only; renderer >= 100x MuJoCo's). Results go to bench/results/pixel_mujoco.{md,jsonl}.

    python bench/pixel_mujoco.py                      # sizes by backend (GPU: 1024 4096 16384)
    python bench/pixel_mujoco.py --robots hopper --sizes 1024 4096 --floors video
    python bench/pixel_mujoco.py --strip-only         # PNG strip of observations per floor
"""

from __future__ import annotations

import argparse
import os
import pathlib
import sys
import time

# MuJoCo's renderer: EGL where there is an NVIDIA GPU, OSMesa (software) elsewhere.
os.environ.setdefault("MUJOCO_GL", "egl" if os.path.exists("/dev/nvidia0") else "osmesa")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
sys.path.insert(1, str(pathlib.Path(__file__).resolve().parents[1]))  # this checkout's jaxnat
import common  # noqa: E402

ROBOTS = ("ant", "half_cheetah", "hopper", "swimmer")
IDS = {"ant": "Ant", "half_cheetah": "HalfCheetah", "hopper": "Hopper", "swimmer": "Swimmer"}


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


def renderer_fps(env, poses, num_envs: int) -> tuple[float, float]:
    """(frames/s, compile s) of the env's renderer over `num_envs` stored poses."""
    reps = -(-num_envs // len(poses["qpos"]))
    args = [jnp.asarray(np.concatenate([poses[k]] * reps)[:num_envs])
            for k in ("cam_pos", "cam_mat", "geom_xpos", "geom_xmat")]
    render = jax.jit(jax.vmap(env.renderer.render))
    t0 = time.perf_counter()
    jax.block_until_ready(render(*args))
    compile_s = time.perf_counter() - t0
    seconds = common.median_seconds(lambda: jax.block_until_ready(render(*args)), repeats=5)
    return num_envs / seconds, compile_s


def rollout_sps(env, params, num_envs: int, num_steps: int) -> tuple[float, float]:
    """(agent steps/s, compile s): `num_steps` vmapped autoreset steps, random actions."""
    space = env.action_space(params)
    low, high = jnp.asarray(space.low), jnp.asarray(space.high)
    step = jax.vmap(env.step, in_axes=(0, 0, 0, None))

    def run(key, state):
        def body(state, key):
            key_act, key_step = jax.random.split(key)
            actions = jax.random.uniform(key_act, (num_envs, *low.shape), minval=low, maxval=high)
            obs, state, reward, *_ = step(jax.random.split(key_step, num_envs), state, actions, params)
            # The observation must be computed: fold one byte of it into the carry-out.
            return state, (reward, obs.reshape(num_envs, -1)[:, 0])
        return jax.lax.scan(body, state, jax.random.split(key, num_steps))

    run = jax.jit(run)
    _, state = jax.jit(jax.vmap(env.reset, in_axes=(0, None)))(
        jax.random.split(jax.random.key(0), num_envs), params)
    t0 = time.perf_counter()
    state2, _ = jax.block_until_ready(run(jax.random.key(1), state))
    compile_s = time.perf_counter() - t0
    seconds = common.median_seconds(
        lambda: jax.block_until_ready(run(jax.random.key(2), state2)), repeats=3)
    return num_envs * num_steps / seconds, compile_s


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
                        help="batch sizes (default: GPU 1024 4096 16384; CPU 16 64)")
    parser.add_argument("--floors", nargs="+", default=None, choices=("checker", "video", "noise"),
                        help="full-env floors (default: video at every size; checker and "
                             "noise at the largest)")
    parser.add_argument("--steps", type=int, default=None, help="scan steps per timed rollout")
    parser.add_argument("--no-env", action="store_true", help="renderer and MuJoCo only")
    parser.add_argument("--shadows", action="store_true", help="render shadows (env default: off)")
    parser.add_argument("--strip-only", action="store_true")
    parser.add_argument("--no-record", action="store_true")
    args = parser.parse_args(argv)

    strip_path = common.RESULTS / "pixel_mujoco_floors.png"
    if args.strip_only:
        save_strip(strip_path)
        return
    import jaxnat

    info = common.machine()
    on_gpu = info["backend"] != "cpu"
    sizes = args.sizes or ([1024, 4096, 16384] if on_gpu else [16, 64])
    steps = args.steps or (20 if on_gpu else 4)
    print(f"{info['backend']}: {info['device']}; sizes {sizes}, {steps} scan steps", flush=True)
    rows = []
    for robot in args.robots:
        env_id = f"PixelMuJoCo/{IDS[robot]}-v0"
        try:
            env, params = jaxnat.make(env_id, floor="video", video_max_frames=2000,
                                      shadows=args.shadows)
            video_floor = "video"
        except Exception as err:  # no natural videos on this machine (opencv-doc)
            print(f"  no video floor ({type(err).__name__}: {str(err).splitlines()[0]}); using noise")
            env, params = jaxnat.make(env_id, floor="noise", shadows=args.shadows)
            video_floor = "noise"
        poses = stored_poses(env.unwrapped.physics.model, 64)
        mujoco_fps = mujoco_renderer_fps(env.unwrapped.physics.model, poses, 84, 84)
        print(f"{robot}: mujoco.Renderer {mujoco_fps or float('nan'):.1f} frames/s", flush=True)
        for num_envs in sizes:
            row = {"robot": robot, "envs": num_envs, "mujoco_fps": mujoco_fps}
            row["render_fps"], row["render_compile_s"] = renderer_fps(env.unwrapped, poses, num_envs)
            if not args.no_env:
                state_env, state_params = jaxnat.make(env_id, observation="state")
                row["physics_sps"], row["physics_compile_s"] = rollout_sps(
                    state_env, state_params, num_envs, steps)
                floors = args.floors or ([video_floor, "checker", "noise"] if num_envs == sizes[-1]
                                         else [video_floor])
                for floor in dict.fromkeys(floors):
                    floor_env, floor_params = ((env, params) if floor == video_floor
                                               else jaxnat.make(env_id, floor=floor,
                                                                shadows=args.shadows))
                    row[f"{floor}_sps"], row[f"{floor}_compile_s"] = rollout_sps(
                        floor_env, floor_params, num_envs, steps)
                    row[f"{floor}_vs_physics"] = row[f"{floor}_sps"] / row["physics_sps"]
            if mujoco_fps:
                row["render_vs_mujoco"] = row["render_fps"] / mujoco_fps
            rows.append(row)
            print("  " + ", ".join(f"{k} {v:.3g}" for k, v in row.items()
                                   if isinstance(v, float)), flush=True)

    columns = [("robot", "robot", ""), ("envs", "envs", ","),
               ("render_fps", "renderer frames/s", ".3e"),
               ("physics_sps", "physics-only steps/s", ".3e")]
    for floor in ("video", "checker", "noise"):
        columns += [(f"{floor}_sps", f"full ({floor}) steps/s", ".3e"),
                    (f"{floor}_vs_physics", f"{floor} / physics", ".1%")]
    columns += [("mujoco_fps", "mujoco.Renderer frames/s", ".1f"),
                ("render_vs_mujoco", "renderer / mujoco", ".0f"),
                ("render_compile_s", "render compile s", ".1f")]
    table = common.markdown_table(rows, columns)
    best = {robot: max((r for r in rows if r["robot"] == robot), key=lambda r: r["render_fps"])
            for robot in args.robots}
    summary = {
        "frame": f"84x84 grayscale, shadows {'on' if args.shadows else 'off (env default)'}, "
                 "frame skip 4, stack 4, autoreset",
        "renderer_peak_frames_per_s": {r: f"{b['render_fps']:.3e} at {b['envs']} envs"
                                       for r, b in best.items()},
        "target_renderer_2M": {r: b["render_fps"] >= 2e6 for r, b in best.items()},
    }
    largest = [r for r in rows if r["envs"] == sizes[-1]]
    if not args.no_env:
        full = [k for k in ("video_vs_physics", "noise_vs_physics", "checker_vs_physics")
                if all(k in r for r in largest)][0]
        summary[f"full_{full}_at_largest"] = {r["robot"]: f"{r[full]:.1%}" for r in largest}
        summary["target_full_50pct"] = {r["robot"]: r[full] >= 0.5 for r in largest}
    if all(r.get("render_vs_mujoco") for r in largest):
        summary["renderer_over_mujoco_at_largest"] = {
            r["robot"]: f"{r['render_vs_mujoco']:.0f}x" for r in largest}
        summary["target_100x_mujoco"] = {r["robot"]: r["render_vs_mujoco"] >= 100 for r in largest}
    common.record("pixel_mujoco", info, table, summary, rows, save=not args.no_record)


if __name__ == "__main__":
    main()
