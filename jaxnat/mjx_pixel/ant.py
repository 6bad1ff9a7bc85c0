"""Ant in MJX with Gymnasium's `Ant-v5` semantics: `MuJoCo/Ant-v0`.

A four-legged robot (a sphere torso on a free joint, eight hinged leg segments) walks forward.
Gymnasium's `ant.xml`, RK4 at 0.01 s, `frame_skip` 5: one step is 0.05 s of simulated time.

- **Action**: float32[8], torques on the hips and ankles, in [-1, 1] (MuJoCo clamps larger
  values).
- **Observation**: float32[105] = `qpos[2:]` (13: torso z, orientation quaternion, 8 joint
  angles; x, y are left out unless `exclude_current_positions_from_observation=False`, then
  [107]), `qvel` (14) and the external contact forces `clip(cfrc_ext[1:], *contact_force_range)`
  (13 bodies x 6 = 78; left out when `include_cfrc_ext_in_observation=False`). As in
  Gymnasium, `cfrc_ext` comes from `mj_rnePostConstraint` after the step's physics and is zero
  in the first observation after reset.
- **Reward**: `forward_reward_weight * dx/dt + healthy_reward * is_healthy
  - ctrl_cost_weight * sum(action^2) - contact_cost_weight * sum(clip(cfrc_ext)^2)` (weights
  1, 1, 0.5, 5e-4), `dx` the change over the step of the torso's `xpos` x (body 1, Gymnasium's
  `main_body`), `dt = 0.05`. Unclipped. As in Gymnasium, `xpos` after a step is that of the
  last Runge-Kutta stage's forward pass, not of the final `qpos`.
- **Healthy**: `qpos` and `qvel` finite and the torso z = `qpos[2]` in `healthy_z_range`
  [0.2, 1.0] (closed interval).
- **Termination**: `not is_healthy` after the step, if `terminate_when_unhealthy` (default).
- **Reset**: `qpos = qpos0 + U(-s, s)`, `qvel = s * N(0, 1)`, `s = reset_noise_scale` (0.1);
  `qpos0` puts the torso at z = 0.75, upright.
- **`physics="fast"`**: Euler instead of RK4 (same 0.01 s step and `frame_skip`, no implicit
  joint damping), one Newton iteration with at most 4 line-search steps, and only four feet
  touch the floor: massless, invisible spheres of the lower legs' radius at their far ends
  (`left_foot` ... `fourth_foot`, one contact each where a capsule makes two); every other geom
  collides with nothing, and the four leg bodies without joints are fused into the torso (the
  same rigid body; their contact forces, zero, keep their place in the observation), as Brax's
  MJX Ant. Faster, further from Gymnasium's trajectories
  (bench/results/mjx_fidelity.md).
- **Time limit**: 1000 steps (`truncated`, never `terminated`).
- **Info**: `x_position`, `y_position`, `distance_from_origin`, `x_velocity`, `y_velocity`,
  `reward_forward`, `reward_ctrl`, `reward_contact`, `reward_survive` (as Gymnasium's).

Example::

    import jax, jaxnat
    env, params = jaxnat.make("MuJoCo/Ant-v0")
    obs, state = env.reset(jax.random.key(0), params)
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxnat.core import EnvParams
from jaxnat.mjx_pixel import mjx_internals
from jaxnat.mjx_pixel.base import MJXEnv, MJXState, PhysicsSettings, fused_body_index
from jaxnat.mjx_pixel.models import load_model

__all__ = ["Ant", "AntState", "AntParams"]


@struct.dataclass
class AntState(MJXState):
    """`time` and the simulator's `data` (`mjx.Data`, with `cfrc_ext` filled after a step)."""


@struct.dataclass
class AntParams(EnvParams):
    """Gymnasium `Ant-v5`'s keyword arguments (traced; vmappable)."""

    max_steps_in_episode: int = 1000
    forward_reward_weight: float = 1.0
    ctrl_cost_weight: float = 0.5
    contact_cost_weight: float = 5e-4
    healthy_reward: float = 1.0
    terminate_when_unhealthy: bool = True
    healthy_z_range: tuple[float, float] = (0.2, 1.0)
    contact_force_range: tuple[float, float] = (-1.0, 1.0)
    reset_noise_scale: float = 0.1


class Ant(MJXEnv):
    """Gymnasium's `Ant-v5` in MJX (see the module docstring for the spec).

    Args: as `MJXEnv` (`frame_skip` 5, `exclude_current_positions_from_observation`,
    `ls_iterations`, `physics`), and
        include_cfrc_ext_in_observation: append the clipped contact forces (Gymnasium's True).
    """

    robot = "ant"
    params_type = AntParams
    state_type = AntState
    qvel_noise = "normal"
    default_frame_skip = 5
    root_position_size = 2
    needs_cfrc_ext = True
    fast_physics = PhysicsSettings(
        integrator="euler", iterations=1, ls_iterations=4, eulerdamp=False,
        contact_geoms=("left_foot", "right_foot", "third_foot", "fourth_foot"), fuse_static=True,
        foot_spheres=(("left_foot", "left_ankle_geom"), ("right_foot", "right_ankle_geom"),
                      ("third_foot", "third_ankle_geom"), ("fourth_foot", "fourth_ankle_geom")),
    )

    def __init__(
        self,
        frame_skip: int | None = None,
        exclude_current_positions_from_observation: bool = True,
        include_cfrc_ext_in_observation: bool = True,
        ls_iterations: int | None = 10,
        physics: str = "default",
        impl: str = "jax",
    ):
        super().__init__(frame_skip, exclude_current_positions_from_observation, ls_iterations,
                         physics, impl)
        self.include_cfrc_ext_in_observation = include_cfrc_ext_in_observation
        gymnasium_model = self.model if physics == "default" else load_model(self.robot)
        self.gymnasium_nbody = gymnasium_model.nbody
        # Where fast physics fused the four static leg bodies into the torso: each Gymnasium
        # body's index in this model (-1: fused). No geom of a fused body collides under fast
        # physics, so their contact forces are zero, as they are in Gymnasium's layout.
        self.body_index = fused_body_index(gymnasium_model, self.model)

    @property
    def observation_size(self) -> int:
        forces = 6 * (self.gymnasium_nbody - 1) if self.include_cfrc_ext_in_observation else 0
        return super().observation_size + forces

    def get_obs(self, state: AntState, params: AntParams) -> jax.Array:
        obs = super().get_obs(state, params)
        if not self.include_cfrc_ext_in_observation:
            return obs
        forces = self.contact_forces(state.data, params)[1:].reshape(-1)
        return jnp.concatenate([obs, forces])

    def contact_forces(self, data, params: AntParams) -> jax.Array:
        """`cfrc_ext` clipped to `contact_force_range`, per body of Gymnasium's model (world
        included)."""
        low, high = params.contact_force_range
        forces = mjx_internals.cfrc_ext(data)
        if self.body_index is not None:
            fused = self.body_index < 0
            forces = jnp.where(fused[:, None], 0.0, forces[np.maximum(self.body_index, 0)])
        return jnp.clip(forces, low, high)

    def is_healthy(self, data, params: AntParams) -> jax.Array:
        low, high = params.healthy_z_range
        finite = jnp.all(jnp.isfinite(data.qpos)) & jnp.all(jnp.isfinite(data.qvel))
        z = data.qpos[2]
        return finite & (low <= z) & (z <= high)

    def step_env(self, key, state: AntState, action, params: AntParams):
        data = self._step_data(state.data, action, post_constraint=True)
        torso = self.torso_body_id
        forward_reward, ctrl_cost, velocity = self._forward_reward_and_ctrl_cost(
            data.xpos[torso, :2] - state.data.xpos[torso, :2], action, params
        )
        forward_reward = forward_reward[0]  # x only
        contact_cost = params.contact_cost_weight * jnp.sum(
            jnp.square(self.contact_forces(data, params))
        )
        healthy = self.is_healthy(data, params)
        healthy_reward = healthy * params.healthy_reward
        reward = forward_reward + healthy_reward - ctrl_cost - contact_cost
        terminated = ~healthy & params.terminate_when_unhealthy
        state = state.replace(data=data)
        info = {
            "x_position": data.qpos[0],
            "y_position": data.qpos[1],
            "distance_from_origin": jnp.linalg.norm(data.qpos[:2]),
            "x_velocity": velocity[0],
            "y_velocity": velocity[1],
            "reward_forward": forward_reward,
            "reward_ctrl": -ctrl_cost,
            "reward_contact": -contact_cost,
            "reward_survive": healthy_reward,
        }
        return self.get_obs(state, params), state, reward, terminated, info
