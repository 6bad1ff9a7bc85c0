"""Continuous control: PPO on the MuJoCo robots from state against CleanRL's published returns,
PixelMuJoCo training throughput against the env alone, and the paper's open-loop experiment.

    python bench/continuous_control.py state [--robots Hopper HalfCheetah] [--num-envs 128 --num-steps 16]
    python bench/continuous_control.py pixels [--env-counts 1024 2048 4096 8192]
    python bench/continuous_control.py open-loop [--robots Hopper] [--algos ppo a2c] [--total-timesteps ...]
    python bench/continuous_control.py plot   # the open-loop PNG from bench/results/open_loop.jsonl

- **state**: `MuJoCo/<robot>-v0`, PPO with the MuJoCo settings of the authors' code
  (`jaxnat.agents.defaults`; observation and reward normalisation on), 5 seeds vmapped in one
  program, 1M env steps per seed. The authors' 1 env x 2048 steps is re-split as
  `--num-envs` x `--num-steps` (default 128 x 16, the same 2048-step batch) so that the GPU
  steps many envs at once. Final return: the mean training episode return over the last 5% of
  updates (CleanRL's figure is its training `episodic_return`) and the sampled policy on 10
  fresh episodes per seed, each with a 95% CI over seeds (Student's t). Reference: CleanRL's
  `ppo_continuous_action.py` at 1M steps (docs/benchmark/ppo_continuous_action.md, tag
  pr-424: 3 seeds, Gymnasium 0.28 `-v4` tasks with mujoco 2.3; jaxnat's robots follow
  Gymnasium's `-v5`, which changed Hopper's and HalfCheetah's defaults little). CleanRL gives
  no 1M-step figure for Swimmer or Ant.
- **pixels**: `PixelMuJoCo/Hopper-v0` (checker floor, 84x84x4), PPO (the paper's settings,
  `--num-steps` per update), one seed: env steps/s of whole training updates (rollout + 4
  epochs x 4 minibatches) against the env alone stepping random actions at the same env count,
  in one run. Target: training >= 50% of the env-only rate.
- **open-loop**: for each robot and algorithm, 5 seeds, observation = state / pixels (checker
  floor) / pixels (video floor) / pure noise, the same env steps each; the final training
  return (last 10% of updates) with a 95% CI, and the learning curves
  (bench/results/open_loop.png, laid out as the paper's PixelMuJoCo figure: one panel per robot).
  It prints, per robot and algorithm, whether noise lies within the CI of pixels (the claim).

Every mode takes `--physics default|fast` (the robots' `physics=` setting; `fast` trades
fidelity for speed, docs/environments.md); rows record which one ran.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import json
import sys
import time

import numpy as np

sys.path.insert(0, __import__("os").path.dirname(__file__))
import common  # noqa: E402

ROBOTS = ("Hopper", "HalfCheetah", "Swimmer", "Ant")
# CleanRL ppo_continuous_action.py, 1M steps: mean ± std over 3 seeds (Gymnasium -v4 tasks).
CLEANRL = {"HalfCheetah": (1442.64, 46.03, 3), "Hopper": (2382.86, 271.74, 3)}
OBSERVATIONS = {  # name -> PixelMuJoCo kwargs
    "state": {"observation": "state"},
    "pixels": {"observation": "pixels", "floor": "checker"},
    "pixels, video floor": {"observation": "pixels", "floor": "video"},
    "noise": {"observation": "noise"},
}


def final_training_return(metrics, fraction: float) -> np.ndarray:
    """Per seed: the mean episode return over the last `fraction` of the updates in which an
    episode ended (with many envs started together and a fixed time limit, as HalfCheetah and
    Swimmer, episodes end in a few updates only)."""
    finals = []
    for returns in np.asarray(metrics["episode_return"], np.float64):
        ended = returns[np.isfinite(returns)]
        finals.append(ended[-max(1, int(round(len(ended) * fraction))):].mean() if len(ended) else np.nan)
    return np.asarray(finals)


def compile_seeds(env, params, config, make, seeds: int, key=0):
    """Compile `seeds` vmapped trainings: (compiled program, keys, learner, compile s)."""
    import jax

    learner = make(config, env, params)
    keys = jax.random.split(jax.random.key(key), seeds)
    start = time.perf_counter()
    train = jax.jit(jax.vmap(learner.train)).lower(keys).compile()
    return train, keys, learner, time.perf_counter() - start


def run_seeds(train, keys):
    """Run a compiled training: (runner, metrics on the host, train s)."""
    import jax

    start = time.perf_counter()
    runner, metrics = jax.block_until_ready(train(keys))
    return runner, jax.device_get(metrics), time.perf_counter() - start


def train_seeds(env, params, config, make, seeds: int, key=0):
    """Compile and run `seeds` vmapped trainings: (runner, metrics, learner, compile s, train s)."""
    train, keys, learner, compile_s = compile_seeds(env, params, config, make, seeds, key)
    runner, metrics, train_s = run_seeds(train, keys)
    return runner, metrics, learner, compile_s, train_s


def state_bench(args) -> None:
    import jax
    import jaxnat
    from jaxnat.agents import config_for, make_ppo
    from jaxnat.agents.rollout import make_evaluate

    rows = []
    for robot in args.robots:
        env, params = jaxnat.make(f"MuJoCo/{robot}-v0", physics=args.physics)
        config = config_for("ppo", env, params, num_envs=args.num_envs, num_steps=args.num_steps,
                            total_timesteps=args.total_timesteps, trunk="mlp")
        runner, metrics, learner, compile_s, train_s = train_seeds(env, params, config, make_ppo, args.seeds)
        test_env, test_params = jaxnat.make(f"MuJoCo/{robot}-v0", autoreset=False, physics=args.physics)
        evaluate = jax.jit(jax.vmap(make_evaluate(learner.network, test_env, test_params, args.eval_episodes)))
        params_, normalizer = learner.policy_of(runner)
        scores = jax.device_get(evaluate(params_, jax.random.split(jax.random.key(1), args.seeds), normalizer))
        train_mean, train_ci = common.mean_ci(final_training_return(metrics, 0.05))
        sampled_mean, sampled_ci = common.mean_ci(scores["sampled_return"])
        row = {"robot": robot, "physics": args.physics, "seeds": args.seeds, "steps_per_seed": learner.num_updates * config.num_envs
               * config.num_steps, "split": f"{config.num_envs}x{config.num_steps}",
               "train_return": train_mean, "train_ci": train_ci, "eval_sampled": sampled_mean,
               "eval_sampled_ci": sampled_ci, "eval_greedy": float(np.mean(scores["greedy_return"])),
               "compile_s": compile_s, "train_s": train_s,
               "steps_per_s": args.seeds * learner.num_updates * config.num_envs * config.num_steps / train_s}
        if robot in CLEANRL:
            mean, std, n = CLEANRL[robot]
            half = common.t_half_width(std, n)
            row.update(cleanrl=mean, cleanrl_ci=half, ratio=train_mean / mean,
                       verdict="above" if train_mean > mean + half else
                       "within" if train_mean >= mean - half else "below")
        rows.append(row)
        print(json.dumps(row), flush=True)
    table = common.markdown_table(rows, [
        ("robot", "robot", ""), ("physics", "physics", ""), ("split", "envs x steps", ""), ("steps_per_seed", "steps/seed", ",d"),
        ("train_return", "final train return", ".1f"), ("train_ci", "± 95% CI", ".1f"),
        ("eval_sampled", "eval sampled", ".1f"), ("eval_sampled_ci", "± CI", ".1f"), ("eval_greedy", "eval greedy", ".1f"),
        ("cleanrl", "CleanRL 1M", ".1f"), ("cleanrl_ci", "± CI", ".1f"), ("ratio", "ratio", ".2f"), ("verdict", "vs CI", ""),
        ("train_s", "train s", ".1f"), ("compile_s", "compile s", ".1f"), ("steps_per_s", "env steps/s", ",.0f")])
    common.record("continuous_control", common.machine(), table, {
        "mode": f"state: PPO, MuJoCo settings of the authors' code, {args.seeds} seeds vmapped",
        "reference": "CleanRL ppo_continuous_action.py 1M steps, docs/benchmark/ppo_continuous_action.md (pr-424)",
        "final train return": "mean training episode return over the last 5% of the updates in which an episode ended; CI: Student's t over seeds",
    }, rows, save=not args.no_record)


def random_box_rollout(env, params, num_envs: int, num_steps: int):
    """A jitted `run(key)`: `num_steps` vmapped env steps with uniform random Box actions."""
    import jax
    import jax.numpy as jnp

    space = env.action_space(params)
    reset = jax.vmap(env.reset, in_axes=(0, None))
    step = jax.vmap(env.step, in_axes=(0, 0, 0, None))

    def run(key):
        obs, state = reset(jax.random.split(key, num_envs), params)

        def body(carry, key):
            obs, state = carry
            key_act, key_step = jax.random.split(key)
            actions = jax.random.uniform(key_act, (num_envs, *space.shape), jnp.float32, space.low, space.high)
            obs, state, reward, *_ = step(jax.random.split(key_step, num_envs), state, actions, params)
            return (obs, state), reward

        return jax.lax.scan(body, (obs, state), jax.random.split(key, num_steps))

    return jax.jit(run)


def pixels_bench(args) -> None:
    import jax
    import jaxnat
    from jaxnat.agents import PPOConfig, make_ppo

    rows = []
    env, params = jaxnat.make(f"PixelMuJoCo/{args.robot}-v0", physics=args.physics)
    for num_envs in args.env_counts:
        run = random_box_rollout(env, params, num_envs, args.num_steps)
        key = jax.random.key(0)
        jax.block_until_ready(run(key))
        env_s = common.median_seconds(lambda: jax.block_until_ready(run(key)), repeats=3)
        config = PPOConfig(total_timesteps=num_envs * args.num_steps * args.updates, num_envs=num_envs,
                           num_steps=args.num_steps, dtype=args.dtype)
        learner = make_ppo(config, env, params)
        runner = jax.jit(learner.init)(key)
        chunk = jax.jit(lambda r: learner.run(r, config, num_updates=1))
        runner, _ = jax.block_until_ready(chunk(runner))  # compile + first update
        start = time.perf_counter()
        for _ in range(args.updates - 1):
            runner, _ = chunk(runner)
        jax.block_until_ready(runner)
        train_s = (time.perf_counter() - start) / (args.updates - 1)
        row = {"robot": args.robot, "num_envs": num_envs, "num_steps": args.num_steps, "dtype": args.dtype,
               "env_only_sps": num_envs * args.num_steps / env_s, "train_sps": num_envs * args.num_steps / train_s}
        row["ratio"] = row["train_sps"] / row["env_only_sps"]
        rows.append(row)
        print(json.dumps(row), flush=True)
    table = common.markdown_table(rows, [
        ("robot", "robot", ""), ("num_envs", "envs", ",d"), ("num_steps", "steps/update", "d"), ("dtype", "trunk dtype", ""),
        ("env_only_sps", "env alone, steps/s", ",.0f"), ("train_sps", "PPO training, steps/s", ",.0f"),
        ("ratio", "training / env", ".2f")])
    common.record("continuous_control", common.machine(), table, {
        "mode": f"pixels: PixelMuJoCo checker floor 84x84x4, physics={args.physics!r}, PPO (paper settings: 4 epochs x 4 minibatches), one seed",
        "env alone": "jit(scan(vmap(step))) with uniform random actions, median of 3",
        "training": f"mean wall time of {args.updates - 1} updates after the first (compile)",
    }, rows, save=not args.no_record)


def open_loop_bench(args) -> None:
    import jaxnat
    from jaxnat.agents import ALGORITHMS, defaults

    out = common.RESULTS / "open_loop.jsonl"
    cells = []
    for robot in args.robots:
        for algo in args.algos:
            for name in args.observations:
                env, params = jaxnat.make(f"PixelMuJoCo/{robot}-v0", physics=args.physics, **OBSERVATIONS[name])
                algorithm = ALGORITHMS[algo]
                overrides = defaults.family_defaults(algo, env.observation_space(params), env.action_space(params))
                overrides.update(total_timesteps=args.total_timesteps, num_envs=args.num_envs)
                if "num_steps" in overrides or algo == "ppo":
                    overrides["num_steps"] = args.num_steps
                cells.append((robot, algo, name, env, params, algorithm.config(**overrides), algorithm.make))
    rows = []
    # Programs compile on worker threads ahead of the cell that runs (compiling is host work;
    # one process keeps the accelerator to one training at a time, so train s stays comparable).
    with concurrent.futures.ThreadPoolExecutor(max(1, args.compile_ahead)) as pool:
        compiled = [pool.submit(compile_seeds, env, params, config, make, args.seeds)
                    for _, _, _, env, params, config, make in cells]
        for (robot, algo, name, _, _, config, _), future in zip(cells, compiled):
            train, keys, learner, compile_s = future.result()
            runner, metrics, train_s = run_seeds(train, keys)
            del train, runner
            mean, half = common.mean_ci(final_training_return(metrics, 0.1))
            steps = config.num_envs * config.num_steps
            row = {"robot": robot, "algo": algo, "observation": name, "physics": args.physics, "seeds": args.seeds,
                   "steps_per_seed": learner.num_updates * steps, "final_return": mean, "ci": half,
                   "train_s": train_s, "compile_s": compile_s,
                   "curve_steps": (np.arange(1, learner.num_updates + 1) * steps).tolist(),
                   "curve": np.asarray(metrics["episode_return"]).tolist()}
            rows.append(row)
            print(json.dumps({k: v for k, v in row.items() if not k.startswith("curve")}), flush=True)
            if not args.no_record:
                with open(out, "a") as f:
                    f.write(json.dumps({"machine": common.machine(), **row}) + "\n")
    table = common.markdown_table(rows, [
        ("robot", "robot", ""), ("algo", "algo", ""), ("observation", "observation", ""), ("physics", "physics", ""),
        ("steps_per_seed", "steps/seed", ",d"), ("final_return", "final return", ".1f"), ("ci", "± 95% CI", ".1f"),
        ("train_s", "train s", ".1f")])
    claims = open_loop_claims(rows)
    for line in claims:
        print(line, flush=True)
    common.record("continuous_control", common.machine(), table, {
        "mode": f"open-loop: PixelMuJoCo, {args.seeds} seeds, state / pixels / pixels with a video floor / pure noise, "
                f"physics={args.physics!r}, {args.num_envs} envs x {args.num_steps} steps per update",
        "the paper's claim (noise within the CI of pixels)": "; ".join(claims) or "no pixels and noise pair run",
        "final return": "mean training episode return over the last 10% of the updates in which an episode ended; CI: Student's t over seeds",
        "curves": "bench/results/open_loop.jsonl; python bench/continuous_control.py plot",
    }, [{k: v for k, v in r.items() if not k.startswith("curve")} for r in rows], save=not args.no_record)


def open_loop_claims(rows) -> list[str]:
    """Per robot and algorithm: whether the pure-noise policy's final return lies within the
    95% CI of the pixel policy's (checker floor), the paper's open-loop claim."""
    found = {(r["robot"], r["algo"], r["observation"]): r for r in rows}
    claims = []
    for (robot, algo, name), noise in found.items():
        pixels = found.get((robot, algo, "pixels"))
        if name != "noise" or pixels is None:
            continue
        within = abs(noise["final_return"] - pixels["final_return"]) <= pixels["ci"]
        claims.append(f"{robot} {algo}: noise {noise['final_return']:.1f} vs pixels {pixels['final_return']:.1f} "
                      f"± {pixels['ci']:.1f}: {'within' if within else 'not within'}")
    return claims


def plot(args) -> None:
    """bench/results/open_loop.png from the newest open-loop row of each condition."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    latest = {}
    for line in (common.RESULTS / "open_loop.jsonl").read_text().splitlines():
        row = json.loads(line)
        latest[(row["robot"], row["algo"], row["observation"])] = row
    robots = [r for r in ROBOTS if any(k[0] == r for k in latest)]
    algos = sorted({k[1] for k in latest})
    fig = Figure(figsize=(max(6.0, 3.2 * len(robots)), 2.8 * len(algos) + 0.4), constrained_layout=True)
    FigureCanvasAgg(fig)
    axes = np.atleast_2d(fig.subplots(len(algos), len(robots), squeeze=False))
    for i, algo in enumerate(algos):
        for j, robot in enumerate(robots):
            ax = axes[i, j]
            for name in OBSERVATIONS:
                row = latest.get((robot, algo, name))
                if row is None:
                    continue
                curve = np.asarray(row["curve"], np.float64)
                with np.errstate(all="ignore"):
                    mean, std = np.nanmean(curve, 0), np.nanstd(curve, 0)
                # Updates in which no episode ended are NaN (fixed-length episodes end together).
                steps, ended = np.asarray(row["curve_steps"]), np.isfinite(mean)
                line, = ax.plot(steps[ended], mean[ended], label=name, linewidth=1)
                ax.fill_between(steps[ended], (mean - std)[ended], (mean + std)[ended], alpha=0.2,
                                color=line.get_color())
            ax.set_title(f"{robot} · {algo.upper()}")
            ax.set_xlabel("env steps per seed")
            ax.set_ylabel("training episode return")
            ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize="small")
    physics = sorted({row.get("physics", "default") for row in latest.values()})
    fig.suptitle(f"PixelMuJoCo: state, pixels and pure noise\n(mean ± std over seeds; physics {', '.join(physics)})")
    path = common.RESULTS / "open_loop.png"
    fig.savefig(path, dpi=100)
    print(path)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="mode", required=True)
    state = sub.add_parser("state")
    state.add_argument("--robots", nargs="*", default=list(ROBOTS))
    state.add_argument("--seeds", type=int, default=5)
    state.add_argument("--total-timesteps", type=int, default=1_000_000)
    state.add_argument("--num-envs", type=int, default=128)
    state.add_argument("--num-steps", type=int, default=16)
    state.add_argument("--eval-episodes", type=int, default=10)
    pixels = sub.add_parser("pixels")
    pixels.add_argument("--robot", default="Hopper")
    pixels.add_argument("--env-counts", type=int, nargs="*", default=[1024, 2048, 4096, 8192])
    pixels.add_argument("--num-steps", type=int, default=16)
    pixels.add_argument("--updates", type=int, default=3)
    pixels.add_argument("--dtype", default="bfloat16")
    loop = sub.add_parser("open-loop")
    loop.add_argument("--robots", nargs="*", default=list(ROBOTS))
    loop.add_argument("--algos", nargs="*", default=["ppo", "a2c"])
    loop.add_argument("--observations", nargs="*", default=list(OBSERVATIONS))
    loop.add_argument("--seeds", type=int, default=5)
    loop.add_argument("--total-timesteps", type=int, default=1_000_000)
    loop.add_argument("--num-envs", type=int, default=64)
    loop.add_argument("--num-steps", type=int, default=32)
    loop.add_argument("--compile-ahead", type=int, default=3,
                      help="programs compiled at once on worker threads while a cell trains")
    sub.add_parser("plot")
    for p in (state, pixels, loop):
        p.add_argument("--physics", default="default", choices=["default", "fast"],
                       help="the robot's physics= setting (mjx_pixel/base.py)")
        p.add_argument("--no-record", action="store_true")
    args = parser.parse_args(argv)
    {"state": state_bench, "pixels": pixels_bench, "open-loop": open_loop_bench, "plot": plot}[args.mode](args)


if __name__ == "__main__":
    main()
