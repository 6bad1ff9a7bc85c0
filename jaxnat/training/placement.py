"""Where a run's seeds and envs live: one device (the default), or split over a 1-D mesh.

`Placement(mesh, shard)` turns the device backend's vmapped-over-seeds functions (init, a chunk
of updates, evaluation) into jitted programs:

- `shard=None` (no `--devices`): plain `jax.jit`, today's programs, bit for bit.
- `shard="envs"`: data parallel. The learner is built with `axis_name=AXIS` (PPO, A2C:
  `rollout.on_policy_learner`) and runs inside `jax.shard_map`: each device steps its
  `num_envs / devices` envs of every seed, and the devices' gradients are averaged with
  `jax.lax.pmean`. The runner's per-env fields (`env_state`, `obs`, the normaliser's running
  returns) are split along their env axis, everything else (parameters, optimizer state,
  keys) is replicated; the global arrays have the shapes of an unsharded run's, so a
  checkpoint restores onto any device count. Evaluation runs replicated.
- `shard="seeds"`: whole seeds on different devices (`seeds / devices` each), each running
  the default learner; no communication at all, and each seed's result is the default's.

    placement = Placement.resolve("ppo", config, seeds=4, devices=2, shard="envs")
    init, chunk = placement.learner_programs("ppo", config, env, env_params, seeds=4)
    params = placement.put(env_params, placement.specs("replicated"))
    runner = init(params, placement.put(keys, placement.specs("keys")))
    runner, metrics = chunk(10)(params, runner)                 # 10 updates of every seed

`Placement.resolve` checks the request (even splits, a data-parallel algorithm) and
`device_count` the device count, with one-line `TrainError`s that name the fix;
`make_sharded_train` is the whole run in one call.
"""

from __future__ import annotations

import dataclasses
import functools
import inspect

import jax
from jax.sharding import Mesh, PartitionSpec

from jaxnat.agents import ALGORITHMS
from jaxnat.agents.rollout import count_updates
from jaxnat.sharding import AXIS, check_split, device_mesh, put_global, resolve_devices, shard_program, shardings
from jaxnat.training.args import TrainError

__all__ = ["SHARDS", "Placement", "device_count", "resumed_devices", "data_parallel", "make_sharded_train"]

SHARDS = ("envs", "seeds")


def device_count(devices) -> int:
    """How many devices `--devices` names (`N` or `all`), or a `TrainError` saying how many exist."""
    try:
        return len(resolve_devices(devices, "--devices "))
    except (TypeError, ValueError) as err:
        raise TrainError(str(err)) from None


def resumed_devices(recorded: int, requested=None) -> int:
    """The device count a sharded run continues on: `requested` (`--devices`) if given, else
    the run's own count, which this machine must have."""
    if requested is not None:
        return device_count(requested)
    available = len(jax.devices())
    if recorded > available:
        raise TrainError(f"this run was on {recorded} devices and there {'is' if available == 1 else 'are'} "
                         f"{available} here: continue on them with --devices {available} (a data-parallel run "
                         "gives the same result on any count that divides num_envs)")
    return recorded


@dataclasses.dataclass(frozen=True)
class Placement:
    """A mesh and what is split over it (`shard`: "envs", "seeds", or None: one device)."""

    mesh: Mesh | None = None
    shard: str | None = None

    @classmethod
    def resolve(cls, algo: str, config, seeds: int, devices: int, shard: str | None) -> Placement:
        """The placement of a run (`devices` a count), checked: the envs (or seeds) split
        evenly, and data parallel only for algorithms that have it."""
        if shard is None:
            return cls()
        if shard not in SHARDS:
            raise TrainError(f"--shard {shard}: choose envs (split each seed's envs, data parallel) or seeds "
                             "(whole seeds on each device)")
        mesh = device_mesh(devices)
        try:
            if shard == "seeds":
                check_split(seeds, mesh.size, "seeds", "--seeds ")
            else:
                if not data_parallel(algo):
                    raise ValueError(f"--shard envs trains ppo and a2c data parallel; {algo} needs the whole batch "
                                     "on one device: use --shard seeds")
                if config.memory:  # ppo and a2c, the data-parallel algorithms, have memory
                    raise ValueError("--shard envs trains feed-forward policies (a recurrent policy's minibatches "
                                     "are whole env rollouts): use --shard seeds, or memory=0")
                check_split(config.num_envs, mesh.size, "num_envs", "--num-envs ")
        except ValueError as err:
            raise TrainError(str(err)) from None
        return cls(mesh, shard)

    @property
    def devices(self) -> int:
        return 1 if self.mesh is None else self.mesh.size

    def learner_factory(self, make):
        """`make(config, env, params)` for this placement (data parallel over `AXIS` for envs)."""
        return functools.partial(make, axis_name=AXIS) if self.shard == "envs" else make

    def runner_specs(self, per_env):
        """PartitionSpecs of a vmapped runner (`[seeds, ...]` leaves), as a prefix of its tree
        (a runner's static fields, e.g. its optimizer, differ between traces); `per_env`: the
        learner's `per_env(runner)`, the parts with an env axis after the seeds'."""
        if self.shard == "seeds":
            return PartitionSpec(AXIS)
        return jax.tree.map(lambda split: PartitionSpec(None, AXIS) if split else PartitionSpec(), per_env)

    def specs(self, kind: str):
        """The specs of one argument or result: "replicated" (env params), "keys" (one per
        seed), "per_seed" (metrics, scores: `[seeds, ...]`); a runner's: `runner_specs`."""
        if self.shard == "seeds" and kind in ("keys", "per_seed"):
            return PartitionSpec(AXIS)
        return PartitionSpec()

    def shardings(self, specs):
        return shardings(self.mesh, specs)

    def program(self, fn, in_specs: tuple, out_specs):
        """`fn` jitted for this placement: as it is on one device; else a `jax.shard_map` of it
        over the mesh with these specs, and jit's shardings to match."""
        if self.mesh is None:
            return jax.jit(fn)
        return shard_program(fn, self.mesh, in_specs, out_specs)

    def learner_programs(self, algo: str, config, env, env_params, seeds: int, callback=None, learner=None):
        """`(init, chunk)`: `init(params, keys [seeds]) -> runner`, jitted for this placement,
        and `chunk(n)`, the jitted `(params, runner) -> (runner, metrics [seeds, n])` of `n`
        more updates (`callback(update, metrics)` on the host after each). `params`: env
        params (`put` them with `specs("replicated")`); every seed is vmapped. `learner`: the
        unsharded learner of `config` on `env`, when the caller built it already."""
        make = ALGORITHMS[algo].make
        placed = self.learner_factory(make)
        keys = jax.ShapeDtypeStruct((seeds,), jax.random.key(0).dtype)
        # The runner's layout, from the unsharded learner (a sharded one traces only inside a
        # shard_map): its specs.
        learner = learner or make(config, env, env_params)
        runner = self.runner_specs(learner.per_env(jax.eval_shape(jax.vmap(learner.init), keys)))
        replicated = self.specs("replicated")

        def init(params, keys):  # networks.init_params loops over seeds
            return jax.vmap(placed(config, env, params).init)(keys)

        def chunk(n: int):
            def run(params, runner):
                learner = placed(config, env, params)
                return jax.vmap(functools.partial(learner.run, config=config, num_updates=n, callback=callback))(runner)

            return self.program(run, (replicated, runner), (runner, self.specs("per_seed")))

        return self.program(init, (replicated, self.specs("keys")), runner), chunk

    def put(self, tree, specs):
        """`tree` placed as `specs` say (unchanged on one device). With several processes
        (`jaxnat.sharding.initialize_from_env`) every process passes the same values and
        gives its own devices' parts."""
        if self.mesh is None:
            return tree
        return put_global(tree, self.shardings(specs))


def data_parallel(algo: str) -> bool:
    """Whether the algorithm's learner trains data parallel (its `make` takes `axis_name`)."""
    return "axis_name" in inspect.signature(ALGORITHMS[algo].make).parameters


def make_sharded_train(algo: str, config, env, env_params, *, seeds: int, devices=None, shard: str = "envs"):
    """`train(keys) -> (runner, metrics)`: `seeds` seeds of `algo` (keys `[seeds]`) in one
    jitted program on `devices` (a count, "all"; None: one device, the default learner), split
    as `shard` says: `jaxnat train --devices N --shard S` without the run directory.

        train = make_sharded_train("ppo", PPOConfig(num_envs=4096), env, params, seeds=2, devices="all")
        runner, metrics = train(jax.vmap(jax.random.key)(jnp.arange(2)))

    Raises `TrainError` for a request the devices cannot take (uneven splits, too few devices,
    an algorithm without data parallel)."""
    count = device_count(devices) if devices is not None else 1
    placement = Placement.resolve(algo, config, seeds, count, shard if devices is not None else None)
    init, chunk = placement.learner_programs(algo, config, env, env_params, seeds)
    run = chunk(count_updates(config))
    params = placement.put(env_params, placement.specs("replicated"))
    return lambda keys: run(params, init(params, placement.put(keys, placement.specs("keys"))))
