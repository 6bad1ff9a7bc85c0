"""MuJoCo robots in MJX (state observations): the env contract, Gymnasium v5's rewards,
termination and observations, and MJX rollouts against MuJoCo C.

MJX compiles slowly on a small CPU, so each robot's `reset`/`step` are jitted once per module
(`Compiled`) and every test reuses them (params are traced: changing them does not retrace);
check_env's own jitted programs are the same, which the persistent compilation cache set in
conftest.py reuses. Each robot's tests form one xdist group (`make test` runs
`--dist loadgroup`), so a robot compiles in one worker only.
"""

import dataclasses

import numpy as np
import pytest

pytest.importorskip("mujoco.mjx")
gymnasium = pytest.importorskip("gymnasium")
pytest.importorskip("imageio")  # Gymnasium's MuJoCo envs import it

import jax
import jax.numpy as jnp
import mujoco

import jaxnat
from jaxnat.mjx_pixel import models
from jaxnat.testing import check_env

ROBOTS = {  # jaxnat / Gymnasium name -> (robot, observation size)
    "Ant": ("ant", 105),
    "HalfCheetah": ("half_cheetah", 17),
    "Hopper": ("hopper", 11),
    "Swimmer": ("swimmer", 8),
}
# How far MJX (float32) may drift from MuJoCo C (float64) over `STEPS` steps from the same
# state under the same actions (measured: Swimmer and Hopper ~1e-6 in qpos, HalfCheetah and
# Ant ~1e-4 once feet touch the floor; the observation's velocities and Ant's contact forces
# drift more). Contact events (a foot within the contact margin or not) make longer rollouts
# part: float32 and float64 decide borderline contacts differently.
STEPS = 6
QPOS_TOL = {"Ant": 1e-3, "HalfCheetah": 1e-3, "Hopper": 1e-4, "Swimmer": 1e-4}
OBS_TOL = {"Ant": 2e-2, "HalfCheetah": 1e-2, "Hopper": 1e-3, "Swimmer": 1e-3}


class Compiled:
    """A robot env with `reset`/`step` jitted once (shared by this module's tests)."""

    def __init__(self, name):
        self.name = name
        self.env, self.params = jaxnat.make(f"MuJoCo/{name}-v0", autoreset=False)
        self.reset = jax.jit(self.env.reset)
        self.step = jax.jit(self.env.step)


_COMPILED = {}


def compiled(name) -> Compiled:
    if name not in _COMPILED:
        _COMPILED[name] = Compiled(name)
    return _COMPILED[name]


def robot_params(*names):
    """`names` as test parameters, each in its robot's xdist group."""
    return [pytest.param(n, marks=pytest.mark.xdist_group(f"mjx-{n}")) for n in names]


@pytest.fixture(scope="module", params=robot_params(*sorted(ROBOTS)))
def robot(request):
    return compiled(request.param)


def gym_env(name, qpos, qvel):
    """Gymnasium's own v5 env (MuJoCo C, float64) set to `qpos`, `qvel`."""
    env = gymnasium.make(f"{name}-v5").unwrapped
    env.reset(seed=0)
    env.set_state(np.asarray(qpos, np.float64), np.asarray(qvel, np.float64))
    return env


def test_models_load_with_torso_body_one():
    for robot in models.ROBOTS:
        model = models.load_model(robot)
        assert models.torso_body_id(robot) == 1
        assert mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, 1) == "torso"
    with pytest.raises(ValueError, match="Unknown robot 'walker'"):
        models.load_model("walker")


def test_contract(robot):
    check_env(robot.env, robot.params, num_steps=4, num_envs=2)


def test_spaces(robot):
    _, size = ROBOTS[robot.name]
    env, params = robot.env, robot.params
    gym = gymnasium.make(f"{robot.name}-v5").unwrapped
    assert env.observation_space(params).shape == (size,) == gym.observation_space.shape
    assert env.action_space(params).shape == gym.action_space.shape
    np.testing.assert_array_equal(env.action_space(params).low, gym.action_space.low)
    np.testing.assert_array_equal(env.action_space(params).high, gym.action_space.high)
    assert env.dt == pytest.approx(gym.dt)


def test_reset_and_step_return_the_same_state_type(robot):
    _, state = robot.reset(jax.random.key(0), robot.params)
    action = jnp.zeros(robot.env.model.nu)
    _, stepped, *_ = robot.step(jax.random.key(1), state, action, robot.params)
    assert type(state) is type(stepped)
    assert jax.tree.structure(state) == jax.tree.structure(stepped)
    for a, b in zip(jax.tree.leaves(state), jax.tree.leaves(stepped)):
        assert (a.shape, a.dtype) == (b.shape, b.dtype)


def test_reset_noise(robot):
    """Gymnasium's reset: qpos0 + U(-s, s) (Ant's free-joint quaternion comes back normalised,
    as MuJoCo C's mj_forward leaves it), qvel U(-s, s) or s N(0, 1)."""
    env, params = robot.env, robot.params
    scale = params.reset_noise_scale
    quaternion = slice(3, 7) if robot.name == "Ant" else slice(0, 0)
    deviations = []
    for k in range(6):
        _, state = robot.reset(jax.random.key(k), params)
        qpos = np.asarray(state.data.qpos)
        noise = np.delete(qpos - env.model.qpos0, np.r_[quaternion])
        assert np.all(np.abs(noise) <= scale + 1e-6)
        if robot.name == "Ant":
            assert np.linalg.norm(qpos[quaternion]) == pytest.approx(1.0, abs=1e-6)
        if env.qvel_noise == "uniform":
            assert np.all(np.abs(np.asarray(state.data.qvel)) <= scale + 1e-6)
        deviations.append(qpos - env.model.qpos0)
        assert int(state.time) == 0
    # (A normalised quaternion's w barely moves: its spread is second order in the noise.)
    spread = np.delete(np.std(deviations, axis=0), np.r_[quaternion])
    assert np.all(spread > 0.1 * scale), "reset noise missing in some qpos entries"


def test_matches_gymnasium_v5(robot):
    """Same initial state, same actions: observations, rewards, termination and info as
    Gymnasium's own v5 env, whose physics is MuJoCo C."""
    env, params, name = robot.env, robot.params, robot.name
    obs, state = robot.reset(jax.random.key(3), params)
    gym = gym_env(name, state.data.qpos, state.data.qvel)
    np.testing.assert_allclose(obs, gym._get_obs(), rtol=0, atol=1e-6)
    rng = np.random.default_rng(0)
    for t in range(STEPS):
        action = rng.uniform(-1, 1, env.model.nu).astype(np.float32)
        obs, state, reward, terminated, truncated, info = robot.step(
            jax.random.key(t), state, jnp.asarray(action), params
        )
        gym_obs, gym_reward, gym_terminated, _, gym_info = gym.step(action.astype(np.float64))
        qpos_error = np.abs(np.asarray(state.data.qpos) - gym.data.qpos).max()
        assert qpos_error < QPOS_TOL[name], f"step {t}: qpos drifted {qpos_error:.2e} from MuJoCo C"
        assert bool(terminated) == gym_terminated and not bool(truncated)
        assert set(info) == set(gym_info)
        np.testing.assert_allclose(obs, gym_obs, rtol=0, atol=OBS_TOL[name], err_msg=f"step {t}")
        assert float(reward) == pytest.approx(gym_reward, rel=1e-3, abs=1e-4), f"step {t}"
        for key, value in gym_info.items():
            assert float(info[key]) == pytest.approx(value, rel=1e-3, abs=1e-3), (t, key)


def test_rewards_follow_the_formulas_with_traced_params(robot):
    """The reward is the sum of the info's terms; the weights are read from the (traced)
    params: scaling them scales the terms, with no retrace."""
    env = robot.env
    # Gymnasium's x: qpos[0], except Ant's, which is its torso body's xpos (`main_body`).
    x = (lambda d: d.xpos[1, 0]) if robot.name == "Ant" else (lambda d: d.qpos[0])
    _, state = robot.reset(jax.random.key(5), robot.params)
    action = jnp.linspace(-0.9, 0.8, env.model.nu)
    traces = None
    for scale in (1.0, 3.0):
        params = robot.params.replace(
            forward_reward_weight=robot.params.forward_reward_weight * scale,
            ctrl_cost_weight=robot.params.ctrl_cost_weight * scale,
        )
        _, stepped, reward, _, _, info = robot.step(jax.random.key(6), state, action, params)
        terms = sum(float(v) for k, v in info.items() if k.startswith("reward_"))
        assert float(reward) == pytest.approx(terms, rel=1e-5, abs=1e-6)
        ctrl = params.ctrl_cost_weight * float(jnp.sum(action**2))
        assert float(info["reward_ctrl"]) == pytest.approx(-ctrl, rel=1e-5)
        dx = float(x(stepped.data) - x(state.data))
        assert float(info["x_velocity"]) == pytest.approx(dx / env.dt, rel=1e-4, abs=1e-5)
        assert float(info["reward_forward"]) == pytest.approx(
            params.forward_reward_weight * dx / env.dt, rel=1e-4, abs=1e-5
        )
        traces = traces or robot.step._cache_size()
    assert robot.step._cache_size() == traces, "changing params retraced step"


@pytest.mark.parametrize("name", robot_params("Hopper", "Ant"))
def test_unhealthy_terminates(name):
    """A torso outside `healthy_z_range` after the step terminates the episode and earns no
    survival reward; with `terminate_when_unhealthy=False` the episode goes on."""
    robot = compiled(name)
    params = robot.params
    _, state = robot.reset(jax.random.key(0), params)
    action = jnp.zeros(robot.env.model.nu)
    *_, terminated, _, info = robot.step(jax.random.key(1), state, action, params)
    assert not bool(terminated) and float(info["reward_survive"]) == 1.0
    # Hopper: z = qpos[1] below 0.7; Ant: torso z = qpos[2] above 1.0.
    index, z = {"Hopper": (1, 0.5), "Ant": (2, 1.5)}[name]
    high = state.replace(data=state.data.replace(qpos=state.data.qpos.at[index].set(z)))
    *_, terminated, _, info = robot.step(jax.random.key(1), high, action, params)
    assert bool(terminated) and float(info["reward_survive"]) == 0.0
    lenient = params.replace(terminate_when_unhealthy=False)
    *_, terminated, _, info = robot.step(jax.random.key(1), high, action, lenient)
    assert not bool(terminated) and float(info["reward_survive"]) == 0.0


@pytest.mark.parametrize("name", robot_params("HalfCheetah", "Swimmer"))
def test_never_terminates(name):
    robot = compiled(name)
    _, state = robot.reset(jax.random.key(0), robot.params)
    wild = state.replace(data=state.data.replace(qvel=state.data.qvel + 50.0))
    action = jnp.ones(robot.env.model.nu)
    *_, terminated, _, _ = robot.step(jax.random.key(1), wild, action, robot.params)
    assert not bool(terminated)


def test_make_routes_kwargs_and_rejects_bad_ones():
    env, params = jaxnat.make(
        "MuJoCo/Hopper-v0", autoreset=False, frame_skip=2, ctrl_cost_weight=0.5,
        exclude_current_positions_from_observation=False,
    )
    assert env.frame_skip == 2 and env.dt == pytest.approx(0.004)
    assert params.ctrl_cost_weight == 0.5
    assert env.observation_space(params).shape == (12,)
    assert env.model.opt.ls_iterations == env.mjx_model.opt.ls_iterations == 10  # jaxnat's
    model_own, _ = jaxnat.make("MuJoCo/Ant-v0", ls_iterations=None)
    assert model_own.unwrapped.mjx_model.opt.ls_iterations == 50  # as Gymnasium's model
    assert models.load_model("ant").opt.ls_iterations == 50  # the cached model is untouched
    with pytest.raises(ValueError, match="ls_iterations must be >= 1"):
        jaxnat.make("MuJoCo/Hopper-v0", ls_iterations=0)
    with pytest.raises(TypeError, match="unknown keyword"):
        jaxnat.make("MuJoCo/Hopper-v0", frame_skipp=2)
    with pytest.raises(ValueError, match="frame_skip must be >= 1"):
        jaxnat.make("MuJoCo/Swimmer-v0", frame_skip=0)


@pytest.mark.xdist_group("mjx-Swimmer")
def test_wrong_action_shape_fails_at_trace_time():
    robot = compiled("Swimmer")
    _, state = robot.reset(jax.random.key(0), robot.params)
    with pytest.raises(ValueError, match="expects shape"):
        robot.env.step(jax.random.key(1), state, jnp.zeros(3), robot.params)


def test_mujoco_is_quiet_and_logs_to_the_cache(tmp_path):
    """Making MuJoCo envs prints nothing about MJX's optional Warp backend and writes no
    MUJOCO_LOG.TXT into the working folder: MuJoCo's warnings (Gymnasium's half_cheetah.xml
    uses the deprecated settotalmass) go to mujoco.log in jaxnat's cache folder."""
    import os
    import subprocess
    import sys

    # Ant, made first, imports the MJX internals it checks (`mjx_internals`): quiet too.
    code = ("import jaxnat\nfor id in ('PixelMuJoCo/Ant-v0', 'MuJoCo/HalfCheetah-v0'):\n"
            "    jaxnat.make(id)\nprint('made')")
    env = {**os.environ, "JAXNAT_CACHE_DIR": str(tmp_path / "cache"), "JAX_PLATFORMS": "cpu"}
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "made" and "Failed to import" not in out.stderr
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists()
    assert "settotalmass" in (tmp_path / "cache" / "mujoco.log").read_text()


def test_physics_setting_is_validated_and_applied():
    """`physics=` takes "default" or "fast"; "fast" changes only the robot's model copy."""
    with pytest.raises(ValueError, match=r"physics must be one of \('default', 'fast'\), got 'quick'"):
        jaxnat.make("MuJoCo/Ant-v0", physics="quick")
    fast = jaxnat.make("MuJoCo/Ant-v0", autoreset=False, physics="fast")[0]
    opt = fast.model.opt
    assert opt.integrator == mujoco.mjtIntegrator.mjINT_EULER
    assert (opt.iterations, opt.ls_iterations) == (1, 4) == (fast.mjx_model.opt.iterations,
                                                            fast.mjx_model.opt.ls_iterations)
    colliding = {mujoco.mj_id2name(fast.model, mujoco.mjtObj.mjOBJ_GEOM, g)
                 for g in range(fast.model.ngeom) if fast.model.geom_contype[g]}
    assert colliding == {"floor", *fast.fast_physics.contact_geoms}
    default = models.load_model("ant")  # the cached model is untouched
    assert default.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4 and default.opt.iterations == 100
    pixel = jaxnat.make("PixelMuJoCo/Hopper-v0", observation="state", physics="fast")[0].unwrapped
    assert pixel.physics.physics_mode == "fast"
    assert pixel.physics.model.opt.integrator == mujoco.mjtIntegrator.mjINT_EULER
    with pytest.raises(ValueError, match="physics must be one of"):
        jaxnat.make("PixelMuJoCo/Hopper-v0", physics="quick")


def test_fast_ant_touches_the_floor_with_massless_invisible_foot_spheres():
    """Fast Ant's contacts are spheres at the ankle capsules' far ends (Brax's Ant's feet): the
    capsule's radius and contact properties, no mass (the bodies' masses and inertias are
    Gymnasium's), group 3 (the renderer leaves them out), one contact each with the floor. A
    name that is not a capsule is refused."""
    from jaxnat.mjx_pixel import mjx_internals
    from jaxnat.mjx_pixel.base import PhysicsSettings
    from jaxnat.mjx_pixel.render import GeomTable

    fast = jaxnat.make("MuJoCo/Ant-v0", autoreset=False, physics="fast")[0]
    # The spheres alone (fast Ant also fuses static bodies, which renumbers bodies and geoms).
    model = dataclasses.replace(fast.fast_physics, fuse_static=False).build("ant")
    gym = models.load_model("ant")
    for field in ("body_mass", "body_inertia", "body_ipos", "qpos0", "dof_armature"):
        np.testing.assert_array_equal(getattr(model, field), getattr(gym, field))
    geom = lambda m, name: mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, name)  # noqa: E731
    for sphere, capsule in fast.fast_physics.foot_spheres:
        s, c = geom(model, sphere), geom(gym, capsule)
        assert model.geom_type[s] == mujoco.mjtGeom.mjGEOM_SPHERE and model.geom_group[s] == 3
        assert model.geom_bodyid[s] == gym.geom_bodyid[c]
        assert model.geom_size[s][0] == gym.geom_size[c][0]
        # the far end: the ankle capsules run from their body's origin, centred halfway
        np.testing.assert_allclose(model.geom_pos[s], gym.geom_pos[c] * 2, atol=1e-6)
        for field in ("geom_contype", "geom_conaffinity", "geom_condim", "geom_friction", "geom_margin",
                      "geom_gap", "geom_solref", "geom_solimp", "geom_solmix", "geom_priority"):
            assert np.array_equal(getattr(model, field)[s], getattr(gym, field)[c]), field

    def visible(m):  # names, or (body, type) for unnamed geoms: ids shift after each sphere
        return {mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g)
                or (int(m.geom_bodyid[g]), int(m.geom_type[g])) for g in GeomTable.from_model(m).geom_ids}

    assert visible(model) == visible(gym)
    state = jax.jit(fast.reset)(jax.random.key(0), fast.default_params)[1]
    assert mjx_internals.contact(state.data).dist.shape == (4,)  # one per foot
    with pytest.raises(ValueError, match="'torso_geom' is not a capsule"):
        PhysicsSettings(foot_spheres=(("foot", "torso_geom"),)).build("ant")
    with pytest.raises(ValueError, match=r"lacks the foot spheres .* PhysicsSettings.build"):
        fast.fast_physics.apply(models.load_model("ant"))


def test_fast_ant_fuses_its_static_leg_bodies_into_the_torso_without_changing_the_dynamics():
    """Fast Ant's four jointless leg bodies are fused into the torso, as Brax's loader does:
    10 bodies where Gymnasium's model has 14, the same total mass, MuJoCo C trajectories equal
    to rounding, and an MJX observation (contact forces included, in Gymnasium's 14-body layout)
    equal to that of the unfused model up to float32 rounding."""
    from jaxnat.mjx_pixel.ant import Ant
    from jaxnat.mjx_pixel.base import fused_body_index

    class UnfusedAnt(Ant):
        fast_physics = dataclasses.replace(Ant.fast_physics, fuse_static=False)

    fused, unfused = Ant(physics="fast"), UnfusedAnt(physics="fast")
    assert (fused.model.nbody, unfused.model.nbody) == (10, 14)
    np.testing.assert_array_equal(fused_body_index(unfused.model, fused.model),
                                  [0, 1, -1, 2, 3, -1, 4, 5, -1, 6, 7, -1, 8, 9])
    assert fused_body_index(unfused.model, unfused.model) is None
    assert fused.body_index is not None and unfused.body_index is None
    np.testing.assert_allclose(fused.model.body_mass.sum(), unfused.model.body_mass.sum(), rtol=1e-12)

    rng = np.random.default_rng(0)
    datas = [mujoco.MjData(m) for m in (fused.model, unfused.model)]
    for _ in range(20):  # 1 s: the Ant lands on its feet
        action = rng.uniform(-1, 1, 8)
        for m, d in zip((fused.model, unfused.model), datas):
            d.ctrl[:] = action
            mujoco.mj_step(m, d, 5)
    assert datas[1].ncon > 0
    np.testing.assert_allclose(datas[0].qpos, datas[1].qpos, atol=1e-9)

    params = fused.default_params
    observations = []
    for env in (fused, unfused):
        step = jax.jit(env.step)
        obs, state = jax.jit(env.reset)(jax.random.key(0), params)
        for t in range(20):
            obs, state, *_ = step(jax.random.key(t), state, jnp.full(8, 0.3 * (-1) ** t), params)
        observations.append(np.asarray(obs))
    assert observations[0].shape == (fused.observation_size,) == (105,)
    forces = observations[1][27:].reshape(13, 6)
    assert np.abs(forces).max() > 0.1  # the feet are on the floor
    np.testing.assert_array_equal(forces[[1, 4, 7, 10]], 0.0)  # the fused bodies
    np.testing.assert_allclose(observations[0], observations[1], atol=1e-3)


@pytest.mark.xdist_group("mjx-Hopper")
def test_fast_physics_steps_near_but_not_on_the_default():
    """Hopper's fast setting (Euler, foot-only contacts) stays close to the default over a few
    steps from the same state, and is not the same arithmetic."""
    robot = compiled("Hopper")
    fast, _ = jaxnat.make("MuJoCo/Hopper-v0", autoreset=False, physics="fast")
    fast_step = jax.jit(fast.step)
    _, state = robot.reset(jax.random.key(3), robot.params)
    fast_state = jax.jit(fast.reset)(jax.random.key(3), robot.params)[1]
    np.testing.assert_array_equal(state.data.qpos, fast_state.data.qpos)
    rng = np.random.default_rng(0)
    for t in range(STEPS):
        action = jnp.asarray(rng.uniform(-1, 1, 3), jnp.float32)
        _, state, *_ = robot.step(jax.random.key(t), state, action, robot.params)
        _, fast_state, reward, *_ = fast_step(jax.random.key(t), fast_state, action, robot.params)
        assert np.isfinite(float(reward))
    gap = np.abs(np.asarray(state.data.qpos) - np.asarray(fast_state.data.qpos)).max()
    assert 0 < gap < 1e-2, gap
