"""Natural Atari training throughput: jaxnat's PPO host loop against the env alone, in one run.

For each `--num-envs`, one game (`--game`, Breakout) with one background (`--background`,
video; also none / noise) at `--threads` ALE threads:

- env alone: `jaxnat.make_vec` stepping uniformly random actions (the reference rate);
- PPO: the trainer's own host path (`jaxnat.training.host_backend.make_train_env` and `make_learner`,
  iterating `learner.updates` as `HostBackend` does): `--warmup` updates (compiling), then
  `--updates` timed updates of `num_envs x --num-steps` env steps each (rollout + update);
  for each `--parts`: 1 is the default one-batch loop, 2+ the pipelined loop
  (`PipelinedVecEnv`: the batch in that many parts stepped in turn, so that each part's
  policy call overlaps the other parts' emulation; every part has `--threads` ALE threads).

With `--side-by-side 1 5 10`, instead: `jaxnat train`'s seeds side by side (`--host-seeds
together`: `make_train_env(..., seeds=S)` and `make_learner(..., seeds=S)`, one ALE batch of
S x `--envs-per-seed` envs, each seed's slice reset as its batch alone, one vmapped policy call
per step) for each seed count S, against the env alone on one batch of the same envs at the
same `--threads`; env steps/s of all seeds, and their ratio. Beside it (`--compare-batches`,
the default) the layout the learner had before: one ALE batch per seed (a `PipelinedVecEnv`
of S parts, every part's emulators stepped at once, the `--threads` shared out among them),
trained and stepped alone under random actions, and the ratio of the one batch to it; and for
each `--parts` above 1 (that divides `--envs-per-seed`), the seeds side by side in that many
pipelined parts (`--host-seeds together --env-parts P`: each part one ALE batch holding
envs-per-seed / P envs of every seed, stepped in turn so that one part's policy call overlaps
the other parts' emulation).

The table gives env steps/s of both, their ratio (target: PPO >= 0.70 of the env alone), and
where a PPO step's time goes (ms per batched step of all envs, from `learner.timings` and
`env.step_timings`): the policy's round trip (observations to the device, the jitted call,
actions back), the env's step (of it: the wait for ALE's emulation and the host pass after
it), `observe` (storing the step, V(final observation) where an episode ended), the rest of
the Python loop, and the update (stacking the rollout, GAE, PPO epochs, metrics to the host)
spread over the update's steps. The env alone is timed before and after the PPO runs (mean).

    python bench/atari_training.py                            # 64 128 256 envs, video
    python bench/atari_training.py --num-envs 16 --threads 2 --updates 2 --num-steps 32
    python bench/atari_training.py --video-sources out/videos   # a folder of your own clips
    python bench/atari_training.py --side-by-side 1 5 10          # seeds side by side, 8 envs each

A host without Debian's opencv-doc needs videos for the video background: copy some there
(e.g. opencv-doc's vtest.avi, tree.avi and Megamind.avi into out/videos/).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import jax
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import common  # noqa: E402

import jaxnat  # noqa: E402
from jaxnat.agents import ppo  # noqa: E402
from jaxnat.agents.networks import default_trunk  # noqa: E402
from jaxnat.agents.rollout import stack_seeds  # noqa: E402
from jaxnat.atari.chunks import default_threads  # noqa: E402
from jaxnat.atari.wrappers import ClipRewardWrapper, PipelinedVecEnv  # noqa: E402
from jaxnat.training.host_backend import make_learner, make_train_env  # noqa: E402


def random_rate(env, steps: int, rng) -> float:
    """Env steps/s of `steps` batched steps under uniformly random actions."""
    actions = rng.integers(0, int(env.single_action_space.n), (steps, env.num_envs))
    start = time.perf_counter()
    for a in actions:
        env.step(a)
    return actions.size / (time.perf_counter() - start)


def env_alone(env, steps: int, rng) -> tuple[float, dict]:
    """Env steps/s under uniformly random actions, and the env's step timings over them."""
    env.step_timings.update(steps=0, ale_s=0.0, ahead_s=0.0, host_s=0.0)
    rate = random_rate(env, steps, rng)
    return rate, dict(env.step_timings)


def batch_per_seed(env_id: str, envs_per_seed: int, env_kwargs: dict, seeds: int):
    """The side-by-side env as the learner had it before one ALE batch held every seed: a
    `PipelinedVecEnv` of one batch per seed, the ALE threads shared out among them."""
    threads = int(env_kwargs.get("num_threads", 0)) or default_threads(seeds * envs_per_seed)
    shares = [max(1, threads // seeds + (i < threads % seeds)) for i in range(seeds)]
    return PipelinedVecEnv([ClipRewardWrapper(jaxnat.make_vec(env_id, envs_per_seed, split="train",
                                                              **{**env_kwargs, "num_threads": share}))
                            for share in shares])


def step_timings(env) -> dict:
    """The summed `step_timings` of a training env (one batch or pipelined parts)."""
    parts = getattr(env, "parts", [env])
    total = {"steps": 0, "ale_s": 0.0, "ahead_s": 0.0, "host_s": 0.0}
    for part in parts:
        for name in total:
            total[name] += part.step_timings[name] if name != "steps" else 0
    total["steps"] = parts[0].step_timings["steps"]  # batched steps: the parts step together
    return total


def train_rate(env, config, warmup: int, updates: int, compiler_options, seed: int = 0, seeds: int | None = None):
    """(env steps/s over `updates` timed updates after `warmup`, of every seed (`seeds`: that
    many side by side, on `make_train_env(..., seeds=)`), timings, step timings, seconds of the
    warm-up)."""
    learner = make_learner("ppo", config, env, compiler_options, seeds=seeds)
    state = learner.init(jax.random.key(seed) if seeds is None else
                         stack_seeds([jax.random.key(seed + i) for i in range(seeds)]))
    it = learner.updates(state)
    start = time.perf_counter()
    for _ in range(warmup):
        next(it)
    warm_s = time.perf_counter() - start
    learner.timings.clear()
    for part in getattr(env, "parts", [env]):
        part.step_timings.update(steps=0, ale_s=0.0, ahead_s=0.0, host_s=0.0)
    start = time.perf_counter()
    for _ in range(updates):
        next(it)
    seconds = time.perf_counter() - start
    it.close()
    rate = updates * config.num_envs * config.num_steps * (seeds or 1) / seconds
    return rate, dict(learner.timings), step_timings(env), warm_s


def side_by_side(args, env_id: str, env_kwargs: dict, compiler_options, rng) -> tuple[list[dict], str]:
    """`--side-by-side`: per seed count, the env alone on all the seeds' envs as one batch, then
    PPO training them side by side; (rows, table)."""
    rows = []
    # `--parts` above 1: also every seed's envs in that many pipelined parts (each must divide
    # the envs of a seed)
    pipelined_parts = [parts for parts in args.parts if parts > 1 and args.envs_per_seed % parts == 0]
    for seeds in args.side_by_side:
        base = jaxnat.make_vec(env_id, seeds * args.envs_per_seed, split="train", **env_kwargs)
        base.reset(seed=0)
        env_alone(base, 10, rng)  # warm: threads started, numba compiled
        before, _ = env_alone(base, args.env_steps, rng)
        config = ppo.PPOConfig(num_envs=args.envs_per_seed, num_steps=args.num_steps,
                               total_timesteps=args.envs_per_seed * args.num_steps * (args.warmup + args.updates),
                               trunk=default_trunk(base.single_observation_space))
        per_seed, per_seed_alone = None, None
        if args.compare_batches:  # the layout before: one ALE batch per seed
            env = batch_per_seed(env_id, args.envs_per_seed, env_kwargs, seeds)
            env.reset(seeds=list(range(seeds)))
            random_rate(env, 10, rng)  # warm
            per_seed_alone = random_rate(env, args.env_steps, rng)
            per_seed = train_rate(env, config, args.warmup, args.updates, compiler_options, seeds=seeds)[0]
            env.close()
        env = make_train_env(env_id, args.envs_per_seed, env_kwargs, seeds=seeds)
        rate, timings, _, warm_s = train_rate(env, config, args.warmup, args.updates, compiler_options, seeds=seeds)
        env.close()
        pipelined = {}
        for parts in pipelined_parts:  # every seed's envs in that many parts stepped in turn
            env = make_train_env(env_id, args.envs_per_seed, env_kwargs, parts, seeds=seeds)
            pipelined[f"parts_{parts}"] = train_rate(env, config, args.warmup, args.updates, compiler_options,
                                                     seeds=seeds)[0]
            env.close()
        after, _ = env_alone(base, args.env_steps, rng)
        base.close()
        alone = (before + after) / 2
        n = timings["steps"]
        rows.append(dict(seeds=seeds, num_envs=seeds * args.envs_per_seed, alone=alone, steps_per_s=rate,
                         ratio=rate / alone, **pipelined,
                         **{f"{name}_ratio": value / alone for name, value in pipelined.items()},
                         policy_ms=1e3 * timings["policy_s"] / n, env_ms=1e3 * timings["env_s"] / n,
                         update_ms=1e3 * (timings["update_s"] - timings["rollout_s"]) / n, warmup_s=warm_s,
                         alone_before=before, alone_after=after, per_seed=per_seed,
                         one_over_per_seed=None if per_seed is None else rate / per_seed,
                         per_seed_alone=per_seed_alone))
    return rows, common.markdown_table(rows, [
        ("seeds", "seeds", "d"), ("num_envs", "envs (all seeds)", "d"), ("alone", "env alone steps/s", ",.0f"),
        ("steps_per_s", "PPO side by side steps/s", ",.0f"), ("ratio", "vs env alone", ".2f"),
        ("per_seed", "PPO, a batch per seed steps/s", ",.0f"), ("one_over_per_seed", "one batch / batch per seed", ".2f"),
        ("per_seed_alone", "env alone, a batch per seed", ",.0f"),
        *[column for parts in pipelined_parts for column in (
            (f"parts_{parts}", f"PPO in {parts} parts steps/s", ",.0f"),
            (f"parts_{parts}_ratio", f"{parts} parts vs env alone", ".2f"))],
        ("policy_ms", "policy ms", ".2f"), ("env_ms", "env step ms", ".2f"), ("update_ms", "update ms", ".2f"),
        ("warmup_s", "warm-up s", ".1f")])


def main(argv=None):
    cores = os.cpu_count() or 1
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--game", default="Breakout")
    parser.add_argument("--background", default="video", choices=["none", "noise", "video"])
    parser.add_argument("--num-envs", type=int, nargs="+", default=[64, 128, 256])
    parser.add_argument("--threads", type=int, default=cores, help="ALE threads (default: one per core)")
    parser.add_argument("--parts", type=int, nargs="+", default=[1, 2],
                        help="PPO loops to time: 1 one batch (the default loop), k>1 pipelined in k parts")
    parser.add_argument("--num-steps", type=int, default=128, help="PPO rollout length (steps per env)")
    parser.add_argument("--updates", type=int, default=3, help="timed PPO updates")
    parser.add_argument("--warmup", type=int, default=1, help="PPO updates before timing (compiling)")
    parser.add_argument("--env-steps", type=int, default=200, help="batched random steps of the env alone, "
                                                                   "before and after the PPO runs each")
    parser.add_argument("--video-sources", default=None, help="default: opencv-doc's videos")
    parser.add_argument("--fast-compile", action="store_true",
                        help="xla_backend_optimization_level=0 (CPU: compiles much faster, runs slower)")
    parser.add_argument("--side-by-side", type=int, nargs="+", default=None, metavar="SEEDS",
                        help="time seeds side by side (as jaxnat train --host-seeds together) for these seed "
                             "counts instead of the --num-envs/--parts loops")
    parser.add_argument("--envs-per-seed", type=int, default=8, help="with --side-by-side: envs of each seed")
    parser.add_argument("--compare-batches", action=argparse.BooleanOptionalAction, default=True,
                        help="with --side-by-side: also train (and step alone) the seeds on one ALE batch per seed, "
                             "the layout before one batch held them all")
    parser.add_argument("--no-record", action="store_true")
    args = parser.parse_args(argv)
    compiler_options = {"xla_backend_optimization_level": 0} if args.fast_compile else None
    env_id = f"NaturalAtari/{args.game}-v0"
    env_kwargs = {"background": args.background, "num_threads": args.threads}
    if args.video_sources:
        env_kwargs["video_sources"] = args.video_sources

    if args.background == "video":
        from jaxnat.datasets import DatasetNotFoundError
        from jaxnat.natural import load_videos

        try:
            load_videos(args.video_sources, shape=(210, 160), split="train")
        except DatasetNotFoundError as err:  # e.g. a host without Debian's opencv-doc
            parser.error(f"no videos for the video background (pass --video-sources a folder of clips, "
                         f"or --background noise): {err}")
    info = common.machine()
    started = time.perf_counter()
    rows = []
    rng = np.random.default_rng(0)
    if args.side_by_side:
        rows, table = side_by_side(args, env_id, env_kwargs, compiler_options, rng)
        summary = {
            "game": args.game, "background": args.background, "ALE threads (all seeds)": args.threads,
            "PPO": f"seeds side by side (jaxnat train --host-seeds together), {args.envs_per_seed} envs per seed, "
                   f"{args.num_steps} steps per env per update, {args.warmup} warm-up + {args.updates} timed updates"
                   + (", xla_backend_optimization_level=0" if args.fast_compile else ""),
            "columns": "env steps/s of all seeds; the env alone steps the same envs as one batch (random actions), "
                       "before and after (mean); 'a batch per seed': the same seeds on one ALE batch each, the "
                       "threads shared out (the learner's layout before); 'in P parts': every seed's envs in P pipelined "
                       "parts (--host-seeds together --env-parts P); ms per batched step of all envs",
            "bench seconds": f"{time.perf_counter() - started:.0f}",
            "video sources": args.video_sources or "opencv-doc",
        }
        common.record("atari_training", info, table, summary, rows, save=not args.no_record)
        return
    for num_envs in args.num_envs:
        base = jaxnat.make_vec(env_id, num_envs, split="train", **env_kwargs)
        base.reset(seed=0)
        env_alone(base, 10, rng)  # warm: threads started, numba compiled
        before, alone_timings = env_alone(base, args.env_steps, rng)
        config = ppo.PPOConfig(num_envs=num_envs, num_steps=args.num_steps,
                               total_timesteps=num_envs * args.num_steps * (args.warmup + args.updates),
                               trunk=default_trunk(base.single_observation_space))
        runs = []
        for parts in args.parts:
            env = ClipRewardWrapper(base) if parts == 1 else make_train_env(env_id, num_envs, env_kwargs, parts)
            runs.append((parts, *train_rate(env, config, args.warmup, args.updates, compiler_options)))
            if parts != 1:
                env.close()
        base.reset(seed=1)
        env_alone(base, 10, rng)
        after, _ = env_alone(base, args.env_steps, rng)
        base.close()
        alone = (before + after) / 2
        steps = alone_timings["steps"]
        rows.append(dict(num_envs=num_envs, loop="env alone (random actions)", steps_per_s=alone, ratio=1.0,
                         env_ms=None, ale_ms=1e3 * alone_timings["ale_s"] / steps,
                         host_ms=1e3 * (alone_timings["ahead_s"] + alone_timings["host_s"]) / steps,
                         alone_before=before, alone_after=after))
        for parts, rate, timings, env_t, warm_s in runs:
            n = timings["steps"]
            per_step = {name: 1e3 * timings[name] / n for name in ("policy_s", "env_s", "observe_s")}
            rollout_ms = 1e3 * timings["rollout_s"] / n
            update_ms = 1e3 * (timings["update_s"] - timings["rollout_s"]) / n
            rows.append(dict(
                num_envs=num_envs, loop="PPO" + (f" pipelined, {parts} parts" if parts > 1 else ""),
                steps_per_s=rate, ratio=rate / alone,
                policy_ms=per_step["policy_s"], env_ms=per_step["env_s"],
                ale_ms=1e3 * env_t["ale_s"] / n, host_ms=1e3 * (env_t["ahead_s"] + env_t["host_s"]) / n,
                observe_ms=per_step["observe_s"],
                python_ms=rollout_ms - sum(per_step.values()), update_ms=update_ms,
                update_share=timings["update_s"] and (timings["update_s"] - timings["rollout_s"]) / timings["update_s"],
                warmup_s=warm_s, update_wall_s=timings["update_s"] / timings["updates"],
            ))

    table = common.markdown_table(rows, [
        ("num_envs", "envs", "d"), ("loop", "loop", "s"), ("steps_per_s", "env steps/s", ",.0f"),
        ("ratio", "vs env alone", ".2f"), ("policy_ms", "policy ms", ".2f"), ("env_ms", "env step ms", ".2f"),
        ("ale_ms", "of it ALE wait ms", ".2f"), ("host_ms", "of it host ms", ".2f"),
        ("observe_ms", "observe ms", ".2f"), ("python_ms", "rest of loop ms", ".2f"),
        ("update_ms", "update ms", ".2f"), ("update_share", "update share", ".0%"),
        ("warmup_s", "warm-up s", ".1f"),
    ])
    best = {}
    for row in rows:
        if row["loop"].startswith("PPO"):
            best[row["num_envs"]] = max(best.get(row["num_envs"], 0.0), row["ratio"])
    summary = {
        "game": args.game, "background": args.background, "ALE threads": args.threads,
        "PPO": f"{args.num_steps} steps per env per update, {args.warmup} warm-up + {args.updates} timed "
               f"updates, default PPOConfig otherwise (4 epochs x 4 minibatches), trunk "
               f"{config.trunk}" + (", xla_backend_optimization_level=0" if args.fast_compile else ""),
        "columns": "ms per batched step of all envs; update ms = the update's time over its steps",
        "target": "PPO >= 0.70 of the env alone at the same envs and threads",
        "best PPO vs env alone": ", ".join(f"{n} envs {r:.2f}" for n, r in best.items()),
        "bench seconds": f"{time.perf_counter() - started:.0f}",
        "video sources": args.video_sources or "opencv-doc",
    }
    common.record("atari_training", info, table, summary, rows, save=not args.no_record)


if __name__ == "__main__":
    main()
