"""The command line of `jaxnat train`: `TrainArgs` (tyro), per-algorithm config overrides, env kwargs."""

from __future__ import annotations

import dataclasses
import inspect
import sys
import typing
from pathlib import Path
from typing import Annotated, Any, Optional

import tyro

from jaxnat.agents import ALGORITHMS
from jaxnat.agents.dqn import LOSSES, OPTIMIZERS
from jaxnat.agents.networks import DTYPES, TRUNKS

PROG = "jaxnat train"
# Fields of the algorithm configs that are top-level arguments rather than overrides.
CORE_CONFIG_FIELDS = ("total_timesteps", "num_envs", "trunk")


class TrainError(Exception):
    """A user error: printed as one line `jaxnat train: error: <message>`, exit status 2."""


def check_split_kwargs(env_kwargs: dict) -> None:
    """Refuse the env kwargs that pick the data split: `jaxnat train` sets them itself (the
    train split for training, the test split for evaluation)."""
    for name in ("split", "video_split"):
        if name in env_kwargs:
            raise TrainError(f"env kwarg {name!r} is set by jaxnat train: {name}=train for training and "
                             f"{name}=test for evaluation")


def _config_fields() -> dict[str, tuple[Any, dict[str, Any]]]:
    """Every algorithm config field except the core ones: name -> (type, {algo: default})."""
    fields: dict[str, tuple[Any, dict[str, Any]]] = {}
    for algo, (config_cls, *_) in ALGORITHMS.items():
        hints = typing.get_type_hints(config_cls)
        for field in dataclasses.fields(config_cls):
            if field.name in CORE_CONFIG_FIELDS:
                continue
            _, defaults = fields.setdefault(field.name, (hints[field.name], {}))
            defaults[algo] = field.default
    return fields


# The values a text or switch field takes, from where the agents define them (shown in --help).
CHOICES = {"dtype": DTYPES, "optimizer": tuple(OPTIMIZERS), "loss": tuple(LOSSES)}
SWITCHES = ("normalize_observations", "normalize_rewards")  # unset: decided by the observation space


# Test episodes per seed per evaluation when --eval-episodes is not given, by env family: sized
# to the episode's length, since every evaluation plays each episode to its end (a scan over the
# time limit) twice, greedy and sampled, and the chance score once more. 1,000 short episodes
# (Classify's 20 steps, Localize's 200) cost no more than a chunk of training and pin accuracy to
# about ±3%; 1,000 of MuJoCo's 1,000-step episodes are 2M physics steps per seed per evaluation
# (13 minutes of silence on a CPU before the first update), so the continuous-control families
# take the 10 that CleanRL and the paper profile use. Natural Atari plays whole games on the host
# (`host_backend.MAX_EVAL_EPISODES`). A family not listed takes `EVAL_EPISODES_OTHER`.
EVAL_EPISODES = {"Classify": 1000, "Localize": 1000, "MuJoCo": 10, "PixelMuJoCo": 10, "NaturalAtari": 32}
EVAL_EPISODES_OTHER = 100


def default_eval_episodes(env_id: str) -> int:
    """`--eval-episodes` when not given: `EVAL_EPISODES` of the env id's family."""
    return EVAL_EPISODES.get(env_id.partition("/")[0], EVAL_EPISODES_OTHER)


# What a config field means, where its name and default do not say (shown in --help).
FIELD_HELP = {
    "clip_rewards": "train on sign(reward) (baselines' ClipRewardEnv), before any reward scaling; "
                    "the episode returns reported stay unclipped.",
    **dict.fromkeys(SWITCHES, "unset: on for vector observations, off for images (VecNormalize's)."),
}


def _metavar(name: str, kind) -> str:
    if name in CHOICES:
        return "{" + ",".join(CHOICES[name]) + "}"
    if name in SWITCHES:
        return "{True,False}"
    return {int: "INT", float: "FLOAT", bool: "{True,False}", str: "STR"}.get(kind, "VALUE")


def _make_overrides_class():
    fields = []
    for name, (kind, defaults) in _config_fields().items():
        hint = "(default: " + ", ".join(f"{algo} {value}" for algo, value in defaults.items()) + ")"
        only = "" if len(defaults) == len(ALGORITHMS) else f"{'/'.join(defaults)} only"
        text = " ".join(part for part in (FIELD_HELP.get(name, ""), only) if part)
        fields.append((name, Annotated[Optional[kind], tyro.conf.arg(
            help=text, help_behavior_hint=hint, metavar=_metavar(name, kind))], None))
    cls = dataclasses.make_dataclass("ConfigOverrides", fields, frozen=True)
    cls.__module__ = __name__
    cls.__doc__ = ("Algorithm settings; unset ones take the algorithm's default. Every field of "
                   f"{', '.join(a.config.__name__ for a in ALGORITHMS.values())} is here or above.")
    return cls


ConfigOverrides = _make_overrides_class()


@dataclasses.dataclass
class TrainArgs:
    """Train PPO, A2C, ACKTR or DQN on a jaxnat env over several seeds at once, evaluate on the test split,
    write metrics, a learning curve and checkpoints to a run directory."""

    env_id: str = "Classify/Digits-v0"
    """A registered env id (see jaxnat.registered_envs())."""
    env_kwargs: Annotated[tuple[str, ...], tyro.conf.arg(metavar="KEY=VALUE [KEY=VALUE ...]")] = ()
    """Keyword arguments of jaxnat.make, e.g. w=3 M=10 start=center; values are read as int, float, bool (true/false), none, else str (an argument whose default is a string keeps the text: background=none). The trainer sets split (train, and test for evaluation)."""
    algo: Annotated[str, tyro.conf.arg(metavar="{" + ",".join(ALGORITHMS) + "}")] = "ppo"
    """The algorithm."""
    seeds: int = 5
    """Number of seeds, trained at once (vmapped)."""
    seed: int = 0
    """The first seed; the run uses seed, seed+1, ..., seed+seeds-1."""
    total_timesteps: Annotated[Optional[int], tyro.conf.arg(metavar="INT", help_behavior_hint="")] = None
    """Env steps per seed (unset: the algorithm's default, 1e6)."""
    num_envs: Annotated[Optional[int], tyro.conf.arg(metavar="INT", help_behavior_hint="")] = None
    """Parallel envs per seed (unset: the algorithm's default, ppo 8, a2c 16, acktr 32, dqn 8; ppo 1 for Box actions on state vectors, as the authors' MuJoCo setting)."""
    env_parts: int = 1
    """Host-batched envs (NaturalAtari) with ppo, a2c or acktr: step the num_envs envs as this many equal parts in turn, so that the policy's call for one part runs while ALE emulates the others (pays with many envs per part, e.g. 2 parts of 128, on a host with many cores; small parts lose). 1: one batch, the loop as it always was. Other parts draw other action samples, so the run differs from the one-batch run. With --host-seeds together each part holds num_envs / N envs of every seed; unset, --host-seeds is sequential with parts."""
    host_seeds: Annotated[Optional[str], tyro.conf.arg(metavar="{together,sequential}", help_behavior_hint="")] = None
    """Host-batched envs (NaturalAtari): together trains every seed at once, their envs one batch of emulators stepped together and one vmapped policy call acting for all (each seed keeps its own keys and games: its result is its run alone, to float tolerance); sequential trains one seed after another. Unset: together for ppo, a2c and acktr, sequential for dqn and with --env-parts above 1."""
    trunk: Annotated[Optional[str], tyro.conf.arg(metavar="{" + ",".join(TRUNKS) + "}",
                                                  help_behavior_hint="")] = None
    """Network trunk (unset: the paper's trunk for the observation size)."""
    devices: Annotated[Optional[str], tyro.conf.arg(metavar="N|all", help_behavior_hint="")] = None
    """Train on this many devices of this machine (all: every one). Unset: one device, the default learner. With --resume: the device count to continue on (unset: the run's). Several hosts: docs/api.md."""
    shard: Annotated[Optional[str], tyro.conf.arg(metavar="{envs,seeds}", help_behavior_hint="")] = None
    """With --devices: envs (the default) splits each seed's envs over the devices and averages gradients across them (data parallel; ppo and a2c; num_envs must divide evenly; the same result on any device count); seeds places whole seeds on the devices (seeds must divide evenly; each seed's result is the one-device run's)."""
    eval_every: Annotated[Optional[int], tyro.conf.arg(metavar="INT", help_behavior_hint="")] = None
    """Updates per chunk: evaluate, log and checkpoint after every this many updates (unset: about 20 evaluations over the run). Host-emulated envs (NaturalAtari) checkpoint only; their seeds are evaluated when each finishes."""
    eval_episodes: Annotated[Optional[int], tyro.conf.arg(
        metavar="INT", help_behavior_hint="", help="Test episodes per seed per evaluation, each played to its end "
        "(unset: sized to the family's episode length: " + ", ".join(f"{f} {n}" for f, n in EVAL_EPISODES.items())
        + f", else {EVAL_EPISODES_OTHER}).")] = None
    run_dir: Annotated[Optional[Path], tyro.conf.arg(metavar="PATH", help_behavior_hint="")] = None
    """Where to write the run (unset: runs/<env>-<algo>-<timestamp>)."""
    resume: Annotated[Optional[Path], tyro.conf.arg(metavar="RUN_DIR", help_behavior_hint="")] = None
    """Continue the run in this directory from its latest checkpoint; other arguments must be left out or match its config.json, except --devices, --log and a larger --total-timesteps, which extends the run to that many env steps per seed (an annealed learning rate follows the new length's schedule from there: docs/api.md)."""
    log: Annotated[tuple[str, ...], tyro.conf.arg(metavar="{tensorboard,wandb} ...")] = ()
    """Also log the training metrics and evaluations to these tools (metrics.jsonl and eval.jsonl are written either way): tensorboard (event files in RUN_DIR/tensorboard/, pip install 'jaxnat[tensorboard]'), wandb (your W&B settings apply: WANDB_MODE, WANDB_PROJECT, ...; pip install 'jaxnat[wandb]'). May differ on --resume."""
    config: Annotated[ConfigOverrides, tyro.conf.OmitArgPrefixes] = dataclasses.field(
        default_factory=ConfigOverrides)
    given: Annotated[tuple[str, ...], tyro.conf.Suppress] = ()
    """The fields named on the command line (set by `parse_args`): with --resume, one given at
    its default value must still match the run's."""


def constructor_parameters(env_id: str) -> dict[str, inspect.Parameter]:
    """`jaxnat.registration.constructor_parameters`, or {} when the entry point cannot be
    imported (`jaxnat.make` then says which dependency is missing, or the id is unknown)."""
    from jaxnat import registration

    try:
        return registration.constructor_parameters(env_id)
    except (ImportError, LookupError, TypeError, ValueError):
        return {}


def parse_env_kwargs(items, env_id: str | None = None) -> dict[str, Any]:
    """`["w=3", "start=center"]` (or a dict of strings) -> `{"w": 3, "start": "center"}`.

    With `env_id`, a value for a constructor argument whose default is a string stays a string
    (`background=none` names Natural Atari's "none" background, not None)."""
    if isinstance(items, dict):
        pairs = items.items()
    else:
        pairs = []
        for item in items:
            key, sep, value = item.partition("=")
            if not sep or not key:
                raise TrainError(f"--env-kwargs takes KEY=VALUE pairs, got {item!r}")
            pairs.append((key.strip(), value.strip()))
    strings = set() if env_id is None else {
        name for name, p in constructor_parameters(env_id).items() if isinstance(p.default, str)}
    return {key: value if key in strings and isinstance(value, str) else _parse_value(value) for key, value in pairs}


def _parse_value(value: Any) -> Any:
    if not isinstance(value, str):
        return value
    for convert in (int, float):
        try:
            return convert(value)
        except ValueError:
            pass
    special = {"true": True, "false": False, "none": None, "null": None}
    return special.get(value.lower(), value)


def parse_args(argv=None) -> TrainArgs:
    argv = sys.argv[1:] if argv is None else list(argv)
    args = tyro.cli(TrainArgs, args=argv, prog=PROG, description=inspect.cleandoc(TrainArgs.__doc__))
    given = {item[2:].partition("=")[0].replace("-", "_") for item in argv if item.startswith("--")}
    return dataclasses.replace(args, given=tuple(sorted(given)))
