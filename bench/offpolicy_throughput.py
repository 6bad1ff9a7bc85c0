"""PPO, A2C, ACKTR and DQN side by side on one classification env: env steps/s with seeds
vmapped, and wall time to a test return of 0.9.

Each algorithm trains `--seeds` seeds in one jitted program (`jit(vmap(run))`, through the same
`Learner` interface as `jaxnat train`), in chunks of updates for at most `--seconds`; after
each chunk every seed is evaluated greedily on the test split (1000 episodes; 200 with --quick). Steps/s exclude
compilation and evaluation. All algorithms get the same number of envs; their own defaults
otherwise (PPO's 128-step rollouts shortened to 32 as in bench/train_throughput.py; DQN with one
env step per update, a replay ratio of 2 samples per env step, Adam 1e-3 and a target copy every
250 gradient steps, see `_configs`). Where the threshold is not reached in the budget the table
says so ("-") and gives the best test return seen and when.

    python bench/offpolicy_throughput.py               # GPU: 2048 envs, 5 seeds, 90 s each
    python bench/offpolicy_throughput.py --quick       # CPU: 16 envs, 2 seeds, 90 s each
"""

from __future__ import annotations

import argparse
import sys


sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parent))
import common  # noqa: E402
import train_throughput  # noqa: E402

import jaxnat  # noqa: E402
from jaxnat.agents import ALGORITHMS  # noqa: E402

THRESHOLD = 0.9


def _configs(num_envs: int, on_gpu: bool) -> dict:
    """Per algorithm: the config (a budget far beyond the run) and one line describing it."""
    big = 10**9  # beyond any run here, and its update count fits the schedules' int32
    ppo, a2c, acktr, dqn = (ALGORITHMS[a].config for a in ("ppo", "a2c", "acktr", "dqn"))
    batch = 256 if on_gpu else 32
    gradient_steps = max(1, 2 * num_envs // batch)  # 2 replayed samples per env step
    return {
        "ppo": (ppo(total_timesteps=big, num_envs=num_envs, num_steps=32, anneal_lr=False),
                "32 steps, 4 epochs x 4 minibatches, Adam 2.5e-4"),
        "a2c": (a2c(total_timesteps=big, num_envs=num_envs),
                "5 steps, RMSprop 7e-4"),
        "acktr": (acktr(total_timesteps=big, num_envs=num_envs, anneal_lr=False),
                  "20 steps, K-FAC lr 0.25, KL clip 0.001"),
        # Adam 1e-3 and a target copy every 250 gradient steps: on the CPU sizes these learn
        # where RMSprop 2.5e-4 (eps 1e-5) with a copy every 1000 barely did (the dqn rows, and
        # the probe moved from here, in bench/results/offpolicy_throughput.md).
        "dqn": (dqn(total_timesteps=big, num_envs=num_envs, num_steps=1, batch_size=batch,
                    gradient_steps=gradient_steps, buffer_size=100_000 if on_gpu else 20_000,
                    optimizer="adam", lr=1e-3, target_update_period=250,
                    learning_starts=10_000 if on_gpu else 1_000,
                    exploration_steps=100_000 if on_gpu else 10_000),
                f"1 step, {gradient_steps} x batch {batch} gradient steps, Adam 1e-3, target period 250, "
                f"buffer {100_000 if on_gpu else 20_000}, epsilon 1 -> 0.1 over "
                f"{100_000 if on_gpu else 10_000:,} steps/seed, learning from {10_000 if on_gpu else 1_000:,}"),
    }


def bench_algo(algo, config, env, params, test_env, test_params, seeds, chunk, seconds, eval_episodes):
    """The last chunk's row, with when the threshold was first reached and the best test return."""
    learner = ALGORITHMS[algo].make(config, env, params)
    rows, _ = train_throughput.train_in_chunks(
        learner, test_env, test_params, per_update=config.num_envs * config.num_steps, seeds=seeds,
        chunk=chunk, seconds=seconds, eval_episodes=eval_episodes, label=f"{algo:5s} ")
    reached = train_throughput.first_reaching(rows, THRESHOLD)
    best = max(rows, key=lambda row: row["test_return"])
    return {
        **rows[-1],
        "algo": algo,
        "threshold_s": reached["train_s"] if reached else None,
        "threshold_steps": reached["env_steps_per_seed"] if reached else None,
        "best_return": best["test_return"],
        "best_accuracy": best["test_accuracy"],
        "best_s": best["train_s"],
        "best_steps": best["env_steps_per_seed"],
    }


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env-id", default="Classify/Digits-v0")
    parser.add_argument("--algos", default="ppo,a2c,acktr,dqn")
    parser.add_argument("--quick", action="store_true", help="CPU sizes: 16 envs, 2 seeds, 90 s per algorithm")
    parser.add_argument("--seeds", type=int, default=None, help="default: 5 (2 with --quick)")
    parser.add_argument("--num-envs", type=int, default=None, help="default: 2048 on GPU, 16 with --quick")
    parser.add_argument("--seconds", type=float, default=None, help="training budget per algorithm; default 90 (also with --quick)")
    parser.add_argument("--chunk-steps", type=int, default=None,
                        help="env steps per seed between evaluations; default num_envs * 160")
    parser.add_argument("--eval-episodes", type=int, default=None, help="test episodes per seed per evaluation; default 1000 (200 with --quick)")
    parser.add_argument("--no-record", action="store_true")
    args = parser.parse_args(argv)

    info = common.machine()
    on_gpu = info["backend"] != "cpu"
    seeds = args.seeds or (2 if args.quick else 5)
    num_envs = args.num_envs or (16 if args.quick or not on_gpu else 2048)
    seconds = args.seconds or 90.0
    chunk_steps = args.chunk_steps or num_envs * 160
    eval_episodes = args.eval_episodes or (200 if args.quick else 1000)
    env, params = jaxnat.make(args.env_id)
    test_env, test_params = jaxnat.make(args.env_id, split="test", autoreset=False)
    configs = _configs(num_envs, on_gpu)

    rows = []
    for algo in args.algos.split(","):
        config, _ = configs[algo]
        chunk = max(1, chunk_steps // (config.num_envs * config.num_steps))
        rows.append(bench_algo(algo, config, env, params, test_env, test_params, seeds, chunk, seconds,
                               eval_episodes))
    table = common.markdown_table(rows, [
        ("algo", "algorithm", "s"), ("steps_per_s", "env steps/s (all seeds)", ".3e"),
        ("threshold_s", f"s to test return >= {THRESHOLD}", ".1f"),
        ("threshold_steps", "steps/seed to it", ","), ("train_s", "trained s", ".1f"),
        ("env_steps_per_seed", "steps/seed", ","), ("best_return", "best test return", "+.3f"),
        ("best_accuracy", "its accuracy", ".1%"), ("best_s", "at s", ".1f"), ("best_steps", "at steps/seed", ","),
        ("test_return", "final test return", "+.3f"),
        ("test_return_std", "std over seeds", ".3f"), ("test_accuracy", "final accuracy", ".1%"),
        ("compile_s", "compile s", ".1f"),
    ])
    summary = {
        "env": args.env_id,
        "setup": f"{seeds} seeds vmapped, {num_envs} envs each; at most {seconds:.0f} s training per algorithm, "
                 f"greedy evaluation on the test split ({eval_episodes} episodes) every {chunk_steps:,} env steps per seed",
        **{f"{algo} settings": configs[algo][1] for algo in args.algos.split(",")},
    }
    common.record("offpolicy_throughput", info, table, summary, rows, save=not args.no_record)


if __name__ == "__main__":
    main()
