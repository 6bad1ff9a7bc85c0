"""One place that resolves a run's config, and says where each value came from.

A value comes from one of four sources, in this order (a later one wins):

- `default`: the algorithm's config dataclass, the paper's settings (`ppo.PPOConfig`, ...);
- `family`: the env family's defaults where they differ (`defaults.family_defaults`: the
  authors' MuJoCo settings for Box actions on state vectors, Nature DQN's Huber loss on Natural
  Atari);
- `given`: what the caller set (`jaxnat train`'s flags, a `jaxnat reproduce` profile, keyword
  arguments of `config_for`);
- `derived`: fields left unset (None) that the observation space decides: the paper's trunk
  for its size, and the normalisation switches (on for vectors, off for images).

    config = config_for("ppo", env, env_params, total_timesteps=1_000_000, num_envs=64, num_steps=64)
    resolved = resolve_config("ppo", observation_space, action_space, {"lr": 1e-3})
    resolved.config, resolved.sources["lr"]   # ..., "given"

`jaxnat train` resolves every run's config here, prints each value's source beside it and saves
them in the run's `config.json` (`config_sources`). A value out of its field's range (`RANGES`:
a negative learning rate, a discount above 1, ...) is a `ValueError` here, before any program
is built; values that are not concrete numbers (a sweep's arrays, traced values) are not checked.
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

from jaxnat.agents import defaults, normalize
from jaxnat.agents.algorithms import ALGORITHMS
from jaxnat.agents.config import RANGES, check_ranges
from jaxnat.agents.networks import default_trunk

__all__ = ["SOURCES", "RANGES", "Resolved", "resolve_config", "config_for", "env_family", "check_ranges"]

SOURCES = ("default", "family", "given", "derived")

class Resolved(NamedTuple):
    config: Any  # the algorithm's config, every field set
    sources: dict[str, str]  # field -> one of SOURCES


def env_family(env_id: str) -> str:
    """The family of a registered env id: `"NaturalAtari"` for `"NaturalAtari/Pong-v0"`."""
    return env_id.partition("/")[0]


def resolve_config(algo: str, observation_space, action_space=None, given: dict | None = None, *,
                   family: str | None = None) -> Resolved:
    """`algo`'s config for an env with these spaces (`action_space` None: a host-batched env,
    whose family's defaults come by `family`, e.g. `env_family(env_id)`) and the `given`
    values (None values count as not given); a `ValueError` names a field `algo` lacks, or a
    value out of its range (`check_ranges`)."""
    if algo not in ALGORITHMS:
        raise ValueError(f"unknown algorithm {algo!r}; choose one of: {', '.join(ALGORITHMS)}")
    config_cls = ALGORITHMS[algo].config
    names = [f.name for f in dataclasses.fields(config_cls)]
    given = {name: value for name, value in (given or {}).items() if value is not None}
    unknown = sorted(set(given) - set(names))
    if unknown:
        raise ValueError(f"{', '.join(unknown)}: not a setting of {algo} (its settings: {', '.join(names)})")
    family_values = defaults.family_defaults(algo, observation_space, action_space, family=family)
    config = config_cls(**{**family_values, **given})
    sources = {name: "given" if name in given else "family" if name in family_values else "default"
               for name in names}
    if config.trunk is None:
        config = config.replace(trunk=default_trunk(observation_space))
        sources["trunk"] = "derived"
    if "normalize_observations" in names:  # saved resolved, as the trunk
        observations, rewards = normalize.switches(config, observation_space)
        for name, value in (("normalize_observations", observations), ("normalize_rewards", rewards)):
            if getattr(config, name) is None:
                sources[name] = "derived"
        config = config.replace(normalize_observations=observations, normalize_rewards=rewards)
    check_ranges(config)
    return Resolved(config, sources)


def config_for(algo: str, env, env_params, **given):
    """`algo`'s config for a JAX env: the env family's defaults, then `given`, with the trunk
    and normalisation decided by the observation space (`resolve_config`). What `jaxnat train`
    would train with, for a library user:

        config = config_for("ppo", env, params, total_timesteps=1_000_000)
        learner = make_ppo(config, env, params)
    """
    return resolve_config(algo, env.observation_space(env_params), env.action_space(env_params), given).config
