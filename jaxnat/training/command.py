"""`jaxnat train`: set up or resume a run, pick its backend (device or host) and hand both to
`chunk_loop.run_training`, which trains chunk by chunk, evaluates, checkpoints and reports."""

from __future__ import annotations

import dataclasses
import datetime
import json
import sys
import time
from pathlib import Path
from typing import Any, Callable

import jax

from jaxnat.cli import exit_status
from jaxnat.sharding import initialize_from_env
from jaxnat.training.args import PROG, TrainArgs, TrainError, default_eval_episodes, parse_args, parse_env_kwargs
from jaxnat.training.host_backend import HostBackend, is_host_env, new_host_spec
from jaxnat.training.placement import Placement, device_count, resumed_devices
from jaxnat.training.device_backend import compiled_program, make_envs, split_argument
from jaxnat.training.records import check_sinks, open_sinks
from jaxnat.training.rundir import (args_json, check_counts, new_run_dir, open_resumed, versions, write_extension,
                                    with_eval_every)
from jaxnat.training.spec import RunSpec, check_algo, check_trunk, resolve_config
from jaxnat.training.chunk_loop import run_training


@dataclasses.dataclass
class TrainResult:
    """What `train` hands back: the run directory, the final state of the last seeds trained
    (the device backend's vmapped runner, or a host seed's `HostState`), the summary written
    to `summary.json`, and whether every seed finished."""

    run_dir: Path
    runner: Any
    summary: dict
    complete: bool


def _setup(args: TrainArgs, console):
    """(spec, run_dir, the saved config.json when resuming else None, the envs `make_envs` built
    for a new run on JAX envs else None)."""
    if args.resume is not None:
        spec, run_dir, saved = open_resumed(args)
        return _resumed_placement(spec, args, console), run_dir, saved, None
    check_algo(args.algo)
    check_trunk(args.trunk)
    check_counts(args)
    run_dir = new_run_dir(args)  # an unwritable one is refused now, not after compiling
    if args.shard is not None and args.devices is None:
        raise TrainError(f"--shard {args.shard} places work on devices: give --devices N (or all) too")
    devices = None if args.devices is None else device_count(args.devices)
    if is_host_env(args.env_id):
        return with_eval_every(new_host_spec(args, console, devices), args), run_dir, None, None
    if args.env_parts != 1:
        raise TrainError(f"--env-parts applies to host-batched envs (NaturalAtari/*); {args.env_id} is a JAX env, "
                         "stepped in one compiled program")
    if args.host_seeds is not None:
        raise TrainError(f"--host-seeds applies to host-batched envs (NaturalAtari/*); {args.env_id} is a JAX env, "
                         "whose seeds train together in one compiled program")
    env_kwargs = parse_env_kwargs(args.env_kwargs, args.env_id)
    # Resolving the trunk needs the observation space: build the env once (cheap; cached data).
    episodes = args.eval_episodes or default_eval_episodes(args.env_id)
    spec = RunSpec(args.env_id, env_kwargs, args.algo, None, args.seeds, args.seed, 1, episodes)
    envs = make_envs(spec)  # handed on to the programs, which need them too
    env, params, *_ = envs
    try:
        config, sources = resolve_config(args, env.observation_space(params), env.action_space(params))
        spec = dataclasses.replace(spec, config=config, config_sources=sources)
    except (TypeError, ValueError) as err:
        raise TrainError(str(err)) from None
    if devices is not None:
        spec = dataclasses.replace(spec, devices=devices, shard=args.shard or "envs")
        Placement.resolve(spec.algo, spec.config, spec.seeds, spec.devices, spec.shard)  # one-line errors now
    return with_eval_every(spec, args), run_dir, None, envs


def _resumed_placement(spec: RunSpec, args: TrainArgs, console) -> RunSpec:
    """The resumed run's spec on the devices it continues on: `--devices` if given, else the
    run's own count (a data-parallel run gives the same result on any count)."""
    if spec.shard is None:
        if args.devices is not None:
            raise TrainError("this run trained on one device without --devices; resume it without --devices "
                             "(a run started with --devices N may continue on another count)")
        return spec
    devices = resumed_devices(spec.devices, args.devices)
    if devices != spec.devices:
        console.print(f"continuing on {devices} device{'s' * (devices != 1)} (the run was on {spec.devices})")
    spec = dataclasses.replace(spec, devices=devices)
    Placement.resolve(spec.algo, spec.config, spec.seeds, spec.devices, spec.shard)
    return spec


def _print_config(console, spec: RunSpec, run_dir: Path) -> None:
    from rich.table import Table

    table = Table(title=f"jaxnat train · {spec.algo} on {spec.env_id}", show_header=False, box=None)
    table.add_column(style="dim")
    table.add_column()
    table.add_row("env kwargs", json.dumps(spec.env_kwargs) if spec.env_kwargs else "—")
    argument = split_argument(spec.env_id, spec.env_kwargs)
    split = f"{argument}=test" if argument else "the training env (no test split)"
    table.add_row("evaluation", f"{spec.eval_episodes} episodes per seed on {split}, every {spec.eval_every} updates")
    how = {"together": " (side by side: one batch of every seed's envs)",
           "sequential": " (one after another)"}.get(spec.host_seeds, "")
    table.add_row("seeds", f"{spec.seed_values}{how}")
    table.add_row("updates", f"{spec.num_updates} x {spec.steps_per_update} env steps per seed")
    if spec.env_parts > 1:
        each = " of each seed" if spec.host_seeds == "together" else ""
        parts = f"{spec.env_parts} of {spec.config.num_envs // spec.env_parts} envs{each}, stepped in turn"
        table.add_row("env parts", parts)
    if spec.shard is not None:
        split = (f"{spec.config.num_envs // spec.devices} envs of each seed per device, gradients averaged"
                 if spec.shard == "envs" else f"{spec.seeds // spec.devices} seeds per device")
        table.add_row("devices", f"{spec.devices} ({split})")
    static = {f.name for f in dataclasses.fields(spec.config) if not f.metadata.get("pytree_node", True)}
    sources = spec.config_sources or {}
    for field in dataclasses.fields(spec.config):
        tag = " (static)" if field.name in static else ""
        source = sources.get(field.name)
        table.add_row(f"{field.name}{tag}", repr(getattr(spec.config, field.name))
                      + ("" if source in (None, "default") else f"  [dim]({source})[/dim]"))
    console.print(table)
    # After the table, never wrapped: a narrow terminal must not cut the path a user copies.
    console.print(f"run dir: {run_dir}", soft_wrap=True, highlight=False)


def train(args: TrainArgs, *, console=None, compiler_options: dict | None = None,
          stop_after_chunks: int | None = None) -> TrainResult:
    """Run (or resume) a training run; raises `TrainError` for user errors.

    Args:
        args: the parsed command line.
        console: a `rich.console.Console` for output (default: stdout).
        compiler_options: XLA options for every compiled program, e.g.
            `{"xla_backend_optimization_level": 0}` (compiles much faster on CPU).
        stop_after_chunks: stop after this many chunks (checkpointed; `--resume` continues).
    """
    from rich.console import Console

    if initialize_from_env() and jax.process_count() > 1:
        raise TrainError(f"jaxnat train writes its run directory from one process, and this is one of "
                         f"{jax.process_count()} (JAX_NUM_PROCESSES): train over several processes with "
                         "jaxnat.training.make_sharded_train, Natural Atari with jaxnat.training.host_backend.make_learner"
                         "(..., devices='all') (docs/api.md, 'Several devices and hosts')")
    console = console or Console()
    check_sinks(args.log)  # a missing package: one line now, not after compiling
    spec, run_dir, saved, envs = _setup(args, console)
    host = is_host_env(spec.env_id)  # NaturalAtari/*: emulated on the host, trained from a Python loop
    _print_config(console, spec, run_dir)
    if host:
        backend = HostBackend(spec, compiler_options)
    else:
        with console.status("compiling init, training chunk and evaluation programs..."):
            compile_start = time.perf_counter()
            backend = compiled_program(spec, compiler_options, envs)
            backend.prepare(_chunk_lengths(spec))
        console.print(f"[dim]programs ready in {time.perf_counter() - compile_start:.1f} s[/dim]")
    new_run = None if saved is not None else {
        "spec": spec.to_json(), "args": args_json(args), "backend": "host" if host else "device",
        "versions": versions(), "created": datetime.datetime.now().isoformat(timespec="seconds"),
        "command": sys.argv}
    data = getattr(backend, "data_manifest", dict)()
    if new_run is not None and any(data.values()):  # the videos and photos the run sees, by content hash
        new_run["data"] = data
    if saved is not None and spec.config.total_timesteps != saved["spec"]["config"]["total_timesteps"]:
        old = RunSpec.from_json(saved["spec"])
        saved = write_extension(run_dir, saved, spec)
        console.print(f"extending the run from {old.num_updates} to {spec.num_updates} updates "
                      f"({spec.num_updates * spec.steps_per_update:,} env steps per seed); a learning rate "
                      "annealed over the run follows the new length's schedule from here (docs/api.md)")
    sinks = []
    try:
        run_dir.mkdir(parents=True, exist_ok=True)
        sinks = open_sinks(args.log, run_dir, spec.to_json())
        state, summary, complete = run_training(spec, run_dir, backend, console=console, new_run=new_run,
                                                stop_after_chunks=stop_after_chunks, sinks=sinks)
    finally:
        for sink in sinks:
            sink.close()
        backend.close()
    return TrainResult(run_dir, state, summary, complete)


def _chunk_lengths(spec: RunSpec) -> set[int]:
    """The lengths of the run's chunks: `eval_every`, and a shorter last one where it does not
    divide the run."""
    return {spec.eval_every, spec.num_updates % spec.eval_every} - {0}


def _nothing() -> None:
    pass


def prepare_programs(args: TrainArgs, *, compiler_options: dict | None = None) -> Callable[[], None]:
    """Trace and lower, on this thread, the programs `train(args)` will run, writing nothing;
    returns `compile()`, which compiles them (XLA only: it may run on another thread, e.g.
    while this one trains another run, as `jaxnat reproduce` does). A later `train` with the
    same arguments (and compiler options) in this process finds them compiled. Host-stepped
    envs (Natural Atari, compiled as they run) get a `compile` that does nothing. Raises
    `TrainError` as `train` would."""
    from rich.console import Console

    if args.resume is None and is_host_env(args.env_id):
        return _nothing
    spec, _, _, envs = _setup(args, Console(quiet=True))
    if is_host_env(spec.env_id):
        return _nothing
    program = compiled_program(spec, compiler_options, envs)
    program.lower(_chunk_lengths(spec))
    return program.compile_pending


def main(argv=None, **train_options) -> int:
    """`jaxnat train` with `argv` (default: sys.argv[1:]); returns the exit status. Keyword
    arguments go to `train` (e.g. `compiler_options`, `stop_after_chunks`)."""
    args = parse_args(argv)
    return exit_status(lambda: train(args, **train_options), TrainError, PROG)


if __name__ == "__main__":
    sys.exit(main())
