"""PPO on `Localize/Clutter-v0`: success rate on the test split (held-out scenes and objects).

Trains PPO with the paper's Cityscapes trunk and a goal embedding (`jaxnat.agents.networks`),
several seeds vmapped, in chunks; after each chunk every seed plays `--eval-episodes` test
episodes greedily and sampled. Success = the episode terminated (the footprint reached an
object of the goal class within 200 steps); the return equals it. A uniform random policy's
success rate on the same test split is measured first, for reference.

    python bench/localize_ppo.py [--seconds 300] [--seeds 3]     # GPU: 256x256, the real task
    python bench/localize_ppo.py --quick                          # CPU smoke run: 64x64 scenes
"""

from __future__ import annotations

import argparse
import sys

import jax
import jax.numpy as jnp

sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parent))
import common  # noqa: E402
import train_throughput  # noqa: E402

import jaxnat  # noqa: E402

ENV_ID = "Localize/Clutter-v0"


def random_policy_success(env_kwargs: dict, episodes: int = 1000) -> float:
    """Fraction of test episodes a uniformly random policy ends by reaching the goal."""
    env, params = jaxnat.make(ENV_ID, split="test", autoreset=False, **env_kwargs)
    reset = jax.vmap(env.reset, in_axes=(0, None))
    step = jax.vmap(env.step, in_axes=(0, 0, 0, None))

    @jax.jit
    def play(key):
        obs, state = reset(jax.random.split(key, episodes), params)

        def body(carry, key):
            state, running, success = carry
            key_act, key_env = jax.random.split(key)
            action = jax.random.randint(key_act, (episodes,), 0, 4)
            _, state, _, terminated, truncated, _ = step(jax.random.split(key_env, episodes),
                                                         state, action, params)
            success = success | (running & terminated)
            return (state, running & ~(terminated | truncated), success), None

        start = (state, jnp.ones(episodes, bool), jnp.zeros(episodes, bool))
        steps = jax.random.split(key, int(params.max_steps_in_episode))
        (_, _, success), _ = jax.lax.scan(body, start, steps)
        return success.mean()

    return float(play(jax.random.key(123)))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--num-envs", type=int, default=64, help="parallel envs per seed")
    parser.add_argument("--num-steps", type=int, default=128, help="steps per env per update (authors: 128)")
    parser.add_argument("--chunk", type=int, default=10, help="updates between evaluations")
    parser.add_argument("--seconds", type=float, default=300.0, help="training wall-time budget")
    parser.add_argument("--lr", type=float, default=2.5e-4)
    parser.add_argument("--eval-episodes", type=int, default=500)
    parser.add_argument("--quick", action="store_true",
                        help="CPU smoke run: 64x64 scenes, 64 of them, 1 seed, 8 envs, 60 s")
    parser.add_argument("--backgrounds", default=None,
                        help="Clutter's photos/videos folder where opencv-doc is not installed "
                             "(scripts/stage_localize_data.py)")
    parser.add_argument("--no-record", action="store_true")
    args = parser.parse_args(argv)
    env_kwargs = {}
    if args.quick:
        env_kwargs = {"image_size": 64, "num_images": 64}
        args.seeds, args.num_envs, args.num_steps, args.chunk = 1, 8, 32, 4
        args.seconds, args.eval_episodes = min(args.seconds, 60.0), 64
    if args.backgrounds:
        env_kwargs["backgrounds"] = args.backgrounds

    info = common.machine()
    baseline = random_policy_success(env_kwargs, args.eval_episodes)
    print(f"random policy, test split: {baseline:.1%} success", flush=True)
    rows, compile_s, train_s, reached = train_throughput.train_and_evaluate(
        ENV_ID, seeds=args.seeds, num_envs=args.num_envs, num_steps=args.num_steps,
        chunk=args.chunk, seconds=args.seconds, lr=args.lr, env_kwargs=env_kwargs,
        eval_episodes=args.eval_episodes, target=0.9)
    table = common.markdown_table(rows, [
        ("updates", "updates", ","), ("env_steps_per_seed", "env steps per seed", ","),
        ("train_s", "train s", ".1f"), ("steps_per_s", "env steps/s (all seeds)", ".3e"),
        ("train_return", "train success", ".1%"), ("test_accuracy", "test success (greedy)", ".1%"),
        ("test_sampled_accuracy", "test success (sampled)", ".1%"),
        ("test_return_std", "std over seeds (greedy)", ".3f"),
    ])
    last = rows[-1]
    summary = {
        "env": ENV_ID + (f" {env_kwargs}" if args.quick else " (256x256, w=10, M=200)"),
        "setup": f"PPO, the paper's trunk for the size (cityscapes at 256x256) + goal embedding, {args.seeds} seeds vmapped, "
                 f"{args.num_envs} envs x {args.num_steps} steps per update, 4 epochs x 4 "
                 f"minibatches, lr {args.lr}; {args.eval_episodes} test episodes per seed",
        "compile s": f"{compile_s:.1f}",
        "random policy, test success": f"{baseline:.1%}",
        "final test success, greedy / sampled (mean over seeds)":
            f"{last['test_accuracy']:.1%} / {last['test_sampled_accuracy']:.1%} after "
            f"{last['env_steps_per_seed']:,} steps per seed, {train_s:.0f} s",
        "env steps/s end to end (all seeds, compile excluded)": f"{last['steps_per_s']:.3e}",
        "paper (Cityscapes)": "PPO fails to learn; A2C and ACKTR reach the object at most 40% of the time",
    }
    common.record("localize_ppo", info, table, summary, rows, save=not args.no_record)


if __name__ == "__main__":
    main()
