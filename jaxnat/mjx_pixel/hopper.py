"""Hopper in MJX with Gymnasium's `Hopper-v5` semantics: `MuJoCo/Hopper-v0`.

A one-legged planar robot (torso, thigh, leg, foot) hops forward. Gymnasium's `hopper.xml`,
RK4 at 0.002 s, `frame_skip` 4: one step is 0.008 s of simulated time.

- **Action**: float32[3], torques on the thigh, leg and foot hinges, in [-1, 1] (MuJoCo clamps
  larger values).
- **Observation**: float32[11] = `qpos[1:]` (z, torso angle, 3 joint angles; the x position is
  left out unless `exclude_current_positions_from_observation=False`, then [12]) and
  `clip(qvel, -10, 10)` (6).
- **Reward**: `forward_reward_weight * dx/dt + healthy_reward * is_healthy
  - ctrl_cost_weight * sum(action^2)`, with `dx` the change of `qpos[0]` over the step and
  `dt = 0.008`. Unclipped.
- **Healthy**: every element of `(qpos[2:], qvel)` in `healthy_state_range` (-100, 100),
  z = `qpos[1]` in `healthy_z_range` (0.7, inf) and the torso angle `qpos[2]` in
  `healthy_angle_range` (-0.2, 0.2), all open intervals. A NaN state is unhealthy.
- **Termination**: `not is_healthy` after the step, if `terminate_when_unhealthy` (default).
- **Reset**: `qpos = qpos0 + U(-s, s)`, `qvel = U(-s, s)`, `s = reset_noise_scale` (5e-3);
  `qpos0` stands the hopper upright at z = 1.25.
- **`physics="fast"`**: Euler instead of RK4 (same 0.002 s step and `frame_skip`), at most 4
  Newton iterations with at most 4 line-search steps each, and only the foot collides (with
  the floor; torso, thigh and leg collide with nothing), as Brax's MJX Hopper. Faster,
  further from Gymnasium's trajectories (bench/results/mjx_fidelity.md).
- **Time limit**: 1000 steps (`truncated`, never `terminated`).
- **Info**: `x_position`, `z_distance_from_origin`, `x_velocity`, `reward_forward`,
  `reward_ctrl`, `reward_survive` (as Gymnasium's).

Example::

    import jax, jaxnat
    env, params = jaxnat.make("MuJoCo/Hopper-v0")
    obs, state = env.reset(jax.random.key(0), params)
    obs, state, reward, terminated, truncated, info = env.step(
        jax.random.key(1), state, jax.numpy.zeros(3), params)
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from jaxnat.core import EnvParams
from jaxnat.mjx_pixel.base import MJXEnv, MJXState, PhysicsSettings

__all__ = ["Hopper", "HopperState", "HopperParams"]


@struct.dataclass
class HopperState(MJXState):
    """`time` and the simulator's `data` (`mjx.Data`)."""


@struct.dataclass
class HopperParams(EnvParams):
    """Gymnasium `Hopper-v5`'s keyword arguments (traced; vmappable)."""

    max_steps_in_episode: int = 1000
    forward_reward_weight: float = 1.0
    ctrl_cost_weight: float = 1e-3
    healthy_reward: float = 1.0
    terminate_when_unhealthy: bool = True
    healthy_state_range: tuple[float, float] = (-100.0, 100.0)
    healthy_z_range: tuple[float, float] = (0.7, float("inf"))
    healthy_angle_range: tuple[float, float] = (-0.2, 0.2)
    reset_noise_scale: float = 5e-3


class Hopper(MJXEnv):
    """Gymnasium's `Hopper-v5` in MJX (see the module docstring for the spec).

    Args: as `MJXEnv` (`frame_skip` 4, `exclude_current_positions_from_observation`,
    `ls_iterations`, `physics`).
    """

    robot = "hopper"
    params_type = HopperParams
    state_type = HopperState
    qvel_noise = "uniform"
    default_frame_skip = 4
    root_position_size = 1
    fast_physics = PhysicsSettings(integrator="euler", iterations=4, ls_iterations=4,
                                   contact_geoms=("foot_geom",))

    def get_obs(self, state: HopperState, params: HopperParams) -> jax.Array:
        data = state.data
        return jnp.concatenate([data.qpos[self.skip_qpos :], jnp.clip(data.qvel, -10.0, 10.0)])

    def is_healthy(self, data, params: HopperParams) -> jax.Array:
        z, angle = data.qpos[1], data.qpos[2]
        state = jnp.concatenate([data.qpos[2:], data.qvel])
        healthy_state = jnp.all(_inside(state, params.healthy_state_range))
        return healthy_state & _inside(z, params.healthy_z_range) & _inside(
            angle, params.healthy_angle_range
        )

    def step_env(self, key, state: HopperState, action, params: HopperParams):
        data = self._step_data(state.data, action)
        forward_reward, ctrl_cost, x_velocity = self._forward_reward_and_ctrl_cost(
            data.qpos[0] - state.data.qpos[0], action, params
        )
        healthy = self.is_healthy(data, params)
        healthy_reward = healthy * params.healthy_reward
        reward = forward_reward + healthy_reward - ctrl_cost
        terminated = ~healthy & params.terminate_when_unhealthy
        state = state.replace(data=data)
        info = {
            "x_position": data.qpos[0],
            "z_distance_from_origin": data.qpos[1] - self.init_qpos[1],
            "x_velocity": x_velocity,
            "reward_forward": forward_reward,
            "reward_ctrl": -ctrl_cost,
            "reward_survive": healthy_reward,
        }
        return self.get_obs(state, params), state, reward, terminated, info


def _inside(x, bounds) -> jax.Array:
    """`low < x < high`, elementwise (Gymnasium's open intervals)."""
    low, high = bounds
    return (low < x) & (x < high)
