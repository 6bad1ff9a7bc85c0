"""Runs on host-batched envs (`NaturalAtari/*`): `train` hands them to `jaxnat.agents.host_run`.

The jitted, vmapped trainer needs a pure-JAX env; ALE runs in C++ on the host, so these runs
use the host loop (seeds one after another), with the same run spec (`config.json`),
checkpoints every `--eval-every` updates and `--resume` (which restarts the games: see
`host_run`).
"""

from __future__ import annotations

import json
from pathlib import Path

import jaxnat
from jaxnat.datasets import DatasetFormatError, DatasetNotFoundError
from jaxnat.registration import MissingDependencyError, UnknownEnvError
from jaxnat.training.args import TrainArgs, TrainError, parse_env_kwargs
from jaxnat.training.spec import RunSpec, check_algo, resolve_config

MAX_EVAL_EPISODES = 32  # whole Atari games are thousands of steps


def is_host_env(env_id: str) -> bool:
    try:
        return jaxnat.spec(env_id).batched
    except UnknownEnvError:
        return False  # the main path reports it


def is_host_run(args: TrainArgs) -> bool:
    """Whether `args` trains (or resumes) a run on a host-batched env."""
    if args.resume is not None:
        try:
            env_id = json.loads((Path(args.resume) / "config.json").read_text())["spec"]["env_id"]
        except (OSError, ValueError, KeyError):
            return False  # the main path reports what is wrong with the run directory
        return is_host_env(env_id)
    return is_host_env(args.env_id)


def _new_spec(args: TrainArgs, console) -> RunSpec:
    from jaxnat.agents.host_run import HOST_ALGORITHMS, observation_space
    from jaxnat.training.loop import _check_counts, _with_eval_every

    check_algo(args.algo)
    if args.algo not in HOST_ALGORITHMS:
        raise TrainError(f"{args.algo} has no host loop: {args.env_id} (host-emulated) trains "
                         f"with {', '.join(HOST_ALGORITHMS)}")
    _check_counts(args)
    env_kwargs = parse_env_kwargs(args.env_kwargs)
    if "split" in env_kwargs:
        raise TrainError("env kwarg 'split' is set by jaxnat train: split=train for training and "
                         "split=test for evaluation")
    config = resolve_config(args, observation_space(args.env_id, env_kwargs))
    eval_episodes = args.eval_episodes
    if eval_episodes > MAX_EVAL_EPISODES:
        console.print(f"[dim]evaluating {MAX_EVAL_EPISODES} test games per seed (not "
                      f"{eval_episodes}): whole Atari games are long[/dim]")
        eval_episodes = MAX_EVAL_EPISODES
    spec = RunSpec(args.env_id, env_kwargs, args.algo, config, args.seeds, args.seed, 1, eval_episodes)
    return _with_eval_every(spec, args)


def train_on_host(args: TrainArgs, console, compiler_options: dict | None,
                  stop_after_chunks: int | None = None):
    from jaxnat.agents.host_run import run_host_training
    from jaxnat.training.loop import TrainResult, _new_run_dir, _resume, _versions

    try:
        if args.resume is not None:
            spec, run_dir, _ = _resume(args)
        else:
            run_dir = _new_run_dir(args)
            spec = _new_spec(args, console)
        summary, complete = run_host_training(
            spec, run_dir, resume=args.resume is not None, console=console,
            compiler_options=compiler_options, stop_after_chunks=stop_after_chunks,
            versions=_versions())
    except (MissingDependencyError, DatasetNotFoundError, DatasetFormatError, TypeError,
            ValueError) as err:
        raise TrainError(f"{args.env_id}: {err}") from None
    return TrainResult(run_dir, None, summary, complete)
