"""Wrappers for host-batched envs (numpy `reset()` / `step(actions)`): reward clipping, JAX arrays.

    env = ClipRewardWrapper(jaxnat.make_vec("NaturalAtari/Breakout-v0", 8))
    env = DeviceArraysWrapper(env)      # jax arrays out, for jitted agents
"""

from __future__ import annotations

import jax
import numpy as np

__all__ = ["HostVecWrapper", "ClipRewardWrapper", "DeviceArraysWrapper"]


class HostVecWrapper:
    """Base: forwards `reset`, `step` and every other attribute to the wrapped env."""

    def __init__(self, env):
        self.env = env

    def reset(self, **kwargs):
        return self.env.reset(**kwargs)

    def step(self, actions):
        return self.env.step(actions)

    def __getattr__(self, name):
        return getattr(self.env, name)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.env!r})"


class ClipRewardWrapper(HostVecWrapper):
    """Training-time reward clipping to `[-bound, bound]` (DQN's sign clipping for bound 1).

    The unclipped reward stays in `info["unclipped_reward"]`; the episode statistics in `info`
    (`returned_episode_returns`) are the env's, i.e. whole games with unclipped rewards.
    """

    def __init__(self, env, bound: float = 1.0):
        super().__init__(env)
        self.bound = float(bound)

    def step(self, actions):
        obs, reward, terminated, truncated, info = self.env.step(actions)
        info = {**info, "unclipped_reward": reward}
        return obs, np.clip(reward, -self.bound, self.bound), terminated, truncated, info


class DeviceArraysWrapper(HostVecWrapper):
    """Outputs as JAX arrays on `device` (default: JAX's default device), for jitted agents.

    One `jax.device_put` of the whole output per call (a single host-to-device transfer of the
    observation batch; on the CPU backend, numpy memory may be used without a copy). Actions may
    be JAX arrays: they come back to the host once per step, as the emulator needs them there.
    """

    def __init__(self, env, device=None):
        super().__init__(env)
        self.device = device

    def reset(self, **kwargs):
        return jax.device_put(self.env.reset(**kwargs), self.device)

    def step(self, actions):
        out = self.env.step(np.asarray(actions))
        return jax.device_put(out, self.device)
