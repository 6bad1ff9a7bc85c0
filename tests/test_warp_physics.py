"""MuJoCo Warp as the MJX robots' physics (`impl="warp"`, jaxnat/mjx_pixel/warp_physics.py):
trajectories against MuJoCo C, one Warp batch for nested `vmap`s, autoreset through the JAX
implementation's reset, and the errors.

Warp runs on its CPU backend here (its kernels compile once per machine, into Warp's cache).
All tests form one xdist group, so the kernels compile in one worker.
"""

import numpy as np
import pytest

pytest.importorskip("mujoco.mjx")
pytest.importorskip("mujoco_warp")
pytest.importorskip("warp")

import jax
import jax.numpy as jnp
import mujoco

from jaxnat.mjx_pixel.half_cheetah import HalfCheetah
from jaxnat.mjx_pixel.hopper import Hopper
from jaxnat.wrappers.autoreset import AutoResetWrapper

pytestmark = pytest.mark.xdist_group("warp_physics")

STEPS = 6


@pytest.fixture(scope="module")
def cheetah():
    return HalfCheetah(physics="fast", impl="warp")


def _rollout(env, keys, actions, params):
    """States' (qpos, qvel, geom_xpos) and rewards after each action; keys and actions carry
    the same leading batch axes, all vmapped (nested when there are two)."""

    def one(key, acts):
        _, state = env.reset(key, params)

        def body(state, action):
            _, state, reward, *_ = env.step(jax.random.key(0), state, action, params)
            return state, (state.data.qpos, state.data.qvel, state.data.geom_xpos, reward)

        return jax.lax.scan(body, state, acts)[1]

    fn = one
    for _ in range(keys.ndim):
        fn = jax.vmap(fn)
    return jax.jit(fn)(keys, actions)


def _inputs(env, batch):
    keys = jax.random.split(jax.random.key(3), int(np.prod(batch))).reshape(batch)
    low, high = env.model.actuator_ctrlrange.T
    actions = jax.random.uniform(jax.random.key(4), batch + (STEPS, env.model.nu),
                                 minval=low, maxval=high)
    return keys, actions


def test_warp_steps_follow_mujoco_c(cheetah):
    """Each world of a nested (2 seeds x 2 envs) batch follows MuJoCo C (float64) from the same
    reset state under the same actions; the geom poses the renderer reads and the reward are
    MuJoCo C's too."""
    env, params = cheetah, cheetah.default_params
    keys, actions = _inputs(env, (2, 2))
    qpos, qvel, geom_xpos, reward = (np.asarray(x) for x in _rollout(env, keys, actions, params))
    for seed in range(2):
        for i in range(2):
            _, state = env.reset(keys[seed, i], params)
            data = mujoco.MjData(env.model)
            data.qpos[:], data.qvel[:] = np.asarray(state.data.qpos), np.asarray(state.data.qvel)
            for t in range(STEPS):
                x_before = data.qpos[0]
                data.ctrl[:] = np.asarray(actions[seed, i, t])
                mujoco.mj_step(env.model, data, nstep=env.frame_skip)
                expected_reward = (data.qpos[0] - x_before) / env.dt - 0.1 * np.sum(data.ctrl ** 2)
                np.testing.assert_allclose(qpos[seed, i, t], data.qpos, atol=1e-3)
                np.testing.assert_allclose(qvel[seed, i, t], data.qvel, atol=5e-2)
                np.testing.assert_allclose(geom_xpos[seed, i, t], data.geom_xpos, atol=1e-3)
                np.testing.assert_allclose(reward[seed, i, t], expected_reward, atol=5e-2)
    assert np.abs(qpos[:, :, -1] - qpos[:, :, 0]).max() > 1e-2  # the robot moved


def test_nested_vmap_is_one_batch_of_worlds(cheetah):
    """2 seeds x 2 envs give the trajectories of 4 envs vmapped once: the batching rule folds
    every vmap axis into one batch of Warp worlds, whatever the nesting."""
    env, params = cheetah, cheetah.default_params
    keys, actions = _inputs(env, (2, 2))
    nested = _rollout(env, keys, actions, params)
    flat = _rollout(env, keys.reshape(4), actions.reshape((4,) + actions.shape[2:]), params)
    for a, b in zip(nested, flat):
        np.testing.assert_allclose(np.asarray(a).reshape(np.shape(b)), np.asarray(b), atol=1e-6)


def test_autoreset_starts_episodes_from_the_jax_reset():
    """Through AutoResetWrapper (a select under vmap), an ended episode's next observation is
    the JAX implementation's reset from the wrapper's reset key, exactly."""
    env = Hopper(physics="fast", impl="warp")
    params = env.default_params.replace(max_steps_in_episode=3)
    wrapped = AutoResetWrapper(env)
    keys = jax.random.split(jax.random.key(5), 2)
    low, high = env.model.actuator_ctrlrange.T
    actions = jax.random.uniform(jax.random.key(6), (7, 2, env.model.nu), minval=low, maxval=high)
    step_keys = jax.random.split(jax.random.key(7), 7 * 2).reshape(7, 2)

    def run(keys, actions, step_keys):
        _, state = jax.vmap(lambda k: wrapped.reset(k, params))(keys)

        def body(state, x):
            action, key = x
            obs, state, _, terminated, truncated, _ = jax.vmap(
                lambda k, s, a: wrapped.step(k, s, a, params))(key, state, action)
            return state, (obs, terminated | truncated)

        return jax.lax.scan(body, state, (actions, step_keys))[1]

    obs, done = (np.asarray(x) for x in jax.jit(run)(keys, actions, step_keys))
    assert done.sum() >= 4  # every env reached its 3-step limit twice
    reset = jax.jit(lambda k: env.reset(k, params)[0])
    for t, i in zip(*np.nonzero(done)):
        expected = reset(jax.random.split(step_keys[t, i])[1])
        np.testing.assert_array_equal(obs[t, i], np.asarray(expected))
    assert np.isfinite(obs).all()


def test_bad_impls_are_one_line_errors():
    from jaxnat.mjx_pixel.ant import Ant
    from jaxnat.mjx_pixel.pixel import PixelMuJoCo

    with pytest.raises(ValueError, match="impl must be one of"):
        HalfCheetah(impl="cuda")
    with pytest.raises(ValueError, match="cfrc_ext"):
        Ant(physics="fast", impl="warp")
    with pytest.raises(ValueError, match="pass impl= to the physics env"):
        PixelMuJoCo(physics=HalfCheetah(physics="fast"), observation="state", physics_impl="warp")


def test_pixel_env_passes_the_impl_to_its_physics():
    from jaxnat.mjx_pixel.pixel import PixelMuJoCo

    env = PixelMuJoCo("hopper", observation="state", physics="fast", physics_impl="warp")
    assert env.physics.impl == "warp" and env.physics.warp is not None
    assert PixelMuJoCo("hopper", observation="state").physics.warp is None


def test_capacity_holds_every_floor_contact_of_fast_half_cheetah():
    """Fast HalfCheetah's five colliding geoms (a sphere: one floor contact; four capsules: two
    each) can touch the floor in 9 contacts of 4 pyramidal rows each, which a trained policy
    reaches (a flipped cheetah); the capacity holds them all, with the 6 joint limits' rows."""
    from jaxnat.mjx_pixel.warp_physics import capacity, rows_per_contact

    env = HalfCheetah(physics="fast")
    contacts, constraints = capacity(env.model, env.frame_skip)
    assert rows_per_contact(env.model) == 4
    assert contacts >= 9 and constraints >= 9 * 4 + 6
