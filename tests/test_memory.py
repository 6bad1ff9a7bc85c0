"""Recurrent policies (`memory > 0`): a GRU that carries what an episode showed and did.

The contracts: the update replays a stored rollout to exactly the outputs the rollout saw
(else PPO's ratio is wrong from the first epoch); the state is zeroed where an episode starts;
PPO and A2C learn a probe that only memory can solve, which a feed-forward policy cannot;
evaluation carries the memory; configurations that cannot work are errors.
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnat import spaces
from jaxnat.agents import A2CConfig, PPOConfig, make_a2c, make_ppo
from jaxnat.agents.networks import Memory, init_params, make_actor_critic
from jaxnat.agents.rollout import act, make_evaluate, replay
from jaxnat.agents.probes import make_probe

_jit = functools.partial(jax.jit, compiler_options={"xla_backend_optimization_level": 0})
SEEDS = 4
# The probes check values in reward units: no normalisation (on by default for vector observations).
RAW = dict(normalize_observations=False, normalize_rewards=False)
CONFIGS = {
    "ppo": PPOConfig(total_timesteps=8192, num_envs=4, num_steps=16, update_epochs=2,
                     num_minibatches=2, trunk="mlp", lr=3e-3, **RAW),
    "a2c": A2CConfig(total_timesteps=8192, num_envs=4, num_steps=8, trunk="mlp", lr=1e-3, **RAW),
}
MAKE = {"ppo": make_ppo, "a2c": make_a2c}


def _network(memory=8):
    """A recurrent MLP policy over 3 floats with `MultiDiscrete([2, 3])` actions."""
    space = spaces.Box(-1.0, 1.0, (3,), jnp.float32)
    network = make_actor_critic(space, spaces.MultiDiscrete([2, 3]), "mlp", memory=memory)
    return network, init_params(network, space, jax.random.key(0))


def _sequence(T=7, B=3, seed=1):
    """Random observations and memory inputs with episode starts in the middle."""
    rng = np.random.default_rng(seed)
    obs = jnp.asarray(rng.normal(size=(T, B, 3)), jnp.float32)
    start = np.zeros((T, B), bool)
    start[0] = True
    start[3, 0] = start[5, 2] = start[1, 1] = True
    memory = Memory(hidden=jnp.asarray(rng.normal(size=(1, B, 8)), jnp.float32),  # as a rollout stores it
                    prev_action=jnp.asarray(rng.integers(0, 2, size=(T, B, 2)), jnp.int32),
                    prev_reward=jnp.asarray(rng.normal(size=(T, B)), jnp.float32),
                    start=jnp.asarray(start))
    return obs, memory


def test_replaying_a_sequence_gives_the_stepwise_outputs():
    network, params = _network()
    obs, memory = _sequence()
    logits, value = replay(network, params, obs, memory)
    hidden = memory.hidden[0]
    for t in range(obs.shape[0]):
        step = Memory(hidden, memory.prev_action[t], memory.prev_reward[t], memory.start[t])
        step_logits, step_value, hidden = act(network, params, obs[t], step)
        for a, b in zip(step_logits, logits):
            np.testing.assert_allclose(a, b[t], rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(step_value, value[t], rtol=1e-5, atol=1e-6)


def test_an_episode_start_forgets_the_state_and_the_previous_step():
    network, params = _network()
    obs, memory = _sequence()
    first = Memory(memory.hidden[0], memory.prev_action[0], memory.prev_reward[0], jnp.ones(3, bool))
    other = Memory(memory.hidden[0] + 5.0, 1 - memory.prev_action[0], memory.prev_reward[0] - 1.0, jnp.ones(3, bool))
    a, b = act(network, params, obs[0], first), act(network, params, obs[0], other)
    jax.tree_util.tree_map(np.testing.assert_array_equal, a, b)
    # ...and without a start they matter (the test above could not fail otherwise).
    c = act(network, params, obs[0], other._replace(start=jnp.zeros(3, bool)))
    assert not np.allclose(a[1], c[1])


def test_the_update_replays_what_the_rollout_stored():
    """Learner-level: in every update of a real run (episodes end and restart inside the
    rollouts), replaying the stored memory gives the rollout's own log-probs and values, and
    the stored memory is the previous step's action, reward and episode end."""
    from jaxnat.agents import distributions, ppo
    from jaxnat.agents.rollout import on_policy_learner

    def checked_update(config, network, train_state, transitions, advantages, targets, key):
        logits, value = replay(network, train_state.params, transitions.obs, transitions.memory)
        memory = transitions.memory
        checks = {
            "log_prob_error": jnp.abs(distributions.log_prob(logits, transitions.action) - transitions.log_prob).max(),
            "value_error": jnp.abs(value - transitions.value).max(),
            "start_mismatches": jnp.sum(memory.start[1:] != (transitions.done[:-1] > 0)),
            "action_mismatches": jnp.sum(memory.prev_action[1:] != transitions.action[:-1]),
            "reward_mismatches": jnp.sum(memory.prev_reward[1:] != transitions.reward[:-1]),
        }
        train_state, losses = ppo.RULE.update_step(config, network, train_state, transitions, advantages, targets, key)
        return train_state, {**losses, **checks}

    env, params = make_probe("recall")
    learner = on_policy_learner(CONFIGS["ppo"].replace(memory=8), env, params,
                                ppo.RULE._replace(update_step=checked_update))
    _, metrics = _jit(learner.train)(jax.random.key(0))
    metrics = jax.tree_util.tree_map(np.asarray, metrics)
    assert metrics["log_prob_error"].max() < 1e-5 and metrics["value_error"].max() < 1e-5
    for name in ("start", "action", "reward"):
        assert metrics[f"{name}_mismatches"].sum() == 0, name
    assert np.nanmean(metrics["episode_return"][-10:]) >= 0.9  # and it learned: the values mattered


@functools.cache
def trained(algo: str, memory: int):
    env, params = make_probe("recall")
    learner = MAKE[algo](CONFIGS[algo].replace(memory=memory), env, params)
    keys = jax.random.split(jax.random.key(0), SEEDS)
    runner, metrics = _jit(jax.vmap(learner.train))(keys)
    final = np.nanmean(np.asarray(metrics["episode_return"])[:, -10:], axis=1)
    return learner, runner, final, env, params


@pytest.mark.parametrize("algo", ["ppo", "a2c"])
def test_recall_probe_is_learned_with_memory_only(algo):
    *_, with_memory, _, _ = trained(algo, 16)
    *_, without, _, _ = trained(algo, 0)
    assert np.all(with_memory >= 0.9), with_memory
    # A feed-forward policy cannot know the cue at step 2: 0.5 in expectation.
    assert np.all(without <= 0.7), without


def test_evaluation_carries_the_memory():
    learner, runner, _, env, params = trained("ppo", 16)
    evaluate = jax.vmap(make_evaluate(learner.network, env, params, num_episodes=200))
    scores = evaluate(runner.train_state.params, jax.random.split(jax.random.key(1), SEEDS))
    np.testing.assert_array_equal(scores["greedy_return"], 1.0)
    np.testing.assert_array_equal(scores["greedy_length"], 2.0)


def test_recurrent_minibatches_must_divide_the_envs():
    env, params = make_probe("recall")
    config = CONFIGS["ppo"].replace(memory=4, num_envs=6, num_minibatches=4, num_steps=16)
    with pytest.raises(ValueError, match="num_envs=6 is not divisible by num_minibatches=4"):
        jax.eval_shape(make_ppo(config, env, params).train, jax.random.key(0))


def test_negative_memory_is_an_error():
    with pytest.raises(ValueError, match="GRU state size"):
        _network(memory=-1)


def test_a_recurrent_network_called_without_memory_is_an_error():
    network, params = _network()
    with pytest.raises(ValueError, match=r"called as \(obs, Memory\)"):
        network.apply(params, jnp.zeros((1, 3)))


def test_host_batched_envs_refuse_a_recurrent_policy():
    from types import SimpleNamespace

    from jaxnat.agents import ppo

    with pytest.raises(ValueError, match="recurrent policies train on jitted envs only"):
        ppo.make_host_ppo(CONFIGS["ppo"].replace(memory=8), SimpleNamespace(num_envs=4))
