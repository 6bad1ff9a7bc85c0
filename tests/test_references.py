"""jaxnat's PPO and DQN match the reference implementations on an env neither side wrote.

PureJaxRL's single-file PPO and DQN (`purejaxrl/ppo.py`, `purejaxrl/dqn.py`) solve gymnax's
CartPole-v1 within 5e5 env steps with their CartPole settings (median final return 492 and 500
over 4 seeds). Here jaxnat's learners get the same settings, mapped field by field onto their
configs, and must reach a median final return of at least 475 over 4 seeds (DQN: 8, below),
vmapped on the CPU.

"Final return" is what PureJaxRL reports: the training episodes' return at the end of training
(the mean of the episodes that ended in the last 1% of env steps, 5,000 steps: about 10
episodes of 500 per seed), not a greedy evaluation. Before the fixes these failed: PPO on one
MLP shared by actor and critic ended at 173, 283, 244 and 235 (median 239), though its greedy
policy already balanced for 500 steps; DQN with the Huber loss on the actor-critic's MLP at
500, 12.5, 12.0 and 9.8 (median 12). Now: 500 x 4, and 500, 500, 500, 496.

DQN at these settings is not always stable to the end of training, PureJaxRL's included: 3 of
its 16 seeds ended below 475, and jaxnat's did on 6 of 40 further seeds (and on 3 of 16 after
the rollout's keys were drawn in bulk, which drew new trajectories). The runs are
deterministic on one machine, but another CPU or XLA version, or a change in how keys are
drawn, draws new trajectories; at those rates a median over 4 seeds falls short in about one
draw in six (the bulk-key change's first draw did: 328, 500, 256, 500), over 8 in about one in
twenty. So DQN's median is taken over `DQN_SEEDS` = 8. A DQN failure after such a change is
still more likely chance than a regression: rerun with `DQN_SEEDS = 16` to tell.
"""

import os

import jax
import numpy as np
import pytest

from jaxnat.agents import DQNConfig, PPOConfig, make_dqn, make_ppo

if os.environ.get("CI"):  # CI installs the dev extra: these tests must run there, not skip
    import gymnax
else:
    gymnax = pytest.importorskip("gymnax")

SEEDS = 4
DQN_SEEDS = 8
STEPS = 500_000

# purejaxrl/ppo.py's CartPole config: LR 2.5e-4 annealed, 4 envs x 128 steps, 4 epochs of 4
# minibatches, gamma 0.99, GAE lambda 0.95, clip 0.2 (policy and value), entropy 0.01, value
# coefficient 0.5, max grad norm 0.5, Adam eps 1e-5; tanh 64x64 actor and critic.
PPO = PPOConfig(total_timesteps=STEPS, num_envs=4, num_steps=128, update_epochs=4, num_minibatches=4,
                anneal_lr=True, trunk="mlp", lr=2.5e-4, gamma=0.99, gae_lambda=0.95, clip_eps=0.2,
                vf_coef=0.5, ent_coef=0.01, max_grad_norm=0.5,
                normalize_observations=False, normalize_rewards=False)  # (PureJaxRL normalises neither)

# purejaxrl/dqn.py's: 10 envs, one gradient step per env step of all of them (TRAINING_INTERVAL
# 10 env steps), batch 128, buffer 10,000, Adam 2.5e-4 (optax's eps 1e-8, no decay, no
# clipping), squared TD error, epsilon 1 -> 0.05 over 250,000 env steps, learning from 10,000,
# a hard target copy every 500 env steps (50 gradient steps), gamma 0.99, one-step targets.
DQN = DQNConfig(total_timesteps=STEPS, num_envs=10, num_steps=1, gradient_steps=1, batch_size=128,
                buffer_size=10_000, optimizer="adam", loss="mse", trunk="mlp", lr=2.5e-4, adam_eps=1e-8,
                gamma=0.99, eps_start=1.0, eps_end=0.05, exploration_steps=250_000, learning_starts=10_000,
                target_update_period=50)


def final_returns(metrics, steps_per_update: int) -> np.ndarray:
    """Per seed: the mean return of the episodes that ended in the last 1% of env steps."""
    last = max(1, STEPS // 100 // steps_per_update)
    returns = np.asarray(metrics["episode_return"])[:, -last:]
    episodes = np.asarray(metrics["episodes"])[:, -last:]
    return np.where(episodes > 0, np.nan_to_num(returns) * episodes, 0.0).sum(1) / episodes.sum(1)


def train(make, config, seeds: int = SEEDS):
    env, params = gymnax.make("CartPole-v1")
    learner = make(config, env, params)
    _, metrics = jax.jit(jax.vmap(learner.train))(jax.random.split(jax.random.key(0), seeds))
    return final_returns(metrics, config.num_envs * config.num_steps)


def test_ppo_learns_cartpole_as_purejaxrl():
    returns = train(make_ppo, PPO)
    assert np.median(returns) >= 475, returns


def test_dqn_learns_cartpole_as_purejaxrl():
    returns = train(make_dqn, DQN, DQN_SEEDS)
    assert np.median(returns) >= 475, returns
