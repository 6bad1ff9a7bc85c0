"""HalfCheetah in MJX with Gymnasium's `HalfCheetah-v5` semantics: `MuJoCo/HalfCheetah-v0`.

A planar two-legged cat-like robot runs forward. Gymnasium's `half_cheetah.xml`, semi-implicit
Euler at 0.01 s, `frame_skip` 5: one step is 0.05 s of simulated time.

- **Action**: float32[6], torques on the back and front thigh, shin and foot hinges, in [-1, 1]
  (MuJoCo clamps larger values).
- **Observation**: float32[17] = `qpos[1:]` (8: the x position is left out unless
  `exclude_current_positions_from_observation=False`, then [18]) and `qvel` (9), unclipped.
- **Reward**: `forward_reward_weight * dx/dt - ctrl_cost_weight * sum(action^2)` (weights 1.0
  and 0.1), `dx` the change of `qpos[0]` over the step, `dt = 0.05`. Unclipped.
- **Termination**: never (the cheetah cannot fall out of its task).
- **Reset**: `qpos = qpos0 + U(-s, s)`, `qvel = s * N(0, 1)`, `s = reset_noise_scale` (0.1).
- **`physics="fast"`**: at most 4 Newton iterations with at most 4 line-search steps each,
  and only the head, thighs and feet touch the floor (torso and shins collide with nothing),
  as Brax's MJX HalfCheetah; the integrator is Gymnasium's Euler already. Faster, further
  from Gymnasium's trajectories (bench/results/mjx_fidelity.md).
- **Time limit**: 1000 steps (`truncated`, never `terminated`).
- **Info**: `x_position`, `x_velocity`, `reward_forward`, `reward_ctrl` (as Gymnasium's).

Example::

    import jax, jaxnat
    env, params = jaxnat.make("MuJoCo/HalfCheetah-v0")
    obs, state = env.reset(jax.random.key(0), params)
"""

from __future__ import annotations

import jax.numpy as jnp
from flax import struct

from jaxnat.core import EnvParams
from jaxnat.mjx_pixel.base import MJXEnv, MJXState, PhysicsSettings

__all__ = ["HalfCheetah", "HalfCheetahState", "HalfCheetahParams"]


@struct.dataclass
class HalfCheetahState(MJXState):
    """`time` and the simulator's `data` (`mjx.Data`)."""


@struct.dataclass
class HalfCheetahParams(EnvParams):
    """Gymnasium `HalfCheetah-v5`'s keyword arguments (traced; vmappable)."""

    max_steps_in_episode: int = 1000
    forward_reward_weight: float = 1.0
    ctrl_cost_weight: float = 0.1
    reset_noise_scale: float = 0.1


class HalfCheetah(MJXEnv):
    """Gymnasium's `HalfCheetah-v5` in MJX (see the module docstring for the spec).

    Args: as `MJXEnv` (`frame_skip` 5, `exclude_current_positions_from_observation`,
    `ls_iterations`, `physics`).
    """

    robot = "half_cheetah"
    params_type = HalfCheetahParams
    state_type = HalfCheetahState
    qvel_noise = "normal"
    default_frame_skip = 5
    root_position_size = 1
    fast_physics = PhysicsSettings(iterations=4, ls_iterations=4,
                                   contact_geoms=("head", "bthigh", "bfoot", "fthigh", "ffoot"))

    def step_env(self, key, state: HalfCheetahState, action, params: HalfCheetahParams):
        data = self._step_data(state.data, action)
        forward_reward, ctrl_cost, x_velocity = self._forward_reward_and_ctrl_cost(
            data.qpos[0] - state.data.qpos[0], action, params
        )
        state = state.replace(data=data)
        info = {
            "x_position": data.qpos[0],
            "x_velocity": x_velocity,
            "reward_forward": forward_reward,
            "reward_ctrl": -ctrl_cost,
        }
        reward = forward_reward - ctrl_cost
        return self.get_obs(state, params), state, reward, jnp.zeros((), jnp.bool_), info
