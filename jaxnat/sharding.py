"""Devices for sharded envs and training: a 1-D mesh, even splits, and several hosts.

    mesh = jaxnat.sharding.device_mesh(4)          # the first 4 devices, axis `AXIS`
    vec = jaxnat.make_vec("Classify/Digits-v0", 4096, devices=4)   # envs split over them

Contract:

- `resolve_devices(devices)` turns `None` (the default device), an int `N` (the first `N` of
  `jax.devices()`), `"all"`, or a sequence of `jax.Device`s into a list of devices; a count the
  machine (or, after `initialize_from_env`, the cluster) does not have is a `ValueError` that
  says how many there are.
- `device_mesh(devices)` is a 1-D `jax.sharding.Mesh` over them, its one axis named `AXIS`,
  of `Auto` type (so `jax.shard_map` and jit's sharding propagation both accept it). A mesh of
  several GPUs switches the process from XLA's Shardy partitioner to GSPMD
  (`avoid_shardy_crash`), unless `JAXNAT_SHARDY=1`.
- `check_split(count, shards, what)` refuses a batch that does not divide evenly, naming the
  nearest counts that do.
- `process_share(count, devices)` is this process's contiguous part `(first, size)` of a batch
  split over the mesh: all of it in one process; with several (`jax.distributed`), the entries
  its devices hold (a host-batched env, Natural Atari, builds that many envs per process).
- `put_global(tree, shardings)` places values that are the same in every process;
  `shard_program(fn, mesh, in_specs, out_specs)` is `fn` under `jax.shard_map`, jitted with
  the matching shardings; `local_copy(tree)` is this process's copy of replicated arrays.
- `initialize_from_env()` starts `jax.distributed` from `JAX_COORDINATOR_ADDRESS`,
  `JAX_NUM_PROCESSES` and `JAX_PROCESS_ID` (jax itself reads only the first), and does nothing
  when they are unset; every process then sees every host's devices in `jax.devices()`.
"""

from __future__ import annotations

import functools
import os
import warnings
from typing import Sequence

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

__all__ = ["AXIS", "ENV_VARS", "SHARDY_ENV_VAR", "resolve_devices", "device_mesh", "avoid_shardy_crash", "check_split", "nearest_multiples", "sharded",
           "replicated", "shardings", "process_share", "put_global", "shard_program", "local_copy",
           "initialize_from_env"]

AXIS = "devices"  # the mesh axis that envs (or seeds) are split along
# What `initialize_from_env` reads: the coordinator's host:port, the process count, this process's id.
ENV_VARS = ("JAX_COORDINATOR_ADDRESS", "JAX_NUM_PROCESSES", "JAX_PROCESS_ID")
# Set to 1 to keep JAX's Shardy partitioner on meshes of several GPUs (`avoid_shardy_crash`).
SHARDY_ENV_VAR = "JAXNAT_SHARDY"


def resolve_devices(devices, flag: str = "devices=") -> list:
    """The devices `devices` names: None (the default device), N (the first N), "all", or
    devices; `flag` names the argument in errors (e.g. "--devices ")."""
    available = jax.devices()
    if devices is None:
        return available[:1]
    if isinstance(devices, str):
        if devices.strip().lower() == "all":
            return list(available)
        try:
            devices = int(devices)
        except ValueError:
            raise ValueError(f"{flag}{devices}: give a device count (e.g. 2) or all") from None
    if isinstance(devices, (int, np.integer)) and not isinstance(devices, bool):
        if devices < 1:
            raise ValueError(f"{flag}{devices}: give at least 1 device (or all)")
        if devices > len(available):
            count = len(available)
            raise ValueError(f"{flag}{devices}: there {'is' if count == 1 else 'are'} only {count} "
                             f"{available[0].platform} device{'s' * (count != 1)} here; use at most {count} (or all)")
        return list(available[:devices])
    if isinstance(devices, Sequence) and devices and all(isinstance(d, jax.Device) for d in devices):
        return list(devices)
    raise TypeError(f"{flag}{devices!r}: give a device count, all, or a list of jax devices")


def device_mesh(devices) -> Mesh:
    """A 1-D mesh (axis `AXIS`) over `resolve_devices(devices)` (`avoid_shardy_crash` first)."""
    mesh = devices if isinstance(devices, Mesh) else Mesh(np.asarray(resolve_devices(devices)), (AXIS,))
    avoid_shardy_crash(mesh)
    return mesh


def avoid_shardy_crash(mesh: Mesh) -> bool:
    """Switch this process to the GSPMD partitioner (`jax_use_shardy_partitioner=False`, with a
    warning, once) when `mesh` spans several GPUs, unless `JAXNAT_SHARDY=1`; whether it did.

    XLA's Shardy partitioner, JAX's default, crashes the process (a segmentation fault in its
    `shardy-xla` pass) compiling MuJoCo MJX's physics inside a `jax.shard_map` over 2+ GPUs,
    which every sharded MuJoCo and PixelMuJoCo program is; the smallest such program is
    `mjx.kinematics` vmapped under `shard_map` (`tests/test_sharding.py` keeps it;
    bench/results/scaling.md records where and on what it was isolated). GSPMD
    compiles and runs it, and every other sharded program of jaxnat the same. The setting is
    the process's, read when a program is lowered, so it changes here, before any program on
    the mesh is built, rather than around each program."""
    gpus = {d.platform for d in mesh.devices.flat} == {"gpu"} and mesh.size > 1
    if not gpus or os.environ.get(SHARDY_ENV_VAR) == "1" or not jax.config.jax_use_shardy_partitioner:
        return False
    jax.config.update("jax_use_shardy_partitioner", False)
    warnings.warn(f"jaxnat: a mesh of {mesh.size} GPUs: switched JAX to the GSPMD partitioner "
                  "(jax_use_shardy_partitioner=False), since Shardy crashes compiling MJX physics under "
                  f"shard_map on several GPUs; set {SHARDY_ENV_VAR}=1 to keep Shardy", stacklevel=2)
    return True


def nearest_multiples(count: int, shards: int) -> list[int]:
    """The multiples of `shards` nearest to `count` (below and above; at least `shards`)."""
    below = count // shards * shards
    return sorted({max(below, shards), below + shards})


def check_split(count: int, shards: int, what: str = "num_envs", fix: str | None = None,
                over: str | None = None) -> None:
    """A `ValueError` unless `count` splits evenly over `shards` devices, naming the nearest
    counts that do (`fix`: how to give one, e.g. "--num-envs"; default `what=`; `over`: what
    the shards are, default "N devices")."""
    if count % shards:
        options = " or ".join(str(n) for n in nearest_multiples(count, shards))
        raise ValueError(f"{what}={count} does not split evenly over {over or f'{shards} devices'}: use "
                         f"{fix or what + '='}{options}")


def sharded(mesh: Mesh, axis: int = 0) -> NamedSharding:
    """Arrays split along `axis` over the mesh."""
    return NamedSharding(mesh, PartitionSpec(*([None] * axis), AXIS))


def replicated(mesh: Mesh) -> NamedSharding:
    """Arrays copied whole onto every device of the mesh."""
    return NamedSharding(mesh, PartitionSpec())


def shardings(mesh: Mesh, specs):
    """A tree of `PartitionSpec`s (a prefix of some tree) as `NamedSharding`s over `mesh`."""
    return jax.tree.map(lambda s: NamedSharding(mesh, s), specs, is_leaf=lambda x: isinstance(x, PartitionSpec))


def process_share(count: int, devices, what: str = "num_envs") -> tuple[int, int]:
    """`(first, size)`: the entries `first .. first + size - 1` of a batch of `count` split along
    `AXIS` over `device_mesh(devices)` that this process's devices hold (with one process,
    `(0, count)`). A `ValueError` when `count` does not split evenly, when this process holds
    none of the devices, or holds parts that are not adjacent (list devices process by process)."""
    mesh = device_mesh(devices)
    processes = len({d.process_index for d in mesh.devices.flat})
    over = f"{mesh.size} devices of {processes} processes" if processes > 1 else None
    check_split(count, mesh.size, what, over=over)
    starts = sorted(index[0].start or 0 for index in sharded(mesh).addressable_devices_indices_map((count,)).values())
    if not starts:
        raise ValueError(f"process {jax.process_index()} holds none of the {mesh.size} devices: give every "
                         "process's devices (devices='all')")
    size = count // mesh.size
    if starts != list(range(starts[0], starts[0] + size * len(starts), size)):
        raise ValueError(f"process {jax.process_index()}'s devices are not adjacent in the mesh: list the devices "
                         "process by process (as jax.devices() does)")
    return starts[0], size * len(starts)


def put_global(tree, placement):
    """`tree` placed as `placement` (a sharding, or a tree of them that is a prefix of `tree`)
    says. With several processes every process passes the same values and fills its devices'
    parts (an array spanning the processes already is left as it is)."""
    if jax.process_count() == 1:
        return jax.device_put(tree, placement)
    return jax.tree.map(lambda sharding, subtree: jax.tree.map(functools.partial(_put_global, sharding=sharding),
                                                               subtree),
                        placement, tree, is_leaf=lambda x: isinstance(x, jax.sharding.Sharding))


def _put_global(x, sharding):
    if isinstance(x, jax.Array) and not x.is_fully_addressable:
        return x
    if isinstance(x, jax.Array) and jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key):
        return jax.random.wrap_key_data(_put_global(jax.random.key_data(x), sharding), impl=jax.random.key_impl(x))
    value = np.asarray(x)
    return jax.make_array_from_callback(value.shape, sharding, lambda index: value[index])


def shard_program(fn, mesh: Mesh, in_specs: tuple, out_specs, jit=jax.jit):
    """`fn` under `jax.shard_map` over `mesh` with these specs, compiled by `jit` (e.g. with
    compiler options) with the matching shardings: its arguments and results are global arrays."""
    # check_vma off: env code mixes per-env values and replicated params in lax.cond and scan
    # carries; what stays replicated is made so by the learners' pmeans.
    mapped = jax.shard_map(fn, mesh=mesh, in_specs=in_specs, out_specs=out_specs, check_vma=False)
    return jit(mapped, in_shardings=shardings(mesh, in_specs), out_shardings=shardings(mesh, out_specs))


def local_copy(tree):
    """This process's copy of replicated global arrays: each leaf on its first device."""
    return jax.tree.map(lambda x: x.addressable_data(0), tree)


def initialize_from_env() -> bool:
    """`jax.distributed.initialize` from `ENV_VARS` when `JAX_NUM_PROCESSES` is set (returns
    True), else nothing (False). Call it before anything touches a device."""
    if not os.environ.get("JAX_NUM_PROCESSES"):
        return False
    missing = [name for name in ENV_VARS if not os.environ.get(name)]
    if missing:
        raise ValueError(f"JAX_NUM_PROCESSES is set but {', '.join(missing)} {'is' if len(missing) == 1 else 'are'} "
                         "not: set all of " + ", ".join(ENV_VARS) + " (see docs/api.md, 'Several hosts')")
    if jax.distributed.is_initialized():
        return True
    try:
        count, index = int(os.environ["JAX_NUM_PROCESSES"]), int(os.environ["JAX_PROCESS_ID"])
    except ValueError:
        raise ValueError("JAX_NUM_PROCESSES and JAX_PROCESS_ID must be whole numbers") from None
    jax.distributed.initialize(os.environ["JAX_COORDINATOR_ADDRESS"], count, index)
    return True
