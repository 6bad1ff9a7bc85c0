"""The run spec: the resolved, saved description of a run (env, algorithm, full config, seeds, chunking)."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

from jaxnat.agents import ALGORITHMS, resolve_config as resolve_agent_config
from jaxnat.agents.networks import TRUNKS
from jaxnat.agents.resolve import env_family
from jaxnat.training.args import CORE_CONFIG_FIELDS, TrainArgs, TrainError

TARGET_EVALUATIONS = 20  # --eval-every's default aims at about this many evaluations
# Run spec fields added since runs were first written: the value an older config.json means
# (every host run stepped its envs as one batch, on one device, one seed after another: a host
# run's `host_seeds` None reads as "sequential").
SPEC_FIELDS_ADDED = {"env_parts": 1, "devices": 1, "shard": None, "host_seeds": None}


@dataclasses.dataclass(frozen=True)
class RunSpec:
    """Everything that determines a run's result; saved as config.json and read on --resume."""

    env_id: str
    env_kwargs: dict
    algo: str
    config: Any  # the algorithm's config dataclass, fully resolved (trunk included)
    seeds: int
    seed: int
    eval_every: int
    eval_episodes: int
    env_parts: int = 1  # host-batched envs: the parts the batch is stepped in (`host_backend.make_train_env`)
    # Where it runs (`placement.Placement`): None, one device; "envs", each seed's envs split over
    # `devices` devices (data parallel: a learner of its own); "seeds", whole seeds on each.
    # `devices` is where the run is now: a resumed run may change it, never `shard`.
    devices: int = 1
    shard: str | None = None
    # Host-batched envs: "together" (every seed side by side on one batch of all their envs) or
    # "sequential" (one seed after another); None: a JAX env's run, or a host run written
    # before the setting (sequential). The same result either way, to float tolerance.
    host_seeds: str | None = None
    # Where each config value came from (`jaxnat.agents.resolve`: default, family, given,
    # derived); None for runs written before it was recorded. Says nothing about the result.
    config_sources: dict | None = dataclasses.field(default=None, compare=False)

    @property
    def num_updates(self) -> int:
        return self.config.total_timesteps // self.steps_per_update

    @property
    def steps_per_update(self) -> int:
        """Env steps per update per seed."""
        return self.config.num_envs * self.config.num_steps

    @property
    def seed_values(self) -> list[int]:
        return list(range(self.seed, self.seed + self.seeds))

    def program_key(self) -> tuple:
        """What the compiled programs depend on (not the seed values: keys are inputs)."""
        return (self.env_id, tuple(sorted(self.env_kwargs.items())), self.algo, self.config,
                self.seeds, self.eval_episodes, self.devices, self.shard)

    def to_json(self) -> dict:
        return {
            "env_id": self.env_id,
            "env_kwargs": self.env_kwargs,
            "algo": self.algo,
            "config": dataclasses.asdict(self.config),
            "static_fields": [f.name for f in dataclasses.fields(self.config)
                              if not f.metadata.get("pytree_node", True)],
            "seeds": self.seeds,
            "seed": self.seed,
            "seed_values": self.seed_values,
            "eval_every": self.eval_every,
            "eval_episodes": self.eval_episodes,
            "env_parts": self.env_parts,
            "devices": self.devices,
            "shard": self.shard,
            "host_seeds": self.host_seeds,
            **({} if self.config_sources is None else {"config_sources": self.config_sources}),
            "num_updates": self.num_updates,
            "steps_per_update": self.steps_per_update,
        }

    @classmethod
    def from_json(cls, data: dict) -> RunSpec:
        if data["algo"] not in ALGORITHMS:
            raise TrainError(f"config.json names algorithm {data['algo']!r}, which this jaxnat lacks")
        config_cls = ALGORITHMS[data["algo"]].config
        if data["algo"] == "dqn" and "loss" not in data["config"]:
            # Written before DQNConfig.loss existed, when every DQN trained with Huber's loss.
            data = {**data, "config": {**data["config"], "loss": "huber"}}
        if data["algo"] != "dqn" and "normalize_observations" not in data["config"]:
            # Written before observation and reward normalisation existed: the run had neither.
            data = {**data, "config": {**data["config"], "normalize_observations": False,
                                       "normalize_rewards": False}}
        data = {**SPEC_FIELDS_ADDED, **data}
        return cls(
            env_id=data["env_id"], env_kwargs=dict(data["env_kwargs"]), algo=data["algo"],
            config=config_cls(**data["config"]), seeds=int(data["seeds"]), seed=int(data["seed"]),
            eval_every=int(data["eval_every"]), eval_episodes=int(data["eval_episodes"]),
            env_parts=int(data["env_parts"]), devices=int(data["devices"]), shard=data["shard"],
            host_seeds=data["host_seeds"],
            config_sources=data.get("config_sources"),
        )


def _check_name(what: str, name: str, valid) -> None:
    if name not in valid:
        import difflib

        close = difflib.get_close_matches(name.lower(), valid, n=1, cutoff=0.5)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise TrainError(f"unknown {what} {name!r}{hint}; choose one of: {', '.join(valid)}")


def check_algo(algo: str) -> None:
    _check_name("algorithm", algo, tuple(ALGORITHMS))


def check_trunk(trunk: str | None) -> None:
    """A `--trunk` name checked before the env is built and the settings printed (None: the
    paper's trunk for the observation, decided later)."""
    if trunk is not None:
        _check_name("trunk", trunk, TRUNKS)


def resolve_config(args: TrainArgs, observation_space, action_space=None):
    """The run's config and where each value came from (`jaxnat.agents.resolve_config`, which
    this feeds with the command line's settings): `(config, sources)`. `action_space` None: a
    host-batched env."""
    names = {f.name for f in dataclasses.fields(ALGORITHMS[args.algo].config)}
    given = {}
    for field in dataclasses.fields(args.config):
        value = getattr(args.config, field.name)
        if value is None:
            continue
        if field.name not in names:
            owners = [algo for algo, algorithm in ALGORITHMS.items()
                      if field.name in {f.name for f in dataclasses.fields(algorithm.config)}]
            raise TrainError(f"--{field.name.replace('_', '-')} is not a setting of {args.algo} (it belongs to "
                             f"{', '.join(owners)})")
        given[field.name] = value
    given.update({name: getattr(args, name) for name in CORE_CONFIG_FIELDS})
    return resolve_agent_config(args.algo, observation_space, action_space, given, family=env_family(args.env_id))


def auto_eval_every(num_updates: int) -> int:
    """About `TARGET_EVALUATIONS` chunks, preferring a chunk length that divides the run (so
    one program serves every chunk)."""
    target = num_updates / TARGET_EVALUATIONS
    if target <= 1:
        return 1
    divisors = [d for d in range(max(1, int(target / 2)), int(target * 2) + 1) if num_updates % d == 0]
    if divisors:
        return min(divisors, key=lambda d: (abs(math.log(d / target)), d))
    return math.ceil(target)
