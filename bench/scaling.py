"""Scaling over devices: env steps/s on 1, 2, 4 ... devices, and the scaling efficiency.

Workloads, each with a fixed number of envs per device (weak scaling: the global batch grows
with the devices), timed after compiling, on the default JAX backend:

- `classify`: `jaxnat.make_vec(<classify id>, n, devices=d)` stepped in one jitted `lax.scan`
  under random actions (`Classify/Digits-v0`: embedded data);
- `localize`: the same with `Localize/Clutter-v0` (digits on natural photos);
- `pixel`: the same with `PixelMuJoCo/<robot>-v0`, `observation="pixels"`, for each of
  `--pixel-robots` on `--pixel-floor` (MJX physics and the pure-JAX renderer, one frame per
  agent step; needs `jaxnat[mujoco]`; `video` needs opencv-doc's videos);
- `ppo`: PPO end to end, `jaxnat train --devices d`'s programs (`training.placement`: each
  device steps its envs, gradients averaged with `pmean`), env steps/s over timed chunks, on
  Classify;
- `ppo-pixel`: the same from pixels, `PixelMuJoCo/<first of --pixel-robots>-v0` with
  `physics="fast"`.

Efficiency at `d` devices = steps/s(d) / (d x steps/s(1)): 100% is perfect scaling. On a CPU
with simulated devices (`XLA_FLAGS=--xla_force_host_platform_device_count=4`) the devices
share the CPU's cores, so the numbers show that the sharded path runs, not how it scales; the
recorded summary says so.

    python bench/scaling.py                                   # every device count 1, 2, 4 ... all
    python bench/scaling.py --devices 1 8 --workloads ppo --envs-per-device 4096
    python bench/scaling.py --envs-per-device 4096 --pixel-envs-per-device 1024 --ppo-envs-per-device 512
    XLA_FLAGS=--xla_force_host_platform_device_count=4 JAX_PLATFORMS=cpu \\
        python bench/scaling.py --envs-per-device 64 --pixel-envs-per-device 4 --ppo-envs-per-device 8 --steps 8
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parent))
import common  # noqa: E402

import jaxnat  # noqa: E402
from jaxnat.agents import PPOConfig  # noqa: E402
from jaxnat.agents.networks import default_trunk  # noqa: E402
from jaxnat.training.placement import Placement  # noqa: E402


def env_rollout(vec, steps: int):
    """A jitted `run(key)`: reset, then `steps` steps of the batch `vec` under random actions."""
    space = vec.action_space(vec.default_params)

    def run(key):
        obs, state = vec.reset(key)

        def body(carry, key):
            obs, state = carry
            key_act, key_step = jax.random.split(key)
            actions = jax.vmap(space.sample)(jax.random.split(key_act, vec.num_envs))
            obs, state, reward, *_ = vec.step(key_step, state, actions)
            return (obs, state), reward

        return jax.lax.scan(body, (obs, state), jax.random.split(key, steps))

    return jax.jit(run)


def time_env(env_id: str, kwargs: dict, num_envs: int, devices: int, steps: int, repeats: int) -> dict:
    vec = jaxnat.make_vec(env_id, num_envs, devices=devices, **kwargs)
    run = env_rollout(vec, steps)
    key = jax.random.key(0)
    start = time.perf_counter()
    run = run.lower(key).compile()
    compile_s = time.perf_counter() - start
    seconds = common.median_seconds(lambda: jax.block_until_ready(run(key)), repeats)
    return {"steps_per_s": num_envs * steps / seconds, "compile_s": compile_s}


def time_ppo(env_id: str, kwargs: dict, num_envs: int, devices: int, steps: int, updates: int,
             repeats: int) -> dict:
    """PPO's chunk of `updates` updates (one seed), as `jaxnat train --devices` compiles it."""
    env, params = jaxnat.make(env_id, **kwargs)
    config = PPOConfig(num_envs=num_envs, num_steps=steps, total_timesteps=num_envs * steps * updates,
                       update_epochs=2, num_minibatches=2)
    config = config.replace(trunk=default_trunk(env.observation_space(params)))
    placement = Placement.resolve("ppo", config, 1, devices, "envs")
    init, chunk = placement.learner_programs("ppo", config, env, params, 1)
    keys = placement.put(jax.vmap(jax.random.key)(jnp.zeros(1, jnp.uint32)), placement.specs("keys"))
    params = placement.put(params, placement.specs("replicated"))
    start = time.perf_counter()
    runner = init(params, keys)
    compiled = chunk(updates).lower(params, runner).compile()
    compile_s = time.perf_counter() - start
    # Each timed call continues from the initial runner: the same work every time.
    seconds = common.median_seconds(lambda: jax.block_until_ready(compiled(params, runner)), repeats)
    return {"steps_per_s": num_envs * steps * updates / seconds, "compile_s": compile_s}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--devices", type=int, nargs="+", default=None,
                        help="device counts (default: 1, 2, 4 ... up to every device)")
    parser.add_argument("--workloads", nargs="+", default=["classify", "pixel", "ppo"],
                        choices=["classify", "localize", "pixel", "ppo", "ppo-pixel"])
    parser.add_argument("--classify-id", default="Classify/Digits-v0")
    parser.add_argument("--pixel-robots", nargs="+", default=["Hopper"],
                        choices=["Ant", "HalfCheetah", "Hopper", "Swimmer"])
    parser.add_argument("--pixel-floor", default="checker", choices=["checker", "video"])
    parser.add_argument("--envs-per-device", type=int, default=None, help="classify (default: GPU 16384, CPU 256)")
    parser.add_argument("--localize-envs-per-device", type=int, default=None, help="localize (default: GPU 4096, CPU 32)")
    parser.add_argument("--pixel-envs-per-device", type=int, default=None, help="pixel (default: GPU 1024, CPU 16)")
    parser.add_argument("--ppo-envs-per-device", type=int, default=None, help="ppo (default: GPU 1024, CPU 16)")
    parser.add_argument("--steps", type=int, default=32, help="env steps per timed call (ppo: per update)")
    parser.add_argument("--ppo-updates", type=int, default=4, help="ppo updates per timed call")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--no-record", action="store_true")
    args = parser.parse_args()

    gpu = jax.default_backend() != "cpu"
    available = jax.device_count()
    counts = args.devices or [d for d in (2 ** i for i in range(16)) if d <= available]
    per_device = {"classify": args.envs_per_device or (16384 if gpu else 256),
                  "localize": args.localize_envs_per_device or (4096 if gpu else 32),
                  "pixel": args.pixel_envs_per_device or (1024 if gpu else 16),
                  "ppo": args.ppo_envs_per_device or (1024 if gpu else 16)}
    per_device["ppo-pixel"] = per_device["pixel"]
    pixel = {"observation": "pixels", "floor": args.pixel_floor}
    # (workload, env id, env kwargs, timer) for every row group: each robot is a group of its own.
    groups = []
    for workload in args.workloads:
        if workload in ("classify", "localize"):
            env_id = args.classify_id if workload == "classify" else "Localize/Clutter-v0"
            groups.append((workload, env_id, {}, time_env))
        elif workload == "pixel":
            groups += [(workload, f"PixelMuJoCo/{robot}-v0", pixel, time_env) for robot in args.pixel_robots]
        elif workload == "ppo":
            groups.append((workload, args.classify_id, {}, time_ppo))
        else:
            groups.append((workload, f"PixelMuJoCo/{args.pixel_robots[0]}-v0", {**pixel, "physics": "fast"}, time_ppo))
    rows = []
    for workload, env_id, kwargs, timer in groups:
        base = None
        for devices in counts:
            num_envs = per_device[workload] * devices
            if timer is time_env:
                result = time_env(env_id, kwargs, num_envs, devices, args.steps, args.repeats)
            else:
                result = time_ppo(env_id, kwargs, num_envs, devices, args.steps, args.ppo_updates, args.repeats)
            base = base if base is not None else result["steps_per_s"] / devices
            row = {"workload": workload, "env": env_id + (f" ({args.pixel_floor} floor)" if "floor" in kwargs else ""),
                   "devices": devices, "num_envs": num_envs, **result,
                   "per_device": result["steps_per_s"] / devices,
                   "efficiency": result["steps_per_s"] / (devices * base) if counts[0] == 1 else None}
            print(f"{workload} · {devices} device(s) · {num_envs} envs · {row['steps_per_s']:,.0f} steps/s",
                  flush=True)
            rows.append(row)

    table = common.markdown_table(rows, [
        ("workload", "workload", ""), ("env", "env", ""), ("devices", "devices", "d"), ("num_envs", "envs", ",d"),
        ("steps_per_s", "env steps/s", ",.0f"), ("per_device", "per device", ",.0f"),
        ("efficiency", "efficiency", ".0%"), ("compile_s", "compile s", ".1f")])
    info = common.machine()
    simulated = not gpu and "xla_force_host_platform_device_count" in os.environ.get("XLA_FLAGS", "")
    summary = {
        "setting": (f"{available} simulated devices (XLA_FLAGS=--xla_force_host_platform_device_count) on a "
                    f"{info['cpu_cores']}-core CPU: the devices share the cores, so these numbers show that the "
                    "sharded path runs, not speed" if simulated else f"{available} {info['device']} devices"),
        "weak scaling": ("envs per device: " + ", ".join(f"{w} {per_device[w]}" for w in args.workloads)
                         + f"; {args.steps} steps per timed call"
                         + (f", ppo {args.ppo_updates} updates (2 epochs x 2 minibatches)"
                            if {"ppo", "ppo-pixel"} & set(args.workloads) else "")),
        "efficiency": "steps/s(d) / (d x steps/s(1))",
    }
    if "ppo" in args.workloads:
        best = max((r for r in rows if r["workload"] == "ppo"), key=lambda r: r["devices"])
        summary["ppo at most devices"] = f"{best['devices']} devices, {best['steps_per_s']:,.0f} env steps/s"
    common.record("scaling", info, table, summary, rows, save=not args.no_record)


if __name__ == "__main__":
    np.set_printoptions(precision=3)
    main()
