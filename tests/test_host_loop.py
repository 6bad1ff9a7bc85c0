"""The host training loop (jaxnat.agents.host_loop) on probe envs behind a numpy batched API.

The probes are jaxnat's own (jaxnat.agents.probes); `HostProbe` steps a batch of them through
a jitted function and hands numpy arrays out, as `NaturalAtariVecEnv` does (same-step autoreset,
`final_observation` and PureJaxRL's episode keys in `info`), so the loop is tested on envs whose
right answers are known.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnat.agents import a2c, ppo
from jaxnat.agents.host_loop import evaluate_host, make_host_learner
from jaxnat.agents.probes import make_probe
from jaxnat.wrappers import LogWrapper

CONFIGS = {
    "ppo": ppo.PPOConfig(total_timesteps=4096, num_envs=4, num_steps=16, update_epochs=2,
                         num_minibatches=2, trunk="mlp", lr=3e-3),
    "a2c": a2c.A2CConfig(total_timesteps=4096, num_envs=4, num_steps=8, trunk="mlp", lr=1e-3),
}
RULES = {"ppo": ppo.RULE, "a2c": a2c.RULE}
FAST = {"xla_backend_optimization_level": 0}  # compiles much faster on CPU


class HostProbe:
    """`num_envs` copies of a probe with numpy `reset(seed=)` / `step(actions)`."""

    def __init__(self, name: str, num_envs: int):
        env, self.params = make_probe(name)
        self.env = LogWrapper(env)
        self.num_envs = num_envs
        self.single_observation_space = env.observation_space(self.params)
        self.single_action_space = env.action_space(self.params)
        self._reset = jax.jit(jax.vmap(self.env.reset, in_axes=(0, None)))
        self._step = jax.jit(jax.vmap(self.env.step, in_axes=(0, 0, 0, None)))

    def reset(self, seed: int = 0):
        self._key = jax.random.key(seed)
        obs, self._state = self._reset(self._keys(), self.params)
        return np.asarray(obs), {}

    def step(self, actions):
        obs, self._state, reward, terminated, truncated, info = self._step(
            self._keys(), self._state, jnp.asarray(actions), self.params
        )
        return (np.asarray(obs), np.asarray(reward), np.asarray(terminated),
                np.asarray(truncated), jax.tree_util.tree_map(np.asarray, info))

    def _keys(self):
        self._key, key = jax.random.split(self._key)
        return jax.random.split(key, self.num_envs)


@functools.cache
def trained(probe: str, algo: str, gamma: float = 0.99):
    config = CONFIGS[algo].replace(gamma=gamma)
    learner = make_host_learner(config, HostProbe(probe, config.num_envs), RULES[algo], FAST)
    train_state, history = learner.train(jax.random.key(0))
    return learner, train_state.params, history


def value(learner, params, obs):
    return np.asarray(learner.network.apply(params, jnp.asarray(obs, jnp.float32))[1])


@pytest.mark.parametrize("algo", ["ppo", "a2c"])
def test_policy_learns_the_sign_probe(algo):
    learner, params, history = trained("sign", algo)
    assert np.nanmean([h["episode_return"] for h in history[-5:]]) >= 0.9
    greedy = evaluate_host(learner, params, HostProbe("sign", 4), 20, jax.random.key(1),
                           greedy=True)
    assert greedy.shape == (20,) and (greedy == 1.0).all()


def test_truncated_steps_bootstrap_from_the_final_observation():
    """As tests/test_agents.py: 5-step episodes that are truncated, never terminated; the first
    step shows [1, 0] and pays -10, later ones [0, 1] and pay 1; gamma 0.9: V([0, 1]) = 10 and
    V([1, 0]) = -1. Bootstrapping from the next episode's first observation gives V([0, 1])
    about -11; treating truncation as termination gives about 2.7."""
    learner, params, history = trained("costly_start", "ppo", gamma=0.9)
    start, later = value(learner, params, [[1.0, 0.0], [0.0, 1.0]])
    assert 8.0 < later < 12.0, later
    assert abs(start + 1.0) < 2.0, start
    assert history[-1]["episode_return"] == -10.0 + 4.0
    assert history[-1]["terminated_fraction"] == 0.0


def test_terminal_steps_do_not_bootstrap():
    """One-step episodes with a constant reward: V = that reward, not reward / (1 - gamma)."""
    learner, params, _ = trained("constant_reward", "a2c")
    probe = HostProbe("constant_reward", 1)
    expected = float(probe.params.reward)
    assert abs(value(learner, params, probe.reset()[0])[0] - expected) < 0.1


def test_batch_size_must_match_the_env():
    with pytest.raises(ValueError, match="num_envs"):
        make_host_learner(CONFIGS["ppo"], HostProbe("sign", 3), ppo.RULE)
    with pytest.raises(ValueError, match="less than one rollout"):
        make_host_learner(CONFIGS["ppo"].replace(total_timesteps=10), HostProbe("sign", 4),
                          ppo.RULE)


def test_jaxnat_train_runs_natural_atari(tmp_path):
    """`jaxnat train` routes NaturalAtari ids to the host loop and writes a run directory."""
    pytest.importorskip("ale_py")
    import json

    from jaxnat.train import main

    run_dir = tmp_path / "run"
    status = main(["--env-id", "NaturalAtari/Breakout-v0", "--algo", "a2c", "--seeds", "1",
                   "--total-timesteps", "32", "--num-envs", "2", "--num-steps", "8",
                   "--eval-episodes", "2", "--run-dir", str(run_dir), "--env-kwargs",
                   "obs_size=36", "num_threads=1", "max_episode_steps=10", "background=noise"],
                  compiler_options=FAST)
    assert status == 0
    rows = [json.loads(line) for line in (run_dir / "metrics.jsonl").read_text().splitlines()]
    assert [r["update"] for r in rows] == [1, 2]
    # 10-step games (time limit) in 8-step rollouts: both envs' first games end in update 2.
    assert rows[0]["episodes"] == 0 and rows[1]["episodes"] == 2
    assert rows[1]["episode_length"] == 10.0
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["complete"] and summary["env_steps_per_seed"] == 32
    assert np.isfinite(summary["test_sampled_return_mean"])
