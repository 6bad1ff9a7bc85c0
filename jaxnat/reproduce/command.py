"""The `jaxnat reproduce` command: check the arguments, estimate, run the grid's cells (skipping
finished ones, resuming interrupted ones), then write the report.

On an accelerator the cells run as two streams at once: the device cells (seeds vmapped on the
accelerator) in this process, one after another (`cells.train_cells`), and the host cells
(Natural Atari: ALE on the host's cores, a small policy on the accelerator) in a child process
(`host_stream`) writing to the same `--out`, both shown on one progress board (`board`). On a
CPU, or with `--sequential`, every cell runs in turn here."""

from __future__ import annotations

import dataclasses
import difflib
import inspect
import sys
from pathlib import Path
from typing import Annotated, Optional

import tyro

from jaxnat.cli import exit_status, unwritable
from jaxnat.reproduce.board import Board
from jaxnat.reproduce.cells import train_cells
from jaxnat.reproduce.estimates import detect_platform, duration, estimate_seconds, estimate_total, split_streams
from jaxnat.reproduce.grid import EXPERIMENTS, PROFILES, RUN_SETTINGS, Cell, Plan, build_grid
from jaxnat.reproduce.host_stream import HostStream

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
    only: Annotated[str, tyro.conf.arg(metavar=",".join(EXPERIMENTS))] = ",".join(EXPERIMENTS)
    """Comma-separated experiments to run and report."""
    seeds: Annotated[Optional[int], tyro.conf.arg(metavar="INT", help_behavior_hint="")] = None
    """Seeds per cell (unset: the profile's, 5 for quick and paper)."""
    out: Annotated[Optional[Path], tyro.conf.arg(metavar="DIR", help_behavior_hint="")] = None
    """Where the cells and the report go (unset: runs/reproduce-<profile>)."""
    report_only: bool = False
    """Write the report from the cells already in --out without training."""
    sequential: bool = False
    """Run every cell in turn, also on an accelerator (by default there the Natural Atari cells, which run on the host's cores, train in a second process alongside the others)."""


def parse_args(argv=None) -> ReproduceArgs:
    argv = sys.argv[1:] if argv is None else list(argv)
    return tyro.cli(ReproduceArgs, args=argv, prog=PROG, description=inspect.cleandoc(ReproduceArgs.__doc__))


def default_profile() -> str:
    """The profile without `--profile`: smoke on a CPU (the others take hours there), else quick."""
    return "smoke" if detect_platform() == "cpu" else "quick"


def make_plan(args: ReproduceArgs) -> Plan:
    """Check the arguments (one-line `ReproduceError`s) and build the grid."""
    name = default_profile() if args.profile is None else args.profile
    if name not in PROFILES:
        close = difflib.get_close_matches(name, PROFILES, n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise ReproduceError(f"unknown --profile {name!r}{hint}; profiles: {', '.join(PROFILES)}")
    profile = PROFILES[name]
    only = tuple(name.strip() for name in args.only.split(",") if name.strip())
    unknown = [name for name in only if name not in EXPERIMENTS]
    if unknown or not only:
        close = difflib.get_close_matches(unknown[0], EXPERIMENTS, n=1) if unknown else []
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        what = f"unknown --only name {unknown[0]!r}{hint}" if unknown else "--only names no experiment"
        raise ReproduceError(f"{what}; experiments: {', '.join(EXPERIMENTS)}")
    seeds = profile.seeds if args.seeds is None else args.seeds
    if seeds < 1:
        raise ReproduceError("--seeds must be at least 1")
    out = Path(args.out) if args.out is not None else Path("runs") / f"reproduce-{profile.name}"
    _check_writable(out)
    return Plan(profile, only, seeds, out, build_grid(profile, only))


def _check_writable(out: Path) -> None:
    reason = unwritable(out)
    if reason is not None:
        raise ReproduceError(f"--out {out} is not writable ({reason}); choose another folder")
    out.mkdir(parents=True, exist_ok=True)  # the cells' logs go there


def _default_overlap(platform: str) -> bool:
    import os

    return platform != "cpu" and os.name == "posix"


def run_cells(plan: Plan, console, *, compile_ahead: bool | None = None, overlap: bool | None = None) -> dict:
    """Train every runnable, unfinished cell of `plan`; returns `{cell name: outcome}` where an
    outcome is "finished before", "finished", or "failed: <one line>".

    `compile_ahead`: compile each device cell's programs while the one before trains (None: on an
    accelerator, not on a CPU, where compiling would take the cores the training uses).
    `overlap`: train the host cells (`Cell.host`) in a child process while the device cells
    train here (None: on an accelerator under POSIX; a CPU's cores are the training's). With
    both kinds to run, the estimate and the ETA are the longer stream's, the child's failures
    (a cell's, or its own death) are reported as the cells', and a Ctrl-C stops both (each
    checkpoints its cell) before `KeyboardInterrupt` propagates."""
    from jaxnat.training import read_run, run_status

    platform = detect_platform()
    runnable = [c for c in plan.cells if not c.skip]
    status = {c.name: run_status(plan.out / c.name) for c in runnable}
    for cell in runnable:
        if status[cell.name] != "new":
            _check_same_run(cell, plan, read_run(plan.out / cell.name).config)
    todo = [c for c in runnable if status[c.name] != "finished"]
    streams = split_streams(todo, _default_overlap(platform) if overlap is None else overlap)
    estimates = {c.name: estimate_seconds(c, plan.seeds, platform) for c in todo}
    total = estimate_total(streams, plan.seeds, platform)
    alongside = ""
    if "host" in streams:
        device, host = (sum(estimates[c.name] for c in streams[k]) for k in ("device", "host"))
        alongside = (f" (host cells {duration(host)} alongside device cells {duration(device)})")
    console.print(f"{PROG}: profile {plan.profile.name} · {len(plan.cells)} cells ({len(runnable) - len(todo)} "
                  f"finished before, {len(plan.cells) - len(runnable)} not runnable here) · {plan.seeds} seeds · "
                  f"estimated {duration(total)} on this {platform.upper()}{alongside} · {plan.out}", highlight=False)
    board = Board(console, streams, estimates)
    board.outcomes.update({c.name: "finished before" for c in runnable if status[c.name] == "finished"})
    resumed = {c.name: status[c.name] == "partial" for c in todo}
    ahead = platform != "cpu" if compile_ahead is None else compile_ahead
    host = None
    try:
        with board.progress:
            if "host" in streams:
                host = HostStream(streams["host"], plan, board, platform)
            train_cells(streams.get("device", streams.get("all")), plan, resumed, board, platform=platform,
                        compile_ahead=ahead, overlapped=host is not None)
            if host is not None:
                host.wait()
    except BaseException as err:
        if host is not None:
            host.stop()
        if isinstance(err, KeyboardInterrupt):
            where = " and ".join(board.running) or "between cells"
            console.print(f"interrupted in {where} (checkpointed); rerun the same command to continue")
        raise
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


def reproduce(args: ReproduceArgs, *, console=None, overlap: bool | None = None) -> Path:
    """Run (or continue) the grid and write the report once every cell has ended; returns the
    report's path. `overlap`: `run_cells`'s (None: its default, unless `args.sequential`)."""
    from rich.console import Console

    from jaxnat.reproduce.report import write_report

    console = console or Console()
    plan = make_plan(args)
    if args.profile is None and plan.profile.name == "smoke":
        console.print("no --profile given: running the smoke profile on this CPU (pass --profile quick or paper "
                      "to run more)", highlight=False, soft_wrap=True)
    if args.sequential:
        overlap = False
    outcomes = {} if args.report_only else run_cells(plan, console, overlap=overlap)
    path = write_report(plan, outcomes)
    console.print(f"report: {path}", highlight=False)
    return path


def main(argv=None) -> int:
    """`jaxnat reproduce` with `argv` (default: sys.argv[1:]); returns the exit status."""
    args = parse_args(argv)
    return exit_status(lambda: reproduce(args), ReproduceError, PROG)
