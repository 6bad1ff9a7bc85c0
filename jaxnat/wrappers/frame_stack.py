"""`FrameStackWrapper`: the last `num_frames` observations, concatenated on the channel axis."""

from __future__ import annotations

import jax
import numpy as np
import jax.numpy as jnp
from flax import struct

from jaxnat import spaces
from jaxnat.wrappers.base import Wrapper


@struct.dataclass
class FrameStackState:
    env_state: object
    frames: jax.Array


class FrameStackWrapper(Wrapper):
    """Channels-last stacking for array observations `[..., C]` -> `[..., C * num_frames]`,
    oldest first. At reset, and after an episode ends (with an autoresetting inner env), the
    stack is filled with copies of the new episode's first observation, so frames never leak
    across episodes.
    """

    def __init__(self, env, num_frames: int = 4):
        super().__init__(env)
        if int(num_frames) < 1:
            raise ValueError(f"num_frames must be >= 1, got {num_frames}")
        self.num_frames = int(num_frames)

    def observation_space(self, params):
        inner = self._env.observation_space(params)
        if not isinstance(inner, spaces.Box):
            raise TypeError(f"FrameStackWrapper stacks Box observations, not {inner}")
        reps = (1,) * (len(inner.shape) - 1) + (self.num_frames,)
        shape = inner.shape[:-1] + (inner.shape[-1] * self.num_frames,)
        return spaces.Box(np.tile(inner.low, reps), np.tile(inner.high, reps), shape, inner.dtype)

    def _fill(self, obs):
        return jnp.concatenate([obs] * self.num_frames, axis=-1)

    def reset(self, key, params=None):
        obs, env_state = self._env.reset(key, params)
        frames = self._fill(obs)
        return frames, FrameStackState(env_state, frames)

    def step(self, key, state, action, params=None):
        obs, env_state, reward, terminated, truncated, info = self._env.step(
            key, state.env_state, action, params
        )
        channels = obs.shape[-1]
        shifted = jnp.concatenate([state.frames[..., channels:], obs], axis=-1)
        frames = jnp.where(terminated | truncated, self._fill(obs), shifted)
        return frames, FrameStackState(env_state, frames), reward, terminated, truncated, info
