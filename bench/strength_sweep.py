"""Train at several distraction strengths in one program, test on a finer grid: a train x test matrix.

PPO is trained at each of `--train` strengths of one dial field (`--param`, default PixelMuJoCo's
`video_alpha`: 0 the checker floor, 1 the video floor) for `--seeds` seeds, all in ONE jitted
program (`jaxnat.training.make_strength_train`: seeds x strengths, each strength's seeds from
the same keys). Each trained (strength, seed) policy then plays `--episodes` test episodes (the
test split: held-out videos) at each of `--test` strengths, again in one program
(`trained.episode_program` vmapped over policies, test strengths and episodes; greedy actions,
or sampled ones with `--sampled`).
The table is the matrix: per train strength and test strength, the mean return over seeds
(each seed's mean over its episodes) with its 95% t-interval over seeds; the figure
(`bench/results/strength_sweep_<family>.png`) is its heat map.

Side by side, in the same run: the strengths trained one after another, each as its own
program (`make_sharded_train` per strength, compiled each time, as separate runs are), and the
wall time of both ways (compiling included); `--no-levels` skips them.

    python bench/strength_sweep.py                                          # PixelMuJoCo HalfCheetah, 3 x 5 seeds, 2M steps
    python bench/strength_sweep.py --env-id NaturalAtari/Breakout-v0 --env-kwargs background=video \\
        preprocessing=deepmind --seeds 2 --num-envs 64 --num-steps 32 --total-timesteps 1500000 \\
        --episodes 8 --max-steps 1000 --parallel 3                          # host envs: a run per strength
    JAX_PLATFORMS=cpu python bench/strength_sweep.py --env-id Classify/Digits-v0 --env-kwargs --param noise_sigma \\
        --train 0 64 --test 0 32 64 --seeds 2 --num-envs 4 --num-steps 8 --total-timesteps 64 --episodes 4 --no-record

Natural Atari (ALE on the host) cannot put its strengths in one program: there each train strength
is one `jaxnat train` run in a temporary folder (`--parallel N`: N runs at once, each in its own
process with 1/N of the host's cores for ALE), and each seed's policy (`jaxnat.trained.load_policy`)
plays `--episodes` whole greedy test games at each test strength, all at once on a batch of that
many envs (`trained.host_episodes`, the same game seeds at every strength). The matrix, table
and figure are the same; the wall times are the runs' and the games'.

Records to `bench/results/strength_sweep.{md,jsonl}` (and the figure) unless `--no-record`.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))


def parse(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--env-id", default="PixelMuJoCo/HalfCheetah-v0")
    parser.add_argument("--env-kwargs", nargs="*", default=["floor=video", "physics=fast"], metavar="KEY=VALUE")
    parser.add_argument("--param", default="video_alpha", help="the dial field to train and test over")
    parser.add_argument("--train", type=float, nargs="+", default=[0.0, 0.5, 1.0], help="training strengths")
    parser.add_argument("--test", type=float, nargs="+", default=[round(0.1 * i, 1) for i in range(11)],
                        help="test strengths")
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--total-timesteps", type=int, default=2_000_000, help="env steps per seed")
    parser.add_argument("--num-envs", type=int, default=1024, help="envs per seed and strength")
    parser.add_argument("--num-steps", type=int, default=16)
    parser.add_argument("--dtype", default=None, help="the trunk's dtype (default: bfloat16 on a GPU, float32 else)")
    parser.add_argument("--episodes", type=int, default=32, help="test episodes per policy and test strength")
    parser.add_argument("--max-steps", type=int, default=None,
                        help="host envs: the env's `max_episode_steps` in training and test games (default: the "
                             "env's, 27,000: a greedy policy that never serves plays Breakout that long)")
    parser.add_argument("--no-levels", action="store_true", help="skip training the strengths one after another")
    parser.add_argument("--sampled", action="store_true",
                        help="test with sampled actions (default: greedy; a greedy Atari policy can ignore the screen)")
    parser.add_argument("--parallel", type=int, default=1,
                        help="host envs: train strengths run at once, each in its own process (ALE's threads shared)")
    parser.add_argument("--no-record", action="store_true")
    args = parser.parse_args(argv)
    for name in ("seeds", "total_timesteps", "num_envs", "num_steps", "episodes"):
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} must be at least 1, got {getattr(args, name)}")
    return args


def ppo_config(args, env, params, gpu: bool):
    """PixelMuJoCo's paper-profile PPO settings (`reproduce.grid.PAPER_SCALE`'s) at this batch."""
    from jaxnat.agents import PPOConfig
    from jaxnat.agents.networks import default_trunk

    return PPOConfig(num_envs=args.num_envs, num_steps=args.num_steps, total_timesteps=args.total_timesteps,
                     normalize_rewards=True, ent_coef=0.0, clip_eps=0.2, lr=3e-4,
                     dtype=args.dtype or ("bfloat16" if gpu else "float32"),
                     trunk=default_trunk(env.observation_space(params)))


def final_return(curves) -> float:
    """The mean training return of the last 10% of each seed's updates that ended an episode
    (`curves[seed]`: a return per update, nan where none ended: PixelMuJoCo's 1,000-step
    episodes end in few updates); nan where no episode ended at all."""
    last = []
    for curve in curves:
        ended = np.asarray(curve, np.float64)
        ended = ended[np.isfinite(ended)]
        last.extend(ended[-max(1, len(ended) // 10):])
    return float(np.mean(last)) if last else float("nan")


def matrix_rows(returns: np.ndarray, train: list[float], test: list[float], common) -> list[dict]:
    """Rows of the matrix from `returns[train, seed, test, episode]`: per train and test strength
    the mean over seeds of each seed's mean over episodes, with its 95% t-interval over seeds."""
    per_seed = returns.mean(axis=-1)  # [train, seed, test]
    rows = []
    for i, a in enumerate(train):
        for j, b in enumerate(test):
            mean, half = common.mean_ci(per_seed[i, :, j])
            rows.append({"train": a, "test": b, "mean": mean, "low": mean - half, "high": mean + half})
    return rows


def heat_map(rows: list[dict], train: list[float], test: list[float], param: str, env_id: str, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    grid = np.array([[r["mean"] for r in rows if r["train"] == a] for a in train])
    fig, ax = plt.subplots(figsize=(1 + 0.6 * len(test), 1 + 0.6 * len(train)))
    image = ax.imshow(grid, aspect="auto", cmap="viridis")
    ax.set_xticks(range(len(test)), [f"{v:g}" for v in test])
    ax.set_yticks(range(len(train)), [f"{v:g}" for v in train])
    ax.set_xlabel(f"test {param}")
    ax.set_ylabel(f"train {param}")
    ax.set_title(f"{env_id}: test return (mean over seeds)", fontsize=9)
    for i in range(len(train)):
        for j in range(len(test)):
            value = grid[i, j]
            ax.text(j, i, f"{value:.0f}" if abs(value) >= 10 else f"{value:.2g}", ha="center", va="center",
                    fontsize=7, color="w")
    fig.colorbar(image, ax=ax)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv=None) -> int:
    args = parse(argv)
    import jax
    import jax.numpy as jnp

    import common
    import jaxnat
    from jaxnat.agents import ALGORITHMS
    from jaxnat.trained import TrainedPolicy, episode_limit, episode_program, policy_step
    from jaxnat.training import make_sharded_train, make_strength_train, parse_env_kwargs
    from jaxnat.training.device_backend import split_argument

    info = common.machine()
    if jaxnat.spec(args.env_id).batched:
        return host_sweep(args, info, common)
    kwargs = parse_env_kwargs(args.env_kwargs, args.env_id)
    env, params = jaxnat.make(args.env_id, **kwargs)
    split = split_argument(args.env_id, kwargs)  # `split`, or PixelMuJoCo's `video_split`: held-out data
    test_env, test_params = jaxnat.make(args.env_id, **kwargs, **({split: "test"} if split else {}))
    config = ppo_config(args, env, params, info["backend"] == "gpu")
    keys = jax.vmap(jax.random.key)(jnp.arange(args.seeds))
    train_values = {args.param: jnp.asarray(args.train, jnp.float32)}

    start = time.perf_counter()
    runner, metrics = jax.block_until_ready(make_strength_train("ppo", config, env, params, **train_values)(keys))
    sweep_s = time.perf_counter() - start
    print(f"{len(args.train)} strengths x {args.seeds} seeds in one program: {sweep_s:.1f} s", flush=True)
    levels_s = None
    if not args.no_levels:
        start = time.perf_counter()
        for value in args.train:
            alone = params.replace(distraction=params.distraction.replace(**{args.param: jnp.float32(value)}))
            jax.block_until_ready(make_sharded_train("ppo", config, env, alone, seeds=args.seeds)(keys))
        levels_s = time.perf_counter() - start
        print(f"the same strengths one after another: {levels_s:.1f} s", flush=True)

    learner = ALGORITHMS["ppo"].make(config, env, params)
    policy_params, normalizer = learner.policy_of(runner)  # leading axes [train strength, seed]
    policy = TrainedPolicy(run_dir=Path("."), env_id=args.env_id, env_kwargs=kwargs, algo="ppo", config=config,
                           split="test", env=test_env, env_params=test_params, seed_index=0, seed_value=0, update=0,
                           network=learner.network, params=None, normalization=None,
                           apply=policy_step(learner.network, test_env.action_space(test_params)), _act=None)
    swept, axes = test_params.sweep(**{args.param: jnp.asarray(args.test, jnp.float32)})
    getattr(test_env, "check_params", lambda _: None)(swept)
    episode = episode_program(policy, episode_limit(policy), not args.sampled)
    per_test = jax.vmap(jax.vmap(episode, in_axes=(None, None, None, 0)), in_axes=(None, None, axes, None))
    play = jax.jit(jax.vmap(jax.vmap(per_test, in_axes=(0, 0, None, None)), in_axes=(0, 0, None, None)))
    start = time.perf_counter()
    results = jax.device_get(play(policy_params, normalizer, swept, jax.random.split(jax.random.key(1), args.episodes)))
    eval_s = time.perf_counter() - start
    returns = np.asarray(results["return"], np.float64)  # [train, seed, test, episode]
    rows = matrix_rows(returns, args.train, args.test, common)
    train_curve = np.asarray(metrics["episode_return"], np.float64)  # [train, seed, updates]

    times = {"one program (seeds x strengths)": f"{sweep_s:.1f} s, compiling included",
             "strengths one after another": "not run" if levels_s is None else
             f"{levels_s:.1f} s ({levels_s / sweep_s:.2f}x the one program's time)",
             "evaluation (one program)": f"{eval_s:.1f} s"}
    finals = [final_return(train_curve[i]) for i in range(len(args.train))]
    record(args, info, rows, args.env_kwargs, f", {config.dtype}", "episodes", times, finals,
           {"sweep_s": sweep_s, "levels_s": levels_s, "eval_s": eval_s})
    return 0


def host_sweep(args, info, common) -> int:
    """The matrix for a host-emulated env (Natural Atari): a `jaxnat train` run per train
    strength (`--parallel` of them at once, each in its own process with its share of the
    host's cores for ALE), then every seed's greedy test games at every test strength, the
    `--episodes` games of a strength at once on a batch of that many envs."""
    import concurrent.futures
    import multiprocessing
    import os
    import tempfile

    from jaxnat.training import parse_env_kwargs

    env_kwargs = [*args.env_kwargs, *([f"max_episode_steps={args.max_steps}"] if args.max_steps else [])]
    kwargs = parse_env_kwargs(env_kwargs, args.env_id)
    if args.param in kwargs:
        sys.exit(f"strength_sweep.py: --env-kwargs sets {args.param}, the swept field; leave it out")
    if args.parallel > 1 and "num_threads" not in kwargs:  # ALE's threads: the cores shared out
        env_kwargs.append(f"num_threads={max(1, (os.cpu_count() or 1) // args.parallel)}")
    # Several processes on one GPU: each takes the memory it needs, not XLA's default share.
    os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="strength_sweep-") as folder:
        jobs = [(args, env_kwargs, value, str(Path(folder) / f"train-{value:g}")) for value in args.train]
        if args.parallel > 1:
            context = multiprocessing.get_context("spawn")  # no fork of a process that runs JAX
            with concurrent.futures.ProcessPoolExecutor(args.parallel, mp_context=context) as pool:
                done = list(pool.map(host_strength, *zip(*jobs)))
        else:
            done = [host_strength(*job) for job in jobs]
    wall_s = time.perf_counter() - start
    returns = np.stack([d["returns"] for d in done])  # [train, seed, test, episode]
    train_s, eval_s = sum(d["train_s"] for d in done), sum(d["eval_s"] for d in done)
    rows = matrix_rows(returns, args.train, args.test, common)
    at_once = f"{args.parallel} runs at once" if args.parallel > 1 else "one run after another"
    times = {f"wall time (training and tests; {at_once})": f"{wall_s:.1f} s",
             "training (a jaxnat train run per strength, ALE on the host; summed over runs)": f"{train_s:.1f} s",
             f"tests ({args.episodes} games at once per seed and test strength; summed over runs)": f"{eval_s:.1f} s"}
    record(args, info, rows, env_kwargs, "", "games", times, [d["train_last"] for d in done],
           {"wall_s": wall_s, "train_s": train_s, "eval_s": eval_s})
    return 0


def host_strength(args, env_kwargs: list[str], value: float, run_dir: str) -> dict:
    """One train strength of `host_sweep`: its `jaxnat train` run in `run_dir`, then each seed's
    greedy test games at every test strength; `returns[seed, test, episode]`, the mean training
    return (`final_return`), the seconds."""
    import dataclasses

    import jax

    import jaxnat
    from jaxnat.trained import host_episodes, load_policy
    from jaxnat.training import parse_args, parse_env_kwargs, read_run, train

    argv = ["--env-id", args.env_id, "--algo", "ppo", "--seeds", str(args.seeds), "--num-envs", str(args.num_envs),
            "--num-steps", str(args.num_steps), "--total-timesteps", str(args.total_timesteps), "--eval-episodes", "1",
            "--run-dir", run_dir, "--env-kwargs", *env_kwargs, f"{args.param}={value:g}"]
    start = time.perf_counter()
    train(parse_args(argv))
    train_s = time.perf_counter() - start
    per_seed = {}
    for row in read_run(Path(run_dir)).metrics:
        ended = row.get("episode_return")
        per_seed.setdefault(row["seed"], []).append(np.nan if ended is None else ended)
    kwargs = parse_env_kwargs(env_kwargs, args.env_id)
    returns = np.zeros((args.seeds, len(args.test), args.episodes))
    start = time.perf_counter()
    policies = [load_policy(Path(run_dir), seed=seed) for seed in range(args.seeds)]
    for policy in policies:
        policy.env.close()  # its one-game batch: the games are played on a batch per strength
    for j, test in enumerate(args.test):
        env = jaxnat.make_vec(args.env_id, args.episodes, split="test", **{**kwargs, args.param: test})
        try:  # the same key at every strength: the same games
            for seed, policy in enumerate(policies):
                games = host_episodes(dataclasses.replace(policy, env=env), jax.random.key(1), args.episodes,
                                      greedy=not args.sampled)
                returns[seed, j] = games["return"]
        finally:
            env.close()
    eval_s = time.perf_counter() - start
    print(f"train {args.param}={value:g}: trained {train_s:.1f} s, tested {eval_s:.1f} s", flush=True)
    return {"returns": returns, "train_last": final_return(list(per_seed.values())),
            "train_s": train_s, "eval_s": eval_s}


def figure_name(env_id: str) -> str:
    """The heat map's file: one per env family (`strength_sweep_pixelmujoco.png`, ...)."""
    return f"strength_sweep_{env_id.split('/')[0].lower()}.png"


def record(args, info, rows: list[dict], env_kwargs: list[str], dtype: str, played: str, times: dict,
           finals: list[float], extras: dict) -> None:
    """Print the matrix and its summary, and (unless `--no-record`) write the heat map and append
    both to `bench/results/strength_sweep.*`: `times` the wall times by what they timed,
    `finals` each train strength's final training return, `extras` the timings in every row."""
    import common

    if not args.no_record:
        heat_map(rows, args.train, args.test, args.param, args.env_id, common.RESULTS / figure_name(args.env_id))
    table = common.markdown_table(rows, [("train", f"train {args.param}", "g"), ("test", f"test {args.param}", "g"),
                                         ("mean", "test return", ".1f"), ("low", "95% low", ".1f"),
                                         ("high", "95% high", ".1f")])
    mode = "sampled" if args.sampled else "greedy"
    summary = {
        "workload": (f"PPO on {args.env_id} ({' '.join(env_kwargs) or 'defaults'}), {args.seeds} seeds x "
                     f"{len(args.train)} train strengths of {args.param}, {args.num_envs} envs x {args.num_steps} steps, "
                     f"{args.total_timesteps:,} env steps per seed{dtype}; tested {mode} on the test split, "
                     f"{args.episodes} {played} per policy and test strength"),
        **times,
        "train return, last 10% of the updates that ended an episode, per train strength": ", ".join(
            f"{a:g}: {r:.1f}" for a, r in zip(args.train, finals)),
        "figure": f"bench/results/{figure_name(args.env_id)}" if not args.no_record else "not written (--no-record)",
    }
    common.record("strength_sweep", info, table, summary, [{**r, **extras} for r in rows], save=not args.no_record)

if __name__ == "__main__":
    sys.exit(main())
