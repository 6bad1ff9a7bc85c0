"""Swimmer in MJX with Gymnasium's `Swimmer-v5` semantics: `MuJoCo/Swimmer-v0`.

A three-link snake swims forward in a viscous fluid on a plane. Gymnasium's `swimmer.xml`, RK4
at 0.01 s, `frame_skip` 4: one step is 0.04 s of simulated time.

- **Fluid**: the model's `<option density="4000" viscosity="0.1">` switches on MuJoCo's
  inertia-box fluid model (viscous and quadratic drag on each body's equivalent box). MJX
  implements that model (`mjx.passive`), with the same formulas as MuJoCo C; nothing is left
  out. Tests bound the drift of MJX rollouts from MuJoCo C's `mj_step`.
- **Action**: float32[2], torques on the two rotors, in [-1, 1] (MuJoCo clamps larger values).
- **Observation**: float32[8] = `qpos[2:]` (3: body angle and two joint angles; the x, y
  position is left out unless `exclude_current_positions_from_observation=False`, then [10])
  and `qvel` (5).
- **Reward**: `forward_reward_weight * dx/dt - ctrl_cost_weight * sum(action^2)` (weights 1.0
  and 1e-4), `dx` the change of `qpos[0]` over the step, `dt = 0.04`. Unclipped.
- **Termination**: never.
- **Reset**: `qpos = qpos0 + U(-s, s)`, `qvel = U(-s, s)`, `s = reset_noise_scale` (0.1).
- **`physics="fast"`**: Euler instead of RK4 (same 0.01 s step and `frame_skip`); Swimmer has
  no contacts, so nothing else changes. Faster, further from Gymnasium's trajectories
  (bench/results/mjx_fidelity.md).
- **Time limit**: 1000 steps (`truncated`, never `terminated`).
- **Info**: `x_position`, `y_position`, `distance_from_origin`, `x_velocity`, `y_velocity`,
  `reward_forward`, `reward_ctrl` (as Gymnasium's).

Example::

    import jax, jaxnat
    env, params = jaxnat.make("MuJoCo/Swimmer-v0")
    obs, state = env.reset(jax.random.key(0), params)
"""

from __future__ import annotations

import jax.numpy as jnp
from flax import struct

from jaxnat.core import EnvParams
from jaxnat.mjx_pixel.base import MJXEnv, MJXState, PhysicsSettings

__all__ = ["Swimmer", "SwimmerState", "SwimmerParams"]


@struct.dataclass
class SwimmerState(MJXState):
    """`time` and the simulator's `data` (`mjx.Data`)."""


@struct.dataclass
class SwimmerParams(EnvParams):
    """Gymnasium `Swimmer-v5`'s keyword arguments (traced; vmappable)."""

    max_steps_in_episode: int = 1000
    forward_reward_weight: float = 1.0
    ctrl_cost_weight: float = 1e-4
    reset_noise_scale: float = 0.1


class Swimmer(MJXEnv):
    """Gymnasium's `Swimmer-v5` in MJX (see the module docstring for the spec).

    Args: as `MJXEnv` (`frame_skip` 4, `exclude_current_positions_from_observation`,
    `ls_iterations`, `physics`).
    """

    robot = "swimmer"
    params_type = SwimmerParams
    state_type = SwimmerState
    qvel_noise = "uniform"
    default_frame_skip = 4
    root_position_size = 2
    fast_physics = PhysicsSettings(integrator="euler", ls_iterations=10)

    def step_env(self, key, state: SwimmerState, action, params: SwimmerParams):
        data = self._step_data(state.data, action)
        forward_reward, ctrl_cost, velocity = self._forward_reward_and_ctrl_cost(
            data.qpos[:2] - state.data.qpos[:2], action, params
        )
        forward_reward = forward_reward[0]  # x only
        state = state.replace(data=data)
        info = {
            "x_position": data.qpos[0],
            "y_position": data.qpos[1],
            "distance_from_origin": jnp.linalg.norm(data.qpos[:2]),
            "x_velocity": velocity[0],
            "y_velocity": velocity[1],
            "reward_forward": forward_reward,
            "reward_ctrl": -ctrl_cost,
        }
        reward = forward_reward - ctrl_cost
        return self.get_obs(state, params), state, reward, jnp.zeros((), jnp.bool_), info
