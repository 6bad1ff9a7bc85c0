"""`jaxnat.training.make_strength_train`: seeds x strengths of a distraction dial trained in one
program, each strength's slice the run that strength trains alone (`make_sharded_train`, a
separate code path: `placement.learner_programs`), from the same keys.

Tiny PPO on Classify/Digits-v0 (2 envs x 8 steps, 2 updates, 2 seeds) with XLA's default CPU
options; the strengths are additive pixel noise 0 and 96 (of 255).
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxnat
from jaxnat.agents import PPOConfig
from jaxnat.training import TrainError, make_sharded_train
from jaxnat.training.strengths import make_strength_train

from test_train import needs_digits

CONFIG = PPOConfig(num_envs=2, num_steps=8, total_timesteps=32, num_minibatches=2, update_epochs=1, trunk="mnist")
STRENGTHS = [0.0, 96.0]


@needs_digits
def test_each_strength_trains_what_it_trains_alone():
    env, params = jaxnat.make("Classify/Digits-v0")
    keys = jax.vmap(jax.random.key)(jnp.arange(2))
    runner, metrics = make_strength_train("ppo", CONFIG, env, params, noise_sigma=STRENGTHS)(keys)
    leaves = jax.tree.leaves(runner.train_state.params)
    assert all(leaf.shape[:2] == (2, 2) for leaf in leaves)  # [strengths, seeds]
    assert metrics["episode_return"].shape[:2] == (2, 2)
    for index, sigma in enumerate(STRENGTHS):
        alone_params = params.replace(distraction=params.distraction.replace(noise_sigma=sigma))
        alone, alone_metrics = make_sharded_train("ppo", CONFIG, env, alone_params, seeds=2)(keys)
        for got, want in zip(leaves, jax.tree.leaves(alone.train_state.params)):
            np.testing.assert_allclose(got[index], want, rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(metrics["episode_return"][index], alone_metrics["episode_return"], atol=1e-6)
    # The dial is what differs: the two strengths' parameters part (same keys, other pixels).
    assert not np.allclose(leaves[0][0], leaves[0][1])


def test_an_env_without_a_dial_or_an_unknown_algorithm_is_one_line():
    from jaxnat.agents.probes import make_probe

    env, params = make_probe("factored")
    with pytest.raises(TrainError, match="params have no distraction dial to train over"):
        make_strength_train("ppo", CONFIG, env, params, noise_sigma=STRENGTHS)
    with pytest.raises(TrainError, match="unknown algorithm 'sac'"):
        make_strength_train("sac", CONFIG, env, params, noise_sigma=STRENGTHS)


@needs_digits
def test_a_strength_out_of_range_is_refused_before_compiling():
    env, params = jaxnat.make("Classify/Digits-v0")
    with pytest.raises(ValueError, match="noise_sigma must be a finite number >= 0"):
        make_strength_train("ppo", CONFIG, env, params, noise_sigma=[0.0, -1.0])
