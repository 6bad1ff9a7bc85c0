"""Wrappers: autoreset, logging, vmap, frame stacking, noise observations, legacy API."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnat.testing import check_env
from jaxnat.wrappers.base import Wrapper
from jaxnat.vision_envs.classify import RIGHT, Classify
from jaxnat.wrappers import (
    AutoResetWrapper,
    FrameStackWrapper,
    LegacyStepAPIWrapper,
    LogWrapper,
    NoiseObservationWrapper,
    VmapWrapper,
)


@pytest.fixture
def env(toy_dataset):
    return Classify(toy_dataset, w=3, M=3)


def wrong(state):
    return jnp.array([RIGHT, (state.label + 1) % 3], jnp.int32)


def right(state):
    return jnp.array([RIGHT, state.label], jnp.int32)


def test_autoreset_on_truncation_keeps_final_observation(env):
    wrapped = AutoResetWrapper(env)
    params = env.default_params
    obs, state = wrapped.reset(jax.random.key(0), params)
    for t in range(3):
        obs, next_state, reward, terminated, truncated, info = wrapped.step(
            jax.random.key(t + 1), state, wrong(state), params
        )
        if t < 2:
            state = next_state
    assert bool(truncated) and not bool(terminated)
    assert int(next_state.time) == 0, "a fresh episode starts at time 0"
    assert (np.asarray(obs[..., 1]) == 255).sum() == 9, "new episode reveals one window"
    final = np.asarray(info["final_observation"])
    assert (final[..., 1] == 255).sum() > 9, "final observation shows the whole episode's reveals"


def test_autoreset_keeps_state_when_not_done(env):
    wrapped = AutoResetWrapper(env)
    params = env.default_params
    _, state = wrapped.reset(jax.random.key(0), params)
    obs, state2, _, terminated, truncated, info = wrapped.step(jax.random.key(1), state, wrong(state), params)
    assert not bool(terminated | truncated)
    assert int(state2.time) == 1
    np.testing.assert_array_equal(np.asarray(obs), np.asarray(info["final_observation"]))


def test_autoreset_contract(env):
    check_env(AutoResetWrapper(env), env.default_params, num_steps=12)


def test_log_wrapper_reports_returns_and_lengths(env):
    wrapped = LogWrapper(AutoResetWrapper(env))
    params = env.default_params
    _, state = wrapped.reset(jax.random.key(0), params)
    # Episode 1: wrong, wrong, right -> return -0.2 + 1 = 0.8, length 3 (M=3, terminated wins).
    infos = []
    for t, policy in enumerate([wrong, wrong, right, wrong]):
        _, state, _, _, _, info = wrapped.step(jax.random.key(t), state, policy(state.env_state), params)
        infos.append(info)
    assert [bool(i["returned_episode"]) for i in infos] == [False, False, True, False]
    assert float(infos[2]["returned_episode_returns"]) == pytest.approx(0.8)
    assert int(infos[2]["returned_episode_lengths"]) == 3
    assert float(infos[3]["returned_episode_returns"]) == pytest.approx(0.8), "held until next end"
    assert int(infos[3]["timestep"]) == 4


def test_vmap_wrapper(env):
    wrapped = VmapWrapper(AutoResetWrapper(env), 5)
    params = env.default_params
    obs, state = wrapped.reset(jax.random.key(0), params)
    assert obs.shape == (5, 12, 10, 3)
    actions = jnp.zeros((5, 2), jnp.int32)
    obs, state, reward, terminated, truncated, _ = jax.jit(wrapped.step)(jax.random.key(1), state, actions, params)
    assert reward.shape == terminated.shape == truncated.shape == (5,)


def test_frame_stack(env):
    wrapped = FrameStackWrapper(AutoResetWrapper(env), num_frames=3)
    params = env.default_params
    assert wrapped.observation_space(params).shape == (12, 10, 9)
    obs, state = wrapped.reset(jax.random.key(0), params)
    np.testing.assert_array_equal(np.asarray(obs[..., 0:3]), np.asarray(obs[..., 6:9]))
    obs1, state, *_ = wrapped.step(jax.random.key(1), state, wrong(state.env_state), params)
    np.testing.assert_array_equal(np.asarray(obs1[..., 3:6]), np.asarray(obs[..., 6:9]))
    # End the episode: the stack refills with the new episode's first frame.
    obs2, state, _, terminated, *_ = wrapped.step(jax.random.key(2), state, right(state.env_state), params)
    assert bool(terminated)
    np.testing.assert_array_equal(np.asarray(obs2[..., 0:3]), np.asarray(obs2[..., 6:9]))
    check_env(wrapped, params, num_steps=8)


@pytest.mark.parametrize("noise", [None, "authors", "centred"])
def test_noise_observation_replaces_pixels(env, noise):
    """The pixels follow the named law; None (no `noise=`) is `DEFAULT_NOISE`, the law of
    every family's noise control."""
    from jaxnat.natural import DEFAULT_NOISE, noise_law
    from jaxnat.testing import check_noise_law

    wrapped = NoiseObservationWrapper(env) if noise is None else NoiseObservationWrapper(env, noise=noise)
    params = env.default_params
    obs, state = wrapped.reset(jax.random.key(0), params)
    real, _ = env.reset(jax.random.split(jax.random.key(0))[0], params)
    assert obs.shape == real.shape and obs.dtype == jnp.uint8
    assert not np.array_equal(np.asarray(obs), np.asarray(real))
    big = np.asarray(VmapWrapper(wrapped, 512).reset(jax.random.key(1), params)[0])
    law = noise_law(DEFAULT_NOISE if noise is None else noise)
    check_noise_law(big, law.probabilities(), f"NoiseObservationWrapper(noise={noise!r})")
    obs2, *_ = wrapped.step(jax.random.key(2), state, wrong(state), params)
    assert not np.array_equal(np.asarray(obs), np.asarray(obs2)), "fresh noise every step"
    check_env(wrapped, params, num_steps=5)


def test_legacy_step_api(env):
    wrapped = LegacyStepAPIWrapper(env)
    params = env.default_params
    _, state = wrapped.reset(jax.random.key(0), params)
    out = wrapped.step(jax.random.key(1), state, right(state), params)
    assert len(out) == 5
    _, _, reward, done, info = out
    assert bool(done) and bool(info["terminated"]) and not bool(info["truncated"])


class _BlankObservation(Wrapper):
    """The same env with every observation zeroed: a noise control built on it must give
    outputs identical to one built on the real env, or a real frame leaked."""

    def reset(self, key, params=None):
        obs, state = self._env.reset(key, params)
        return jnp.zeros_like(obs), state

    def step(self, key, state, action, params=None):
        obs, *rest = self._env.step(key, state, action, params)
        return (jnp.zeros_like(obs), *rest)


def _rollout(env, params, steps: int = 12):
    """Every output of `steps` steps of 16 envs (random actions), `info` included."""
    vec = VmapWrapper(env, 16)
    obs, state = vec.reset(jax.random.key(0), params)
    outputs = [obs]
    for i in range(steps):
        keys = jax.random.split(jax.random.key(100 + i), 16)
        action = jax.vmap(env.action_space(params).sample)(keys)
        obs, state, reward, terminated, truncated, info = vec.step(jax.random.key(i), state, action, params)
        outputs.append((obs, reward, terminated, truncated, info))
    return outputs, bool(np.any(np.asarray([np.asarray(o[2] | o[3]) for o in outputs[1:]])))


@pytest.mark.parametrize("order", ["noise outside autoreset", "noise inside autoreset"])
def test_noise_control_leaks_no_real_observation(env, order):
    """Built either way round, no output of `reset` or `step` (info included) depends on the
    real observation: the same keys give the same outputs over the real env and a blanked one."""
    compose = {"noise outside autoreset": lambda e: NoiseObservationWrapper(AutoResetWrapper(e)),
               "noise inside autoreset": lambda e: AutoResetWrapper(NoiseObservationWrapper(e))}[order]
    params = env.default_params.replace(max_steps_in_episode=3)  # truncations bootstrap from final_observation
    real, ended = _rollout(compose(env), params)
    blank, _ = _rollout(compose(_BlankObservation(env)), params)
    assert ended
    jax.tree.map(lambda a, b: np.testing.assert_array_equal(np.asarray(a), np.asarray(b)), real, blank)
    # And the control fails the leak test it is meant to fail: the real env's own outputs differ.
    plain, _ = _rollout(AutoResetWrapper(env), params)
    plain_blank, _ = _rollout(AutoResetWrapper(_BlankObservation(env)), params)
    assert not np.array_equal(np.asarray(plain[-1][4]["final_observation"]),
                              np.asarray(plain_blank[-1][4]["final_observation"]))


def test_make_observation_noise_composes_inside_the_autoreset():
    import jaxnat
    from jaxnat.datasets import DatasetNotFoundError

    try:
        env, params = jaxnat.make("Classify/Digits-v0", observation_noise=True, M=3)
    except DatasetNotFoundError:
        pytest.skip("Classify/Digits-v0 data not installed")
    assert isinstance(env, AutoResetWrapper) and isinstance(env._env, NoiseObservationWrapper)
    assert int(params.max_steps_in_episode) == 3
    from jaxnat.natural import DEFAULT_NOISE, NOISE_LAWS

    assert env._env.law is NOISE_LAWS[DEFAULT_NOISE]
    centred, _ = jaxnat.make("Classify/Digits-v0", observation_noise="centred")
    assert centred._env.law is NOISE_LAWS["centred"]
    with pytest.raises(TypeError, match="background='noise'"):
        jaxnat.make_vec("NaturalAtari/Pong-v0", 2, observation_noise=True)


def test_any_in_batch_is_one_value_for_the_whole_batch():
    """Under nested vmap the predicate is one unbatched value (any env of every axis), so a
    cond on it stays a conditional; unbatched it is the flag itself."""
    from jaxnat.gating import any_in_batch

    def f(x):
        done = x > 1.0
        return jax.lax.cond(any_in_batch(done), lambda: jnp.where(done, -x, x), lambda: x + 0.5)

    x = jnp.array([[0.5, 2.0], [0.1, 0.2]])
    np.testing.assert_array_equal(jax.jit(jax.vmap(jax.vmap(f)))(x), x.at[0, 1].set(-2.0))
    np.testing.assert_array_equal(jax.vmap(jax.vmap(f))(x * 0.1), x * 0.1 + 0.5)  # none ended
    assert float(f(jnp.float32(3.0))) == -3.0 and float(f(jnp.float32(0.0))) == 0.5
    text = str(jax.make_jaxpr(jax.vmap(jax.vmap(f)))(x))
    assert "cond[" in text and "select_n" in text  # the cond kept, the per-env where inside it
    # Differentiable through (the flag carries no tangent).
    np.testing.assert_array_equal(jax.grad(lambda x: jax.vmap(f)(x).sum())(x[0]), [1.0, -1.0])


def test_rows_of_take_rows_put_rows_round_trip():
    """The true rows in order, padded out of range; the padding reads the last row and its
    writes are dropped."""
    from jaxnat.gating import put_rows, rows_of, take_rows

    mask = jnp.array([False, True, False, True, True])
    rows = rows_of(mask, 4)
    np.testing.assert_array_equal(rows, [1, 3, 4, 5])
    np.testing.assert_array_equal(rows_of(mask, 2), [1, 3])  # at most `size` kept
    tree = {"a": jnp.arange(5.0), "b": jnp.arange(10).reshape(5, 2)}
    taken = take_rows(tree, rows)
    np.testing.assert_array_equal(taken["a"], [1.0, 3.0, 4.0, 4.0])
    put = put_rows(tree, rows, jax.tree.map(lambda x: -x - 1, taken))
    np.testing.assert_array_equal(put["a"], [0.0, -2.0, 2.0, -4.0, -5.0])
    np.testing.assert_array_equal(put["b"][:, 0], [0, -3, 4, -7, -9])


def test_compact_sizes_are_the_tiers_rows():
    from jaxnat.gating import compact_sizes

    assert compact_sizes(0.125, 6) == (1,) and compact_sizes(0.125, 32768) == (4096,)
    assert compact_sizes((0.125, 0.375), 6) == (1, 3) and compact_sizes((0.125, 0.375), 2) == (1,)
    assert compact_sizes(None, 8) == ()
    for bad in (0.0, -0.5, 1.5, "0.5", (0.2, 1.2)):
        with pytest.raises(ValueError, match=r"share must be in \(0, 1\]"):
            compact_sizes(bad, 8)
    with pytest.raises(ValueError, match="shares must be increasing"):
        compact_sizes((0.5, 0.25), 8)


@pytest.mark.parametrize("needed, branch", [(0, 0), (1, 1), (2, 2), (3, 2), (4, 3), (8, 3)])
def test_switch_rows_takes_the_smallest_tier_that_holds_the_rows(needed, branch):
    """Branch 0 for no row, then the first tier whose size holds the rows (sizes 1 and 3), then
    every row; the tier's rows are the needed ones, padded out of range."""
    from jaxnat.gating import switch_rows

    mask = jnp.arange(8) < needed
    out = jax.jit(lambda m: switch_rows(
        m, (1, 3), lambda: (jnp.int32(0), jnp.full(3, -1)),
        lambda rows: (jnp.int32(len(rows)), jnp.pad(rows, (0, 3 - len(rows)), constant_values=-1)),
        lambda: (jnp.int32(8), jnp.full(3, -1))))(mask)
    size, rows = (int(out[0]), np.asarray(out[1]))
    assert size == (0, 1, 3, 8)[branch]
    if branch in (1, 2):
        np.testing.assert_array_equal(rows[:size], [i if i < needed else 8 for i in range(size)])


def test_autoreset_reset_share_out_of_range_is_an_error(env):
    with pytest.raises(ValueError, match="share must be in"):
        AutoResetWrapper(env, reset_share=0.0)
