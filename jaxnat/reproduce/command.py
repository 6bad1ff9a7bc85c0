"""The `jaxnat reproduce` command: check the arguments, estimate, run the grid's cells (skipping
finished ones, resuming interrupted ones), then write the report."""

from __future__ import annotations

import dataclasses
import datetime
import difflib
import inspect
import json
import sys
import time
from pathlib import Path
from typing import Annotated, Optional

import tyro

from jaxnat.reproduce.grid import EXPERIMENTS, PROFILES, RUN_SETTINGS, Cell, Profile, build_grid

PROG = "jaxnat reproduce"

# Rough env steps/s (all seeds of a cell together) and the seconds a cell spends besides
# training (compiling, where it is not hidden behind the cell before, evaluating, test play),
# per experiment, for the estimate printed before starting; the progress bar's ETA then follows
# the measured pace. The GPU figures follow the quick profile's cells (bench/reproduce_cost.py;
# Atari: 256 envs in two parts, the seeds one after another).
RATES = {"cpu": {"classify": 2e3, "localize": 3e2, "atari": 1e3, "mujoco": 2e2},
         "gpu": {"classify": 3.2e4, "localize": 1.5e4, "atari": 1e4, "mujoco": 2.5e4}}
COMPILE_S = {"cpu": {"classify": 15, "localize": 45, "atari": 15, "mujoco": 60},
             "gpu": {"classify": 8, "localize": 23, "atari": 106, "mujoco": 35}}


class ReproduceError(Exception):
    """A user error: printed as one line `jaxnat reproduce: error: <message>`, exit status 2."""


@dataclasses.dataclass
class ReproduceArgs:
    """Run the paper's experiments (a grid of `jaxnat train` runs) and write a findings report.
    Rerunning the same command skips finished cells and resumes an interrupted one."""

    profile: Annotated[str, tyro.conf.arg(metavar="{" + ",".join(PROFILES) + "}")] = "quick"
    """smoke: every cell type, tiny budgets, minutes on a CPU; quick: every finding, reduced budgets (one sitting on one GPU); paper: the paper's budgets (run piecewise with --only)."""
    only: Annotated[str, tyro.conf.arg(metavar=",".join(EXPERIMENTS))] = ",".join(EXPERIMENTS)
    """Comma-separated experiments to run and report."""
    seeds: Annotated[Optional[int], tyro.conf.arg(metavar="INT", help_behavior_hint="")] = None
    """Seeds per cell (unset: the profile's, 5 for quick and paper)."""
    out: Annotated[Optional[Path], tyro.conf.arg(metavar="DIR", help_behavior_hint="")] = None
    """Where the cells and the report go (unset: runs/reproduce-<profile>)."""
    report_only: bool = False
    """Write the report from the cells already in --out without training."""


@dataclasses.dataclass(frozen=True)
class Plan:
    profile: Profile
    only: tuple[str, ...]
    seeds: int
    out: Path
    cells: list[Cell]


def parse_args(argv=None) -> ReproduceArgs:
    argv = sys.argv[1:] if argv is None else list(argv)
    return tyro.cli(ReproduceArgs, args=argv, prog=PROG, description=inspect.cleandoc(ReproduceArgs.__doc__))


def make_plan(args: ReproduceArgs) -> Plan:
    """Check the arguments (one-line `ReproduceError`s) and build the grid."""
    if args.profile not in PROFILES:
        close = difflib.get_close_matches(args.profile, PROFILES, n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise ReproduceError(f"unknown --profile {args.profile!r}{hint}; profiles: {', '.join(PROFILES)}")
    profile = PROFILES[args.profile]
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
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = out / ".write-test"
        probe.write_text("")
        probe.unlink()
    except OSError as err:
        raise ReproduceError(f"--out {out} is not writable ({err.strerror or err}); choose another folder") from None


def _platform() -> str:
    import jax

    return "cpu" if jax.default_backend() == "cpu" else "gpu"


def estimate_seconds(cell: Cell, seeds: int, platform: str) -> float:
    """A rough wall time of `cell` (compile + training + evaluation), for the ETA."""
    steps = cell.budget.total_timesteps * seeds
    return COMPILE_S[platform][cell.experiment] + steps / RATES[platform][cell.experiment]


def _train_argv(cell: Cell, plan: Plan, resume: bool) -> list[str]:
    """The `jaxnat train` arguments of `cell`: a new run, or `--resume` of its folder."""
    run_dir = plan.out / cell.name
    argv = cell.train_argv(plan.seeds, run_dir)
    if resume:
        cut = argv.index("--run-dir")
        argv = ["--resume", str(run_dir), *argv[:cut], *argv[cut + 2:]]
    return argv


class _CompileAhead:
    """Compiles the next cell's programs on a worker thread while the current cell trains: XLA
    compiles on the host's cores while the run keeps the accelerator busy, so a grid of short
    cells is not paced by its compiles. The programs are traced and lowered on the calling
    thread first (`jaxnat.training.prepare_programs`; JAX's tracing is not shared across
    threads), then `train` finds them compiled in the process's cache. A failure here is left
    for `train` to report."""

    def __init__(self, enabled: bool, compiler_options: dict | None):
        from concurrent.futures import ThreadPoolExecutor

        self.enabled, self.compiler_options = enabled, compiler_options
        self.pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="compile-ahead") if enabled else None
        self.pending = None

    def start(self, argv: list[str] | None) -> None:
        """Lower the programs of the run `argv` describes and start compiling them (None:
        nothing to compile)."""
        if not self.enabled or argv is None:
            return
        from jaxnat.training import parse_args as parse_train_args, prepare_programs

        try:
            compile_programs = prepare_programs(parse_train_args(argv), compiler_options=self.compiler_options)
        except Exception:  # noqa: BLE001 (train reports it, in its own words, when the cell runs)
            return
        self.pending = self.pool.submit(compile_programs)

    def wait(self) -> None:
        """Block until the compile started last is done (its errors are left for `train`)."""
        if self.pending is not None:
            self.pending.exception()
            self.pending = None

    def close(self) -> None:
        if self.pool is not None:
            self.pool.shutdown(wait=False, cancel_futures=True)


def run_cells(plan: Plan, console, *, compile_ahead: bool | None = None) -> dict:
    """Train every runnable, unfinished cell of `plan`; returns `{cell name: outcome}` where an
    outcome is "finished before", "finished", or "failed: <one line>". `compile_ahead`: compile
    each cell's programs while the one before trains (None: on an accelerator, not on a CPU,
    where compiling would take the cores the training uses)."""
    from rich.console import Console
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    from jaxnat.training import TrainError, parse_args as parse_train_args, read_run, run_status, train

    platform = _platform()
    compiler_options = {"xla_backend_optimization_level": 0} if plan.profile.fast_compile else None
    runnable = [c for c in plan.cells if not c.skip]
    status = {c.name: run_status(plan.out / c.name) for c in runnable}
    for cell in runnable:
        if status[cell.name] != "new":
            _check_same_run(cell, plan, read_run(plan.out / cell.name).config)
    todo = [c for c in runnable if status[c.name] != "finished"]
    estimates = {c.name: estimate_seconds(c, plan.seeds, platform) for c in todo}
    total = sum(estimates.values())
    console.print(f"{PROG}: profile {plan.profile.name} · {len(plan.cells)} cells ({len(runnable) - len(todo)} "
                  f"finished before, {len(plan.cells) - len(runnable)} not runnable here) · {plan.seeds} seeds · "
                  f"estimated {_duration(total)} on this {platform.upper()} · {plan.out}", highlight=False)
    outcomes = {c.name: "finished before" for c in runnable if c.name not in {t.name for t in todo}}
    logs = plan.out / "logs"
    logs.mkdir(exist_ok=True)
    timings_path = plan.out / "timings.jsonl"
    live = console.is_terminal
    progress = Progress(TextColumn("{task.description}"), BarColumn(bar_width=20), TextColumn("{task.fields[cells]}"),
                        TimeElapsedColumn(), TextColumn("eta"), TimeRemainingColumn(), console=console,
                        disable=not live)
    task = progress.add_task("cells", total=max(total, 1e-9), cells=f"0/{len(todo)}")
    ahead = _CompileAhead(platform != "cpu" if compile_ahead is None else compile_ahead, compiler_options)
    argvs = [_train_argv(c, plan, status[c.name] == "partial") for c in todo]
    ahead.start(argvs[0] if argvs else None)
    with progress:
        for index, cell in enumerate(todo):
            resume = status[cell.name] == "partial"
            progress.update(task, description=f"{cell.name}{' (resumed)' if resume else ''}")
            if not live:
                console.print(f"[{index + 1}/{len(todo)}] {cell.name}{' (resumed)' if resume else ''} ...",
                              highlight=False)
            argv = argvs[index]
            start = time.perf_counter()
            ahead.wait()  # this cell's programs (their compile time is counted in this cell)
            ahead.start(argvs[index + 1] if index + 1 < len(todo) else None)
            with (logs / f"{cell.name}.log").open("a") as log:
                log_console = Console(file=log, width=120, force_terminal=False)
                try:
                    train(parse_train_args(argv), console=log_console, compiler_options=compiler_options)
                    outcomes[cell.name] = "finished"
                except TrainError as err:
                    outcomes[cell.name] = f"failed: {err}"
                    console.print(f"{cell.name}: {err}", style="red", highlight=False)
                except KeyboardInterrupt:
                    ahead.close()
                    console.print(f"interrupted in {cell.name} (checkpointed); rerun the same command to continue")
                    raise
            seconds = time.perf_counter() - start
            with timings_path.open("a") as f:
                f.write(json.dumps({"cell": cell.name, "experiment": cell.experiment, "seconds": seconds,
                                    "estimate": estimates[cell.name], "resumed": resume,
                                    "outcome": outcomes[cell.name].split(":")[0], "message": outcomes[cell.name],
                                    "platform": platform,
                                    "date": datetime.datetime.now().isoformat(timespec="seconds")}) + "\n")
            progress.update(task, advance=estimates[cell.name], cells=f"{index + 1}/{len(todo)}")
            if not live:
                console.print(f"[{index + 1}/{len(todo)}] {cell.name}: {outcomes[cell.name]} in {seconds:.0f} s",
                              highlight=False)
    ahead.close()
    return outcomes


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


def _duration(seconds: float) -> str:
    seconds = int(round(seconds))
    return f"{seconds // 3600}h{seconds % 3600 // 60:02d}m" if seconds >= 3600 else f"{seconds // 60}m{seconds % 60:02d}s"


def reproduce(args: ReproduceArgs, *, console=None) -> Path:
    """Run (or continue) the grid and write the report; returns the report's path."""
    from rich.console import Console

    from jaxnat.reproduce.report import write_report

    console = console or Console()
    plan = make_plan(args)
    outcomes = {} if args.report_only else run_cells(plan, console)
    path = write_report(plan, outcomes)
    console.print(f"report: {path}", highlight=False)
    return path


def main(argv=None) -> int:
    """`jaxnat reproduce` with `argv` (default: sys.argv[1:]); returns the exit status."""
    args = parse_args(argv)
    try:
        reproduce(args)
    except ReproduceError as err:
        print(f"{PROG}: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    return 0
