"""Runs on host-batched envs (`NaturalAtari/*`): `train` hands them to `jaxnat.agents.host_run`.

The jitted, vmapped trainer needs a pure-JAX env; ALE runs in C++ on the host, so these runs
use the host loop (seeds one after another; no --resume yet).
"""

from __future__ import annotations

import jaxnat
from jaxnat.datasets import DatasetFormatError, DatasetNotFoundError
from jaxnat.registration import MissingDependencyError, UnknownEnvError
from jaxnat.training.args import TrainArgs, TrainError, parse_env_kwargs
from jaxnat.training.spec import check_algo, resolve_config


def is_host_env(env_id: str) -> bool:
    try:
        return jaxnat.spec(env_id).batched
    except UnknownEnvError:
        return False  # the main path reports it


def train_on_host(args: TrainArgs, console, compiler_options: dict | None):
    from jaxnat.agents.host_run import run_host_training
    from jaxnat.training.loop import TrainResult, _default_run_dir

    check_algo(args.algo)
    if args.resume is not None:
        raise TrainError(f"--resume is not supported for {args.env_id} (host-emulated) yet")
    try:
        summary, run_dir = run_host_training(
            args.env_id, args.algo, lambda space: resolve_config(args, space),
            env_kwargs=parse_env_kwargs(args.env_kwargs), seeds=args.seeds, seed=args.seed,
            eval_episodes=args.eval_episodes, console=console, compiler_options=compiler_options,
            run_dir=args.run_dir or _default_run_dir(args.env_id, args.algo))
    except (MissingDependencyError, DatasetNotFoundError, DatasetFormatError, TypeError,
            ValueError) as err:
        raise TrainError(f"{args.env_id}: {err}") from None
    return TrainResult(run_dir, None, summary, True)
