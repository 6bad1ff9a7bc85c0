"""What the four MJX robots share: the model, the state, reset noise and frame-skipped stepping.

Each robot (`ant.py`, `half_cheetah.py`, `hopper.py`, `swimmer.py`) subclasses `MJXEnv` and adds
its reward and termination (and observation where it differs from `(qpos, qvel)`) (Gymnasium MuJoCo v5's, see each docstring).

- **State**: `state.data` is the full `mjx.Data` (the renderer reads `geom_xpos`, `geom_xmat`
  and `xpos[torso_body_id]` from it). `reset` and `step` return the same pytree type, shapes
  and dtypes, so `AutoResetWrapper`'s select between them needs no second trace.
- **Reset** (Gymnasium's `reset_model`): `qpos = qpos0 + U(-s, s)`, `qvel = U(-s, s)` or
  `s * N(0, 1)` (per robot) with `s = params.reset_noise_scale`, everything else as `mj_resetData` leaves it (zero `ctrl`,
  `act`, warm start), then the position stage of `mj_forward` (body, geom and camera poses,
  centres of mass): all that an observation or the renderer reads. The first step's forward
  pass computes the rest from `qpos`, `qvel` alone, so trajectories are those after a full
  `mj_forward`, and reset compiles in seconds, not half a minute (it also runs inside every
  autoresetting step).
- **Step** (Gymnasium's `do_simulation`): `ctrl = action` (MuJoCo clamps it to `ctrlrange`),
  `frame_skip` calls of `mj_step`, then `mj_rnePostConstraint` where the robot reads
  `cfrc_ext` (Ant). As in MuJoCo C, the position-dependent fields of the data after a step
  (`xpos`, `geom_xpos`, contacts) are those of the last forward pass (the step's start for
  Euler, the last Runge-Kutta stage for RK4), not of the new `qpos`.
- **Compile time**: MJX's `rungekutta4` unrolls its three inner stages, so XLA compiles four
  copies of the forward dynamics (with the contact solver) per physics step; on a 2-core CPU
  that is over a minute for Hopper. `_rk4_step` runs the same four stages as one `lax.scan`
  (one copy of the forward dynamics), with MJX's own tableau and state advance, so the
  arithmetic is MJX's. Tests check it against MuJoCo C's `mj_step`.
- **Precision**: MJX runs in float32 (MuJoCo C in float64). Its matrix products are traced
  at full float32 precision: JAX's default on recent NVIDIA GPUs (TF32) makes the contact
  solver visibly less accurate.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from flax import struct
from mujoco import mjx
from mujoco.mjx._src import forward as mjx_forward  # RK4 tableau and state advance, see _rk4_step
from mujoco.mjx._src import scan as mjx_scan

from jaxnat import spaces
from jaxnat.core import Environment, EnvParams, EnvState
from jaxnat.mjx_pixel.models import load_model, torso_body_id

__all__ = ["MJXState", "MJXEnv"]


@struct.dataclass
class MJXState(EnvState):
    """`time` (steps this episode) and the simulator's `data` (an `mjx.Data`)."""

    data: mjx.Data


class MJXEnv(Environment):
    """A Gymnasium-v5-style MuJoCo task stepped by MJX. Subclasses set the class attributes
    below and implement `step_env` (and `get_obs`, `observation_size` if theirs differ)."""

    robot: str  # a key of `jaxnat.mjx_pixel.models.ROBOTS`
    state_type: type  # the robot's MJXState subclass
    qvel_noise: str  # reset noise on qvel: "uniform" U(-s, s) or "normal" s * N(0, 1)

    def __init__(self, frame_skip: int, skip_qpos: int):
        if int(frame_skip) < 1:
            raise ValueError(f"frame_skip must be >= 1, got {frame_skip}")
        self.frame_skip = int(frame_skip)
        self.skip_qpos = skip_qpos  # leading qpos entries (the root's x or x, y) left out of obs
        self.model = load_model(self.robot)  # mujoco.MjModel, for MuJoCo C and the renderer
        self.torso_body_id = torso_body_id(self.model)
        with _full_precision():
            self.mjx_model = mjx.put_model(self.model)
        self.dt = float(self.model.opt.timestep) * self.frame_skip  # seconds per env step
        self.init_qpos = np.asarray(self.model.qpos0, np.float32)
        self.init_qvel = np.zeros(self.model.nv, np.float32)

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
        qpos = self.init_qpos + jax.random.uniform(key_qpos, (self.model.nq,), jnp.float32, -scale, scale)
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
        with _full_precision():
            data = data.replace(ctrl=jnp.asarray(action, data.ctrl.dtype))
            data = jax.lax.fori_loop(0, self.frame_skip, lambda _, d: self._physics_step(d), data)
            if post_constraint:  # fills cfrc_ext (and cacc, cfrc_int), as Gymnasium does
                data = mjx.rne_postconstraint(self.mjx_model, data)
        return data

    def _physics_step(self, data: mjx.Data) -> mjx.Data:
        """One `mj_step`."""
        if self.model.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4:
            return _rk4_step(self.mjx_model, data)
        return mjx.step(self.mjx_model, data)

    def _forward_reward_and_ctrl_cost(self, position_change, action, params):
        """`(forward_reward_weight * velocity, ctrl_cost_weight * |action|^2, velocity)`, the
        velocity being `position_change / dt`, as every Gymnasium locomotion task computes."""
        velocity = position_change / self.dt
        ctrl_cost = params.ctrl_cost_weight * jnp.sum(jnp.square(action))
        return params.forward_reward_weight * velocity, ctrl_cost, velocity


def _full_precision():
    """Trace matrix products at full float32 precision (see the module docstring)."""
    return jax.default_matmul_precision("float32")


def _rk4_step(m: mjx.Model, d0: mjx.Data) -> mjx.Data:
    """`mjx.step` for the RK4 integrator with one forward pass in the compiled program.

    Stage `i` (0..3) evaluates the dynamics at `x0 + a_i * h * k_{i-1}` with `a = (0, 1/2, 1/2,
    1)` (stage 0 is `x0` itself, as `mjx.step`'s first `forward`), and the weighted sums with
    `b = (1/6, 1/3, 1/3, 1/6)` advance the state, as `mjx.rungekutta4` does.
    """
    h = m.opt.timestep
    a = jnp.concatenate([jnp.zeros(1), jnp.diag(jnp.asarray(mjx_forward._RK4_A))])
    b = jnp.asarray(mjx_forward._RK4_B)
    times = d0.time + h * jnp.concatenate([jnp.zeros(1), jnp.tril(mjx_forward._RK4_A).sum(0)])
    first = jnp.arange(4) == 0

    def integrate(qpos, qvel):
        fn = lambda *args: mjx_forward._integrate_pos(*args, dt=h)
        return mjx_scan.flat(m, fn, "jqv", "q", m.jnt_type, qpos, qvel)

    def stage(carry, x):
        sums, d = carry  # d: the previous stage's dynamics
        a_i, b_i, t_i, is_first = x
        # Stage 0 is x0 exactly (a select, not x0 + 0 * k, which a NaN would poison).
        kqvel = jnp.where(is_first, d0.qvel, d0.qvel + a_i * d.qacc * h)
        kact = jnp.where(is_first, d0.act, d0.act + a_i * d.act_dot * h)
        kqpos = jnp.where(is_first, d0.qpos, integrate(d0.qpos, a_i * d.qvel))
        d = mjx.forward(m, d.replace(qpos=kqpos, qvel=kqvel, act=kact, time=t_i))
        sums = jax.tree.map(lambda s, k: s + b_i * k, sums, (kqvel, d.qacc, d.act_dot))
        return (sums, d), None

    zeros = jax.tree.map(jnp.zeros_like, (d0.qvel, d0.qacc, d0.act_dot))
    (sums, d1), _ = jax.lax.scan(stage, (zeros, d0), (a, b, times, first))
    qvel, qacc, act_dot = sums
    d = d1.replace(qpos=d0.qpos, qvel=d0.qvel, act=d0.act, time=d0.time)
    return mjx_forward._advance(m, d, act_dot, qacc, qvel)
