"""DQN: the TD target by hand (plain and double), n-step returns by hand, epsilon schedule,
target-network period, learning start, replay ring buffer, and probe environments (one step,
observation-dependent, factored, two steps, time limits) under vmap over seeds."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnat.agents.dqn import DQNConfig, epsilon, make_dqn, nstep_transition, td_error_loss, td_loss
from jaxnat.agents.probes import make_probe
from jaxnat.agents.replay import replay_add, replay_init, replay_sample

_jit = functools.partial(jax.jit, compiler_options={"xla_backend_optimization_level": 0})

SEEDS = 5


# --- the pieces -------------------------------------------------------------------------------


class QTable:
    """A stand-in network: `apply(params, states) -> (Q per factor [B, n_f], unused value)`."""

    def apply(self, params, states):
        return tuple(q[states] for q in params), jnp.zeros(states.shape)


def huber(error):
    """Huber's loss with delta 1, written out."""
    return np.where(np.abs(error) <= 1.0, 0.5 * np.square(error), np.abs(error) - 0.5)


@pytest.mark.parametrize("loss", ["mse", "huber"])
@pytest.mark.parametrize("double", [False, True])
@pytest.mark.parametrize("terminated", [0.0, 1.0])
def test_td_target_by_hand(double, terminated, loss):
    # Two factors (2 and 3 actions), states 0 and 1; the transition 0 -> 1 took action (0, 1).
    online = (jnp.array([[0.5, 0.0], [0.0, 5.0]]), jnp.array([[0.0, -1.0, 0.0], [2.0, 1.0, 0.0]]))
    target = (jnp.array([[9.0, 9.0], [3.0, 1.0]]), jnp.array([[9.0, 9.0, 9.0], [0.0, 4.0, 1.0]]))
    batch = {"obs": jnp.array([0]), "action": jnp.array([[0, 1]]), "reward": jnp.array([1.0]),
             "next_obs": jnp.array([1]), "discount": jnp.array([0.5 * (1.0 - terminated)])}
    config = DQNConfig(gamma=0.5, double_dqn=double, loss=loss)
    # Plain: each head's best target value, 3 and 4; double: the target's values of the online
    # network's best actions (1 and 0), 1 and 0. The next-state value is their mean.
    next_value = 0.5 if double else 3.5
    y = 1.0 + 0.5 * (1.0 - terminated) * next_value
    errors = np.array([0.5 - y, -1.0 - y])  # per head: Q(s, a_f) - y
    expected = np.mean(np.square(errors) if loss == "mse" else huber(errors))
    loss, info = td_loss(config, QTable(), online, target, batch)
    np.testing.assert_allclose(float(loss), expected, rtol=1e-6)
    np.testing.assert_allclose(float(info["q_mean"]), -0.25)


def test_td_error_losses_by_hand():
    """"mse" squares the TD error; "huber" (Nature DQN's, delta 1) is half its square within 1
    and grows linearly beyond, so a large error pulls no harder than an error of 1."""
    errors = jnp.array([0.5, -2.0, 3.0])
    np.testing.assert_allclose(td_error_loss(errors, "mse"), [0.25, 4.0, 9.0])
    np.testing.assert_allclose(td_error_loss(errors, "huber"), [0.125, 1.5, 2.5])
    assert DQNConfig().loss == "mse"
    with pytest.raises(ValueError, match=r"^DQN loss 'l2' is not one of \('mse', 'huber'\)$"):
        td_error_loss(errors, "l2")


def test_nstep_transition_by_hand():
    """Three one-step transitions of three envs, oldest first, gamma 0.5. Env 0 runs on: the
    return covers all 3 steps and bootstraps from the third next observation with 0.5^3. Env 1
    terminates at step 2: 2 steps, no bootstrap. Env 2 is truncated at step 1: 1 step,
    bootstrapping from the final observation with 0.5. Rewards after an episode end are not
    counted."""
    reward = jnp.array([[1.0, 2.0, 4.0], [8.0, 16.0, 32.0], [64.0, 128.0, 256.0]])  # [n, B]
    terminated = jnp.array([[0, 0, 0], [0, 1, 0], [0, 0, 0]], bool)
    done = jnp.array([[0, 0, 1], [0, 1, 0], [0, 0, 1]], bool)
    next_obs = jnp.array([[10, 11, 12], [20, 21, 22], [30, 31, 32]])
    recent = {"obs": jnp.array([[0, 1, 2], [10, 11, 12], [20, 21, 22]]),
              "action": jnp.array([[[5], [6], [7]], [[0], [0], [0]], [[0], [0], [0]]]),
              "reward": reward, "next_obs": next_obs, "terminated": terminated, "done": done}
    out = jax.jit(nstep_transition)(recent, 0.5)
    np.testing.assert_allclose(out["reward"], [1 + 0.5 * 8 + 0.25 * 64, 2 + 0.5 * 16, 4.0])
    np.testing.assert_allclose(out["discount"], [0.125, 0.0, 0.5])
    np.testing.assert_array_equal(out["next_obs"], [30, 21, 12])
    np.testing.assert_array_equal(out["obs"], [0, 1, 2])
    np.testing.assert_array_equal(out["action"], [[5], [6], [7]])
    # One step: the Nature DQN target, r + gamma * (1 - terminated).
    one = nstep_transition(jax.tree.map(lambda x: x[1:2], recent), 0.5)
    np.testing.assert_allclose(one["reward"], [8.0, 16.0, 32.0])
    np.testing.assert_allclose(one["discount"], [0.5, 0.0, 0.5])


def test_nstep_returns_in_the_buffer():
    """Two-step returns on the two-step probe: the step-1 transition carries the step-2 reward
    (discounted once) and does not bootstrap (the episode terminated); the step-2 transition
    holds its own reward alone; the first `n_step - 1` steps of a run store nothing yet."""
    env, params = make_probe("two_step")
    config = DQNConfig(total_timesteps=16, num_envs=2, num_steps=4, gradient_steps=1, batch_size=4,
                       buffer_size=64, n_step=2, gamma=0.5, trunk="mlp")
    learner = make_dqn(config, env, params)
    runner, _ = _jit(learner.train)(jax.random.key(0))
    buffer = jax.tree.map(np.asarray, runner.buffer)
    assert int(buffer.size) == 2 * (8 - 1)  # 8 steps of 2 envs, the first one still pending
    data = jax.tree.map(lambda x: x[: buffer.size], buffer.data)
    first = data["obs"][:, 1] == 0.0  # step 1 shows [c, 0], step 2 [0, 1]
    right = data["action"][:, 0] == (data["obs"][:, 0] > 0)
    assert first.any() and (~first).any()
    np.testing.assert_allclose(data["reward"][first], 0.5 * right[first])
    np.testing.assert_allclose(data["discount"], 0.0)  # every return reaches the terminal step
    np.testing.assert_array_equal(data["next_obs"][first], [[0.0, 1.0]] * first.sum())


def test_epsilon_schedule():
    config = DQNConfig(eps_start=1.0, eps_end=0.1, exploration_steps=1000)
    values = [float(epsilon(config, t)) for t in (0, 250, 500, 1000, 5000)]
    np.testing.assert_allclose(values, [1.0, 0.775, 0.55, 0.1, 0.1], rtol=1e-6)


def test_replay_buffer_is_a_ring():
    buffer = replay_init({"x": jnp.zeros((2,), jnp.uint8), "r": jnp.float32(0)}, capacity=5)
    batch = lambda lo, hi: {"x": jnp.arange(lo, hi, dtype=jnp.uint8)[:, None].repeat(2, 1),  # noqa: E731
                            "r": jnp.arange(lo, hi, dtype=jnp.float32)}
    buffer = replay_add(buffer, batch(0, 3))
    assert int(buffer.size) == 3 and int(buffer.position) == 3
    buffer = jax.jit(replay_add)(buffer, batch(3, 7))  # wraps: 5 and 6 overwrite 0 and 1
    assert int(buffer.size) == 5 and int(buffer.position) == 2
    np.testing.assert_array_equal(buffer.data["r"], [5, 6, 2, 3, 4])
    assert buffer.data["x"].dtype == jnp.uint8
    sample = replay_sample(buffer, jax.random.key(0), 200)
    assert set(np.asarray(sample["r"]).tolist()) == {2.0, 3.0, 4.0, 5.0, 6.0}
    np.testing.assert_array_equal(sample["x"][:, 0], sample["r"])
    with pytest.raises(ValueError, match="capacity 5"):
        replay_add(buffer, batch(0, 6))


def test_target_network_update_period_and_learning_start():
    """One gradient step per update; the target copies the online network after gradient steps
    3 and 6 and stays put in between; nothing learns before `learning_starts` env steps."""
    env, params = make_probe("sign")
    config = DQNConfig(total_timesteps=64, num_envs=2, num_steps=1, gradient_steps=1, batch_size=4,
                       buffer_size=64, optimizer="adam", lr=1e-2, learning_starts=4,
                       target_update_period=3, trunk="mlp")
    learner = make_dqn(config, env, params)
    run = _jit(functools.partial(learner.run, num_updates=1))
    runner = learner.init(jax.random.key(0))
    initial = runner.train_state.params
    same = lambda a, b: all(np.array_equal(x, y) for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)))  # noqa: E731
    steps, copies = [], []
    for update in range(1, 9):
        previous_target = runner.target_params
        runner, _ = run(runner)
        steps.append(int(runner.train_state.step))
        copies.append(not same(runner.target_params, previous_target))
        if int(runner.train_state.step) % 3 == 0 and int(runner.train_state.step) > 0:
            assert same(runner.target_params, runner.train_state.params)
    # Env steps after update u: 2u; learning starts at 4 env steps (update 2).
    assert steps == [0, 1, 2, 3, 4, 5, 6, 7]
    assert copies == [False, False, False, True, False, False, True, False]
    assert int(runner.buffer.size) == 16
    assert not same(runner.train_state.params, initial)


def test_soft_target_updates_move_a_fraction_tau_of_the_way():
    """With `tau < 1` each target update (the same gradient steps as a copy's) moves the target
    `tau` of the way to the online network (Polyak averaging), and only then."""
    env, params = make_probe("sign")
    config = DQNConfig(total_timesteps=64, num_envs=2, num_steps=1, gradient_steps=1, batch_size=4,
                       buffer_size=64, optimizer="adam", lr=1e-2, learning_starts=4,
                       target_update_period=3, tau=0.25, trunk="mlp")
    learner = make_dqn(config, env, params)
    run = _jit(functools.partial(learner.run, num_updates=1))
    runner = learner.init(jax.random.key(0))
    moved = []
    for update in range(1, 9):
        previous_target = runner.target_params
        runner, _ = run(runner)
        leaves = zip(jax.tree.leaves(runner.target_params), jax.tree.leaves(previous_target),
                     jax.tree.leaves(runner.train_state.params))
        if int(runner.train_state.step) % 3 == 0 and int(runner.train_state.step) > 0:
            leaves = list(leaves)
            for target, previous, online in leaves:
                np.testing.assert_allclose(target, 0.25 * online + 0.75 * previous, rtol=1e-6, atol=1e-7)
            assert not all(np.allclose(target, online) for target, _, online in leaves)  # not a copy
            moved.append(True)
        else:
            moved.append(not all(np.array_equal(t, p) for t, p, _ in leaves))
    assert moved == [False, False, False, True, False, False, True, False]

def test_bad_config_is_a_clear_error():
    env, params = make_probe("sign")
    with pytest.raises(ValueError, match="optimizer 'sgd'"):
        make_dqn(DQNConfig(optimizer="sgd", trunk="mlp"), env, params)
    with pytest.raises(ValueError, match="buffer_size=4 is smaller"):
        make_dqn(DQNConfig(buffer_size=4, trunk="mlp"), env, params)
    with pytest.raises(ValueError, match="n_step=0"):
        make_dqn(DQNConfig(n_step=0, trunk="mlp"), env, params)
    for tau in (0.0, 1.5):
        with pytest.raises(ValueError, match=rf"^tau={tau} must be in \(0, 1\]"):
            make_dqn(DQNConfig(tau=tau, trunk="mlp"), env, params)
    with pytest.raises(ValueError, match=r"^DQN loss 'l1' is not one of \('mse', 'huber'\)$"):
        make_dqn(DQNConfig(loss="l1", trunk="mlp"), env, params)


# --- learning the probes ----------------------------------------------------------------------
# The two-step probe's step-2 observation hides whether the step-1 action was right, so
# one-step Q-learning values both step-1 actions alike: it needs (and gets) two-step returns.

# mlp trunk, 4 envs x 4 steps, 2 gradient steps per update (a replay ratio of 8 samples per
# env step), Adam 3e-3, double DQN, epsilon 1 -> 0 over 1024 env steps, 256 updates.
CONFIG = DQNConfig(total_timesteps=4096, num_envs=4, num_steps=4, gradient_steps=2, buffer_size=1024,
                   optimizer="adam", lr=3e-3, eps_end=0.0, exploration_steps=1024, learning_starts=128,
                   target_update_period=25, double_dqn=True, trunk="mlp")
PROBE_CONFIG = {"endless": {"gamma": 0.9}}
STATIC = {"two_step": {"n_step": 2}}  # config fields that change the program


@functools.cache
def trained(probe: str):
    env, params = make_probe(probe)
    config = CONFIG.replace(**STATIC.get(probe, {}))
    learner = make_dqn(config, env, params)
    config = config.replace(**PROBE_CONFIG.get(probe, {}))
    runner, metrics = _jit(jax.vmap(learner.train, in_axes=(0, None)))(jax.random.split(jax.random.key(0), SEEDS), config)
    return learner, runner.train_state.params, jax.tree_util.tree_map(np.asarray, metrics)


def q_values(learner, params, obs):
    """Q per factor `[S, B, n]` for every seed."""
    q, _ = jax.vmap(lambda p: learner.network.apply(p, jnp.asarray(obs, jnp.float32)))(params)
    return [np.asarray(x) for x in q]


def final_return(metrics, last=10):
    return np.nanmean(metrics["episode_return"][:, -last:], axis=1)


def test_q_learns_constant_reward():
    learner, params, metrics = trained("constant_reward")
    (q,) = q_values(learner, params, [[1.0]])
    np.testing.assert_allclose(q[:, 0, 0], 1.0, atol=0.05)


def test_greedy_policy_reads_the_observation():
    learner, params, metrics = trained("sign")
    (q,) = q_values(learner, params, [[1.0], [-1.0]])
    np.testing.assert_array_equal(q.argmax(-1), [[1, 0]] * SEEDS)
    np.testing.assert_allclose(q.max(-1), 1.0, atol=0.1)
    assert np.all(final_return(metrics) >= 0.95), final_return(metrics)


def test_factored_heads():
    learner, params, metrics = trained("factored")
    targets = [(a, b) for a in range(2) for b in range(3)]
    obs = [np.concatenate([np.eye(2)[a], np.eye(3)[b]]) for a, b in targets]
    q_a, q_b = q_values(learner, params, obs)
    greedy = np.stack([q_a.argmax(-1), q_b.argmax(-1)], axis=-1)
    np.testing.assert_array_equal(greedy, np.broadcast_to(targets, greedy.shape))
    assert np.all(final_return(metrics) >= 0.95), final_return(metrics)


def test_q_bootstraps_through_time_limits():
    """Reward 1 per step, truncated (never terminated) after 5 steps, gamma 0.9: Q = 10. A target
    that stopped at truncations would give about 2.7 (see test_agents.py)."""
    learner, params, metrics = trained("endless")
    (q,) = q_values(learner, params, [[1.0]])
    assert np.all(q[:, 0, 0] > 8.0) and np.all(q[:, 0, 0] < 12.0), q[:, 0, 0]
    # Updates of 4 steps and episodes of 5: some updates see no episode end (NaN).
    np.testing.assert_array_equal(np.nanmax(metrics["terminated_fraction"][:, -10:], axis=1), 0.0)
    np.testing.assert_array_equal(np.nanmean(metrics["episode_return"][:, -10:], axis=1), 5.0)


def test_two_step_credit_assignment():
    """Step 1 shows the cue +-1, step 2 shows [0, 1] whatever was done; the step-2 reward is 1
    only if the step-1 action matched the cue. With two-step returns Q(step 1, right) = gamma
    and Q(step 1, wrong) = 0 (less exactly: epsilon falls to 0, so wrong actions get rare)."""
    learner, params, metrics = trained("two_step")
    (q,) = q_values(learner, params, [[1.0, 0.0], [-1.0, 0.0]])
    np.testing.assert_array_equal(q.argmax(-1), [[1, 0]] * SEEDS)
    np.testing.assert_allclose(q.max(-1), CONFIG.gamma, atol=0.1)
    assert np.all(q.min(-1) < 0.3), q
    assert np.all(final_return(metrics) >= 0.95), final_return(metrics)
