"""Two processes joined by `jax.distributed` train PPO as one process on two devices does: the
same parameters, and env steps/s.

PPO (one seed, `--updates` updates of `--num-steps` steps, 2 epochs x 2 minibatches, as
`bench/scaling.py`'s `ppo`) on a device env, in three settings, each a fresh child process
(or two) of this script:

- (a) one process, 1 GPU, `--envs-per-process` envs: the baseline;
- (b) one process, 2 GPUs, twice the envs, data parallel (`training.placement`, as
  `jaxnat train --devices 2 --shard envs`: each device steps its envs, gradients `pmean`ed);
- (c) two processes, one GPU each (`CUDA_VISIBLE_DEVICES`), joined through `jax.distributed`
  (`jaxnat.sharding.initialize_from_env`: `JAX_COORDINATOR_ADDRESS=127.0.0.1:<port>`,
  `JAX_NUM_PROCESSES=2`, `JAX_PROCESS_ID`), the same program and global batch as (b), as two
  hosts would run it.

On a host-emulated env (`--env-id NaturalAtari/Breakout-v0`) the learner is the host loop's
(`jaxnat.training.host_backend.make_learner`, the Atari trunk): each process steps its share of
the ALE batch on its own cores, as one host of several would, and times whole training runs
from the same key (the first, compiling, untimed).

Each child compiles (timed), runs the program once untimed, then times `--repeats` runs of
it from the same initial state (median): global env steps/s. The final parameters of (b) and
(c) must match (the largest difference is printed); both processes of (c) must hold the same
ones. The table records to `bench/results/distributed.{md,jsonl}` unless `--no-record`.

On a host with 2 GPUs (the first two of `CUDA_VISIBLE_DEVICES` if set, else GPUs 0 and 1):

    python bench/distributed.py
    python bench/distributed.py --env-id PixelMuJoCo/HalfCheetah-v0 --env-kwargs physics=fast
    python bench/distributed.py --env-id NaturalAtari/Breakout-v0 --envs-per-process 64 --num-steps 128 --updates 4

On a CPU (`JAX_PLATFORMS=cpu`, or no GPU) the children use CPU devices instead ((b): 2
simulated ones, `--xla_force_host_platform_device_count=2`; (c): gloo collectives) that share
the cores: that run shows the script and the distributed path work, not speed:

    JAX_PLATFORMS=cpu python bench/distributed.py --envs-per-process 8 --num-steps 8 --updates 2 --repeats 1 --no-record
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

SETTINGS = {  # name: (processes, devices in all, what)
    "a": (1, 1, "1 process, 1 device"),
    "b": (1, 2, "1 process, 2 devices"),
    "c": (2, 2, "2 processes (jax.distributed), 1 device each"),
}
# (b) and (c) run the same program, so their parameters agree to float rounding. On a CPU that
# rounding is the same in both; on GPUs each setting compiles on its own and XLA autotunes its
# convolutions and matrix products per process, so the two may round differently, and 20 updates
# grow the difference: a looser tolerance there (the largest difference is printed either way).
TOLERANCE = {"cpu": (1e-4, 1e-5), "gpu": (1e-3, 1e-3)}  # platform -> (rtol, atol)


def parse() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env-id", default="Classify/Digits-v0")
    parser.add_argument("--env-kwargs", nargs="*", default=[], metavar="KEY=VALUE")
    parser.add_argument("--envs-per-process", type=int, default=None, help="envs per device (default: GPU 1024, CPU 16)")
    parser.add_argument("--num-steps", type=int, default=32, help="env steps per update")
    parser.add_argument("--updates", type=int, default=20, help="PPO updates per timed run")
    parser.add_argument("--repeats", type=int, default=3, help="timed runs per setting (median)")
    parser.add_argument("--settings", nargs="+", default=list(SETTINGS), choices=list(SETTINGS))
    parser.add_argument("--timeout", type=float, default=1800, help="seconds a setting may take")
    parser.add_argument("--no-record", action="store_true")
    # Internal: a child process of one setting.
    parser.add_argument("--child", choices=list(SETTINGS), help=argparse.SUPPRESS)
    parser.add_argument("--num-envs", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--out", help=argparse.SUPPRESS)
    parser.add_argument("--probe", action="store_true", help=argparse.SUPPRESS)
    return parser.parse_args()


# ---------------------------------------------------------------- child: one process of a setting


def child(args: argparse.Namespace) -> None:
    import jaxnat.sharding

    jaxnat.sharding.initialize_from_env()  # before anything touches a device

    import jax
    import jax.numpy as jnp
    import numpy as np

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import common

    import jaxnat
    from jaxnat.agents import ALGORITHMS, PPOConfig
    from jaxnat.agents.networks import default_trunk
    from jaxnat.training import parse_env_kwargs
    from jaxnat.training.placement import Placement

    processes, devices, _ = SETTINGS[args.child]
    assert jax.process_count() == processes and jax.device_count() == devices, (jax.process_count(), jax.devices())
    if jaxnat.spec(args.env_id).batched:
        return host_child(args)
    env, params = jaxnat.make(args.env_id, **parse_env_kwargs(args.env_kwargs, args.env_id))
    steps = args.num_envs * args.num_steps * args.updates
    config = PPOConfig(num_envs=args.num_envs, num_steps=args.num_steps, total_timesteps=steps,
                       update_epochs=2, num_minibatches=2)
    config = config.replace(trunk=default_trunk(env.observation_space(params)))
    placement = Placement.resolve("ppo", config, 1, devices, "envs")
    learner = ALGORITHMS["ppo"].make(config, env, params)  # reads the runner: `policy_of`
    init, chunk = placement.learner_programs("ppo", config, env, params, 1, learner=learner)
    keys = placement.put(jax.vmap(jax.random.key)(jnp.zeros(1, jnp.uint32)), placement.specs("keys"))
    params = placement.put(params, placement.specs("replicated"))
    start = time.perf_counter()
    runner = jax.block_until_ready(init(params, keys))
    compiled = chunk(args.updates).lower(params, runner).compile()
    compile_s = time.perf_counter() - start
    # Every run starts from the initial runner: the same work, and the same result, every time.
    final, metrics = jax.block_until_ready(compiled(params, runner))  # warm-up, untimed
    seconds = common.median_seconds(lambda: jax.block_until_ready(compiled(params, runner)), args.repeats)
    # Replicated results: this process's copy (the whole array with one process).
    leaves = [np.asarray(x, np.float64) for x in jax.tree.leaves(jaxnat.sharding.local_copy(learner.policy_of(final)[0]))]
    returns = np.asarray(jaxnat.sharding.local_copy(metrics)["episode_return"], np.float64)[0]
    _write_child(args, jax.process_index(), jax.process_count(), jax.device_count(), steps, seconds, compile_s,
                 leaves, float(returns[-1]) if np.isfinite(returns[-1]) else None, common)


def host_child(args: argparse.Namespace) -> None:
    """A child of a setting on a host-emulated env (Natural Atari): the data-parallel host PPO
    (`jaxnat.training.host_backend.make_learner(..., devices=)`; (a) the default learner), this
    process stepping its share of the ALE batch on its own cores. Each timed run trains from the
    same key: the same games, the same result, every time."""
    import jax
    import numpy as np

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import common

    import jaxnat
    from jaxnat.agents import PPOConfig
    from jaxnat.training import parse_env_kwargs
    from jaxnat.training.host_backend import make_learner, make_train_env

    steps = args.num_envs * args.num_steps * args.updates
    config = PPOConfig(num_envs=args.num_envs, num_steps=args.num_steps, total_timesteps=steps,
                       update_epochs=2, num_minibatches=2, trunk="atari")
    devices = None if args.child == "a" else "all"
    env = make_train_env(args.env_id, args.num_envs, parse_env_kwargs(args.env_kwargs, args.env_id), devices=devices)
    try:
        learner = make_learner("ppo", config, env, devices=devices)
        start = time.perf_counter()
        learner.train(jax.random.key(0), 1)  # compiles the policy and update programs
        compile_s = time.perf_counter() - start
        final = [None]

        def run():
            final[0] = learner.train(jax.random.key(0))

        seconds = common.median_seconds(run, args.repeats)
        state, history = final[0]
        leaves = [np.asarray(x, np.float64) for x in jax.tree.leaves(jaxnat.sharding.local_copy(learner.params(state)))]
    finally:
        env.close()
    returns = [row.get("episode_return") for row in history]
    last = next((float(r) for r in reversed(returns) if r is not None and np.isfinite(r)), None)
    _write_child(args, jax.process_index(), jax.process_count(), jax.device_count(), steps, seconds, compile_s,
                 leaves, last, common)


def _write_child(args, index: int, processes: int, devices: int, steps: int, seconds: float, compile_s: float,
                 leaves: list, final_return, common) -> None:
    """Save a child's parameters (`<setting>_<process>.npz`) and its line (`.json`); print it."""
    import numpy as np

    np.savez(Path(args.out) / f"{args.child}_{index}.npz", *leaves)
    line = {"setting": args.child, "process": index, "processes": processes, "devices": devices,
            "num_envs": args.num_envs, "steps_per_s": steps / seconds, "seconds": seconds, "compile_s": compile_s,
            "param_abs_sum": float(sum(np.abs(x).sum() for x in leaves)),
            "param_first": [float(v) for v in np.concatenate([x.ravel() for x in leaves])[:4]],
            "final_return": final_return, "machine": common.machine() if args.child == "b" else None}
    with open(Path(args.out) / f"{args.child}_{index}.json", "w") as f:
        f.write(json.dumps(line) + "\n")
    print(f"({args.child}) process {index}: {line['steps_per_s']:,.0f} env steps/s, compile {compile_s:.1f} s",
          flush=True)


def probe() -> None:
    """Print the default backend and its device count (the parent never starts a backend: on a
    GPU it would take the children's memory)."""
    import jax

    print(json.dumps({"backend": jax.default_backend(), "devices": jax.device_count()}))


# ---------------------------------------------------------------- parent: launch, collect, report


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _base_env() -> dict:
    """This environment less the distributed variables and any simulated device count."""
    env = {k: v for k, v in os.environ.items() if k not in ("JAX_COORDINATOR_ADDRESS", "JAX_NUM_PROCESSES",
                                                              "JAX_PROCESS_ID")}
    flags = [f for f in env.get("XLA_FLAGS", "").split() if "xla_force_host_platform_device_count" not in f]
    env["XLA_FLAGS"] = " ".join(flags)
    return env


def child_envs(setting: str, gpu: bool, gpu_ids: list[str]) -> list[dict]:
    """The environment of each process of `setting`."""
    base = _base_env()
    if gpu:
        visible = {"a": [gpu_ids[0]], "b": [",".join(gpu_ids)], "c": gpu_ids}[setting]
        envs = [{**base, "CUDA_VISIBLE_DEVICES": v} for v in visible]
    else:
        base["JAX_PLATFORMS"] = "cpu"
        if setting == "b":
            base["XLA_FLAGS"] = (base["XLA_FLAGS"] + " --xla_force_host_platform_device_count=2").strip()
        envs = [dict(base) for _ in range(SETTINGS[setting][0])]
    if setting == "c":
        address = f"127.0.0.1:{_free_port()}"
        envs = [{**e, "JAX_COORDINATOR_ADDRESS": address, "JAX_NUM_PROCESSES": "2", "JAX_PROCESS_ID": str(i)}
                for i, e in enumerate(envs)]
    return envs


def run_setting(setting: str, args, num_envs: int, out: Path, gpu: bool, gpu_ids: list[str]) -> list[dict]:
    command = [sys.executable, __file__, "--child", setting, "--num-envs", str(num_envs), "--out", str(out),
               "--env-id", args.env_id, "--num-steps", str(args.num_steps), "--updates", str(args.updates),
               "--repeats", str(args.repeats)]
    if args.env_kwargs:
        command += ["--env-kwargs", *args.env_kwargs]
    procs = [subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
             for env in child_envs(setting, gpu, gpu_ids)]
    try:
        outputs = [p.communicate(timeout=args.timeout)[0] for p in procs]
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
    if any(p.returncode for p in procs):
        logs = "\n".join(f"--- ({setting}) process {i}, exit {p.returncode}:\n{o[-3000:]}"
                         for i, (p, o) in enumerate(zip(procs, outputs)))
        sys.exit(f"{logs}\ndistributed.py: setting ({setting}) failed (its output above)")
    for o in outputs:
        print(o.strip().splitlines()[-1], flush=True)
    return [json.loads((out / f"{setting}_{i}.json").read_text()) for i in range(len(procs))]


def compare(first: Path, second: Path, rtol: float, atol: float) -> tuple[float, bool]:
    """The largest absolute difference between two saved parameter sets, and whether every
    leaf is allclose."""
    import numpy as np

    a, b = np.load(first), np.load(second)
    assert a.files == b.files, (a.files, b.files)
    diff = max((float(np.max(np.abs(a[k] - b[k]))) for k in a.files if a[k].size), default=0.0)
    return diff, all(np.allclose(a[k], b[k], rtol=rtol, atol=atol) for k in a.files)


def parent(args: argparse.Namespace) -> None:
    probe_env = {**_base_env(), "XLA_PYTHON_CLIENT_PREALLOCATE": "false"}  # it exits at once: take no memory
    found = subprocess.run([sys.executable, __file__, "--probe"], env=probe_env, check=False,
                           capture_output=True, text=True)
    if found.returncode:
        sys.exit(found.stdout + found.stderr + "\ndistributed.py: could not start JAX (output above)")
    backend = json.loads(found.stdout.strip().splitlines()[-1])
    gpu = backend["backend"] != "cpu"
    rtol, atol = TOLERANCE["gpu" if gpu else "cpu"]
    if gpu and backend["devices"] < 2:
        sys.exit(f"distributed.py: needs 2 GPUs but only {backend['devices']} {backend['backend']} device is visible "
                 f"(CUDA_VISIBLE_DEVICES={os.environ.get('CUDA_VISIBLE_DEVICES', 'unset')})")
    visible = [v.strip() for v in os.environ.get("CUDA_VISIBLE_DEVICES", "").split(",") if v.strip()]
    gpu_ids = visible[:2] if len(visible) >= 2 else ["0", "1"]
    per_process = args.envs_per_process or (1024 if gpu else 16)
    from jaxnat.training import parse_env_kwargs

    parse_env_kwargs(args.env_kwargs)  # a malformed pair fails here, not in a child
    results = {}
    with tempfile.TemporaryDirectory(prefix="jaxnat-distributed-") as tmp:
        out = Path(tmp)
        for setting in args.settings:
            num_envs = per_process * SETTINGS[setting][1]
            results[setting] = run_setting(setting, args, num_envs, out, gpu, gpu_ids)
        diffs = {}
        if "c" in results:
            diffs["c0-c1"] = compare(out / "c_0.npz", out / "c_1.npz", rtol, atol)
        if {"b", "c"} <= results.keys():
            diffs["b-c"] = compare(out / "b_0.npz", out / "c_0.npz", rtol, atol)

    import common

    base = results["a"][0]["steps_per_s"] if "a" in results else None
    rows = []
    for setting, lines in results.items():
        first = lines[0]  # process 0 (the processes of (c) wait on each other: alike)
        rows.append({"setting": f"({setting}) {SETTINGS[setting][2]}", "processes": first["processes"],
                     "devices": first["devices"], "num_envs": first["num_envs"],
                     "steps_per_s": first["steps_per_s"],
                     "speedup": first["steps_per_s"] / base if base else None, "compile_s": first["compile_s"],
                     "final_return": first["final_return"], "param_abs_sum": first["param_abs_sum"],
                     "per_process": [{k: line[k] for k in ("steps_per_s", "seconds", "compile_s", "param_abs_sum",
                                                           "param_first")} for line in lines]})
    table = common.markdown_table(rows, [
        ("setting", "setting", ""), ("processes", "processes", "d"), ("devices", "devices", "d"),
        ("num_envs", "envs", ",d"), ("steps_per_s", "env steps/s", ",.0f"), ("speedup", "speed-up vs (a)", ".2f"),
        ("compile_s", "compile s", ".1f"), ("final_return", "final return", ".3g"),
        ("param_abs_sum", "sum |params|", ".6g")])
    info = next((lines[0]["machine"] for lines in results.values() if lines[0]["machine"]), None)
    if info is None:  # (b) not run: this process's view (no GPU memory is taken by the summary alone)
        info = common.machine()
    summary = {
        "setting": (f"CPU ({info['cpu_cores']} cores): the devices and processes share the cores, so these numbers "
                    "show that the distributed path runs and matches, not speed" if not gpu
                    else f"GPUs {','.join(gpu_ids)} ({info['device']}); (c) over the loopback address"),
        "workload": (f"PPO on {args.env_id}" + (f" ({' '.join(args.env_kwargs)})" if args.env_kwargs else "")
                     + f", {per_process} envs per device, {args.num_steps} steps x {args.updates} updates "
                     f"(2 epochs x 2 minibatches), 1 seed; median of {args.repeats} runs after a warm-up"),
    }
    if "b-c" in diffs:
        diff, close = diffs["b-c"]
        summary["(b) vs (c) final parameters"] = (f"{'match' if close else 'DIFFER'} (allclose rtol={rtol:g}, "
                                                  f"atol={atol:g}): max abs difference {diff:.3g}")
    if "c0-c1" in diffs:
        diff, close = diffs["c0-c1"]
        summary["(c) process 0 vs 1 final parameters"] = ("identical" if diff == 0 else
                                                          f"{'match' if close else 'DIFFER'}: max abs difference {diff:.3g}")
    common.record("distributed", info, table, summary, rows, save=not args.no_record)
    if not all(close for _, close in diffs.values()):
        sys.exit("distributed.py: the parameters differ (above)")


def main() -> None:
    args = parse()
    if args.probe:
        probe()
    elif args.child:
        child(args)
    else:
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        parent(args)


if __name__ == "__main__":
    main()
