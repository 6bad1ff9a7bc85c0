"""A training run on a host-batched env (`NaturalAtari/*`), for `jaxnat train`.

`jaxnat train --env-id NaturalAtari/Breakout-v0 --algo ppo|a2c|dqn` comes here (the jitted,
vmapped trainer needs a pure-JAX env). Seeds train one after another with `host_loop`, on
rewards clipped to [-1, 1] (`ClipRewardWrapper`, as DQN and the authors' code); the returns
reported (train and test) are whole games with unclipped rewards. After training, each seed's
policy plays `eval_episodes` whole games on the test split (videos the agent never saw),
sampled and greedy. The run directory holds `config.json` (the run spec, as the jitted
trainer's), `metrics.jsonl` (one row per update and seed), `eval.jsonl` (one row per seed),
`summary.json` and `checkpoints/seed_<s>/` (orbax; every `eval_every` updates and at the end
of a seed; the last 2 kept).

`--resume RUN_DIR` skips the seeds that finished, restores the latest checkpoint of the one in
progress (params, optimizer state, DQN's target network and replay buffer, the update count
and the PRNG key) and goes on from there, dropping metrics rows written after that checkpoint.
The emulators' state cannot be saved, so the resumed seed starts new games (from a seed drawn
from the restored key): unlike a resumed jitted run, the result is not the uninterrupted one
bit for bit.
"""

from __future__ import annotations

import dataclasses
import datetime
import json
import sys
import time
from pathlib import Path

import jax
import numpy as np

import jaxnat
from jaxnat.agents import a2c, ppo
from jaxnat.agents.host_loop import evaluate_host, make_host_dqn, make_host_learner
from jaxnat.atari.wrappers import ClipRewardWrapper
from jaxnat.training.checkpoints import Checkpoints
from jaxnat.training.records import read_jsonl, write_jsonl

__all__ = ["HOST_ALGORITHMS", "observation_space", "run_host_training", "make_learner"]

HOST_ALGORITHMS = ("ppo", "a2c", "dqn")
RULES = {"ppo": ppo.RULE, "a2c": a2c.RULE}


def observation_space(env_id: str, env_kwargs: dict):
    """The observation space, from one env without background (cheap), for the default trunk."""
    probe = jaxnat.make_vec(env_id, 1, **{**env_kwargs, "background": "none"})
    try:
        return probe.single_observation_space
    finally:
        probe.close()


def make_learner(algo: str, config, env, compiler_options: dict | None = None):
    if algo == "dqn":
        return make_host_dqn(config, env, compiler_options)
    return make_host_learner(config, env, RULES[algo], compiler_options)


def _done_seeds(eval_rows: list[dict]) -> dict[int, dict]:
    return {row["seed"]: row for row in eval_rows}


def run_host_training(spec, run_dir: Path, *, resume: bool = False, console=None,
                      compiler_options: dict | None = None, stop_after_chunks: int | None = None,
                      versions: dict | None = None) -> tuple[dict, bool]:
    """Train (or resume) the run `spec` (a `training.RunSpec`; `eval_every`: updates between
    checkpoints); returns `(summary, complete)`. `stop_after_chunks`: stop after saving this
    many checkpoints (`--resume` continues)."""
    from rich.console import Console

    console = console or Console()
    if "split" in spec.env_kwargs:
        raise ValueError("env kwarg 'split' is set by jaxnat train: split=train for training and "
                         "split=test for evaluation")
    config = spec.config
    env = ClipRewardWrapper(jaxnat.make_vec(spec.env_id, config.num_envs, split="train",
                                            **spec.env_kwargs))
    test_env = jaxnat.make_vec(spec.env_id, config.num_envs, split="test", **spec.env_kwargs)
    learner = make_learner(spec.algo, config, env, compiler_options)
    run_dir.mkdir(parents=True, exist_ok=True)
    metrics_path, eval_path = run_dir / "metrics.jsonl", run_dir / "eval.jsonl"
    if not resume:
        (run_dir / "config.json").write_text(json.dumps({
            "spec": spec.to_json(), "loop": "host (jaxnat.agents.host_loop)", "command": sys.argv,
            "versions": versions or {}, "created": datetime.datetime.now().isoformat(timespec="seconds"),
        }, indent=2, default=str) + "\n")
        metrics_path.write_text("")
        eval_path.write_text("")
    num_updates, steps_per_update = learner.num_updates, spec.steps_per_update
    console.print(f"{spec.env_id} · {spec.algo} · {spec.seeds} seed(s) one after another (host "
                  f"loop) · {num_updates} updates of {steps_per_update} env steps · checkpoint "
                  f"every {spec.eval_every} updates · run: {run_dir}")
    done = _done_seeds(read_jsonl(eval_path))
    # Metrics rows of finished seeds stay; a seed in progress keeps those up to its checkpoint.
    checkpoints = {s: Checkpoints(run_dir / "checkpoints" / f"seed_{s}") for s in spec.seed_values}
    kept = {s: num_updates if s in done else (checkpoints[s].latest_step() or 0) for s in spec.seed_values}
    write_jsonl(metrics_path, [r for r in read_jsonl(metrics_path) if r["update"] <= kept.get(r["seed"], 0)], "w")
    start = time.perf_counter()
    last_print = [start]
    chunks_left = [stop_after_chunks]
    complete = True
    try:
        for s in spec.seed_values:
            if s in done:
                console.print(f"seed {s} · finished before (test greedy {done[s]['greedy_return']:+.1f})")
                continue
            state = learner.init(jax.random.key(s))
            if checkpoints[s].latest_step() is not None:
                state, meta = checkpoints[s].restore(state)
                console.print(f"seed {s} · resumed from checkpoint at update {meta['update']} "
                              "(new games: emulator state is not checkpointed)")

            def log(state, metrics, seconds, s=s):
                update = int(state.update)
                row = {"update": update, "env_steps": update * steps_per_update, "seed": s,
                       **{k: (None if np.isnan(v) else v) for k, v in metrics.items()},
                       "steps_per_second": steps_per_update / seconds}
                write_jsonl(metrics_path, [row])
                if update % spec.eval_every == 0 or update == num_updates:
                    checkpoints[s].save(state, {"update": update, "env_steps": update * steps_per_update,
                                                "seed": s})
                # About 20 lines a seed, and at least one every 30 s (a CPU run is slow).
                if update in (1, num_updates) or update % max(1, num_updates // 20) == 0 \
                        or time.perf_counter() - last_print[0] > 30:
                    last_print[0] = time.perf_counter()
                    ret = metrics["episode_return"]
                    ret = "no game ended yet" if np.isnan(ret) else f"train return {ret:+.1f}"
                    console.print(f"seed {s} · update {update}/{num_updates} · {ret} · "
                                  f"{row['steps_per_second']:,.0f} steps/s"
                                  + (" (compiling)" if update == 1 else ""))

            stop_at = num_updates
            if chunks_left[0] is not None:  # the update of the chunks_left-th checkpoint from here
                stop_at = min(num_updates, (int(state.update) // spec.eval_every + chunks_left[0]) * spec.eval_every)
                chunks_left[0] -= -(-(stop_at - int(state.update)) // spec.eval_every)
            state, _ = learner.run(state, stop_at, callback=log)
            if int(state.update) < num_updates:
                complete = False
                break
            scores = {}
            for mode in ("sampled", "greedy"):
                returns = evaluate_host(learner, learner.params(state), test_env, spec.eval_episodes,
                                        jax.random.key(10_000 + s), greedy=mode == "greedy")
                scores[f"{mode}_return"] = float(returns.mean())
            done[s] = {"update": num_updates, "seed": s, **scores}
            write_jsonl(eval_path, [done[s]])
            console.print(f"seed {s} · test split ({spec.eval_episodes} games): sampled "
                          f"{scores['sampled_return']:+.1f} · greedy {scores['greedy_return']:+.1f}")
    finally:
        for c in checkpoints.values():
            c.close()
        env.close()
        test_env.close()
    summary = _summary(spec, done, read_jsonl(metrics_path), time.perf_counter() - start, complete)
    (run_dir / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    if complete:
        console.print(f"done in {summary['wall_time_s']:.0f} s · test sampled return "
                      f"{summary['test_sampled_return_mean']:+.1f} · run directory: {run_dir}")
    else:
        console.print(f"stopped; continue with: jaxnat train --resume {run_dir}")
    return summary, complete


def _summary(spec, done: dict, metrics_rows: list[dict], wall: float, complete: bool) -> dict:
    per_seed = []
    for s in spec.seed_values:
        if s not in done:
            continue
        train_returns = [r["episode_return"] for r in metrics_rows
                         if r["seed"] == s and r["episode_return"] is not None][-10:]
        per_seed.append({"seed": s, "sampled_return": done[s]["sampled_return"],
                         "greedy_return": done[s]["greedy_return"],
                         "final_train_return": float(np.mean(train_returns)) if train_returns else None})
    mean = lambda name: float(np.mean([p[name] for p in per_seed])) if per_seed else None  # noqa: E731
    return {
        "env_id": spec.env_id, "algo": spec.algo, "config": dataclasses.asdict(spec.config),
        "seeds": per_seed, "test_sampled_return_mean": mean("sampled_return"),
        "test_greedy_return_mean": mean("greedy_return"),
        "env_steps_per_seed": spec.num_updates * spec.steps_per_update,
        "wall_time_s": wall, "complete": complete,
    }
