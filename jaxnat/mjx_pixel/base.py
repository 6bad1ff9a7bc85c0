"""What the four MJX robots share: the model, the state, reset noise and frame-skipped stepping.

Each robot (`ant.py`, `half_cheetah.py`, `hopper.py`, `swimmer.py`) subclasses `MJXEnv` and
adds Gymnasium MuJoCo v5's reward and termination (and observation where it is not
`(qpos, qvel)`), specified in its docstring.

- **State**: `state.data` is the full `mjx.Data` (the renderer reads `geom_xpos`, `geom_xmat`
  and `xpos[torso_body_id]` from it). `reset` and `step` return the same pytree type, shapes
  and dtypes, so `AutoResetWrapper`'s select between them needs no second trace.
- **Reset** (Gymnasium's `reset_model`): `qpos = qpos0 + U(-s, s)`, `qvel = U(-s, s)` or
  `s * N(0, 1)` (per robot) with `s = params.reset_noise_scale`, everything else as
  `mj_resetData` leaves it (zero `ctrl`, `act`, warm start), then the position stage of
  `mj_forward` (body, geom and camera poses, centres of mass; free-joint quaternions come
  back normalised, as C leaves them): all that an observation or the renderer reads. The
  first step's forward pass computes the rest from `qpos`, `qvel` alone, so trajectories are
  those after a full `mj_forward`, and reset, which also runs inside every autoresetting step,
  compiles only those stages: no collision detection, no constraint solver.
- **Step** (Gymnasium's `do_simulation`): `ctrl = action` (MuJoCo clamps it to `ctrlrange`),
  `frame_skip` calls of `mj_step`, then `mj_rnePostConstraint`'s `cfrc_ext` where the robot
  reads it (Ant; its `cacc` and `cfrc_int`, which no robot reads, are not computed). As in
  MuJoCo C, the position-dependent fields of the data after a step (`xpos`, `geom_xpos`,
  contacts) are those of the last forward pass (the step's start for Euler, the last
  Runge-Kutta stage for RK4), not of the new `qpos`.
- **Compile time**: MJX's `rungekutta4` unrolls its three inner stages, so XLA compiles four
  copies of the forward dynamics (with the contact solver) per physics step. `_rk4_step` runs
  the same four stages as one `lax.scan` (one copy of the forward dynamics), with MJX's own
  tableau and state advance (`mjx_internals`), so the arithmetic is MJX's and the compile is
  shorter (compile seconds: bench/results/mjx_physics.md). Tests check it against MuJoCo C's
  `mj_step`.
- **Contact frames**: plane-capsule contacts get MuJoCo C's frame (`_forward_with_c_capsule_
  frames`); MJX's differs for steep capsules, which changes pyramidal friction (Ant). Models
  where no plane and capsule can collide (Swimmer, fast Ant) run `mjx.forward` itself.
- **Line search**: MJX's contact solver runs its line search as a `lax.scan` of
  `ls_iterations` steps (the models say 50) that go idle once converged; under `vmap` an idle
  step still costs a full evaluation, so every solver iteration pays for all of them. On
  random-action rollouts of each robot MuJoCo C's line search never needed 10 evaluations in
  an iteration, and MJX rollouts bounded below 10 equal those bounded at 50, so jaxnat's
  default bound is 10: batched physics runs faster with the same trajectories (the
  `ls_iterations=50` rows and the moved notes of bench/results/mjx_physics.md).
  `ls_iterations=None` restores the model's 50. The Newton iterations themselves keep the
  model's bound and tolerance.
- **Physics settings** (`physics=`): `"default"` keeps Gymnasium v5's model as it is
  (integrator, contacts, Newton iterations and tolerance; only the line-search bound above
  differs, which leaves the converged solution alone). `"fast"` applies the robot's
  `fast_physics` (`PhysicsSettings`: Euler, fewer Newton and line-search iterations, fewer
  colliding geoms, as Brax's and MuJoCo Playground's MJX envs do), listed in each robot's
  docstring; its distance from Gymnasium's dynamics is measured in
  bench/results/mjx_fidelity.md. Where the default's time goes: bench/results/mjx_profile.md.
- **Precision**: MJX runs in float32 (MuJoCo C in float64). Its matrix products are traced
  at full float32 precision: JAX's default on recent NVIDIA GPUs is TF32 (10-bit mantissa),
  too coarse for a contact solver.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from flax import struct

from jaxnat import spaces
from jaxnat.core import Environment, EnvState
from jaxnat.mjx_pixel.models import import_mjx, load_model, model_path, torso_body_id

mjx = import_mjx()  # (before mjx_internals, which imports MJX's private modules)

from jaxnat.mjx_pixel import mjx_internals  # noqa: E402  MJX's private names: RK4 tableau, `_impl` fields

__all__ = ["MJXState", "MJXEnv", "PhysicsSettings", "PHYSICS", "IMPLS", "fused_body_index"]

PHYSICS = ("default", "fast")  # the values of `MJXEnv(physics=...)`
IMPLS = ("jax", "warp")  # the values of `MJXEnv(impl=...)`

_PLANE, _CAPSULE = int(mujoco.mjtGeom.mjGEOM_PLANE), int(mujoco.mjtGeom.mjGEOM_CAPSULE)


@struct.dataclass
class MJXState(EnvState):
    """`time` (steps this episode) and the simulator's `data` (an `mjx.Data`)."""

    data: mjx.Data


@dataclasses.dataclass(frozen=True)
class PhysicsSettings:
    """Changes to Gymnasium's model for `physics="fast"` (None: the model's own).

    integrator: "euler" or "rk4". iterations, ls_iterations: bounds on the Newton solver's
    iterations and on each one's line search. contact_geoms: names of the robot's geoms that
    still collide (with whatever they collided with); every other geom of the robot (not of the
    world body) collides with nothing. eulerdamp: keep Euler's implicit joint damping.
    foot_spheres: `(name, capsule)` pairs: a sphere `name` of the capsule's radius added at its
    far end (`fromto`'s second point), massless, invisible (group 3) and with the capsule's
    contact properties, as Brax's Ant has foot spheres: a sphere meets the floor in one contact
    where a capsule makes two. List the spheres in `contact_geoms` for them to collide.
    fuse_static: merge each body without joints into its parent (MuJoCo's `fusestatic`, as
    Brax's loader compiles its models): the same rigid bodies in fewer tree nodes, so every
    pass over the body tree is shorter. Trajectories agree to rounding; bodies and geoms are
    renumbered (`fused_body_index` maps the bodies back).
    """

    integrator: str | None = None
    iterations: int | None = None
    ls_iterations: int | None = None
    contact_geoms: tuple[str, ...] | None = None
    eulerdamp: bool = True
    foot_spheres: tuple[tuple[str, str], ...] = ()
    fuse_static: bool = False

    def build(self, robot: str) -> mujoco.MjModel:
        """Robot `robot`'s model with these settings (a fresh copy)."""
        if not self.foot_spheres and not self.fuse_static:
            model = load_model(robot)
        else:
            spec = mujoco.MjSpec.from_file(model_path(robot))
            for name, capsule_name in self.foot_spheres:
                capsule = spec.geom(capsule_name)
                if capsule is None or capsule.type != mujoco.mjtGeom.mjGEOM_CAPSULE or not np.all(
                        np.isfinite(capsule.fromto)):
                    raise ValueError(f"foot_spheres: {capsule_name!r} is not a capsule given by "
                                     f"fromto in the {robot} model")
                sphere = capsule.parent.add_geom(
                    name=name, type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[capsule.size[0], 0, 0],
                    pos=capsule.fromto[3:], mass=0.0, group=3)
                for field in ("contype", "conaffinity", "condim", "friction", "margin", "gap",
                              "solref", "solimp", "solmix", "priority"):
                    setattr(sphere, field, getattr(capsule, field))
            spec.compiler.fusestatic = self.fuse_static
            model = spec.compile()
        self.apply(model)
        return model

    def apply(self, model: mujoco.MjModel) -> None:
        """Change `model` in place (`build` adds `foot_spheres`, which need a new model)."""
        absent = [name for name, _ in self.foot_spheres
                  if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, name) < 0]
        if absent:
            raise ValueError(f"the model lacks the foot spheres {absent}: build the model with "
                             f"PhysicsSettings.build(robot), which adds them")
        if self.integrator is not None:
            model.opt.integrator = {"euler": mujoco.mjtIntegrator.mjINT_EULER,
                                    "rk4": mujoco.mjtIntegrator.mjINT_RK4}[self.integrator]
        if self.iterations is not None:
            model.opt.iterations = self.iterations
        if self.ls_iterations is not None:
            model.opt.ls_iterations = self.ls_iterations
        if not self.eulerdamp:
            model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_EULERDAMP
        if self.contact_geoms is not None:
            keep = {mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, n) for n in self.contact_geoms}
            if -1 in keep:
                raise ValueError(f"contact_geoms {self.contact_geoms} names a geom the model lacks")
            for geom in range(model.ngeom):
                if model.geom_bodyid[geom] != 0 and geom not in keep:
                    model.geom_contype[geom] = model.geom_conaffinity[geom] = 0


def fused_body_index(original: mujoco.MjModel, model: mujoco.MjModel) -> np.ndarray | None:
    """For each body of `original`, its index in `model`, the same model with its static bodies
    fused (`PhysicsSettings.fuse_static`), or -1 where it was fused into its parent; None when
    `model` has every body of `original`. Bodies are matched through their joints, which fusion
    keeps in order (a body that keeps its place has joints, or is the world)."""
    if model.nbody == original.nbody:
        return None
    if model.njnt != original.njnt:
        raise ValueError(f"{model.njnt} joints where the original model has {original.njnt}: "
                         f"not the same model with static bodies fused")
    jointed = np.asarray(original.body_jntnum) > 0
    index = np.where(jointed, np.asarray(model.jnt_bodyid)[np.asarray(original.body_jntadr)], -1)
    index[0] = 0
    return index.astype(np.int32)


class MJXEnv(Environment):
    """A Gymnasium-v5-style MuJoCo task stepped by MJX. Subclasses set the class attributes
    below and implement `step_env` (and `get_obs`, `observation_size` if theirs differ).

    Args:
        frame_skip: physics steps (`mj_step`) per env step (default: Gymnasium's, per robot).
        exclude_current_positions_from_observation: leave the root's position in the plane
            (x, or x and y) out of the observation (Gymnasium's True).
        ls_iterations: bound on the contact solver's line-search iterations: 10 by default,
            `None` for the model's own (50). See the module docstring. Under `physics="fast"`
            the fast settings' own bound is used instead.
        physics: `"default"` (Gymnasium v5's dynamics) or `"fast"` (the robot's
            `fast_physics`: speed over fidelity; see the module docstring).
        impl: who steps the physics: `"jax"` (MJX's JAX implementation) or `"warp"` (MuJoCo
            Warp, the `warp` extra: the same model, solver and bounds, faster on a GPU;
            `warp_physics.py`). Reset is the JAX implementation's either way.
    """

    robot: str  # a key of `jaxnat.mjx_pixel.models.ROBOTS`
    params_type: type  # the robot's EnvParams subclass
    state_type: type  # the robot's MJXState subclass
    qvel_noise: str  # reset noise on qvel: "uniform" U(-s, s) or "normal" s * N(0, 1)
    default_frame_skip: int  # Gymnasium v5's
    root_position_size: int  # leading qpos entries that hold the root's x (or x, y)
    fast_physics: PhysicsSettings  # what physics="fast" changes
    needs_cfrc_ext: bool = False  # steps with post_constraint=True (impl="warp" cannot)

    def __init__(
        self,
        frame_skip: int | None = None,
        exclude_current_positions_from_observation: bool = True,
        ls_iterations: int | None = 10,
        physics: str = "default",
        impl: str = "jax",
    ):
        if physics not in PHYSICS:
            raise ValueError(f"physics must be one of {PHYSICS}, got {physics!r}")
        if impl not in IMPLS:
            raise ValueError(f"impl must be one of {IMPLS}, got {impl!r}")
        if impl == "warp" and self.needs_cfrc_ext:
            raise ValueError(f"impl='warp' cannot step {type(self).__name__}: its observation and "
                             f"reward read cfrc_ext, which MJX's Warp implementation does not "
                             f"compute; use impl='jax'")
        self.physics_mode = physics
        frame_skip = self.default_frame_skip if frame_skip is None else frame_skip
        if int(frame_skip) < 1:
            raise ValueError(f"frame_skip must be >= 1, got {frame_skip}")
        self.frame_skip = int(frame_skip)
        # Leading qpos entries left out of the observation.
        exclude = exclude_current_positions_from_observation
        self.skip_qpos = self.root_position_size if exclude else 0
        if ls_iterations is not None and int(ls_iterations) < 1:
            raise ValueError(f"ls_iterations must be >= 1, got {ls_iterations}")
        if physics == "fast":
            self.model = self.fast_physics.build(self.robot)  # for MuJoCo C and the renderer
        else:
            self.model = load_model(self.robot)
            if ls_iterations is not None:
                self.model.opt.ls_iterations = int(ls_iterations)
        self.torso_body_id = torso_body_id(self.model)
        with _full_precision():
            # The JAX implementation explicitly: the frames fix reads its data layout.
            self.mjx_model = mjx.put_model(self.model, impl="jax")
        self.dt = float(self.model.opt.timestep) * self.frame_skip  # seconds per env step
        self.init_qpos = np.asarray(self.model.qpos0, np.float32)
        self.init_qvel = np.zeros(self.model.nv, np.float32)
        self.impl = impl
        self.warp = None
        if impl == "warp":
            from jaxnat.mjx_pixel.warp_physics import WarpPhysics  # noqa: PLC0415  optional

            self.warp = WarpPhysics(self.model, self.frame_skip)

    @property
    def default_params(self):
        return self.params_type()

    @property
    def observation_size(self) -> int:
        return self.model.nq - self.skip_qpos + self.model.nv

    def get_obs(self, state: MJXState, params) -> jax.Array:
        """`(qpos[skip_qpos:], qvel)`, Gymnasium's observation for most robots."""
        return jnp.concatenate([state.data.qpos[self.skip_qpos :], state.data.qvel])

    def observation_space(self, params) -> spaces.Box:
        return spaces.Box(-np.inf, np.inf, (self.observation_size,), jnp.float32)

    def action_space(self, params) -> spaces.Box:
        low, high = np.asarray(self.model.actuator_ctrlrange, np.float32).T
        return spaces.Box(low, high, (self.model.nu,), jnp.float32)

    def reset_env(self, key, params):
        """Gymnasium's `reset_model`: noisy `qpos0` and zero velocity (see the module doc)."""
        key_qpos, key_qvel = jax.random.split(key)
        scale = params.reset_noise_scale
        qpos_noise = jax.random.uniform(key_qpos, (self.model.nq,), jnp.float32, -scale, scale)
        qpos = self.init_qpos + qpos_noise
        if self.qvel_noise == "normal":
            qvel_noise = scale * jax.random.normal(key_qvel, (self.model.nv,), jnp.float32)
        else:
            qvel_noise = jax.random.uniform(key_qvel, (self.model.nv,), jnp.float32, -scale, scale)
        data = self._reset_data(qpos, self.init_qvel + qvel_noise)
        state = self.state_type(time=jnp.zeros((), jnp.int32), data=data)
        return self.get_obs(state, params), state

    def _reset_data(self, qpos: jax.Array, qvel: jax.Array) -> mjx.Data:
        """Fresh data (as `mj_resetData`) with `qpos`, `qvel` set and positions computed."""
        m = self.mjx_model
        with _full_precision():
            data = mjx.make_data(m).replace(qpos=qpos, qvel=qvel)
            return mjx.camlight(m, mjx.com_pos(m, mjx.kinematics(m, data)))

    def _step_data(self, data: mjx.Data, action: jax.Array, *, post_constraint: bool = False):
        """Gymnasium's `do_simulation(action, frame_skip)`."""
        if self.warp is not None:
            return self.warp.advance(data, action)
        with _full_precision():
            data = data.replace(ctrl=jnp.asarray(action, data.ctrl.dtype))
            data = jax.lax.fori_loop(0, self.frame_skip, lambda _, d: self._physics_step(d), data)
            if post_constraint:  # fills cfrc_ext, as Gymnasium's mj_rnePostConstraint
                data = mjx_internals.with_cfrc_ext(self.mjx_model, data)
        return data

    def _physics_step(self, data: mjx.Data) -> mjx.Data:
        """One `mj_step`."""
        forward = mjx.forward
        if _plane_capsule_pairs(self.model):
            forward = _forward_with_c_capsule_frames
        if self.model.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4:
            return _rk4_step(self.mjx_model, data, forward)
        if self.model.opt.integrator == mujoco.mjtIntegrator.mjINT_EULER:
            return mjx.euler(self.mjx_model, forward(self.mjx_model, data))
        raise NotImplementedError(f"integrator {self.model.opt.integrator} is not used here")

    def _forward_reward_and_ctrl_cost(self, position_change, action, params):
        """`(forward_reward_weight * velocity, ctrl_cost_weight * |action|^2, velocity)`, the
        velocity being `position_change / dt`, as every Gymnasium locomotion task computes."""
        velocity = position_change / self.dt
        ctrl_cost = params.ctrl_cost_weight * jnp.sum(jnp.square(action))
        return params.forward_reward_weight * velocity, ctrl_cost, velocity


def _plane_capsule_pairs(model: mujoco.MjModel) -> bool:
    """Whether a plane and a capsule of `model` may collide (their contype and conaffinity
    match): only then can a contact need `_forward_with_c_capsule_frames`."""
    types = np.asarray(model.geom_type)
    contype, conaffinity = np.asarray(model.geom_contype), np.asarray(model.geom_conaffinity)
    planes, capsules = np.flatnonzero(types == _PLANE), np.flatnonzero(types == _CAPSULE)
    return bool(np.any((contype[planes, None] & conaffinity[None, capsules])
                       | (contype[None, capsules] & conaffinity[planes, None])))


def _full_precision():
    """Trace matrix products at full float32 precision (see the module docstring)."""
    return jax.default_matmul_precision("float32")


def _rk4_step(m: mjx.Model, d0: mjx.Data, forward) -> mjx.Data:
    """`mjx.step` for the RK4 integrator with one forward pass in the compiled program.

    Stage `i` (0..3) evaluates the dynamics at `x0 + a_i * h * k_{i-1}` with `a = (0, 1/2, 1/2,
    1)` (stage 0 is `x0` itself, as `mjx.step`'s first `forward`), and the weighted sums with
    `b = (1/6, 1/3, 1/3, 1/6)` advance the state, as `mjx.rungekutta4` does.
    """
    h = m.opt.timestep
    a = jnp.concatenate([jnp.zeros(1), jnp.diag(jnp.asarray(mjx_internals.RK4_A))])
    b = jnp.asarray(mjx_internals.RK4_B)
    times = d0.time + h * jnp.concatenate([jnp.zeros(1), jnp.tril(mjx_internals.RK4_A).sum(0)])
    first = jnp.arange(4) == 0

    def integrate(qpos, qvel):
        fn = lambda *args: mjx_internals.integrate_pos(*args, dt=h)
        return mjx_internals.scan_flat(m, fn, "jqv", "q", m.jnt_type, qpos, qvel)

    def stage(carry, x):
        sums, d = carry  # d: the previous stage's dynamics
        a_i, b_i, t_i, is_first = x
        # Stage 0 is x0 exactly (a select, not x0 + 0 * k, which a NaN would poison).
        kqvel = jnp.where(is_first, d0.qvel, d0.qvel + a_i * d.qacc * h)
        kact = jnp.where(is_first, d0.act, d0.act + a_i * d.act_dot * h)
        kqpos = jnp.where(is_first, d0.qpos, integrate(d0.qpos, a_i * d.qvel))
        d = forward(m, d.replace(qpos=kqpos, qvel=kqvel, act=kact, time=t_i))
        sums = jax.tree.map(lambda s, k: s + b_i * k, sums, (kqvel, d.qacc, d.act_dot))
        return (sums, d), None

    zeros = jax.tree.map(jnp.zeros_like, (d0.qvel, d0.qacc, d0.act_dot))
    (sums, d1), _ = jax.lax.scan(stage, (zeros, d0), (a, b, times, first))
    qvel, qacc, act_dot = sums
    d = d1.replace(qpos=d0.qpos, qvel=d0.qvel, act=d0.act, time=d0.time)
    return mjx_internals.advance(m, d, act_dot, qacc, qvel)


def _forward_with_c_capsule_frames(m: mjx.Model, d: mjx.Data) -> mjx.Data:
    """`mjx.forward`, with plane-capsule contact frames as MuJoCo C makes them.

    Both align a plane-capsule contact's first tangent with the capsule's axis projected on the
    plane, but MJX falls back to a fixed world axis when that projection is shorter than 0.5
    (a capsule within 30 degrees of the plane's normal, e.g. a steep Ant shin), while MuJoCo C
    projects any axis not parallel to the normal. Under the pyramidal friction cones of these
    models the tangents orient the friction pyramid, so the two give different contact
    forces and Ant's rollouts part from MuJoCo C's at the first steep foot contact. The frames
    are rebuilt as C does before the constraints are made; the rest is `mjx.forward`'s stages.
    """
    d = mjx.fwd_position(m, d)
    contact = mjx_internals.contact(d)
    plane, capsule = contact.geom[:, 0], contact.geom[:, 1]
    geom_type = jnp.asarray(m.geom_type)
    is_plane_capsule = (geom_type[plane] == _PLANE) & (geom_type[capsule] == _CAPSULE)
    normal = contact.frame[:, 0]
    axis = d.geom_xmat[capsule][:, :, 2]
    tangent = axis - normal * jnp.sum(normal * axis, axis=-1, keepdims=True)
    length = jnp.linalg.norm(tangent, axis=-1, keepdims=True)
    use = (is_plane_capsule & (length[:, 0] > 1e-6))[:, None, None]
    tangent = tangent / jnp.maximum(length, 1e-6)
    frame = jnp.stack([normal, tangent, jnp.cross(normal, tangent)], axis=1)
    d = mjx_internals.replace_contact_frame(d, jnp.where(use, frame, contact.frame))
    # The constraints made inside fwd_position from the old frames are dead code to XLA.
    d = mjx.make_constraint(m, d)
    # The rest of mjx.forward.
    d = mjx.sensor_pos(m, d)
    d = mjx.fwd_velocity(m, d)
    d = mjx.sensor_vel(m, d)
    d = mjx.fwd_actuation(m, d)
    d = mjx.fwd_acceleration(m, d)
    if mjx_internals.constraint_jacobian(d).size == 0:
        return d.replace(qacc=d.qacc_smooth)
    d = mjx.solve(m, d)
    return mjx.sensor_acc(m, d)
