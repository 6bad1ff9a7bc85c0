"""PPO sample efficiency on a classification env at a fixed CPU budget: which settings learn most.

The main job (`make run`) must train 5 seeds on a 2-core CPU in minutes, so what counts is test
return per CPU second, not per env step. A step costs about two forward passes (the action and
the value of the final observation) plus one backward per epoch, each priced per sample at the
one-core costs of the MNIST trunk (`FORWARD_MS`, `BACKWARD_MS`; the budget line of
bench/results/ppo_sweep.md states them). Each setting gets the env steps that budget buys
(`--cpu-seconds` for all seeds), and is run for several learning rates and seeds at once:
`jit(vmap(run))` over (hyperparameters x seeds), on any backend (the learning is the same; a
GPU just sweeps faster). Prints the greedy test return after each quarter.

    python bench/ppo_sweep.py [--env-id Classify/Digits-v0] [--cpu-seconds 400] [--env-kwargs w=7]
"""

from __future__ import annotations

import argparse
import functools
import sys

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parent))
import common  # noqa: E402

import jaxnat  # noqa: E402
from jaxnat.agents import ppo  # noqa: E402
from jaxnat.agents.rollout import make_evaluate  # noqa: E402
from jaxnat.train import parse_env_kwargs  # noqa: E402

FORWARD_MS, BACKWARD_MS = 0.20, 0.22  # per sample, one core, MNIST trunk (see the docstring)
SETTINGS = [  # (num_envs, num_steps, update_epochs, num_minibatches)
    (16, 32, 2, 2), (64, 32, 2, 4), (32, 32, 1, 1), (16, 16, 1, 1),
    (16, 32, 4, 4), (16, 32, 4, 8), (16, 32, 4, 16), (16, 32, 8, 8), (8, 32, 4, 4),
    (16, 32, 3, 8), (32, 32, 4, 8), (8, 16, 4, 4),
]
LEARNING_RATES = [5e-4, 1e-3, 2e-3]
QUARTERS = 4


def steps_for(cpu_seconds: float, seeds: int, epochs: int) -> int:
    return int(cpu_seconds / seeds / ((2 * FORWARD_MS + epochs * BACKWARD_MS) / 1000))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env-id", default="Classify/Digits-v0")
    parser.add_argument("--env-kwargs", nargs="*", default=[])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--cpu-seconds", type=float, default=400.0, help="the budget of all seeds")
    parser.add_argument("--eval-episodes", type=int, default=500)
    parser.add_argument("--no-record", action="store_true")
    args = parser.parse_args(argv)
    env_kwargs = parse_env_kwargs(args.env_kwargs)

    info = common.machine()
    env, params = jaxnat.make(args.env_id, **env_kwargs)
    test_env, test_params = jaxnat.make(args.env_id, split="test", autoreset=False, **env_kwargs)
    rows = []
    for num_envs, num_steps, epochs, minibatches in SETTINGS:
        per_update = num_envs * num_steps
        updates = steps_for(args.cpu_seconds, args.seeds, epochs) // per_update
        updates -= updates % QUARTERS
        base = ppo.PPOConfig(total_timesteps=updates * per_update, num_envs=num_envs,
                             num_steps=num_steps, update_epochs=epochs, num_minibatches=minibatches)
        learner = ppo.make_ppo(base, env, params)
        configs = [base.replace(lr=lr) for lr in LEARNING_RATES for _ in range(args.seeds)]
        stacked = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *configs)
        keys = jax.random.split(jax.random.key(0), len(configs))
        run = jax.jit(jax.vmap(functools.partial(learner.run, num_updates=updates // QUARTERS)))
        evaluate = jax.jit(jax.vmap(make_evaluate(learner.network, test_env, test_params,
                                                  args.eval_episodes)))
        runner = jax.jit(jax.vmap(learner.init))(keys, stacked)
        greedy, accuracy = [], []
        for _ in range(QUARTERS):
            runner, _ = run(runner, stacked)
            scores = jax.device_get(evaluate(learner.policy_of(runner)[0], keys))
            greedy.append(np.asarray(scores["greedy_return"]).reshape(len(LEARNING_RATES), -1))
            accuracy.append(np.asarray(scores["greedy_terminated_fraction"]).reshape(len(LEARNING_RATES), -1))
        for i, lr in enumerate(LEARNING_RATES):
            row = {"setting": f"{num_envs} envs x {num_steps} steps, {epochs} epochs x {minibatches} mb",
                   "lr": lr, "steps_per_seed": updates * per_update,
                   **{f"q{q + 1}": float(greedy[q][i].mean()) for q in range(QUARTERS)},
                   "std": float(greedy[-1][i].std()), "accuracy": float(accuracy[-1][i].mean())}
            rows.append(row)
            print(f"{row['setting']:38s} lr {lr:.0e} {row['steps_per_seed']:>7,} steps/seed  greedy test "
                  f"return by quarter {' '.join(format(row['q%d' % (q + 1)], '+.2f') for q in range(QUARTERS))}"
                  f"  accuracy {row['accuracy']:.0%}", flush=True)
    table = common.markdown_table(rows, [
        ("setting", "setting", "s"), ("lr", "lr", ".0e"), ("steps_per_seed", "env steps per seed", ","),
        *[(f"q{q + 1}", f"test return at {q + 1}/4", "+.2f") for q in range(QUARTERS)],
        ("std", "std over seeds", ".2f"), ("accuracy", "test accuracy (greedy)", ".0%"),
    ])
    best = max(rows, key=lambda r: r[f"q{QUARTERS}"])
    summary = {"env": f"{args.env_id} {env_kwargs or ''}".strip(),
               "budget": f"{args.cpu_seconds:.0f} CPU-seconds for {args.seeds} seeds "
                         f"(forward {FORWARD_MS} ms, backward {BACKWARD_MS} ms per sample)",
               "best": f"{best['setting']}, lr {best['lr']:.0e}: greedy test return {best[f'q{QUARTERS}']:+.2f}, "
                       f"accuracy {best['accuracy']:.0%}"}
    common.record("ppo_sweep", info, table, summary, rows, save=not args.no_record)


if __name__ == "__main__":
    main()
