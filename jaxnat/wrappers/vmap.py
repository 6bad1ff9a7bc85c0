"""`VmapWrapper`: `num_envs` copies of an env behind one key."""

from __future__ import annotations

import jax

from jaxnat.wrappers.base import Wrapper


class VmapWrapper(Wrapper):
    """`reset(key)` splits the key into `num_envs` and vmaps; `step` takes batched state and
    actions (leading axis `num_envs`) and one key. Params are shared by all envs (not batched).

    Spaces stay those of one env (as Gymnasium's `single_observation_space`); every output has a
    leading `num_envs` axis. `params`: the params used when a call passes none (default: the
    env's `default_params`).
    """

    def __init__(self, env, num_envs: int, params=None):
        super().__init__(env)
        if int(num_envs) < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        self.num_envs = int(num_envs)
        self._params = params

    @property
    def default_params(self):
        return self._env.default_params if self._params is None else self._params

    def reset(self, key, params=None):
        if params is None:
            params = self.default_params
        keys = jax.random.split(key, self.num_envs)
        return jax.vmap(self._env.reset, in_axes=(0, None))(keys, params)

    def step(self, key, state, action, params=None):
        if params is None:
            params = self.default_params
        keys = jax.random.split(key, self.num_envs)
        return jax.vmap(self._env.step, in_axes=(0, 0, 0, None))(keys, state, action, params)
