"""PPO from pixels end to end, the env alone beside it, and where an update's time goes.

    python bench/pixel_ppo.py [--robots HalfCheetah Hopper] [--observations checker video noise]
        [--total-envs 1024 4096 16384] [--seeds 5] [--dtypes float32 bfloat16] [--convs s2d unrolled]
        [--impls jax warp] [--compaction on off]

For each robot, observation, total env count (split over `--seeds` vmapped seeds, as
`jaxnat train --seeds` and `jaxnat reproduce` run them), trunk dtype and convolution form
(`jaxnat.agents.conv`), physics implementation (`--impls`: MJX's JAX implementation, or
MuJoCo Warp, `physics_impl="warp"`) and compaction (`--compaction`: "on", the default, resets
the few envs of a step that ended and values their final observations alone, up to the
library's shares of the batch (`AutoResetWrapper.reset_share`, `FINAL_VALUE_SHARE`); a number
sets both shares; "off" computes both for every env in a step where any ended), one row:

- **compile s**: lowering and compiling the training program, and the env alone's program
  beside it (the first row compiles alone; later rows compile side by side on
  `--compile-ahead` threads while another row runs, so theirs are upper bounds) (`--updates` PPO updates of every
  seed in one `lax.scan`, as a chunk of `jaxnat train`);
- **train steps/s**: env steps per second of that program, timed on its second call, at the
  paper profile's PixelMuJoCo PPO settings (`jaxnat.reproduce.grid.PAPER_SCALE`: 16 steps per
  env per update, 4 epochs x 4 minibatches, normalised rewards);
- **env alone steps/s**: the same envs (all seeds' in one batch) stepping uniform random actions
  in `jit(scan(vmap(step)))`, in the same run; **train / env** is the issue's ratio;
- **phases** (`--phases`, each jitted alone, vmapped over seeds, seconds per update): the rollout
  (env steps plus acting), acting alone (the policy's forward pass on the rollout's batches,
  N per step: with compaction on, a step values the previous step's truncated final
  observations alone, a few rows, in the same call; off, every row in such a step),
  and the update's GAE and epochs (the end-to-end update time less the rollout's; the bench
  reads the runner only through its learner, as code outside the agents must). Rollout minus
  acting is the env inside the learner;
- **learner TFLOP/s**: the update's convolution and dense FLOPs (3x the trunk's forward FLOPs
  per sample per epoch: forward, and backward for inputs and weights; XLA:CPU's cost analysis
  of one forward pass, which counts XLA's own convolutions) over the update's time.

Each robot is `PixelMuJoCo/<robot>-v0` with `physics="fast"` (`--physics`); observations
`checker` and `video` are the 84x84x4 pixel frames on those floors, `noise` is pure-noise
pixels of the same shape.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import json
import sys
import time

sys.path.insert(0, __import__("os").path.dirname(__file__))
import common  # noqa: E402
from continuous_control import random_box_rollout  # noqa: E402

from jaxnat.agents.conv import IMPLEMENTATIONS  # noqa: E402

ROBOTS = ("HalfCheetah", "Hopper", "Swimmer", "Ant")
OBSERVATIONS = {"checker": {"observation": "pixels", "floor": "checker"},
                "video": {"observation": "pixels", "floor": "video"},
                "noise": {"observation": "noise"}}


def ppo_config(envs_per_seed: int, updates: int, dtype: str):
    """The paper profile's PixelMuJoCo PPO settings at this batch."""
    from jaxnat.agents import PPOConfig
    from jaxnat.reproduce.grid import PAPER_SCALE

    scale = PAPER_SCALE["mujoco"]
    settings = {**scale["ppo"], "normalize_rewards": scale["normalize_rewards"], "dtype": dtype}
    return PPOConfig(total_timesteps=envs_per_seed * settings["num_steps"] * updates, num_envs=envs_per_seed,
                     **settings)


def learner_for(config, env, params, conv: str, compaction: str = "on"):
    """PPO's learner with the trunk's convolutions computed as `conv`; `compaction="off"`
    values every final observation in a step where any env truncated (`final_value_share`)."""
    from jaxnat.agents import ppo
    from jaxnat.agents.rollout import dtype_and_memory, on_policy_learner
    from jaxnat.agents.rollout.on_policy import FINAL_VALUE_SHARE

    rule = ppo.RULE._replace(network_options=lambda config: {**dtype_and_memory(config), "conv": conv})
    share = compaction_share(compaction, FINAL_VALUE_SHARE)
    return on_policy_learner(config, env, params, rule, final_value_share=share)


def compaction_share(compaction: str, default: float):
    """The share a `--compaction` value means: "on" the library's `default`, "off" None (no
    compacted branch), a number that share."""
    if compaction in ("on", "off"):
        return default if compaction == "on" else None
    return float(compaction)


def seconds(fn, *args, repeats: int = 3) -> float:
    """Median seconds of `fn(*args)` after a first call."""
    import jax

    jax.block_until_ready(fn(*args))
    return common.median_seconds(lambda: jax.block_until_ready(fn(*args)), repeats=repeats)


def prepare(args, robot: str, observation: str, total_envs: int, dtype: str, conv: str, impl: str,
            compaction: str) -> dict:
    """One row's programs, compiled from shapes alone (no device work, so rows compile on
    worker threads while another row runs): the row's settings and `programs`."""
    import jax
    import jax.numpy as jnp

    import jaxnat
    from jaxnat.wrappers import AutoResetWrapper

    env, params = jaxnat.make(f"PixelMuJoCo/{robot}-v0", physics=args.physics, physics_impl=impl,
                              autoreset=False, **OBSERVATIONS[observation])
    env = AutoResetWrapper(env, reset_share=compaction_share(compaction, AutoResetWrapper(env).reset_share))
    per_seed = total_envs // args.seeds
    config = ppo_config(per_seed, args.updates, dtype)
    row = {"robot": robot, "observation": observation, "seeds": args.seeds, "envs_per_seed": per_seed,
           "total_envs": per_seed * args.seeds, "num_steps": config.num_steps, "dtype": dtype, "conv": conv,
           "physics_impl": impl, "compaction": compaction}
    learner = learner_for(config, env, params, conv, compaction)
    keys = jax.eval_shape(lambda: jax.random.split(jax.random.key(1), args.seeds))
    init = jax.jit(jax.vmap(learner.init))
    runner = jax.eval_shape(init, keys)
    start = time.perf_counter()
    programs = {"env": random_box_rollout(env, params, row["total_envs"], config.num_steps)
                .lower(jax.eval_shape(lambda: jax.random.key(0))).compile()}
    row["env_compile_s"] = time.perf_counter() - start
    programs["init"] = init.lower(keys).compile()
    chunk = jax.jit(jax.vmap(lambda r: learner.run(r, config, num_updates=args.updates)), donate_argnums=0)
    start = time.perf_counter()
    programs["chunk"] = chunk.lower(runner).compile()
    row["compile_s"] = time.perf_counter() - start
    network = learner.network
    seeds_params = learner.policy_of(runner)[0]  # the runner is read through its learner only
    one_seed = jax.tree_util.tree_map(lambda x: jax.ShapeDtypeStruct(x.shape[1:], x.dtype), seeds_params)
    row["forward_mflop"] = common.forward_mflop(network, one_seed, env.observation_space(params))
    if args.phases:
        rollout = jax.jit(jax.vmap(lambda r: learner.rollout(r, config)))
        programs["rollout"] = rollout.lower(runner).compile()
        _, transitions = jax.eval_shape(rollout, runner)
        programs["acting"] = jax.jit(jax.vmap(lambda p, o: jax.lax.map(
            lambda x: network.apply(p, x)[1].sum(), o))).lower(
                seeds_params, transitions.obs).compile()
    programs["policy_of"] = learner.policy_of
    row["programs"] = programs
    return row


def measure(args, row: dict) -> dict:
    """Run a prepared row's programs and fill in its rates."""
    import jax

    from jaxnat.agents import ppo

    programs = row.pop("programs")
    steps_per_update = row["total_envs"] * row["num_steps"]
    row["env_sps"] = steps_per_update / seconds(programs["env"], jax.random.key(0))
    keys = jax.random.split(jax.random.key(1), args.seeds)
    runner = programs["init"](keys)
    runner, _ = jax.block_until_ready(programs["chunk"](runner))
    start = time.perf_counter()
    runner, _ = jax.block_until_ready(programs["chunk"](runner))
    row["update_s"] = (time.perf_counter() - start) / args.updates
    row["train_sps"] = steps_per_update / row["update_s"]
    row["train_over_env"] = row["train_sps"] / row["env_sps"]
    if args.trace:
        import tempfile

        with tempfile.TemporaryDirectory() as trace_dir:
            with jax.profiler.trace(trace_dir, create_perfetto_trace=True):
                runner, _ = jax.block_until_ready(programs["chunk"](runner))
            row["top_kernels"] = common.device_kernels(trace_dir, args.updates)[:20]
        for name, ms, share in row["top_kernels"]:
            print(f"    {ms:9.2f} ms/update {share:6.1%}  {name[:110]}", flush=True)
    learner_flop = 3 * row["forward_mflop"] * 1e6 * ppo.PPOConfig.update_epochs * steps_per_update
    if args.phases:
        row["rollout_s"] = seconds(programs["rollout"], runner)
        _, transitions = programs["rollout"](runner)
        row["acting_s"] = seconds(programs["acting"], programs["policy_of"](runner)[0], transitions.obs)
        # The update's GAE and epochs: the whole update less its rollout.
        row["learn_s"] = row["update_s"] - row["rollout_s"]
        row["learner_tflops"] = learner_flop / row["learn_s"] / 1e12
        del transitions
    row["end_to_end_tflops"] = (learner_flop + 2 * row["forward_mflop"] * 1e6 * steps_per_update) / row["update_s"] / 1e12
    return row


def compaction_value(text: str) -> str:
    """A `--compaction` value: "on", "off" or a share in (0, 1]."""
    if text in ("on", "off"):
        return text
    try:
        share = float(text)
    except ValueError:
        share = -1.0
    if not 0.0 < share <= 1.0:
        raise argparse.ArgumentTypeError(f"{text!r}: expected on, off or a share in (0, 1]")
    return text


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--robots", nargs="+", default=["HalfCheetah", "Hopper"], choices=ROBOTS)
    parser.add_argument("--observations", nargs="+", default=["checker"], choices=list(OBSERVATIONS))
    parser.add_argument("--total-envs", nargs="+", type=int, default=[1024, 4096, 16384])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--dtypes", nargs="+", default=["float32", "bfloat16"], choices=["float32", "bfloat16"])
    parser.add_argument("--convs", nargs="+", default=["s2d", "unrolled"], choices=IMPLEMENTATIONS)
    parser.add_argument("--impls", nargs="+", default=["jax"], choices=["jax", "warp"],
                        help="who steps the physics: MJX's JAX implementation or MuJoCo Warp")
    parser.add_argument("--compaction", nargs="+", default=["on"], type=compaction_value,
                        help="on: resets and final values of the few envs that ended computed "
                             "alone (`jaxnat.gating`, the library's shares); a number in (0, 1]: "
                             "that share of a batch for both; off: for every env in a step where any ended")
    parser.add_argument("--updates", type=int, default=3, help="PPO updates per timed program call")
    parser.add_argument("--physics", default="fast", choices=["fast", "default"])
    parser.add_argument("--phases", action=argparse.BooleanOptionalAction, default=True,
                        help="also time the rollout, acting and update alone")
    parser.add_argument("--trace", action="store_true",
                        help="profile one program call per row and print its top device kernels")
    parser.add_argument("--compile-ahead", type=int, default=4,
                        help="rows compiled at once on worker threads (compiling is host work)")
    parser.add_argument("--no-record", action="store_true")
    args = parser.parse_args(argv)
    start = time.perf_counter()
    specs = [(robot, observation, total_envs, dtype, conv, impl, compaction) for robot in args.robots
             for observation in args.observations
             for total_envs in args.total_envs for dtype in args.dtypes for conv in args.convs
             for impl in args.impls for compaction in args.compaction]
    rows = []
    first = prepare(args, *specs[0])  # alone: its compile time is the clean one
    with concurrent.futures.ThreadPoolExecutor(max(1, args.compile_ahead)) as pool:
        futures = [pool.submit(prepare, args, *spec) for spec in specs[1:]]
        for prepared in [first, *(future.result() for future in futures)]:
            try:
                row = measure(args, prepared)
            except Exception as error:  # a row too big for the device is a row of the table, not the end of the run
                if "RESOURCE_EXHAUSTED" not in str(error):
                    raise
                prepared.pop("programs", None)
                row = {**prepared, "outcome": "out of device memory"}
            rows.append(row)
            print(json.dumps({k: v for k, v in row.items() if k != "top_kernels"}), flush=True)
    table = common.markdown_table(rows, [
        ("robot", "robot", ""), ("observation", "observation", ""), ("total_envs", "envs (all seeds)", ",d"),
        ("dtype", "trunk dtype", ""), ("conv", "conv", ""), ("physics_impl", "physics", ""),
        ("compaction", "compaction", ""), ("compile_s", "compile s", ".0f"),
        ("env_compile_s", "env compile s", ".0f"),
        ("env_sps", "env alone steps/s", ".3e"), ("train_sps", "train steps/s", ".3e"),
        ("train_over_env", "train / env", ".2f"), ("update_s", "update s", ".3f"), ("rollout_s", "rollout s", ".3f"),
        ("acting_s", "acting s", ".3f"), ("learn_s", "learn s", ".3f"),
        ("learner_tflops", "learner TFLOP/s", ".1f"), ("end_to_end_tflops", "end-to-end TFLOP/s", ".1f"),
        ("outcome", "outcome", "")])
    best = {}
    for row in (r for r in rows if "train_sps" in r):
        key = f"{row['robot']} {row['observation']} compaction {row['compaction']}"
        if key not in best or row["train_sps"] > best[key]["train_sps"]:
            best[key] = row
    summary = {
        "settings": f"PixelMuJoCo physics={args.physics!r}, 84x84x4 frames; PPO at the paper profile's PixelMuJoCo "
                    f"settings ({args.seeds} seeds vmapped, 16 steps per env, 4 epochs x 4 minibatches, "
                    f"normalised rewards); {args.updates} updates per timed call",
        "best train steps/s": {k: f"{r['train_sps']:.3e} ({r['total_envs']} envs, {r['dtype']}, {r['conv']}, "
                                  f"{r['physics_impl']} physics, "
                                  f"train/env {r['train_over_env']:.2f})" for k, r in best.items()},
        "target": "issue 40: >= 5e5 env steps/s end to end, training >= 50% of the env alone, compile <= 60 s",
        "bench_seconds": round(time.perf_counter() - start),
    }
    common.record("pixel_ppo", common.machine(), table, summary, rows, save=not args.no_record)


if __name__ == "__main__":
    main()
