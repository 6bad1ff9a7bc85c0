"""`NoiseObservationWrapper`: the paper's open-loop test."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxnat.wrappers.base import Wrapper


class NoiseObservationWrapper(Wrapper):
    """Replace every observation with i.i.d. Gaussian noise of the same shape and dtype.

    A policy that learns as well from this as from real pixels is open loop: it ignores what it
    sees (the paper's finding on PixelMuJoCo). Float observations get `loc + scale * N(0, 1)`;
    integer observations (uint8 pixels) get it rounded and clipped to the dtype's range.
    Dict observations are noised leaf by leaf. Fresh noise at every reset and step, drawn from
    a key split off the one passed in (the inner env sees its own, independent key).

    Leak-free in either order: wrapped around an autoresetting env it also replaces
    `info["final_observation"]` (else a learner bootstrapping truncated episodes would see the
    real last frame); `jaxnat.make(id, observation_noise=True)` puts it inside the autoreset,
    where the final observation is already noise.

    Args:
        loc, scale: mean and standard deviation of the noise. The defaults (None) pick
            `N(0, 1)` for floats and `N(127.5, 50)` for integers, both well inside the range.
    """

    def __init__(self, env, loc: float | None = None, scale: float | None = None):
        super().__init__(env)
        self.loc = loc
        self.scale = scale

    def _noise(self, key, obs):
        leaves, treedef = jax.tree_util.tree_flatten(obs)
        keys = jax.random.split(key, len(leaves))
        return jax.tree_util.tree_unflatten(
            treedef, [self._noise_like(k, x) for k, x in zip(keys, leaves)]
        )

    def _noise_like(self, key, x):
        is_int = jnp.issubdtype(x.dtype, jnp.integer)
        loc = self.loc if self.loc is not None else (127.5 if is_int else 0.0)
        scale = self.scale if self.scale is not None else (50.0 if is_int else 1.0)
        noise = loc + scale * jax.random.normal(key, x.shape, jnp.float32)
        if is_int:
            info = jnp.iinfo(x.dtype)
            return jnp.clip(jnp.round(noise), info.min, info.max).astype(x.dtype)
        return noise.astype(x.dtype)

    def reset(self, key, params=None):
        key_env, key_noise = jax.random.split(key)
        obs, state = self._env.reset(key_env, params)
        return self._noise(key_noise, obs), state

    def step(self, key, state, action, params=None):
        key_env, key_noise = jax.random.split(key)
        obs, state, reward, terminated, truncated, info = self._env.step(
            key_env, state, action, params
        )
        if "final_observation" in info:  # an autoreset inside: its last frame is real
            info = {**info, "final_observation": self._noise(jax.random.fold_in(key_noise, 1),
                                                             info["final_observation"])}
        return self._noise(key_noise, obs), state, reward, terminated, truncated, info
