"""A training run on a host-batched env (`NaturalAtari/*`), for `jaxnat train`.

`jaxnat train --env-id NaturalAtari/Breakout-v0 --algo ppo` comes here (the jitted, vmapped
trainer needs a pure-JAX env). Seeds train one after another with `host_loop`, on rewards
clipped to [-1, 1] (`ClipRewardWrapper`, as DQN and the authors' code); the returns reported
(train and test) are whole games with unclipped rewards. After training,
each seed's policy plays `eval_episodes` whole games on the test split (videos the agent never
saw), sampled and greedy. The run directory holds `config.json`, `metrics.jsonl` (one row per
update and seed), `eval.jsonl` and `summary.json`. No checkpoints or `--resume` yet.
"""

from __future__ import annotations

import dataclasses
import datetime
import json
import sys
import time
from pathlib import Path
from typing import Callable

import jax
import numpy as np

import jaxnat
from jaxnat.agents import a2c, ppo
from jaxnat.agents.host_loop import evaluate_host, make_host_learner
from jaxnat.atari.wrappers import ClipRewardWrapper

__all__ = ["RULES", "run_host_training"]

RULES = {"ppo": ppo.RULE, "a2c": a2c.RULE}


def run_host_training(
    env_id: str,
    algo: str,
    resolve_config: Callable,
    *,
    env_kwargs: dict,
    seeds: int,
    seed: int,
    eval_episodes: int,
    run_dir: Path,
    console=None,
    max_eval_episodes: int = 32,
    compiler_options: dict | None = None,
) -> tuple[dict, Path]:
    """Train `seeds` seeds of `algo` on `env_id`; returns `(summary, run_dir)`.

    `resolve_config(observation_space)` gives the algorithm's config (the trainer's overrides
    applied, the trunk resolved for the observation space). Evaluation plays `min(eval_episodes, max_eval_episodes)` games
    per seed: whole Atari games are thousands of steps.
    """
    from rich.console import Console

    console = console or Console()
    if "split" in env_kwargs:
        raise ValueError("env kwarg 'split' is set by jaxnat train: split=train for training and "
                         "split=test for evaluation")
    # The observation space, from one env without background (cheap), for the default trunk.
    probe = jaxnat.make_vec(env_id, 1, **{**env_kwargs, "background": "none"})
    config = resolve_config(probe.single_observation_space)
    probe.close()
    env = ClipRewardWrapper(jaxnat.make_vec(env_id, config.num_envs, split="train", **env_kwargs))
    test_env = jaxnat.make_vec(env_id, config.num_envs, split="test", **env_kwargs)
    learner = make_host_learner(config, env, RULES[algo], compiler_options)
    if eval_episodes > max_eval_episodes:
        console.print(f"[dim]evaluating {max_eval_episodes} test games per seed (not "
                      f"{eval_episodes}): whole Atari games are long[/dim]")
        eval_episodes = max_eval_episodes
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "config.json").write_text(json.dumps({
        "env_id": env_id, "env_kwargs": env_kwargs, "algo": algo,
        "config": dataclasses.asdict(config), "seeds": seeds, "seed": seed,
        "eval_episodes": eval_episodes, "num_updates": learner.num_updates,
        "loop": "host (jaxnat.agents.host_loop)", "command": sys.argv,
        "created": datetime.datetime.now().isoformat(timespec="seconds"),
    }, indent=2, default=str) + "\n")
    steps_per_update = config.num_envs * config.num_steps
    console.print(f"{env_id} · {algo} · {seeds} seed(s) one after another (host loop) · "
                  f"{learner.num_updates} updates of {steps_per_update} env steps · run: {run_dir}")
    start = time.perf_counter()
    per_seed = []
    last_print = [start]
    with open(run_dir / "metrics.jsonl", "w") as metrics_file, \
            open(run_dir / "eval.jsonl", "w") as eval_file:
        for s in range(seed, seed + seeds):
            def log(update, metrics, seconds, s=s):
                row = {"update": update, "env_steps": update * steps_per_update, "seed": s,
                       **{k: (None if np.isnan(v) else v) for k, v in metrics.items()},
                       "steps_per_second": steps_per_update / seconds}
                metrics_file.write(json.dumps(row) + "\n")
                metrics_file.flush()
                # About 20 lines a seed, and at least one every 30 s (a CPU run is slow).
                if update in (1, learner.num_updates) \
                        or update % max(1, learner.num_updates // 20) == 0 \
                        or time.perf_counter() - last_print[0] > 30:
                    last_print[0] = time.perf_counter()
                    ret = metrics["episode_return"]
                    ret = "no game ended yet" if np.isnan(ret) else f"train return {ret:+.1f}"
                    console.print(f"seed {s} · update {update}/{learner.num_updates} · {ret} · "
                                  f"{row['steps_per_second']:,.0f} steps/s"
                                  + (" (compiling)" if update == 1 else ""))

            train_state, history = learner.train(jax.random.key(s), callback=log)
            scores = {}
            for mode in ("sampled", "greedy"):
                returns = evaluate_host(learner, train_state.params, test_env,
                                        eval_episodes, jax.random.key(10_000 + s),
                                        greedy=mode == "greedy")
                scores[f"{mode}_return"] = float(returns.mean())
            eval_file.write(json.dumps({"update": learner.num_updates, "seed": s, **scores}) + "\n")
            console.print(f"seed {s} · test split ({eval_episodes} games): sampled "
                          f"{scores['sampled_return']:+.1f} · greedy {scores['greedy_return']:+.1f}")
            train_returns = [h["episode_return"] for h in history[-10:]]
            per_seed.append({"seed": s, **scores,
                             "final_train_return": float(np.nanmean(train_returns))
                             if not np.isnan(train_returns).all() else None})
    wall = time.perf_counter() - start
    summary = {
        "env_id": env_id, "algo": algo, "seeds": per_seed,
        "test_sampled_return_mean": float(np.mean([p["sampled_return"] for p in per_seed])),
        "test_greedy_return_mean": float(np.mean([p["greedy_return"] for p in per_seed])),
        "env_steps_per_seed": learner.num_updates * steps_per_update,
        "wall_time_s": wall, "complete": True,
    }
    (run_dir / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    console.print(f"done in {wall:.0f} s · test sampled return "
                  f"{summary['test_sampled_return_mean']:+.1f} · run directory: {run_dir}")
    env.close()
    test_env.close()
    return summary, run_dir
