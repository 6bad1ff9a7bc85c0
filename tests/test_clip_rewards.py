"""`clip_rewards` (every algorithm's config): the learner trains on sign(r), baselines'
`ClipRewardEnv`, while the episode returns it reports stay the env's; clipped before any
reward scaling; on the jitted and the host on-policy paths, DQN's replay, and `jaxnat train`.

`Steps` is a toy env whose rewards are known step by step, so the contract is checked on the
exact records the update trains on (`Learner.rollout`) and the metrics it reports."""

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxnat import spaces
from jaxnat.agents import PPOConfig, make_ppo, normalize
from jaxnat.core import Environment, EnvParams, EnvState
from jaxnat.wrappers import AutoResetWrapper

FAST = {"xla_backend_optimization_level": 0}  # compiles much faster on CPU
REWARDS = np.array([2.5, -0.3, 0.0, -7.0], np.float32)  # one episode, whatever the actions
RETURN = float(REWARDS.sum(dtype=np.float32))


@struct.dataclass
class StepsState(EnvState):
    pass


@struct.dataclass
class StepsParams(EnvParams):
    pass


class Steps(Environment):
    """Reward `REWARDS[t]` at step t; terminates after `len(REWARDS)` steps; observes t."""

    @property
    def default_params(self):
        return StepsParams()

    def action_space(self, params):
        return spaces.Discrete(2)

    def observation_space(self, params):
        return spaces.Box(0.0, len(REWARDS), (1,), jnp.float32)

    def reset_env(self, key, params):
        return jnp.zeros((1,), jnp.float32), StepsState(time=jnp.zeros((), jnp.int32))

    def step_env(self, key, state, action, params):  # (`step` then counts `state.time` up)
        reward = jnp.asarray(REWARDS)[state.time]
        time = state.time + 1
        return time.astype(jnp.float32)[None], state, reward, time >= len(REWARDS), {}


def ppo(**fields):
    env = AutoResetWrapper(Steps())
    config = PPOConfig(total_timesteps=16, num_envs=2, num_steps=8, update_epochs=1, num_minibatches=1,
                       trunk="mlp", normalize_observations=False, normalize_rewards=False, **fields)
    return config, make_ppo(config, env, env.default_params)


def test_training_rewards_are_sign_clipped_and_reported_returns_are_not():
    config, learner = ppo(clip_rewards=True)
    runner = learner.init(jax.random.key(0))
    _, transitions = jax.jit(learner.rollout, static_argnums=1, compiler_options=FAST)(runner, config)
    per_step = np.tile(REWARDS, 2)[:, None].repeat(2, axis=1)  # [T, N]: two episodes per env
    np.testing.assert_array_equal(transitions.reward, np.sign(per_step))
    ended = np.asarray(transitions.info["returned_episode"])
    assert ended.sum() == 4
    np.testing.assert_array_equal(np.asarray(transitions.info["returned_episode_returns"])[ended], RETURN)
    _, metrics = jax.jit(learner.train, compiler_options=FAST)(jax.random.key(0))
    assert float(metrics["episode_return"][-1]) == RETURN  # the env's return, unclipped


def test_off_by_default_trains_on_the_env_s_rewards():
    config, learner = ppo()
    assert config.clip_rewards is False
    _, transitions = jax.jit(learner.rollout, static_argnums=1, compiler_options=FAST)(learner.init(jax.random.key(0)), config)
    np.testing.assert_array_equal(transitions.reward[:4, 0], REWARDS)


def test_clipped_before_scaled():
    """With reward scaling on too, the clipped rewards are scaled: the running return and its
    variance are those of sign(r), as `VecNormalize` around a `ClipRewardEnv`."""
    rng = np.random.default_rng(0)
    rewards = rng.normal(0.0, 5.0, (20, 3)).astype(np.float32)
    rewards[::4] = 0.0
    dones = rng.random((20, 3)) < 0.2
    box = spaces.Box(-1.0, 1.0, (2,), jnp.float32)
    clipped = scaled = normalize.init_normalizer(False, True, box, 3)
    for r, d in zip(rewards, dones):
        clipped, out = normalize.scale_rewards(clipped, jnp.asarray(r), jnp.asarray(d), 0.9, clip=True)
        scaled, expected = normalize.scale_rewards(scaled, jnp.sign(jnp.asarray(r)), jnp.asarray(d), 0.9)
        np.testing.assert_array_equal(out, expected)
    np.testing.assert_array_equal(clipped.running_return, scaled.running_return)
    # Without a normaliser: sign(r) itself, float32, 0 stays 0.
    _, out = normalize.scale_rewards(None, jnp.asarray([3, -2, 0]), None, None, clip=True)
    assert out.dtype == jnp.float32 and out.tolist() == [1.0, -1.0, 0.0]


def test_host_path_clips_the_training_rewards_only():
    """The host on-policy learner's transitions (`_host_transitions`, what its update trains
    on): rewards sign-clipped with `clip`, episode statistics untouched."""
    from jaxnat.agents.rollout.on_policy_host import _host_transitions

    steps, envs = 4, 2
    reward = np.tile(REWARDS[:, None], (1, envs))
    ended = np.zeros((steps, envs), bool)
    ended[-1] = True
    rollout = {"obs": np.zeros((steps, envs, 1), np.float32), "action": np.zeros((steps, envs, 1), np.int32),
               "log_prob": np.zeros((steps, envs), np.float32), "value": np.zeros((steps, envs), np.float32),
               "reward": reward, "done": ended, "terminated": ended,
               "final_value": np.zeros((steps, envs), np.float32), "returned_episode": ended,
               "returned_episode_returns": np.where(ended, RETURN, 0.0).astype(np.float32),
               "returned_episode_lengths": np.where(ended, steps, 0).astype(np.int32)}
    rollout = {name: [value] for name, value in rollout.items()}  # one part, stacked already
    last_value = [jnp.zeros(envs)]
    clipped = _host_transitions(rollout, last_value, True)
    raw = _host_transitions(rollout, last_value)
    np.testing.assert_array_equal(clipped.reward, np.sign(reward))
    np.testing.assert_array_equal(raw.reward, reward)
    for a, b in zip(jax.tree.leaves(clipped.info), jax.tree.leaves(raw.info)):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(clipped.info["returned_episode_returns"][-1], RETURN)


def test_dqn_stores_sign_clipped_rewards():
    from jaxnat.agents.dqn import DQNConfig, _stored
    from jaxnat.agents.rollout import EnvStep

    assert DQNConfig().clip_rewards is False
    s = EnvStep(None, None, None, np.array([2.5, -0.3, 0.0], np.float32), None, None, None, {})
    np.testing.assert_array_equal(_stored(s, True)["reward"], [1.0, -1.0, 0.0])
    assert _stored(s)["reward"] is s.reward  # off: stored as the env gave it


def test_jaxnat_train_takes_clip_rewards():
    from jaxnat.training.args import parse_args

    assert parse_args(["--clip-rewards", "True"]).config.clip_rewards is True
    assert parse_args(["--clip-rewards", "False"]).config.clip_rewards is False
    assert parse_args([]).config.clip_rewards is None  # unset: the algorithm's default, False
