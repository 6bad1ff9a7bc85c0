"""`NoiseObservationWrapper`: the paper's open-loop test."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from jaxnat.natural.noise import DEFAULT_NOISE, NoiseLaw, noise_law
from jaxnat.wrappers.base import Wrapper


class NoiseObservationWrapper(Wrapper):
    """Replace every observation with i.i.d. Gaussian noise of the same shape and dtype.

    A policy that learns as well from this as from real pixels is open loop: it ignores what it
    sees (the paper's finding on PixelMuJoCo). Integer observations (uint8 pixels) get the
    pixel-noise law `noise` (`jaxnat.natural.NOISE_LAWS`; the default, `DEFAULT_NOISE`, is the
    one every family's noise control uses: `clip(N(0, 1) * 50, 0)` truncated to uint8, the
    authors' law). Float observations have no pixel range: they get `N(0, 1)`. Dict observations
    are noised leaf by leaf. Fresh noise at every reset and step, drawn from a key split off the
    one passed in (the inner env sees its own, independent key).

    Leak-free in either order: wrapped around an autoresetting env it also replaces
    `info["final_observation"]` (else a learner bootstrapping truncated episodes would see the
    real last frame); `jaxnat.make(id, observation_noise=True)` puts it inside the autoreset,
    where the final observation is already noise.

    Args:
        loc, scale: override the mean and the standard deviation of the Gaussian (None: the
            law's for integers, 0 and 1 for floats).
        noise: the law of integer observations, a name in `NOISE_LAWS` (`"authors"`, the
            default, or `"centred"`: N(127.5, 50) rounded) or a `NoiseLaw`.
    """

    def __init__(self, env, loc: float | None = None, scale: float | None = None, *,
                 noise: str | NoiseLaw = DEFAULT_NOISE):
        super().__init__(env)
        self.loc = loc
        self.scale = scale
        self.law = noise_law(noise)

    def _noise(self, key, obs):
        leaves, treedef = jax.tree_util.tree_flatten(obs)
        keys = jax.random.split(key, len(leaves))
        return jax.tree_util.tree_unflatten(
            treedef, [self._noise_like(k, x) for k, x in zip(keys, leaves)]
        )

    def _noise_like(self, key, x):
        if jnp.issubdtype(x.dtype, jnp.integer):
            law = dataclasses.replace(self.law, **{k: v for k, v in (("mean", self.loc), ("scale", self.scale))
                                                   if v is not None})
            info = jnp.iinfo(x.dtype)  # the law's values are 0 ... 255: fit narrower dtypes
            values = law.sample(key, x.shape).astype(jnp.int32)
            return jnp.clip(values, max(info.min, 0), min(info.max, 255)).astype(x.dtype)
        loc = 0.0 if self.loc is None else self.loc
        scale = 1.0 if self.scale is None else self.scale
        return (loc + scale * jax.random.normal(key, x.shape, jnp.float32)).astype(x.dtype)

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
