"""The `jaxnat reproduce` command: check the arguments, estimate, run the grid's cells (skipping
finished ones, resuming interrupted ones), then write the report.

On an accelerator the cells run as streams at once: the device cells (seeds vmapped on the
accelerator) in this process, one after another (`cells.train_cells`), and the host cells
(Natural Atari: ALE on the host's cores, a small policy on the accelerator) in a child process
(`cell_stream`) writing to the same `--out`, all shown on one progress board (`board`). With two
or more GPUs (`--gpus`, found by `gpus.find_devices` without starting JAX on them here) the
device cells are shared among one child process per GPU and this process trains none. On a
CPU, or with `--sequential`, every cell runs in turn here."""

from __future__ import annotations

import dataclasses
import difflib
import fnmatch
import inspect
import os
import shutil
import sys
import time
from pathlib import Path
from typing import Annotated, Optional

import tyro

from jaxnat.cli import exit_status, unwritable
from jaxnat.reproduce.board import Board
from jaxnat.reproduce.cells import Claims, train_cells
from jaxnat.reproduce.cell_stream import CellStream, child_streams, stop_streams
from jaxnat.reproduce.estimates import (SHARD_PLATFORM, detect_platform, duration, estimate_seconds, estimate_total,
                                        shard_cells, split_streams)
from jaxnat.reproduce.gpus import Devices, find_devices, keep_jax_off_gpus
from jaxnat.reproduce.grid import EXPERIMENTS, ONLY_NAMES, PROFILES, RUN_SETTINGS, TRUNKS, Cell, Plan, build_grid

PROG = "jaxnat reproduce"


class ReproduceError(Exception):
    """A user error: printed as one line `jaxnat reproduce: error: <message>`, exit status 2."""


@dataclasses.dataclass
class ReproduceArgs:
    """Run the paper's experiments (a grid of `jaxnat train` runs) and write a findings report.
    Rerunning the same command skips finished cells and resumes an interrupted one."""

    profile: Annotated[Optional[str], tyro.conf.arg(metavar="{" + ",".join(PROFILES) + "}",
                                                    help_behavior_hint="")] = None
    """smoke: every cell type, tiny budgets, minutes on a CPU; quick: every finding, reduced budgets (one sitting on one GPU); paper: the paper's budgets (run piecewise with --only). Unset: smoke on a CPU, quick on an accelerator."""
    only: Annotated[str, tyro.conf.arg(metavar=",".join(ONLY_NAMES))] = ",".join(EXPERIMENTS)
    """Comma-separated experiments to run and report; `calibration` (not run unless named) trains the paper profile's batch beside the authors' at matched env steps."""
    trunks: Annotated[str, tyro.conf.arg(metavar=",".join(TRUNKS))] = ",".join(TRUNKS)
    """Comma-separated trunks of the vision cells to run and report (the paper profile's ResNet-18 cells are a second tier: `--trunks cnn` leaves them for another sitting)."""
    seeds: Annotated[Optional[int], tyro.conf.arg(metavar="INT", help_behavior_hint="")] = None
    """Seeds per cell (unset: the profile's, 5 for quick and paper)."""
    out: Annotated[Optional[Path], tyro.conf.arg(metavar="DIR", help_behavior_hint="")] = None
    """Where the cells and the report go (unset: runs/reproduce-<profile>)."""
    report_only: bool = False
    """Write the report from the cells already in --out without training."""
    sequential: bool = False
    """Run every cell in turn, also on an accelerator (by default there the Natural Atari cells, which run on the host's cores, train in a second process alongside the others)."""
    shard: Annotated[Optional[str], tyro.conf.arg(metavar="I/N", help_behavior_hint="")] = None
    """Train only the I-th (0-based) of N disjoint shares of the cells, balanced by estimated cost and the same on every machine: N jobs (a SLURM array, --array=0-<N-1>) may write into one shared --out; each writes the report of whatever has finished there, and --report-only merges them at the end."""
    dry_run: bool = False
    """Print the cells each shard (or this run) would train and their estimated GPU-hours and host-hours, then stop."""
    gpus: Annotated[str, tyro.conf.arg(metavar="N|all")] = "all"
    """GPUs to train on: with 2 or more the device cells are shared among one process per GPU, side by side (by their estimated times); 1: all of them in this process, on one GPU."""
    pack_small: Annotated[int, tyro.conf.arg(metavar="N")] = 1
    """Train the small device cells (latency-bound: at most 8,192 env steps per update over all seeds, as the authors' A2C and ACKTR batches) N at a time on a GPU, each in a process of its own with an N-th of the GPU's memory, the other cells on GPUs of their own (with one GPU, beside them). 1: one cell per GPU."""
    cells: Annotated[Optional[str], tyro.conf.arg(metavar="PATTERNS", help_behavior_hint="")] = None
    """Comma-separated shell-style patterns of cell names (`mujoco-*-state-*`, `classify-sweep-*`): train only the matching cells of --only (`--dry-run` lists them); the report still covers every cell there. Unset: every cell."""


def parse_args(argv=None) -> ReproduceArgs:
    argv = sys.argv[1:] if argv is None else list(argv)
    return tyro.cli(ReproduceArgs, args=argv, prog=PROG, description=inspect.cleandoc(ReproduceArgs.__doc__))


def default_profile(devices: Devices) -> str:
    """The profile without `--profile`: quick on a GPU, else smoke (the others take hours on a
    CPU). `devices`: `find_devices()`, which asks without starting JAX on the GPUs here."""
    return "quick" if devices.platform == "gpu" else "smoke"


def make_plan(args: ReproduceArgs, devices: Devices | None = None) -> Plan:
    """Check the arguments (one-line `ReproduceError`s) and build the grid; `devices` decides the
    profile when `--profile` is not given (None: `find_devices()`)."""
    name = args.profile or default_profile(devices or find_devices())
    if name not in PROFILES:
        close = difflib.get_close_matches(name, PROFILES, n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise ReproduceError(f"unknown --profile {name!r}{hint}; profiles: {', '.join(PROFILES)}")
    profile = PROFILES[name]
    only = tuple(name.strip() for name in args.only.split(",") if name.strip())
    unknown = [name for name in only if name not in ONLY_NAMES]
    if unknown or not only:
        close = difflib.get_close_matches(unknown[0], ONLY_NAMES, n=1) if unknown else []
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        what = f"unknown --only name {unknown[0]!r}{hint}" if unknown else "--only names no experiment"
        raise ReproduceError(f"{what}; experiments: {', '.join(ONLY_NAMES)}")
    trunks = tuple(name.strip() for name in args.trunks.split(",") if name.strip())
    wrong = [name for name in trunks if name not in TRUNKS]
    if wrong or not trunks:
        what = f"unknown --trunks name {wrong[0]!r}" if wrong else "--trunks names no trunk"
        raise ReproduceError(f"{what}; trunks: {', '.join(TRUNKS)}")
    seeds = profile.seeds if args.seeds is None else args.seeds
    if seeds < 1:
        raise ReproduceError("--seeds must be at least 1")
    _gpus_wanted(args)
    _pack_wanted(args)
    out = Path(args.out) if args.out is not None else Path("runs") / f"reproduce-{profile.name}"
    _check_writable(out)
    cells = [c for c in build_grid(profile, only) if c.labels.get("trunk", trunks[0]) in trunks]
    return Plan(profile, only, seeds, out, cells)


def parse_shard(text: str | None) -> tuple[int, int] | None:
    """`--shard I/N` as `(I, N)` (None: no sharding); a one-line `ReproduceError` otherwise."""
    if text is None:
        return None
    index, _, count = text.partition("/")
    if not (index.strip().isdigit() and count.strip().isdigit()) or int(count) < 1 or int(index) >= int(count):
        raise ReproduceError(f"--shard takes I/N with 0 <= I < N (the I-th of N shares, 0-based), not {text!r}")
    return int(index), int(count)


def cell_patterns(args: ReproduceArgs, plan: Plan) -> tuple[str, ...] | None:
    """`--cells` as patterns, each matching a cell of `plan` (None: every cell)."""
    if args.cells is None:
        return None
    patterns = tuple(p.strip() for p in args.cells.split(",") if p.strip())
    if not patterns:
        raise ReproduceError("--cells names no pattern; give cell names or patterns such as 'mujoco-*-state-*'")
    names = [c.name for c in plan.cells]
    for pattern in patterns:
        if not fnmatch.filter(names, pattern):
            close = difflib.get_close_matches(pattern, names, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise ReproduceError(f"--cells pattern {pattern!r} matches no cell of --only {','.join(plan.only)}{hint}; "
                                 "--dry-run lists the cells")
    return patterns


def pick_plan(plan: Plan, patterns: tuple[str, ...] | None) -> Plan:
    """The plan whose cells match one of `patterns` (`cell_patterns`; None: `plan`)."""
    if patterns is None:
        return plan
    return dataclasses.replace(plan, cells=[c for c in plan.cells if any(fnmatch.fnmatchcase(c.name, p)
                                                                           for p in patterns)])


def shard_plan(plan: Plan, shard: tuple[int, int] | None) -> Plan:
    """The plan whose cells this run trains: the shard's share of the runnable cells (all of
    them without `--shard`); the report still covers the whole `plan`."""
    if shard is None:
        return plan
    runnable = [c for c in plan.cells if not c.skip]
    return dataclasses.replace(plan, cells=shard_cells(runnable, *shard, plan.seeds))


def dry_run(plan: Plan, shard: tuple[int, int] | None, console) -> None:
    """Print each shard's cells (or this run's) with their estimated hours: GPU-hours of the
    device cells, host-hours of the host cells (Natural Atari: a 16-core host's)."""
    from rich.table import Table

    runnable = [c for c in plan.cells if not c.skip]
    count = shard[1] if shard else 1
    shards = [shard[0]] if shard else range(count)
    table = Table(title=f"{PROG} --dry-run: profile {plan.profile.name}, {plan.seeds} seeds, {len(runnable)} cells "
                        f"in {count} share{'s' * (count != 1)}")
    for column in ("shard", "cells", "GPU-hours", "host-hours", "cell names"):
        table.add_column(column, overflow="fold")
    for index in shards:
        cells = shard_cells(runnable, index, count, plan.seeds)
        hours = {kind: sum(estimate_seconds(c, plan.seeds, SHARD_PLATFORM) for c in cells if c.host == host) / 3600
                 for kind, host in (("gpu", False), ("host", True))}
        table.add_row(f"{index}/{count}", str(len(cells)), f"{hours['gpu']:.2f}", f"{hours['host']:.2f}",
                      ", ".join(c.name for c in cells))
    console.print(table)


def _check_writable(out: Path) -> None:
    reason = unwritable(out)
    if reason is not None:
        raise ReproduceError(f"--out {out} is not writable ({reason}); choose another folder")
    out.mkdir(parents=True, exist_ok=True)  # the cells' logs go there


def check_report_imports() -> None:
    """Raise `ReproduceError` now, before any cell trains, when the report's aggregates could
    not be computed at the end: rliable (and arch and pandas under it) must import. A broken
    install otherwise shows only after the last cell, as a traceback."""
    from jaxnat.reproduce.aggregates import rliable_modules

    try:
        rliable_modules()
    except Exception as error:  # arch 7 under pandas 3 fails with a TypeError, not an ImportError
        raise ReproduceError(
            f"the report's aggregates need rliable, which does not import here ({type(error).__name__}: "
            f"{error}); install the agents extra's versions (pip install 'jaxnat[agents]', which pins "
            f"pandas below 3 for arch 7)") from error


def _gpus_wanted(args: ReproduceArgs) -> int | None:
    """`--gpus` as a count (None: all)."""
    if args.gpus == "all":
        return None
    count = int(args.gpus) if args.gpus.strip().isdigit() else 0
    if count < 1:
        raise ReproduceError(f"--gpus takes a number of GPUs (1 or more) or 'all', not {args.gpus!r}")
    if count > 1 and args.sequential:
        raise ReproduceError(f"--sequential trains every cell in turn on one GPU; it cannot use --gpus {count}")
    return count


def _pack_wanted(args: ReproduceArgs) -> int:
    """`--pack-small` checked: 1 or more, and not with `--sequential`."""
    if args.pack_small < 1:
        raise ReproduceError(f"--pack-small takes the number of small cells per GPU (1 or more), not {args.pack_small}")
    if args.pack_small > 1 and args.sequential:
        raise ReproduceError(f"--sequential trains every cell in turn; it cannot use --pack-small {args.pack_small}")
    return args.pack_small


def choose_gpus(args: ReproduceArgs, devices: Devices | None = None) -> tuple[str | None, tuple[str, ...]]:
    """`(platform, gpus)` for `run_cells`: the `CUDA_VISIBLE_DEVICES` ids of the GPUs to train on
    side by side (none: one stream of device cells here, as with one GPU; with `--pack-small`
    2 or more, a single GPU's id too, since packed cells train in child processes), and the
    platform when it had to be found without starting JAX here (None: `run_cells` asks JAX
    here). `devices`: what `find_devices` finds (None: ask it; it is not asked with `--gpus 1`
    or `--sequential`, unless packing). A count the machine lacks is a `ReproduceError`."""
    wanted, pack = _gpus_wanted(args), _pack_wanted(args)
    if (wanted == 1 and pack == 1) or args.sequential:
        return None, ()
    devices = find_devices() if devices is None else devices
    found = devices.gpus
    if wanted is not None and wanted > len(found):
        have = (f"cannot count its GPUs ({devices.problem})" if devices.problem else
                f"JAX finds {len(found) or 'no'} GPU{'' if len(found) == 1 else 's'} here"
                + (f" (platform {devices.platform})" if not found else ""))
        raise ReproduceError(f"--gpus {wanted}: {have}")
    gpus = found[:wanted] if wanted else found
    return devices.platform or None, gpus if len(gpus) >= 2 or (pack > 1 and gpus) else ()


def _default_overlap(platform: str) -> bool:
    import os

    return platform != "cpu" and os.name == "posix"


def run_cells(plan: Plan, console, *, compile_ahead: bool | None = None, overlap: bool | None = None,
              platform: str | None = None, gpus: tuple[str, ...] = (), pack: int = 1) -> dict:
    """Train every runnable, unfinished cell of `plan`; returns `{cell name: outcome}` where an
    outcome is "finished before", "finished", or "failed: <one line>".

    `compile_ahead`: compile each device cell's programs while the one before trains (None: on an
    accelerator, not on a CPU, where compiling would take the cores the training uses).
    `overlap`: train the host cells (`Cell.host`) in a child process while the device cells
    train here (None: on an accelerator under POSIX; a CPU's cores are the training's).
    `gpus`: two or more `CUDA_VISIBLE_DEVICES` ids (`choose_gpus`), one child process each for
    a share of the device cells, and the host cells in one more; this process then trains
    nothing, and its JAX, if it has not started, is kept on the CPU (`platform` is the one found
    for the children: JAX here would take 75% of every GPU). `pack`: with 2 or more and one GPU
    or more, the small cells train that many to a GPU (`estimates.split_streams`), always in
    child processes. `platform`: None to ask JAX here.
    With several streams the estimate and the ETA are the longest stream's, a child's failures
    (a cell's, or its own death) are reported as its cells', and a Ctrl-C stops every stream
    (each checkpoints its cell) before `KeyboardInterrupt` propagates."""
    from jaxnat.training import read_run, run_status

    gpus = tuple(gpus) if len(gpus) >= 2 or (pack > 1 and gpus) else ()
    if gpus:
        keep_jax_off_gpus()
    platform = platform or detect_platform()
    runnable = [c for c in plan.cells if not c.skip]
    status = {c.name: run_status(plan.out / c.name) for c in runnable}
    for cell in runnable:
        if status[cell.name] != "new":
            _check_same_run(cell, plan, read_run(plan.out / cell.name).config)
    todo = [c for c in runnable if status[c.name] != "finished"]
    estimates = {c.name: estimate_seconds(c, plan.seeds, platform) for c in todo}
    streams = split_streams(todo, _default_overlap(platform) if overlap is None else overlap, len(gpus), estimates,
                            pack, plan.seeds)
    total = estimate_total(streams, plan.seeds, platform)
    side = ""
    if len(streams) > 1:
        side = " (" + ", ".join(f"{name if name.startswith('gpu') else name + ' cells'} "
                                f"{duration(sum(estimates[c.name] for c in cells))}"
                                for name, cells in streams.items()) + " side by side)"
    machine = f"{len(gpus)} GPU{'s' * (len(gpus) != 1)}" if gpus else f"this {platform.upper()}"
    console.print(f"{PROG}: profile {plan.profile.name} · {len(plan.cells)} cells ({len(runnable) - len(todo)} "
                  f"finished before, {len(plan.cells) - len(runnable)} not runnable here) · {plan.seeds} seeds · "
                  f"estimated {duration(total)} on {machine}{side} · {plan.out}", highlight=False)
    board = Board(console, streams, estimates)
    board.outcomes.update({c.name: "finished before" for c in runnable if status[c.name] == "finished"})
    resumed = {c.name: status[c.name] == "partial" for c in todo}
    ahead = platform != "cpu" if compile_ahead is None else compile_ahead
    children: list[CellStream] = []
    # GPU streams of one kind share their cells (`cell_stream.pool_streams`) through claims in a
    # folder of this run's own: a claim left by an earlier, stopped run frees its cell again.
    claims = plan.out / "logs" / "claims" / f"{os.getpid()}-{time.time_ns()}" if gpus else None
    try:
        if claims is not None:
            claims.mkdir(parents=True)
        with board.progress:
            for spec in child_streams(streams, gpus, estimates, ahead, claims):
                children.append(CellStream(spec, plan, board, platform))
            here = streams.get("device", streams.get("all"))
            if here is not None:
                train_cells(here, plan, resumed, board, platform=platform, compile_ahead=ahead,
                            overlapped=bool(children))
            for child in children:
                child.wait()
            by_name = {child.spec.name: child for child in children}
            for cell in todo:  # a pooled stream's cell no stream finished: the claimer's (or planned one's) end
                if cell.name not in board.outcomes:
                    holder = (claims and Claims.holder(claims, cell.name)) or board.stream_of[cell.name]
                    child = by_name.get(holder)
                    why = child.failure(child.proc.returncode) if child else f"the {holder} stream did not train it"
                    board.done(cell, f"failed: {why}", 0.0)
    except BaseException as err:
        stop_streams(children)
        if isinstance(err, KeyboardInterrupt):
            where = " and ".join(board.running) or "between cells"
            console.print(f"interrupted in {where} (checkpointed); rerun the same command to continue")
        raise
    finally:
        if claims is not None:
            shutil.rmtree(claims, ignore_errors=True)
    return board.outcomes


def _check_same_run(cell: Cell, plan: Plan, config: dict) -> None:
    """A cell folder written with other seeds or budgets is not silently mixed into this grid."""
    spec = config.get("spec", {})
    from jaxnat.training import parse_env_kwargs

    saved = (spec.get("env_id"), spec.get("env_kwargs"), spec.get("algo"), spec.get("seeds"),
             spec.get("config", {}).get("total_timesteps"), spec.get("env_parts", RUN_SETTINGS["env_parts"]))
    wanted = (cell.env_id, parse_env_kwargs({k: str(v) for k, v in cell.env_kwargs.items()}, cell.env_id), cell.algo, plan.seeds,
              cell.budget.total_timesteps, cell.overrides.get("env_parts", RUN_SETTINGS["env_parts"]))
    if saved != wanted:
        raise ReproduceError(f"{plan.out / cell.name} holds a run with other settings (env, kwargs, algo, seeds, "
                             f"steps, env parts {saved}; this grid wants {wanted}); use another --out, or the same "
                             "--profile and --seeds")
    # The profile's settings of the cell (a changed batch must not pass as the run it replaced).
    saved_config = spec.get("config", {})
    changed = {k: (saved_config.get(k), v) for k, v in cell.overrides.items()
               if k not in RUN_SETTINGS and saved_config.get(k, v) != v}
    if "eval_every" in cell.overrides and spec.get("eval_every") != cell.overrides["eval_every"]:
        changed["eval_every"] = (spec.get("eval_every"), cell.overrides["eval_every"])
    if changed:
        said = ", ".join(f"{k} {old!r} (this grid: {new!r})" for k, (old, new) in changed.items())
        raise ReproduceError(f"{plan.out / cell.name} holds a run with other settings: {said}; use another --out, "
                             "or move the folder aside to train the cell again")


def reproduce(args: ReproduceArgs, *, console=None, overlap: bool | None = None,
              devices: Devices | None = None) -> Path:
    """Run (or continue) the grid and write the report once every cell has ended; returns the
    report's path. `overlap`: `run_cells`'s (None: its default, unless `args.sequential`).
    `devices`: `choose_gpus`'s (None: found here; a test names GPUs to run device streams on
    its CPU)."""
    from rich.console import Console

    from jaxnat.reproduce.report import write_report

    console = console or Console()
    if args.profile is None and devices is None:  # found once, for the profile and the GPUs
        devices = find_devices()
    plan = make_plan(args, devices)
    if args.profile is None and plan.profile.name == "smoke":
        console.print("no --profile given: running the smoke profile on this CPU (pass --profile quick or paper "
                      "to run more)", highlight=False, soft_wrap=True)
    if args.sequential:
        overlap = False
    shard = parse_shard(args.shard)
    picked = pick_plan(plan, cell_patterns(args, plan))
    if args.dry_run:
        dry_run(picked, shard, console)
        return plan.out / "report.md"
    check_report_imports()
    outcomes = {}
    if not args.report_only:
        platform, gpus = choose_gpus(args, devices)
        outcomes = run_cells(shard_plan(picked, shard), console, overlap=overlap, platform=platform, gpus=gpus,
                             pack=args.pack_small)
    path = write_report(plan, outcomes)
    console.print(f"report: {path}", highlight=False)
    return path


def main(argv=None) -> int:
    """`jaxnat reproduce` with `argv` (default: sys.argv[1:]); returns the exit status."""
    args = parse_args(argv)
    return exit_status(lambda: reproduce(args), ReproduceError, PROG)
