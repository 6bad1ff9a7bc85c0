"""Observation normalisation and reward scaling (`jaxnat.agents.normalize`): the statistics
against NumPy on the same stream, the learner's state over rollouts, frozen at evaluation,
defaults per observation type, and exact resume through `jaxnat train`."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnat import spaces
from jaxnat.agents import A2CConfig, PPOConfig, make_a2c, make_ppo, normalize
from jaxnat.agents.probes import make_probe
from jaxnat.agents.rollout import make_evaluate

_jit = functools.partial(jax.jit, compiler_options={"xla_backend_optimization_level": 0})


def test_moments_equal_numpy_on_the_same_stream():
    rng = np.random.default_rng(0)
    batches = [rng.normal(3.0, 2.0, (n, 4)) * [1, 10, 0.1, 1] for n in (1, 7, 64, 3, 200)]
    moments = normalize.init_moments((4,))
    for batch in batches:
        moments = normalize.update_moments(moments, jnp.asarray(batch, jnp.float32))
    stream = np.concatenate(batches)
    np.testing.assert_allclose(moments.mean, stream.mean(0), rtol=1e-5)
    np.testing.assert_allclose(moments.var, stream.var(0), rtol=1e-4)
    assert float(moments.count) == len(stream)


def test_reward_scaling_follows_the_discounted_return():
    """baselines' rule: `R <- gamma R + r`, reset where an episode ends; rewards are divided by
    the running standard deviation of R and clipped to +-10."""
    rng = np.random.default_rng(1)
    rewards = rng.normal(5.0, 3.0, (50, 4)).astype(np.float32)
    dones = rng.random((50, 4)) < 0.1
    state = normalize.init_normalizer(False, True, spaces.Box(-1.0, 1.0, (2,), jnp.float32), 4)
    running, returns, scaled = np.zeros(4), [], []
    for r, d in zip(rewards, dones):
        state, out = normalize.scale_rewards(state, jnp.asarray(r), jnp.asarray(d), 0.9)
        running = 0.9 * running + r
        returns.append(running.copy())
        running[d] = 0.0
        scaled.append(np.clip(r / np.sqrt(np.var(np.concatenate(returns)) + 1e-8), -10, 10))
        np.testing.assert_allclose(out, scaled[-1], rtol=1e-4)
    np.testing.assert_allclose(state.running_return, running, rtol=1e-5)


def test_learner_statistics_are_those_of_every_observation_the_policy_saw():
    """Rollouts of one step: the policy sees exactly `runner.obs` before each, so the stream is
    known; after 12 rollouts the learner's moments equal NumPy's over it."""
    env, params = make_probe("target")
    config = PPOConfig(total_timesteps=64, num_envs=8, num_steps=1, trunk="mlp")
    learner = make_ppo(config, env, params)
    rollout = jax.jit(learner.rollout)
    runner = learner.init(jax.random.key(0))
    seen = []
    for _ in range(12):
        seen.append(np.asarray(runner.obs))
        runner, transitions = rollout(runner, config)
    stream = np.concatenate(seen)
    np.testing.assert_allclose(runner.normalizer.obs.mean, stream.mean(0), rtol=1e-5)
    np.testing.assert_allclose(runner.normalizer.obs.var, stream.var(0), rtol=1e-4)
    # What was stored (and trained on) is the normalised observation.
    moments = runner.normalizer.obs
    last = (seen[-1] - np.asarray(moments.mean)) / np.sqrt(np.asarray(moments.var) + 1e-8)
    np.testing.assert_allclose(transitions.obs[0], last, rtol=1e-5, atol=1e-6)


def test_defaults_on_for_vectors_off_for_images_and_refused_on_images():
    vector = spaces.Box(-1.0, 1.0, (3,), jnp.float32)
    image = spaces.Box(0, 255, (84, 84, 4), jnp.uint8)
    assert normalize.switches(PPOConfig(), vector) == (True, True)
    assert normalize.switches(PPOConfig(), image) == (False, False)
    assert normalize.switches(A2CConfig(normalize_rewards=False), vector) == (True, False)
    with pytest.raises(ValueError, match="leave it off for images"):
        normalize.init_normalizer(True, False, image, 4)
    assert normalize.init_normalizer(False, False, vector, 4) is None


def test_evaluation_reads_the_frozen_statistics():
    """A2C on the target probe with observations normalised: evaluated with its statistics the
    policy is near optimal; given none it reads raw observations it was never trained on and
    scores worse. The statistics are an input of `evaluate`, which returns scores only."""
    env, params = make_probe("target")
    config = A2CConfig(total_timesteps=16384, num_envs=4, num_steps=8, trunk="mlp", lr=3e-3)
    learner = make_a2c(config, env, params)
    runner, _ = _jit(learner.train)(jax.random.key(0))
    evaluate = _jit(make_evaluate(learner.network, env, params, num_episodes=256))
    key = jax.random.key(1)
    with_stats = evaluate(runner.train_state.params, key, runner.normalizer)
    without = evaluate(runner.train_state.params, key, None)
    assert float(with_stats["greedy_return"]) > -0.01
    assert float(without["greedy_return"]) < float(with_stats["greedy_return"]) - 0.01
    # The same key and statistics give the same scores: nothing was updated in between.
    again = evaluate(runner.train_state.params, key, runner.normalizer)
    assert float(again["greedy_return"]) == float(with_stats["greedy_return"])
