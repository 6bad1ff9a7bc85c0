"""`LogWrapper`: episode returns and lengths in `info`, with PureJaxRL's key names."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from jaxnat.wrappers.base import Wrapper


@struct.dataclass
class LogState:
    env_state: object
    episode_return: jax.Array
    episode_length: jax.Array
    returned_episode_return: jax.Array
    returned_episode_length: jax.Array
    timestep: jax.Array


class LogWrapper(Wrapper):
    """Adds to `info`:

    - `returned_episode` (bool): an episode ended on this step;
    - `returned_episode_returns` / `returned_episode_lengths`: return and length of the most
      recently finished episode (held until the next one finishes);
    - `timestep`: steps taken since `reset`.

    Put it outside `AutoResetWrapper` (as `jaxnat.make` builds envs), so it sees episode ends.
    It also wraps envs with the five-value step of gymnax 0.x (`done` counts as termination)
    and returns the six-value form.
    """

    def reset(self, key, params=None):
        obs, env_state = self._env.reset(key, params)
        zero_f, zero_i = jnp.zeros((), jnp.float32), jnp.zeros((), jnp.int32)
        return obs, LogState(env_state, zero_f, zero_i, zero_f, zero_i, zero_i)

    def step(self, key, state, action, params=None):
        out = self._env.step(key, state.env_state, action, params)
        if len(out) == 5:  # gymnax 0.x / PureJaxRL five-value step: `done` only
            obs, env_state, reward, terminated, info = out
            truncated = jnp.zeros_like(terminated)
        else:
            obs, env_state, reward, terminated, truncated, info = out
        done = terminated | truncated
        episode_return = state.episode_return + reward
        episode_length = state.episode_length + 1
        state = LogState(
            env_state=env_state,
            episode_return=jnp.where(done, 0.0, episode_return),
            episode_length=jnp.where(done, 0, episode_length),
            returned_episode_return=jnp.where(done, episode_return, state.returned_episode_return),
            returned_episode_length=jnp.where(done, episode_length, state.returned_episode_length),
            timestep=state.timestep + 1,
        )
        info = {
            **info,
            "returned_episode_returns": state.returned_episode_return,
            "returned_episode_lengths": state.returned_episode_length,
            "returned_episode": done,
            "timestep": state.timestep,
        }
        return obs, state, reward, terminated, truncated, info
