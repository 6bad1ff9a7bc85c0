"""The run spec: the resolved, saved description of a run (env, algorithm, full config, seeds, chunking)."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

from jaxnat.agents import ALGORITHMS, defaults, normalize
from jaxnat.agents.networks import default_trunk
from jaxnat.training.args import CORE_CONFIG_FIELDS, TrainArgs, TrainError

TARGET_EVALUATIONS = 20  # --eval-every's default aims at about this many evaluations
# Run spec fields added since runs were first written: the value an older config.json means
# (every host run stepped its envs as one batch, on one device).
SPEC_FIELDS_ADDED = {"env_parts": 1, "devices": 1, "shard": None}


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
    env_parts: int = 1  # host-batched envs: the parts the batch is stepped in (`host.make_train_env`)
    # Where it runs (`placement.Placement`): None, one device; "envs", each seed's envs split over
    # `devices` devices (data parallel: a learner of its own); "seeds", whole seeds on each.
    # `devices` is where the run is now: a resumed run may change it, never `shard`.
    devices: int = 1
    shard: str | None = None

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
        )


def check_algo(algo: str) -> None:
    if algo not in ALGORITHMS:
        import difflib

        close = difflib.get_close_matches(algo.lower(), ALGORITHMS, n=1, cutoff=0.5)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise TrainError(f"unknown algorithm {algo!r}{hint}; choose one of: {', '.join(ALGORITHMS)}")


def resolve_config(args: TrainArgs, observation_space, action_space=None):
    """The algorithm's config: the env family's defaults (`agents.defaults`: MuJoCo settings for
    Box actions on state vectors), every override applied, the trunk and normalisation resolved."""
    config_cls = ALGORITHMS[args.algo].config
    names = {f.name for f in dataclasses.fields(config_cls)}
    values = {} if action_space is None else defaults.family_defaults(args.algo, observation_space, action_space)
    for field in dataclasses.fields(args.config):
        value = getattr(args.config, field.name)
        if value is None:
            continue
        if field.name not in names:
            owners = [algo for algo, algorithm in ALGORITHMS.items()
                      if field.name in {f.name for f in dataclasses.fields(algorithm.config)}]
            raise TrainError(f"--{field.name.replace('_', '-')} is not a setting of {args.algo} (it belongs to "
                             f"{', '.join(owners)})")
        values[field.name] = value
    for name in CORE_CONFIG_FIELDS:
        if getattr(args, name) is not None:
            values[name] = getattr(args, name)
    config = config_cls(**values)
    if config.trunk is None:
        config = config.replace(trunk=default_trunk(observation_space))
    if "normalize_observations" in names:  # saved resolved, as the trunk
        observations, rewards = normalize.switches(config, observation_space)
        config = config.replace(normalize_observations=observations, normalize_rewards=rewards)
    return config


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
