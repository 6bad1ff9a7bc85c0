"""A fingerprint of small `jaxnat train` runs, for refactors that must not change behaviour.

Runs one tiny run per learner path (PPO, recurrent PPO, A2C, ACKTR and DQN on Classify/Digits-v0;
continuous PPO on MuJoCo/Swimmer-v0; PPO, A2C and DQN on NaturalAtari/Breakout-v0 through the host
loop) and prints a SHA-256 of each run's metrics and evaluation rows with every timing field left
out, then one of them all. Identical digests before and after a change: the change kept every
learner's numbers bit for bit on this machine.

    python scripts/fingerprint.py            # all runs
    python scripts/fingerprint.py ppo dqn    # some of them
"""

from __future__ import annotations

import hashlib
import json
import sys
import tempfile
from pathlib import Path

FAST = {"xla_backend_optimization_level": 0}
DIGITS = ["--env-id", "Classify/Digits-v0", "--seeds", "2", "--num-envs", "8", "--num-steps", "16",
          "--total-timesteps", "512", "--eval-every", "2", "--eval-episodes", "16", "--trunk", "mnist"]
ATARI = ["--env-id", "NaturalAtari/Breakout-v0", "--seeds", "2", "--total-timesteps", "32", "--num-envs", "2",
         "--eval-episodes", "2", "--eval-every", "1", "--num-steps", "8", "--env-kwargs", "obs_size=36",
         "num_threads=1", "max_episode_steps=10", "background=noise"]
RUNS = {
    "ppo": [*DIGITS, "--algo", "ppo"],
    "ppo_recurrent": [*DIGITS, "--algo", "ppo", "--memory", "8", "--num-minibatches", "2"],
    "a2c": [*DIGITS, "--algo", "a2c"],
    "acktr": [*DIGITS, "--algo", "acktr"],
    "dqn": [*DIGITS, "--algo", "dqn", "--buffer-size", "256", "--learning-starts", "64", "--batch-size", "16"],
    "ppo_swimmer": ["--env-id", "MuJoCo/Swimmer-v0", "--algo", "ppo", "--seeds", "2", "--num-envs", "4",
                    "--num-steps", "16", "--total-timesteps", "256", "--eval-every", "2", "--eval-episodes", "2",
                    "--env-kwargs", "max_steps_in_episode=20"],
    "atari_ppo": [*ATARI, "--algo", "ppo", "--num-minibatches", "2"],
    "atari_a2c": [*ATARI, "--algo", "a2c"],
    "atari_dqn": [*ATARI, "--algo", "dqn", "--buffer-size", "64", "--learning-starts", "16", "--gradient-steps",
                  "2", "--batch-size", "8", "--n-step", "3"],
}
# Fields that hold times or counts of seconds, which differ between any two runs.
TIMED = ("time", "seconds", "_s", "steps_per_second", "sps", "compile")


def _untimed(row):
    if isinstance(row, dict):
        return {k: _untimed(v) for k, v in sorted(row.items()) if not any(t in k for t in TIMED)}
    if isinstance(row, list):
        return [_untimed(v) for v in row]
    return row


def fingerprint(name: str, argv: list[str]) -> str:
    from rich.console import Console

    from jaxnat.train import parse_args, train

    with tempfile.TemporaryDirectory() as tmp:
        run_dir = Path(tmp) / name
        train(parse_args([*argv, "--run-dir", str(run_dir)]), console=Console(quiet=True), compiler_options=FAST)
        digest = hashlib.sha256()
        for file in sorted(run_dir.glob("*.jsonl")):
            for line in file.read_text().splitlines():
                digest.update(json.dumps(_untimed(json.loads(line)), sort_keys=True).encode())
        summary = json.loads((run_dir / "summary.json").read_text())
        digest.update(json.dumps(_untimed(summary.get("metrics", {})), sort_keys=True).encode())
        return digest.hexdigest()[:16]


def main(names: list[str]) -> None:
    names = names or list(RUNS)
    unknown = sorted(set(names) - set(RUNS))
    if unknown:
        raise SystemExit(f"unknown runs {unknown}: choose from {sorted(RUNS)}")
    total = hashlib.sha256()
    results = {}
    for name in names:
        results[name] = fingerprint(name, RUNS[name])
        total.update(f"{name}={results[name]}".encode())
    for name, digest in results.items():
        print(f"{name:14s} {digest}")
    print(f"{'all':14s} {total.hexdigest()[:16]}")


if __name__ == "__main__":
    main(sys.argv[1:])
