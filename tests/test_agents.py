"""PPO and A2C: probe environments, GAE with time limits, traced hyperparameters, config errors.

The probes (`jaxnat.agents.probes`) are one- and two-step tasks whose answer is known, so a
learner that trains without error but learns the wrong thing fails here. Every training runs
several seeds under one `jit(vmap(train))`, with the config passed in as a traced (stacked)
argument; each compiled trainer is cached for the module, so a test that reuses a probe and an
algorithm (the traced-hyperparameter test) does not compile again.
"""

import functools
import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import struct

from jaxnat import spaces
from jaxnat.agents import A2CConfig, PPOConfig, make_a2c, make_ppo
from jaxnat.agents.rollout import Transition, gae, pack_vectors, unpack_vectors
from jaxnat.agents.probes import make_probe
from jaxnat.testing import check_env

# XLA:CPU spends most of a tiny learner's test time optimising machine code that then runs for
# a fraction of a second; unoptimised code compiles about 3x faster and trains the same.
_jit = functools.partial(jax.jit, compiler_options={"xla_backend_optimization_level": 0})

SEEDS = 5
ALGOS = ["ppo", "a2c"]

# Tiny networks (trunk="mlp": dense 64, 64), 4 envs, 8192 steps: 128 PPO / 256 A2C updates.
# Over 96 seeds, PPO solved every probe within 25 updates and A2C within 120 (the factored one
# is the slowest). A2C gets lr 1e-3: its RMSprop at 3e-3 keeps jittering a converged value
# by up to 0.15.
# The probes check values in reward units: no normalisation (on by default for vector observations).
RAW = dict(normalize_observations=False, normalize_rewards=False)
CONFIGS = {
    "ppo": PPOConfig(total_timesteps=8192, num_envs=4, num_steps=16, update_epochs=2,
                     num_minibatches=2, trunk="mlp", lr=3e-3, **RAW),
    "a2c": A2CConfig(total_timesteps=8192, num_envs=4, num_steps=8, trunk="mlp", lr=1e-3, **RAW),
}
MAKE = {"ppo": make_ppo, "a2c": make_a2c}
# Per-probe changes to the traced hyperparameters.
PROBE_CONFIG = {"endless": {"gamma": 0.9}, "costly_start": {"gamma": 0.9}}


def stack(*configs):
    """One config whose traced fields have a leading batch axis (static fields must agree)."""
    return jax.tree_util.tree_map(lambda *x: jnp.stack(x), *configs)


@functools.cache
def trainer(probe: str, algo: str):
    """`(learner, jit(vmap(train)))` for a probe; `train(keys, configs)` takes stacked configs."""
    env, params = make_probe(probe)
    learner = MAKE[algo](CONFIGS[algo], env, params)
    return learner, _jit(jax.vmap(learner.train))


@functools.cache
def trained(probe: str, algo: str):
    """`(learner, params, metrics)` after training SEEDS seeds; params and metrics are batched
    over seeds, metrics are NumPy arrays `[SEEDS, num_updates]`."""
    learner, train = trainer(probe, algo)
    config = CONFIGS[algo].replace(**PROBE_CONFIG.get(probe, {}))
    keys = jax.random.split(jax.random.key(0), SEEDS)
    runner, metrics = train(keys, stack(*[config] * SEEDS))
    return learner, runner.train_state.params, jax.tree_util.tree_map(np.asarray, metrics)


def apply(learner, params, obs):
    """The network on `obs` for every seed: `(logits per factor [S, B, n], values [S, B])`."""
    return jax.vmap(lambda p: learner.network.apply(p, jnp.asarray(obs, jnp.float32)))(params)


def final_return(metrics, last: int = 10):
    """Mean episode return over the last updates, per seed."""
    return np.nanmean(metrics["episode_return"][:, -last:], axis=1)


# --- the probes themselves ------------------------------------------------------------------


@pytest.mark.parametrize("probe", ["sign", "two_step", "factored"])
def test_random_probes_keep_the_env_contract(probe):
    env, params = make_probe(probe)
    check_env(env, params, num_steps=6)


def test_two_step_probe_rewards_only_the_first_action():
    env, params = make_probe("two_step")
    step = jax.jit(env.step)
    for cue, first, second in itertools.product([0, 1], [0, 1], [0, 1]):
        key = jax.random.key(cue)
        obs, state = env.reset(key, params)
        state = state.replace(cue=jnp.array([cue, 0], jnp.int32))  # force the cue
        obs = env.unwrapped.get_obs(state, params)
        np.testing.assert_array_equal(np.asarray(obs), [2 * cue - 1, 0])
        obs, state, r1, term1, trunc1, _ = step(key, state, jnp.int32(first), params)
        np.testing.assert_array_equal(np.asarray(obs), [0, 1])  # step 2 shows nothing of step 1
        assert float(r1) == 0 and not bool(term1) and not bool(trunc1)
        _, state, r2, term2, trunc2, info = step(key, state, jnp.int32(second), params)
        assert float(r2) == float(first == cue), (cue, first, second)
        assert bool(term2) and not bool(trunc2) and int(state.time) == 0


def test_endless_probe_is_truncated_never_terminated():
    env, params = make_probe("endless")
    _, state = env.reset(jax.random.key(0), params)
    flags = []
    for t in range(10):
        _, state, reward, terminated, truncated, _ = env.step(jax.random.key(t), state, jnp.int32(0), params)
        assert float(reward) == 1.0 and not bool(terminated)
        flags.append(bool(truncated))
    assert flags == [False] * 4 + [True] + [False] * 4 + [True]


# --- learning the probes ----------------------------------------------------------------------


@pytest.mark.parametrize("algo", ALGOS)
def test_value_learns_constant_reward(algo):
    learner, params, metrics = trained("constant_reward", algo)
    _, value = apply(learner, params, [[1.0]])
    np.testing.assert_allclose(np.asarray(value)[:, 0], 1.0, atol=0.05)
    np.testing.assert_array_equal(metrics["episode_length"][:, -1], 1.0)


@pytest.mark.parametrize("algo", ALGOS)
def test_policy_reads_the_observation(algo):
    learner, params, metrics = trained("sign", algo)
    (logits,), _ = apply(learner, params, [[1.0], [-1.0]])
    greedy = np.asarray(jnp.argmax(logits, axis=-1))
    np.testing.assert_array_equal(greedy, [[1, 0]] * SEEDS)
    assert np.all(final_return(metrics) >= 0.9), final_return(metrics)


@pytest.mark.parametrize("algo", ALGOS)
def test_credit_assignment_over_two_steps(algo):
    learner, params, metrics = trained("two_step", algo)
    (logits,), _ = apply(learner, params, [[1.0, 0.0], [-1.0, 0.0]])
    greedy = np.asarray(jnp.argmax(logits, axis=-1))
    np.testing.assert_array_equal(greedy, [[1, 0]] * SEEDS)
    assert np.all(final_return(metrics) >= 0.9), final_return(metrics)
    np.testing.assert_array_equal(metrics["episode_length"][:, -1], 2.0)


@pytest.mark.parametrize("algo", ALGOS)
def test_factored_multidiscrete_action(algo):
    learner, params, metrics = trained("factored", algo)
    targets = list(itertools.product(range(2), range(3)))
    obs = [np.concatenate([np.eye(2)[a], np.eye(3)[b]]) for a, b in targets]
    (logits_a, logits_b), _ = apply(learner, params, obs)
    greedy = np.stack([jnp.argmax(logits_a, -1), jnp.argmax(logits_b, -1)], axis=-1)
    np.testing.assert_array_equal(greedy, np.broadcast_to(targets, greedy.shape))
    assert np.all(final_return(metrics) >= 0.9), final_return(metrics)


@pytest.mark.parametrize("algo", ALGOS)
def test_value_bootstraps_through_time_limits(algo):
    """Reward 1 per step, never terminated, truncated after 5 steps, gamma 0.9: the value is
    1 / (1 - 0.9) = 10. Treating truncation as termination gives about 2.7 instead (the mean
    of the 1- to 5-step discounted sums, as the constant observation cannot tell them apart)."""
    learner, params, metrics = trained("endless", algo)
    _, value = apply(learner, params, [[1.0]])
    value = np.asarray(value)[:, 0]
    assert np.all(value > 8.0) and np.all(value < 12.0), value
    np.testing.assert_array_equal(metrics["episode_length"][:, -1], 5.0)
    np.testing.assert_array_equal(metrics["episode_return"][:, -1], 5.0)
    np.testing.assert_array_equal(metrics["terminated_fraction"][:, -1], 0.0)


@pytest.mark.parametrize("algo", ALGOS)
def test_truncated_steps_bootstrap_from_the_final_observation(algo):
    """The first step of each 5-step episode shows [1, 0] and pays -10, later ones show [0, 1]
    and pay 1; gamma 0.9: V([0, 1]) = 10, V([1, 0]) = -1. Bootstrapping the truncated step
    from the next episode's first observation instead of `final_observation` gives about
    V([0, 1]) = -11 (the constant observation of the test above cannot tell the two apart)."""
    learner, params, metrics = trained("costly_start", algo)
    _, value = apply(learner, params, [[1.0, 0.0], [0.0, 1.0]])
    start, later = np.asarray(value).T
    assert np.all(later > 8.0) and np.all(later < 12.0), later
    assert np.all(np.abs(start - (-1.0)) < 2.0), start
    np.testing.assert_array_equal(metrics["episode_return"][:, -1], -10.0 + 4.0)


@pytest.mark.parametrize("num_steps", [10, 12])
@pytest.mark.parametrize("final_rows", ["normalised", "all", "compacted", "uncompacted"])
def test_rollout_next_value_is_the_value_of_the_final_observation(num_steps, final_rows):
    """The rollout's `next_value` (read in the next step's network call for a feed-forward
    policy, the last step's after the loop) is exactly V(final observation) on every step of
    an untrained policy: on the costly-start probe every final observation is [0, 1], and the
    truncated steps (t = 4, 9) would read V([1, 0]) from the next episode's first observation
    if it came from the wrong place. With 10 steps the last one is truncated; with 12 not.
    Unnormalised observations value only the truncated rows' final ones: every env of the
    probe truncates together, past the compacted share (all rows valued) or within it when
    the share is the whole batch (the truncated rows gathered, valued and put back), or with
    no compacted call (share None)."""
    from jaxnat.agents import ppo
    from jaxnat.agents.rollout import on_policy_learner

    env, params = make_probe("costly_start")
    config = CONFIGS["ppo"].replace(num_steps=num_steps)
    if final_rows != "normalised":
        config = config.replace(normalize_observations=False)
    share = {"compacted": 1.0, "uncompacted": None}.get(final_rows, 0.125)
    learner = on_policy_learner(config, env, params, ppo.RULE, final_value_share=share)
    runner = learner.init(jax.random.key(3))
    _, batch = jax.jit(learner.rollout)(runner, config)
    _, value = learner.network.apply(runner.train_state.params, jnp.asarray([[0.0, 1.0], [1.0, 0.0]]))
    assert abs(float(value[0] - value[1])) > 1e-3  # the probe can tell the two apart
    np.testing.assert_allclose(np.asarray(batch.next_value), float(value[0]), rtol=1e-6, atol=1e-6)
    np.testing.assert_array_equal(np.asarray(batch.done)[:, 0], [t % 5 == 4 for t in range(num_steps)])
    # Where no episode ended, the next step's own value is the same number.
    ongoing = np.asarray(batch.done)[:-1] == 0
    np.testing.assert_allclose(np.asarray(batch.next_value)[:-1][ongoing], np.asarray(batch.value)[1:][ongoing],
                               rtol=1e-6, atol=1e-6)


# --- GAE against hand computations ---------------------------------------------------------------


def transitions(reward, value, done, next_value):
    r = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
    zeros = jnp.zeros_like(r(reward))
    return Transition(obs=zeros, action=zeros.astype(jnp.int32)[..., None], log_prob=zeros,
                      value=r(value), reward=r(reward), done=r(done), next_value=r(next_value),
                      info={})


def gae_loop(reward, value, done, next_value, gamma, lam):
    """The textbook backward recursion, one env at a time, in float64 Python."""
    reward, value, done, next_value = (np.asarray(x, np.float64) for x in (reward, value, done, next_value))
    advantages = np.zeros_like(reward)
    for env in range(reward.shape[1]):
        running = 0.0
        for t in reversed(range(reward.shape[0])):
            delta = reward[t, env] + gamma * next_value[t, env] - value[t, env]
            running = delta + (0.0 if done[t, env] else gamma * lam * running)
            advantages[t, env] = running
    return advantages, advantages + value


def test_gae_small_example_by_hand():
    # t=0: ongoing, next obs has V=3;  t=1: truncated, V(final obs)=4;  t=2: terminated.
    batch = transitions(reward=[1, 0, 2], value=[2, 3, 1], done=[0, 1, 1], next_value=[3, 4, 0])
    advantages, targets = gae(batch, 0.5, 0.5)
    # deltas: 1 + .5*3 - 2 = .5;  0 + .5*4 - 3 = -1;  2 + 0 - 1 = 1.
    # A2 = 1;  A1 = -1 (trace cut: t=1 ended its episode);  A0 = .5 + .25 * A1 = .25.
    np.testing.assert_allclose(np.asarray(advantages), [0.25, -1.0, 1.0], atol=1e-6)
    np.testing.assert_allclose(np.asarray(targets), [2.25, 2.0, 2.0], atol=1e-6)


def test_gae_matches_python_loop_with_truncation_and_termination():
    T, N, gamma, lam = 9, 3, 0.9, 0.8
    rng = np.random.default_rng(0)
    reward = rng.normal(size=(T, N))
    value = rng.normal(size=(T, N))
    # env 0: truncated at t=3 (bootstraps from V(final obs) != 0), terminated at t=6;
    # env 1: never ends; env 2: terminated at t=0 and t=8, truncated at t=4.
    done = np.zeros((T, N))
    terminated = np.zeros((T, N), bool)
    for t, env, term in [(3, 0, False), (6, 0, True), (0, 2, True), (4, 2, False), (8, 2, True)]:
        done[t, env], terminated[t, env] = 1, term
    # Not ended: V of the next observation (the next step's value); truncated: V(final obs),
    # which is not the next step's value (that one is a fresh episode's); terminated: 0.
    next_value = np.concatenate([value[1:], rng.normal(size=(1, N))])
    truncated = (done == 1) & ~terminated
    next_value[truncated] = rng.normal(size=truncated.sum()) + 5.0
    next_value[terminated] = 0.0

    advantages, targets = jax.jit(gae)(transitions(reward, value, done, next_value), gamma, lam)
    want_adv, want_targets = gae_loop(reward, value, done, next_value, gamma, lam)
    np.testing.assert_allclose(np.asarray(advantages), want_adv, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(np.asarray(targets), want_targets, rtol=1e-5, atol=1e-5)


def test_gae_trace_is_cut_at_episode_ends():
    T, gamma, lam = 6, 0.99, 0.95
    rng = np.random.default_rng(1)
    reward, value = rng.normal(size=(T, 1)), rng.normal(size=(T, 1))
    next_value = np.concatenate([value[1:], [[0.5]]])
    done = np.zeros((T, 1))
    done[2] = 1  # truncated at t=2
    next_value[2] = 7.0
    base, _ = gae(transitions(reward, value, done, next_value), gamma, lam)

    # Whatever happens after the episode end cannot change the advantages up to it ...
    later = reward.copy()
    later[3:] += 100.0
    changed, _ = gae(transitions(later, value, done, next_value), gamma, lam)
    np.testing.assert_allclose(np.asarray(changed)[:3], np.asarray(base)[:3], atol=1e-5)
    assert np.all(np.abs(np.asarray(changed)[3:] - np.asarray(base)[3:]) > 1.0)
    # ... but the value of the truncated episode's final observation does.
    bootstrap = next_value.copy()
    bootstrap[2] = 8.0
    moved, _ = gae(transitions(reward, value, done, bootstrap), gamma, lam)
    np.testing.assert_allclose(np.asarray(moved)[2] - np.asarray(base)[2], gamma * 1.0, rtol=1e-5)
    np.testing.assert_allclose(np.asarray(moved)[1] - np.asarray(base)[1], gamma * lam * gamma, rtol=1e-5)
    # Without the episode end the later rewards flow back.
    no_end = done.copy()
    no_end[2] = 0
    flowing, _ = gae(transitions(later, value, no_end, next_value), gamma, lam)
    assert np.all(np.asarray(flowing)[:3] - np.asarray(base)[:3] > 1.0)


# --- other env APIs, traced hyperparameters, config errors -----------------------------------


@struct.dataclass
class LegacyState:
    cue: jax.Array
    time: jax.Array


@struct.dataclass
class LegacyParams:
    max_steps_in_episode: int = 10


class LegacySignEnv:
    """gymnax 0.x / PureJaxRL style: no jaxnat base class, `step` returns
    `(obs, state, reward, done, info)` and resets by itself. The sign probe: obs `[+-1]`,
    reward 1 for action `(obs > 0)`, one-step episodes."""

    default_params = LegacyParams()

    def reset(self, key, params):
        state = LegacyState(jax.random.bernoulli(key).astype(jnp.int32), jnp.int32(0))
        return self._obs(state), state

    def _obs(self, state):
        return (2.0 * state.cue - 1.0)[None].astype(jnp.float32)

    def step(self, key, state, action, params):
        reward = (action == state.cue).astype(jnp.float32)
        obs, state = self.reset(key, params)  # done every step: gymnax resets inside step
        return obs, state, reward, jnp.bool_(True), {"discount": jnp.float32(0.0)}

    def observation_space(self, params):
        return spaces.Box(-1.0, 1.0, (1,), jnp.float32)

    def action_space(self, params):
        return spaces.Discrete(2)


def test_gymnax_0x_five_tuple_env_trains():
    env = LegacySignEnv()
    learner = make_ppo(CONFIGS["ppo"], env, env.default_params)
    runner, metrics = _jit(jax.vmap(learner.train))(jax.random.split(jax.random.key(0), 2))
    metrics = jax.tree_util.tree_map(np.asarray, metrics)
    for name in ["episode_return", "episode_length", "terminated_fraction", "policy_loss",
                 "value_loss", "entropy"]:
        assert np.all(np.isfinite(metrics[name])), name
    np.testing.assert_array_equal(metrics["terminated_fraction"], 1.0)  # done counts as termination
    assert np.all(final_return(metrics) >= 0.9), final_return(metrics)


def test_hyperparameters_are_traced_and_vmappable():
    learner, train = trainer("sign", "ppo")  # compiled (and cached) by the probe test
    lrs = [3e-3, 3e-3, 1e-3, 0.0, 0.0]
    assert len(lrs) == SEEDS  # same shapes as the probe run: no new compile
    configs = stack(*[CONFIGS["ppo"].replace(lr=lr) for lr in lrs])
    keys = jnp.stack([jax.random.key(3)] * SEEDS)
    runner, metrics = train(keys, configs)
    initial = _jit(jax.vmap(learner.init))(keys, configs).train_state.params
    leaves = [np.asarray(x) for x in jax.tree_util.tree_leaves(runner.train_state.params)]
    initial = [np.asarray(x) for x in jax.tree_util.tree_leaves(initial)]

    def same(i, j):
        return all(np.array_equal(x[i], x[j]) for x in leaves)

    assert same(0, 1), "same key and config, different params"
    assert not same(0, 2), "a different learning rate gave the same params: lr is not used"
    # `initial` comes from another program, whose orthogonal init (a QR) may round differently
    # (by ~3e-6); 128 Adam steps at lr >= 1e-3 move the params by far more.
    for i in (3, 4):
        for x, x0 in zip(leaves, initial):
            np.testing.assert_allclose(x[i], x0[i], rtol=0, atol=1e-5, err_msg="lr=0 changed the params")
    for i in (0, 2):
        assert max(np.abs(x[i] - x0[i]).max() for x, x0 in zip(leaves, initial)) > 1e-2
    assert np.all(np.isfinite(np.asarray(metrics["value_loss"])))


def test_chunked_runs_take_traced_configs():
    """`init` and `run` in separate jitted calls (a long run in chunks), config passed in."""
    env, params = make_probe("sign")
    learner = make_a2c(CONFIGS["a2c"], env, params)
    configs = stack(*[CONFIGS["a2c"].replace(lr=lr) for lr in (1e-3, 3e-3)])
    runner = _jit(jax.vmap(learner.init))(jax.random.split(jax.random.key(0), 2), configs)
    run = _jit(jax.vmap(lambda runner, config: learner.run(runner, config, num_updates=4)))
    for _ in range(2):
        runner, metrics = run(runner, configs)
    np.testing.assert_array_equal(np.asarray(runner.update), [8, 8])
    assert np.all(np.isfinite(np.asarray(metrics["value_loss"])))


@pytest.mark.parametrize("algo", ALGOS)
def test_budget_below_one_rollout_is_an_error(algo):
    env, params = make_probe("sign")
    config = CONFIGS[algo]
    config = config.replace(total_timesteps=config.num_envs * config.num_steps - 1)
    with pytest.raises(ValueError, match="less than one rollout"):
        MAKE[algo](config, env, params)
    # Exactly one rollout is one update.
    one_rollout = config.replace(total_timesteps=config.num_envs * config.num_steps)
    assert MAKE[algo](one_rollout, env, params).num_updates == 1


@pytest.mark.parametrize("algo", ALGOS)
def test_trunk_that_does_not_fit_the_observation_is_an_error(algo):
    env, params = make_probe("sign")
    with pytest.raises(ValueError, match="mnist.*needs \\[H, W, C\\] images.*mlp"):
        MAKE[algo](CONFIGS[algo].replace(trunk="mnist"), env, params)
    with pytest.raises(ValueError, match="Unknown trunk 'mpl'.*'mlp'"):
        MAKE[algo](CONFIGS[algo].replace(trunk="mpl"), env, params)


def test_default_trunk_for_vector_observations_is_mlp():
    env, params = make_probe("sign")
    assert make_ppo(CONFIGS["ppo"].replace(trunk=None), env, params).network.trunk == "mlp"


def test_minibatches_must_divide_the_batch():
    env, params = make_probe("sign")
    config = CONFIGS["ppo"].replace(num_minibatches=3)  # 4 envs * 16 steps = 64
    with pytest.raises(ValueError, match="not divisible by num_minibatches=3"):
        jax.eval_shape(make_ppo(config, env, params).train, jax.random.key(0))


def test_vmapped_init_equals_per_seed_init_for_the_paper_trunk():
    """Five seeds' MNIST-trunk parameters built under `jit(vmap(...))` are exactly the ones each
    seed gets alone. (A batched orthogonal init used to deadlock here on a 2-core CPU.)"""
    from jaxnat.agents.networks import init_params, make_actor_critic

    observation_space = spaces.Box(0, 255, (28, 28, 3), jnp.uint8)
    network = make_actor_critic(observation_space, spaces.MultiDiscrete([4, 10]), "mnist")
    keys = jax.random.split(jax.random.key(3), SEEDS)
    batched = jax.jit(jax.vmap(lambda k: init_params(network, observation_space, k)))(keys)
    for seed in range(SEEDS):
        alone = init_params(network, observation_space, keys[seed])
        jax.tree_util.tree_map(
            lambda b, a: np.testing.assert_array_equal(b[seed], a), batched, alone
        )


def test_bfloat16_trunk_learns_a_probe():
    env, params = make_probe("sign")
    learner = make_ppo(CONFIGS["ppo"].replace(dtype="bfloat16"), env, params)
    runner, metrics = _jit(jax.vmap(learner.train))(jax.random.split(jax.random.key(0), 2))
    assert {x.dtype for x in jax.tree_util.tree_leaves(runner.train_state.params)} == {jnp.dtype("float32")}
    assert np.all(final_return(jax.tree_util.tree_map(np.asarray, metrics)) >= 0.9)


def test_ppo_weight_decay_is_decoupled_and_off_by_default():
    from jaxnat.agents.ppo import _optimizer

    params = {"w": jnp.array([1.0, -2.0])}
    zero_grads = {"w": jnp.zeros(2)}
    for weight_decay, expected in [(0.0, [0.0, 0.0]), (0.5, [-0.005, 0.01])]:
        tx = _optimizer(PPOConfig(lr=0.01, anneal_lr=False, weight_decay=weight_decay), 10)
        updates, _ = tx.update(zero_grads, tx.init(params), params)
        np.testing.assert_allclose(updates["w"], expected, rtol=1e-6)
    assert PPOConfig().weight_decay == 0.0


@pytest.mark.parametrize("probe, expected", [("sign", 0.5), ("factored", 1 / 6)])
def test_chance_is_the_uniform_random_policy(probe, expected):
    """`make_chance` scores uniformly drawn actions: half the sign probe's right answers, one in
    six of the factored probe's (2 x 3 actions, one right pair)."""
    from jaxnat.agents.rollout import make_chance

    env, params = make_probe(probe)
    scores = jax.jit(make_chance(env, params, num_episodes=4000, max_steps=1))(jax.random.key(0))
    assert abs(float(scores["return"]) - expected) < 0.03, scores
    assert float(scores["length"]) == 1.0 and float(scores["unfinished"]) == 0.0


def test_a_steps_per_env_scalars_round_trip_exactly_through_one_packed_write():
    """The scan driver writes a step's 1-D float32/bool leaves as one [N, k] array: stacked over
    steps and unpacked, every leaf comes back with its dtype and its exact values; other leaves
    (ints, observations) are left as they are."""
    key = jax.random.key(3)
    record = {"obs": jax.random.normal(key, (4, 2, 2)), "reward": jax.random.normal(key, (4,)) * 1e30,
              "done": jnp.array([True, False, True, False]), "length": jnp.arange(4, dtype=jnp.int32),
              "info": {"value": jnp.array([np.nan, -0.0, np.inf, 1e-45], jnp.float32)}}
    layout = {}
    packed, others = pack_vectors(record, layout)
    assert packed.shape == (4, 3) and [x.dtype for x in others] == [jnp.int32, jnp.float32]
    stacked = jax.tree_util.tree_map(lambda *x: jnp.stack(x), (packed, others), (packed, others))
    back = unpack_vectors(stacked, layout)
    for name, x in jax.tree_util.tree_leaves_with_path(record):
        got = functools.reduce(lambda t, k: t[k.key], name, back)
        assert got.dtype == x.dtype and got.shape == (2, *x.shape)
        np.testing.assert_array_equal(np.asarray(got[1]), np.asarray(x))
    assert np.signbit(back["info"]["value"][0, 1])  # -0.0 survives
    one = {"reward": jnp.zeros(4), "obs": jnp.zeros((4, 2))}  # a single vector: nothing to pack
    assert pack_vectors(one, layout) is one and unpack_vectors(one, layout) is one
