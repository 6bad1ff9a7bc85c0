"""What memory is worth on a classification env: feed-forward vs recurrent PPO, and the repeats.

A classification episode goes on after a wrong label (-0.1), and the observation does not show
which labels were tried: a feed-forward policy that is unsure of an image may guess the same
wrong label again and again. This trains PPO with and without memory (`memory`: a GRU that
also reads the previous action and reward) on the same data, seeds and settings, then scores
each on the train and test splits twice: as it is, and with labels the env already judged
wrong in the episode masked out of the label head (an oracle memory of wrong guesses). The gap
between the two columns is what remembering wrong guesses is worth to that policy.

    python bench/memory_gap.py [--env-kwargs start=center] [--memory 128] [--updates 160]
"""

from __future__ import annotations

import argparse
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parent))
import common  # noqa: E402

import jaxnat  # noqa: E402
from jaxnat.agents import distributions, ppo  # noqa: E402
from jaxnat.agents.networks import Memory, initial_memory  # noqa: E402
from jaxnat.agents.rollout import act  # noqa: E402
from jaxnat.training import parse_env_kwargs  # noqa: E402


def make_play(network, env, env_params, num_episodes: int, greedy: bool, mask_wrong: bool):
    """`play(network_params, key) -> mean return` of the first episode of `num_episodes` envs;
    with `mask_wrong`, labels judged wrong earlier in the episode get no probability."""
    reset = jax.vmap(env.reset, in_axes=(0, None))
    step = jax.vmap(env.step, in_axes=(0, 0, 0, None))
    num_classes = int(env.action_space(env_params).nvec[1])
    recurrent = bool(network.memory)

    def play(network_params, key):
        key_reset, key_steps = jax.random.split(key)
        obs, state = reset(jax.random.split(key_reset, num_episodes), env_params)

        def body(carry, key):
            obs, state, running, total, wrong, memory = carry
            key_act, key_env = jax.random.split(key)
            (move, label), _, hidden = act(network, network_params, obs, memory)
            label = jnp.where(mask_wrong & wrong, -jnp.inf, label)
            logits = (move, label)
            action = distributions.mode(logits) if greedy else distributions.sample(key_act, logits)
            obs, state, reward, terminated, truncated, _ = step(
                jax.random.split(key_env, num_episodes), state, action, env_params)
            total = total + jnp.where(running, reward, 0.0)
            wrong = wrong | (jax.nn.one_hot(action[:, 1], num_classes, dtype=bool) & ~terminated[:, None])
            running = running & ~(terminated | truncated)
            if recurrent:
                memory = Memory(hidden, action, reward.astype(jnp.float32), jnp.zeros_like(running))
            return (obs, state, running, total, wrong, memory), None

        memory = initial_memory(network, num_episodes) if recurrent else None
        carry = (obs, state, jnp.ones(num_episodes, bool), jnp.zeros(num_episodes),
                 jnp.zeros((num_episodes, num_classes), bool), memory)
        (_, _, _, total, _, _), _ = jax.lax.scan(
            body, carry, jax.random.split(key_steps, int(env_params.max_steps_in_episode)))
        return total.mean()

    return play


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env-id", default="Classify/Digits-v0")
    parser.add_argument("--env-kwargs", nargs="*", default=("start=center",), metavar="KEY=VALUE")
    parser.add_argument("--memory", type=int, default=128, help="GRU size of the recurrent policy")
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--num-envs", type=int, default=None, help="default: 512 on GPU, 32 on CPU")
    parser.add_argument("--num-minibatches", type=int, default=4)
    parser.add_argument("--updates", type=int, default=160)
    parser.add_argument("--eval-episodes", type=int, default=1000)
    parser.add_argument("--no-record", action="store_true")
    args = parser.parse_args(argv)

    info = common.machine()
    num_envs = args.num_envs or (32 if info["backend"] == "cpu" else 512)
    env_kwargs = parse_env_kwargs(args.env_kwargs)
    env, params = jaxnat.make(args.env_id, **env_kwargs)
    splits = {split: jaxnat.make(args.env_id, split=split, autoreset=False, **env_kwargs)
              for split in ("train", "test")}
    keys = jax.random.split(jax.random.key(0), args.seeds)
    rows = []
    for memory in (0, args.memory):
        config = ppo.PPOConfig(
            total_timesteps=args.updates * num_envs * 32, num_envs=num_envs, num_steps=32,
            update_epochs=4, num_minibatches=args.num_minibatches, lr=1e-3, weight_decay=0.1,
            dtype="float32" if info["backend"] == "cpu" else "bfloat16", memory=memory)
        learner = ppo.make_ppo(config, env, params)
        t0 = time.perf_counter()
        runner, metrics = jax.block_until_ready(jax.jit(jax.vmap(learner.train))(keys))
        seconds = time.perf_counter() - t0
        row = {"policy": f"recurrent (memory={memory})" if memory else "feed-forward",
               "train_return": float(np.nanmean(np.asarray(metrics["episode_return"])[:, -1])),
               "seconds": seconds}
        for split, (split_env, split_params) in splits.items():
            for greedy in (True, False):
                for mask in (False, True):
                    play = make_play(learner.network, split_env, split_params, args.eval_episodes, greedy, mask)
                    score = jax.jit(jax.vmap(play))(learner.policy_of(runner)[0], keys)
                    name = f"{split}_{'greedy' if greedy else 'sampled'}{'_masked' if mask else ''}"
                    row[name] = float(np.mean(score))
        rows.append(row)
        print(f"{row['policy']}: test sampled {row['test_sampled']:+.3f} -> {row['test_sampled_masked']:+.3f} "
              f"with wrong labels masked, greedy {row['test_greedy']:+.3f} -> {row['test_greedy_masked']:+.3f}",
              flush=True)

    columns = [("policy", "policy", "s"), ("train_return", "train return (rollouts)", "+.3f")]
    for split in ("test", "train"):
        for policy in ("greedy", "sampled"):
            columns += [(f"{split}_{policy}", f"{split} {policy}", "+.3f"),
                        (f"{split}_{policy}_masked", f"{split} {policy}, wrong labels masked", "+.3f")]
    columns.append(("seconds", "train s (compile included)", ".1f"))
    table = common.markdown_table(rows, columns)
    summary = {
        "env": args.env_id + (f" {env_kwargs}" if env_kwargs else ""),
        "setup": f"PPO, {args.seeds} seeds vmapped, {num_envs} envs x 32 steps, 4 epochs x "
                 f"{args.num_minibatches} minibatches, lr 1e-3 annealed over {args.updates} updates, weight decay 0.1, "
                 f"{args.eval_episodes} episodes per seed per score",
        **{f"test sampled return, {r['policy']}": f"{r['test_sampled']:+.3f} (wrong labels masked: "
           f"{r['test_sampled_masked']:+.3f})" for r in rows},
    }
    common.record("memory_gap", info, table, summary, rows, save=not args.no_record)


if __name__ == "__main__":
    main()
