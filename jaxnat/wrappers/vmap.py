"""`VmapWrapper`: `num_envs` copies of an env behind one key, optionally split over devices."""

from __future__ import annotations

import jax
from jax.sharding import PartitionSpec

from jaxnat.sharding import AXIS, check_split, device_mesh, replicated
from jaxnat.wrappers.base import Wrapper


class VmapWrapper(Wrapper):
    """`reset(key)` splits the key into `num_envs` and vmaps; `step` takes batched state and
    actions (leading axis `num_envs`) and one key. Params are shared by all envs (not batched).

    Spaces stay those of one env (as Gymnasium's `single_observation_space`); every output has a
    leading `num_envs` axis. `params`: the params used when a call passes none (default: the
    env's `default_params`).

    `devices` (a count, "all", devices or a `jaxnat.sharding.device_mesh`) splits the batch
    along its leading axis over a 1-D mesh (`NamedSharding`, `jaxnat.sharding.AXIS`): `reset`
    and `step` are `jax.shard_map`s in which each device steps its own `num_envs / devices`
    envs (no cross-device traffic), and their outputs stay split. Env `i` gets the same key as
    without `devices` (the key is split into `num_envs` first), so sharded and unsharded runs
    give the same envs. `num_envs` must divide evenly (the error names the nearest counts).
    """

    def __init__(self, env, num_envs: int, params=None, devices=None):
        super().__init__(env)
        if int(num_envs) < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        self.num_envs = int(num_envs)
        self._params = params
        self.mesh = None if devices is None else device_mesh(devices)
        if self.mesh is not None:
            check_split(self.num_envs, self.mesh.size)
            # Placed on every device once, not at every call.
            self._params = jax.device_put(self.default_params, replicated(self.mesh))

    @property
    def default_params(self):
        return self._env.default_params if self._params is None else self._params

    @property
    def sharding(self):
        """The `NamedSharding` of the batched outputs (None without `devices`)."""
        return None if self.mesh is None else jax.sharding.NamedSharding(self.mesh, PartitionSpec(AXIS))

    def _batched(self, fn, keys, *args):
        """`fn(keys, *args)` over the batch: one vmap, or one per device inside a shard_map
        (the last argument, the params, copied to every device)."""
        if self.mesh is None:
            return fn(keys, *args)
        specs = (PartitionSpec(AXIS),) * len(args) + (PartitionSpec(),)
        # check_vma off: env code mixes per-env values and shared params in lax.cond and scan
        # carries, which the varying-axes check rejects although every output is per env.
        return jax.shard_map(fn, mesh=self.mesh, in_specs=specs, out_specs=PartitionSpec(AXIS),
                             check_vma=False)(keys, *args)

    def reset(self, key, params=None):
        if params is None:
            params = self.default_params
        keys = jax.random.split(key, self.num_envs)
        return self._batched(jax.vmap(self._env.reset, in_axes=(0, None)), keys, params)

    def step(self, key, state, action, params=None):
        if params is None:
            params = self.default_params
        keys = jax.random.split(key, self.num_envs)
        return self._batched(jax.vmap(self._env.step, in_axes=(0, 0, 0, None)), keys, state, action, params)
