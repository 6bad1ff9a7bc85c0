"""Every family and algorithm under `jaxnat train --devices N`: trains, or refuses in one line.

For each env family (Classify, Localize, PixelMuJoCo from pixels, MuJoCo from state, Natural
Atari) x algorithm (PPO, A2C, ACKTR, DQN) x `--shard` (envs, seeds), one tiny `jaxnat train`
run on `--devices N` in a child process; then the runs that trained are continued on 1 device
(`--resume RUN --devices 1 --total-timesteps 2x`) and back on N devices (`--devices N`, 3x), as
docs/api.md promises. Each row records the outcome (`trained`, `refused` with the one-line
message, or `crashed` with the exit status and the last line of output) and the wall time. A crash is what this bench exists to catch:
the run exits non-zero (status 1) if any row crashed or refused in more than one line.

    python bench/devices_matrix.py                         # 2 devices, every family and algorithm
    python bench/devices_matrix.py --devices 4 --families classify mujoco --algos ppo a2c --jobs 4
    XLA_FLAGS=--xla_force_host_platform_device_count=2 JAX_PLATFORMS=cpu \\
        python bench/devices_matrix.py --families classify --algos ppo acktr --no-record

On GPUs the children do not preallocate memory (`XLA_PYTHON_CLIENT_PREALLOCATE=false`), so
`--jobs` runs may share the GPUs (compiling is most of a tiny run's time, and it is the host's
work). On a CPU the children see `--devices` simulated devices: the rows show what runs and
what is refused, not speed. Natural Atari needs ale-py and its ROMs (a missing one is a
`skipped` row with the reason).
"""

from __future__ import annotations

import argparse
import concurrent.futures
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
# This process only reads the machine's description: it must not take the GPUs' memory.
os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")

# family -> (env id, env kwargs as `KEY=VALUE`, envs per seed, steps per env)
FAMILIES = {
    "classify": ("Classify/Digits-v0", [], 8, 8),
    "localize": ("Localize/Clutter-v0", ["image_size=64", "M=10"], 8, 8),
    "pixel": ("PixelMuJoCo/HalfCheetah-v0", ["physics=fast", "max_steps_in_episode=10"], 8, 8),
    "mujoco": ("MuJoCo/Hopper-v0", ["max_steps_in_episode=10"], 8, 8),
    "atari": ("NaturalAtari/Breakout-v0", ["max_episode_steps=20"], 8, 8),
}
ALGOS = ("ppo", "a2c", "acktr", "dqn")
SHARDS = ("envs", "seeds")


def _train_argv(family: str, algo: str, shard: str, devices: int, run_dir: Path) -> list[str]:
    env_id, kwargs, envs, steps = FAMILIES[family]
    seeds = devices  # --shard seeds: one seed per device
    argv = [sys.executable, "-m", "jaxnat.cli", "train", "--env-id", env_id, "--algo", algo, "--seeds", str(seeds),
            "--num-envs", str(envs), "--total-timesteps", str(2 * envs * steps), "--eval-episodes", "2",
            "--eval-every", "1", "--devices", str(devices), "--shard", shard, "--run-dir", str(run_dir)]
    if algo != "dqn":
        argv += ["--num-steps", str(steps)]
    if algo == "ppo":
        argv += ["--num-minibatches", "2", "--update-epochs", "1"]
    if kwargs:
        argv += ["--env-kwargs", *kwargs]
    return argv


def _resume_argv(run_dir: Path, total: int, devices: int = 1) -> list[str]:
    return [sys.executable, "-m", "jaxnat.cli", "train", "--resume", str(run_dir), "--devices", str(devices),
            "--total-timesteps", str(total)]


def _outcome(done: subprocess.CompletedProcess) -> tuple[str, str]:
    """(outcome, message): trained; refused (exit 2, a one-line `error:` message); crashed."""
    lines = [line for line in (done.stdout + done.stderr).strip().splitlines() if line.strip()]
    last = lines[-1].strip() if lines else ""
    if done.returncode == 0:
        return "trained", ""
    errors = [line for line in lines if ": error: " in line]
    if done.returncode == 2 and len(errors) == 1:
        return "refused", errors[0].split(": error: ", 1)[1]
    return "crashed", f"exit {done.returncode}: {last[-300:]}"


def run_row(family: str, algo: str, shard: str, devices: int, env: dict, folder: Path, timeout: float) -> dict:
    run_dir = folder / f"{family}-{algo}-{shard}"
    row = {"family": family, "env": FAMILIES[family][0], "algo": algo, "shard": shard, "devices": devices}
    start = time.perf_counter()
    try:
        done = subprocess.run(_train_argv(family, algo, shard, devices, run_dir), env=env, capture_output=True,
                              text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {**row, "outcome": "crashed", "message": f"no end within {timeout:.0f} s", "seconds": timeout,
                "resume": "", "back": ""}
    row["outcome"], row["message"] = _outcome(done)
    if "No module named 'ale_py'" in row["message"] or "ROM" in row["message"]:
        row["outcome"] = "skipped"
    row["resume"] = row["back"] = ""
    _, _, envs, steps = FAMILIES[family]
    # Continued on 1 device, then back on the run's first count: each from the last checkpoint.
    for key, total, count in (("resume", 4 * envs * steps, 1), ("back", 6 * envs * steps, devices)):
        if row["outcome"] != "trained" or (key == "back" and not row["resume"].startswith("trained")):
            break
        try:
            resumed = subprocess.run(_resume_argv(run_dir, total, count), env=env, capture_output=True, text=True,
                                     timeout=timeout)
            outcome, message = _outcome(resumed)
        except subprocess.TimeoutExpired:
            outcome, message = "crashed", f"no end within {timeout:.0f} s"
        row[key] = outcome + (f": {message}" if message else "")
    row["seconds"] = time.perf_counter() - start
    return row


def child_env(devices: int) -> dict:
    """The children's environment: this checkout's jaxnat; no preallocation (rows may share the
    GPUs); on a CPU, `devices` simulated devices."""
    env = {**os.environ, "XLA_PYTHON_CLIENT_PREALLOCATE": "false"}
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(Path(__file__).resolve().parents[1]),
                                                      env.get("PYTHONPATH")]))
    if env.get("JAX_PLATFORMS", "") == "cpu":
        flag = f"--xla_force_host_platform_device_count={devices}"
        env["XLA_FLAGS"] = " ".join(f for f in env.get("XLA_FLAGS", "").split()
                                    if "force_host_platform_device_count" not in f) + " " + flag
    return env


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--devices", type=int, default=2)
    parser.add_argument("--families", nargs="+", default=list(FAMILIES), choices=list(FAMILIES))
    parser.add_argument("--algos", nargs="+", default=list(ALGOS), choices=list(ALGOS))
    parser.add_argument("--shards", nargs="+", default=list(SHARDS), choices=list(SHARDS))
    parser.add_argument("--jobs", type=int, default=1, help="rows run at once")
    parser.add_argument("--timeout", type=float, default=900.0, help="seconds per child run")
    parser.add_argument("--no-record", action="store_true")
    args = parser.parse_args()
    if args.devices < 2:
        parser.error("--devices must be at least 2 (the matrix is about several devices)")

    import common

    env = child_env(args.devices)
    jobs = [(f, a, s) for f in args.families for a in args.algos for s in args.shards]
    rows = []
    with tempfile.TemporaryDirectory(prefix="jaxnat-devices-") as tmp, \
            concurrent.futures.ThreadPoolExecutor(max(1, args.jobs)) as pool:
        futures = {pool.submit(run_row, *job, args.devices, env, Path(tmp), args.timeout): job for job in jobs}
        for future in concurrent.futures.as_completed(futures):
            row = future.result()
            rows.append(row)
            print(f"{row['family']} · {row['algo']} · --shard {row['shard']}: {row['outcome']}"
                  + (f" ({row['message']})" if row["message"] else "")
                  + (f" · resumed on 1 device: {row['resume']}" if row["resume"] else "")
                  + (f" · back on {args.devices}: {row['back']}" if row["back"] else ""), flush=True)
    order = {job: i for i, job in enumerate(jobs)}
    rows.sort(key=lambda r: order[r["family"], r["algo"], r["shard"]])
    table = common.markdown_table(rows, [
        ("env", "env", ""), ("algo", "algo", ""), ("shard", "--shard", ""), ("devices", "devices", "d"),
        ("outcome", "outcome", ""), ("message", "message", ""), ("resume", "resumed on 1 device", ""),
        ("back", f"back on {args.devices} devices", ""), ("seconds", "seconds", ".0f")])
    info = common.machine()
    simulated = info["backend"] == "cpu"
    counts = {k: sum(r["outcome"] == k for r in rows) for k in ("trained", "refused", "crashed", "skipped")}
    summary = {
        "setting": (f"{args.devices} simulated CPU devices: what runs and what is refused, not speed" if simulated
                    else f"{info['num_devices']} {info['device']} devices, runs on {args.devices}"),
        "outcomes": ", ".join(f"{v} {k}" for k, v in counts.items()),
        "tiny runs": ("8 envs per seed x 8 steps, 2 updates, a seed per device; resumed to twice the steps on "
                      f"1 device, then to 3x on {args.devices}"),
    }
    common.record("devices_matrix", info, table, summary, rows, save=not args.no_record)
    bad = [r for r in rows if "crashed" in (r["outcome"], r["resume"][:7], r["back"][:7])]
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
