"""Continuous (Box) actions: the Gaussian policy in PPO, A2C and ACKTR on probes under vmap over
seeds, what a rollout stores, PPO's first ratio, and the errors and rules at the env boundary."""

import functools
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnat import spaces
from jaxnat.agents import (A2CConfig, ACKTRConfig, DQNConfig, PPOConfig, distributions, make_a2c, make_acktr,
                           make_dqn, make_ppo)
from jaxnat.agents.distributions import Gaussian
from jaxnat.agents.probes import make_probe
from jaxnat.agents.rollout import env_action, make_evaluate

_jit = functools.partial(jax.jit, compiler_options={"xla_backend_optimization_level": 0})

SEEDS = 5
# Tiny MLPs, 4 envs, 16,384 steps per seed. Over these 5 seeds every learner reached a greedy
# return above -0.006 on both probes (best 0; a policy that ignores the target scores -0.213,
# the untrained one -0.25 on the open-loop probe).
CONFIGS = {
    "ppo": (PPOConfig(total_timesteps=16384, num_envs=4, num_steps=16, update_epochs=2, num_minibatches=2,
                      trunk="mlp", lr=3e-3), make_ppo),
    "a2c": (A2CConfig(total_timesteps=16384, num_envs=4, num_steps=8, trunk="mlp", lr=3e-3), make_a2c),
    "acktr": (ACKTRConfig(total_timesteps=16384, num_envs=4, num_steps=8, trunk="mlp"), make_acktr),
}


@pytest.mark.parametrize("probe", ["target", "open_loop"])
@pytest.mark.parametrize("algo", ["ppo", "a2c", "acktr"])
def test_continuous_probes_are_solved_for_every_seed(algo, probe):
    """`target`: the Gaussian's mean must follow the observation; `open_loop`: the observation is
    pure noise and the optimum one fixed action, found from noise (the paper's control)."""
    config, make = CONFIGS[algo]
    env, params = make_probe(probe)
    learner = make(config, env, params)
    runner, _ = _jit(jax.vmap(learner.train))(jax.random.split(jax.random.key(0), SEEDS))
    evaluate = _jit(jax.vmap(make_evaluate(learner.network, env, params, num_episodes=256)))
    scores = evaluate(runner.train_state.params, jax.random.split(jax.random.key(1), SEEDS), runner.normalizer)
    greedy = np.asarray(scores["greedy_return"])
    assert np.all(greedy > -0.01), greedy
    # The learned log-std shrank from its initial 0: the policy became confident.
    assert np.all(np.asarray(runner.train_state.params["params"]["log_std"]["bias"]) < -1.0)


def _rollout(config):
    env, params = make_probe("target")
    learner = make_ppo(config, env, params)
    runner = learner.init(jax.random.key(0))
    return learner, learner.rollout(runner, config)


def test_rollout_stores_the_unclipped_sample_and_its_log_prob():
    """The env is given the action clipped to [-1, 1]; the rollout stores the sample itself and
    its log-prob, so the update's log-probs are of the action the policy drew."""
    config = PPOConfig(total_timesteps=512, num_envs=16, num_steps=32, trunk="mlp",
                       normalize_observations=False, normalize_rewards=False)
    learner, (_, transitions) = _rollout(config)
    action = np.asarray(transitions.action)[..., 0]
    assert np.mean(np.abs(action) > 1.0) > 0.2  # std 1 at the start: many samples out of bounds
    params = learner.init(jax.random.key(0)).train_state.params
    policy, _ = learner.network.apply(params, transitions.obs)
    np.testing.assert_allclose(transitions.log_prob, distributions.log_prob(policy, transitions.action),
                               rtol=1e-5, atol=1e-5)
    # ... while the reward is that of the clipped action: -(clip(a) - target)^2.
    target = np.asarray(transitions.obs)[..., 0]
    np.testing.assert_allclose(transitions.reward, -(np.clip(action, -1, 1) - target) ** 2, rtol=1e-5, atol=1e-6)


def test_ppo_ratio_is_one_on_the_first_minibatch():
    """One epoch of one minibatch: the update's policy is the one that collected the data, so
    every ratio is 1 (to float precision) and none is clipped."""
    config = PPOConfig(total_timesteps=256, num_envs=8, num_steps=32, update_epochs=1, num_minibatches=1,
                       trunk="mlp")
    env, params = make_probe("target")
    _, metrics = jax.jit(make_ppo(config, env, params).train)(jax.random.key(0))
    assert abs(float(metrics["approx_kl"][0])) < 1e-7
    assert float(metrics["clip_fraction"][0]) == 0.0
    # Over more minibatches the policy moves: the metric can tell.
    config = config.replace(num_minibatches=4, update_epochs=4)
    _, metrics = jax.jit(make_ppo(config, env, params).train)(jax.random.key(0))
    assert float(metrics["approx_kl"][0]) > 1e-6


def test_dqn_refuses_a_box_action_space():
    env, params = make_probe("target")
    with pytest.raises(ValueError, match="train continuous actions with ppo, a2c or acktr"):
        make_dqn(DQNConfig(total_timesteps=64, num_envs=4, trunk="mlp"), env, params)


def test_env_action_clips_to_the_bounds_and_stops_nan():
    box = spaces.Box(-1.0, 2.0, (3,), jnp.float32)
    action = jnp.array([[-5.0, jnp.nan, 7.0], [0.5, -jnp.inf, 1.0]])
    np.testing.assert_array_equal(env_action(action, box), [[-1.0, 0.0, 2.0], [0.5, -1.0, 1.0]])
    np.testing.assert_array_equal(env_action(np.asarray(action), box), [[-1.0, 0.0, 2.0], [0.5, -1.0, 1.0]])
    # Infinite bounds (documented): the action passes unclipped; NaN still becomes 0.
    free = spaces.Box(-np.inf, np.inf, (2,), jnp.float32)
    np.testing.assert_array_equal(env_action(jnp.array([[1e6, jnp.nan]]), free), [[1e6, 0.0]])


def test_gaussian_head_shapes_and_initial_log_std():
    from jaxnat.agents.networks import init_params, make_actor_critic

    observation_space = spaces.Box(-np.inf, np.inf, (11,), jnp.float32)
    network = make_actor_critic(observation_space, spaces.Box(-1.0, 1.0, (3,), jnp.float32))
    params = init_params(network, observation_space, jax.random.key(0))
    policy, value = network.apply(params, jnp.ones((7, 11)))
    assert isinstance(policy, Gaussian) and policy.mean.shape == (7, 3) and value.shape == (7,)
    np.testing.assert_array_equal(policy.log_std, np.zeros((7, 3)))  # std 1, as the authors'
    assert set(params["params"]) == {"actor", "critic", "mean", "log_std", "Dense_0"}
    with pytest.raises(ValueError, match="one dimension"):
        make_actor_critic(observation_space, spaces.Box(-1.0, 1.0, (2, 2), jnp.float32))


# --- `jaxnat train` on a MuJoCo robot ----------------------------------------------------------

FAST = {"xla_backend_optimization_level": 0}
# Episodes of 32 steps: the test episodes of Gymnasium's 1,000 steps took most of the test's
# time on a CPU (MJX at XLA's lowest optimisation level), and no contract here needs them long.
SWIMMER = ["--env-id", "MuJoCo/Swimmer-v0", "--env-kwargs", "max_steps_in_episode=32", "--algo", "ppo",
           "--seeds", "2", "--num-envs", "4", "--num-steps", "8", "--total-timesteps", "128",
           "--eval-every", "2", "--eval-episodes", "2"]


@pytest.mark.xdist_group("mujoco_train")
def test_mujoco_run_takes_the_family_defaults_and_resumes_exactly(tmp_path):
    """A Box-action run from state: the MuJoCo settings and normalisation are resolved into
    config.json, the run writes its curve and checkpoints (MJX's zero-size state fields
    included), and a resumed run ends bit for bit where the uninterrupted one does, the
    normalisation statistics with it."""
    pytest.importorskip("mujoco.mjx")
    from jaxnat import train
    from jaxnat.training import checkpoints

    full, resumed = tmp_path / "full", tmp_path / "resumed"
    assert train.main([*SWIMMER, "--run-dir", str(full)], compiler_options=FAST) == 0
    config = json.loads((full / "config.json").read_text())["spec"]["config"]
    assert config["normalize_observations"] is True and config["normalize_rewards"] is True
    assert (config["update_epochs"], config["num_minibatches"], config["clip_eps"], config["ent_coef"]) == (10, 32, 0.2, 0.0)
    assert config["num_envs"] == 4 and config["num_steps"] == 8  # the command line wins
    assert (full / "curve.png").exists()
    assert train.main([*SWIMMER, "--run-dir", str(resumed)], compiler_options=FAST, stop_after_chunks=1) == 0
    assert train.main(["--resume", str(resumed)], compiler_options=FAST) == 0
    (expected, _), (actual, meta) = (train.load_checkpoint(d, compiler_options=FAST) for d in (full, resumed))
    assert meta["update"] == 4
    assert float(expected.normalizer.obs.count[0]) == 4 * 4 * 8  # every observation the policy saw
    for a, b in zip(jax.tree.leaves(checkpoints.to_saveable(expected)),
                    jax.tree.leaves(checkpoints.to_saveable(actual)), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_dqn_on_a_mujoco_robot_is_refused_in_one_line(tmp_path, capsys):
    pytest.importorskip("mujoco.mjx")
    from jaxnat import train

    argv = ["--env-id", "MuJoCo/Swimmer-v0", "--algo", "dqn", "--run-dir", str(tmp_path / "r")]
    assert train.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "ppo, a2c or acktr" in err, err
