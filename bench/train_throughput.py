"""PPO end to end on a classification env: env steps/s with seeds vmapped, and learning speed.

One jitted program trains `--seeds` seeds at once (`jit(vmap(run))`), in chunks of updates;
after each chunk every seed is evaluated on the test split, greedy and sampled. Reports steps/s
(compile excluded), and the wall time until the mean test return over seeds first reaches 0.9.

    python bench/train_throughput.py [--env-id Classify/FashionMNIST-v0] [--seconds 120]
    python bench/train_throughput.py --update-epochs 2 --num-minibatches 2     # throughput
    python bench/train_throughput.py --num-envs 512 --env-kwargs start=center  # authors' start
    python bench/train_throughput.py --config dtype=bfloat16 ent_coef=0.03       # PPOConfig fields
    python bench/train_throughput.py --num-envs 512 --env-kwargs start=center \
        --config anneal_lr=true total_timesteps=2621440 weight_decay=0.1 dtype=bfloat16 memory=128
                                                     # the 0.9-in-60-s run (recurrent policy)
"""

from __future__ import annotations

import argparse
import functools
import sys
import time

import jax
import numpy as np

sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parent))
import common  # noqa: E402

import jaxnat  # noqa: E402
from jaxnat.agents import ppo  # noqa: E402
from jaxnat.agents.rollout import make_evaluate  # noqa: E402
from jaxnat.training import parse_env_kwargs  # noqa: E402


def train_in_chunks(learner, test_env, test_params, *, per_update: int, seeds: int, chunk: int,
                    seconds: float, eval_episodes: int, label: str = ""):
    """Train `learner` (any `jaxnat.agents` Learner) with `seeds` seeds vmapped, in chunks of
    `chunk` updates, for about `seconds` of training (compile and evaluation excluded); after
    each chunk evaluate every seed on the test split, greedy and sampled. Stops early at the
    learner's own update count (`learner.num_updates`: where an annealed learning rate ends).

    `per_update`: env steps per update and seed (`num_envs * num_steps` of every learner's
    config). Returns (one row per chunk, compile seconds)."""
    evaluate = jax.jit(jax.vmap(make_evaluate(learner.network, test_env, test_params, eval_episodes)))
    run = jax.jit(jax.vmap(functools.partial(learner.run, num_updates=chunk)))
    keys = jax.random.split(jax.random.key(0), seeds)

    t0 = time.perf_counter()
    runner = jax.jit(jax.vmap(learner.init))(keys)
    run = run.lower(runner).compile()
    evaluate = evaluate.lower(learner.policy_of(runner)[0], keys).compile()
    compile_s = time.perf_counter() - t0

    if chunk > learner.num_updates:
        raise SystemExit(f"--chunk {chunk} is more updates than the run has ({learner.num_updates}: "
                         "raise total_timesteps)")
    rows, train_s = [], 0.0
    # Never past the learner's own update count: an annealed learning rate would turn negative.
    while train_s < seconds and (rows[-1]["updates"] if rows else 0) + chunk <= learner.num_updates:
        t0 = time.perf_counter()
        runner, metrics = jax.block_until_ready(run(runner))
        train_s += time.perf_counter() - t0
        scores = jax.device_get(evaluate(learner.policy_of(runner)[0], keys))
        updates = int(learner.updates_of(runner)[0])
        row = {
            "updates": updates,
            "env_steps_per_seed": updates * per_update,
            "train_s": train_s,
            "steps_per_s": seeds * updates * per_update / train_s,
            "train_return": float(np.nanmean(np.asarray(metrics["episode_return"])[:, -1]))
            if "episode_return" in metrics else float("nan"),
            "test_return": float(np.mean(scores["greedy_return"])),
            "test_return_std": float(np.std(scores["greedy_return"])),
            "test_sampled_return": float(np.mean(scores["sampled_return"])),
            "test_accuracy": float(np.mean(scores["greedy_terminated_fraction"])),
            "test_sampled_accuracy": float(np.mean(scores["sampled_terminated_fraction"])),
            "compile_s": compile_s,
        }
        rows.append(row)
        print(f"  {label}{updates:6d} updates, {row['env_steps_per_seed']:>11,} steps/seed, {train_s:6.1f}s: "
              f"{row['steps_per_s']:.3e} steps/s, test return {row['test_return']:+.3f} greedy, "
              f"{row['test_sampled_return']:+.3f} sampled, "
              f"accuracy {row['test_accuracy']:.1%}", flush=True)
    return rows, compile_s


def first_reaching(rows, target: float, column: str = "test_return"):
    """The first row whose `column` reached `target`, or None."""
    return next((row for row in rows if row[column] >= target), None)


def train_and_evaluate(env_id: str, *, seeds: int, num_envs: int, num_steps: int, chunk: int,
                       seconds: float, lr: float, env_kwargs: dict | None = None,
                       eval_episodes: int = 1000, target: float = 0.9, update_epochs: int = 4,
                       num_minibatches: int = 4, overrides: dict | None = None):
    """Train PPO on `env_id` with `seeds` seeds vmapped (`train_in_chunks`); `overrides`:
    further `PPOConfig` fields (with `anneal_lr=True`, set `total_timesteps` per seed too).

    Returns (rows, compile seconds, training seconds, `{"greedy": row, "sampled": row}`: per
    policy, the first row whose mean test return reached `target`, or None)."""
    env_kwargs = env_kwargs or {}
    env, params = jaxnat.make(env_id, **env_kwargs)
    test_env, test_params = jaxnat.make(env_id, split="test", autoreset=False, **env_kwargs)
    config = ppo.PPOConfig(total_timesteps=num_envs * num_steps * 10**6, num_envs=num_envs,
                           num_steps=num_steps, update_epochs=update_epochs,
                           num_minibatches=num_minibatches, lr=lr, anneal_lr=False)
    config = config.replace(**(overrides or {}))
    learner = ppo.make_ppo(config, env, params)
    rows, compile_s = train_in_chunks(learner, test_env, test_params, per_update=num_envs * num_steps,
                                      seeds=seeds, chunk=chunk, seconds=seconds,
                                      eval_episodes=eval_episodes)
    reached = {"greedy": first_reaching(rows, target, "test_return"),
               "sampled": first_reaching(rows, target, "test_sampled_return")}
    return rows, compile_s, rows[-1]["train_s"], reached


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env-id", default="Classify/Digits-v0")
    parser.add_argument("--env-kwargs", nargs="*", default=(), metavar="KEY=VALUE",
                        help="env options, as `jaxnat train --env-kwargs` (e.g. start=center)")
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--num-envs", type=int, default=None, help="default: 2048 on GPU, 32 on CPU")
    parser.add_argument("--num-steps", type=int, default=32)
    parser.add_argument("--update-epochs", type=int, default=4)
    parser.add_argument("--num-minibatches", type=int, default=None, help="default: 4 on GPU, 8 on CPU")
    parser.add_argument("--chunk", type=int, default=10, help="updates between evaluations")
    parser.add_argument("--seconds", type=float, default=120.0, help="training wall-time budget")
    parser.add_argument("--lr", type=float, default=1e-3)
    parser.add_argument("--config", nargs="*", default=(), metavar="KEY=VALUE",
                        help="further PPOConfig fields, e.g. dtype=bfloat16 ent_coef=0.03; "
                             "anneal_lr=true needs total_timesteps=N (per seed)")
    parser.add_argument("--eval-episodes", type=int, default=1000)
    parser.add_argument("--no-record", action="store_true")
    args = parser.parse_args(argv)

    info = common.machine()
    on_cpu = info["backend"] == "cpu"
    # On a CPU the main job's settings (make run; bench/results/ppo_sweep.md), on a GPU big batches.
    num_envs = args.num_envs or (32 if on_cpu else 2048)
    minibatches = args.num_minibatches or (8 if on_cpu else 4)
    env_kwargs = parse_env_kwargs(args.env_kwargs)
    overrides = parse_env_kwargs(args.config)
    rows, compile_s, train_s, reached = train_and_evaluate(
        args.env_id, env_kwargs=env_kwargs, seeds=args.seeds, num_envs=num_envs, num_steps=args.num_steps,
        chunk=args.chunk, seconds=args.seconds, lr=args.lr, eval_episodes=args.eval_episodes,
        update_epochs=args.update_epochs, num_minibatches=minibatches, overrides=overrides)
    table = common.markdown_table(rows, [
        ("updates", "updates", ","), ("env_steps_per_seed", "env steps per seed", ","),
        ("train_s", "train s", ".1f"), ("steps_per_s", "env steps/s (all seeds)", ".3e"),
        ("train_return", "train return", "+.3f"), ("test_return", "test return (greedy)", "+.3f"),
        ("test_return_std", "std over seeds", ".3f"), ("test_sampled_return", "test return (sampled)", "+.3f"),
        ("test_accuracy", "test accuracy", ".1%"),
        ("test_sampled_accuracy", "test accuracy (sampled)", ".1%"),
    ])
    summary = {
        "env": args.env_id + (f" {env_kwargs}" if env_kwargs else ""),
        "setup": f"PPO, {args.seeds} seeds vmapped, {num_envs} envs x {args.num_steps} steps per update, "
                 f"{args.update_epochs} epochs x {minibatches} minibatches, lr {args.lr}, "
                 f"{args.eval_episodes} test episodes per seed per evaluation"
                 + "".join(f", {key} {value}" for key, value in overrides.items()),
        "compile s": f"{compile_s:.1f}",
        "env steps/s end to end (all seeds, compile excluded)": f"{rows[-1]['steps_per_s']:.3e} (target on one H100: >= 1e6)",
        **{f"time to mean test return >= 0.9 ({policy} policy)":
           (f"{row['train_s']:.1f} s ({row['env_steps_per_seed']:,} steps per seed)"
            if row else f"not reached in {train_s:.0f} s (target: <= 60 s)")
           for policy, row in reached.items()},
        "final test return / accuracy (greedy)": f"{rows[-1]['test_return']:+.3f} / {rows[-1]['test_accuracy']:.1%}",
        "final test return / accuracy (sampled)": f"{rows[-1]['test_sampled_return']:+.3f} / {rows[-1]['test_sampled_accuracy']:.1%}",
    }
    common.record("train_throughput", info, table, summary, rows, save=not args.no_record)


if __name__ == "__main__":
    main()
