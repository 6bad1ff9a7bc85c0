"""The run directory's bookkeeping that both backends of `jaxnat train` share: a new or resumed
run's spec and folder, the checks on its counts, the versions recorded in `config.json`.

Only `jaxnat.training` touches run directories; the agents know nothing of them.
"""

from __future__ import annotations

import dataclasses
import datetime
import importlib
import json
import platform
from pathlib import Path

import jax

import jaxnat
from jaxnat.cli import unwritable
from jaxnat.agents.rollout import count_updates
from jaxnat.training.args import TrainArgs, TrainError, parse_env_kwargs
from jaxnat.training.spec import SPEC_FIELDS_ADDED, RunSpec, auto_eval_every


def versions() -> dict:
    versions = {"jaxnat": jaxnat.__version__, "jax": jax.__version__, "python": platform.python_version()}
    for name in ("jaxlib", "flax", "optax", "orbax.checkpoint"):
        try:
            versions[name] = importlib.import_module(name).__version__
        except Exception:  # noqa: BLE001 (versions are informative only)
            pass
    versions["device"] = str(jax.devices()[0].device_kind)
    return versions


def default_run_dir(env_id: str, algo: str) -> Path:
    stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
    return Path("runs") / f"{env_id.replace('/', '_')}-{algo}-{stamp}"


def check_resume_args(args: TrainArgs, saved: dict) -> None:
    """Arguments given with --resume must match the run's; defaults count as left out."""
    defaults = TrainArgs()
    conflicts = []
    for field in dataclasses.fields(TrainArgs):
        # --devices and --log may change on resume: where a run continues and where its rows
        # are mirrored do not change its result. --total-timesteps may grow it (`extended`).
        if field.name in ("resume", "run_dir", "config", "given", "devices", "log", "total_timesteps"):
            continue
        value, default = getattr(args, field.name), getattr(defaults, field.name)
        if field.name == "env_kwargs":
            value, default = parse_env_kwargs(value, saved["env_id"]), parse_env_kwargs(default, saved["env_id"])
        given = value != default or field.name in args.given
        saved_value = saved.get(field.name, saved["config"].get(field.name, SPEC_FIELDS_ADDED.get(field.name)))
        if given and value != saved_value:
            conflicts.append(_conflict(field.name, value, saved_value))
    for field in dataclasses.fields(args.config):
        value = getattr(args.config, field.name)
        if value is not None and value != saved["config"].get(field.name):
            conflicts.append(_conflict(field.name, value, saved["config"].get(field.name)))
    if args.run_dir is not None and Path(args.run_dir).absolute() != Path(args.resume).absolute():
        conflicts.append(f"--run-dir {args.run_dir} (the run is in {args.resume})")
    if conflicts:
        verb = "conflicts" if len(conflicts) == 1 else "conflict"
        raise TrainError(f"{', '.join(conflicts)} {verb} with the config of the run being resumed "
                         f"({Path(args.resume) / 'config.json'}); leave them out")


def _conflict(name: str, given, saved) -> str:
    """`--name GIVEN (the run: SAVED)`: what a resume was given against what the run holds."""
    return f"--{name.replace('_', '-')} {given!r} (the run: {saved!r})"


def open_resumed(args: TrainArgs):
    """The run `--resume` names: (spec, run_dir, its saved config.json)."""
    run_dir = Path(args.resume)
    config_path = run_dir / "config.json"
    if not config_path.is_file():
        raise TrainError(f"cannot resume {run_dir}: no config.json there")
    try:
        saved = json.loads(config_path.read_text())
    except (OSError, UnicodeDecodeError, ValueError) as err:
        raise TrainError(f"cannot resume {run_dir}: {config_path} is not readable JSON ({err}); restore it "
                         "from a copy, or start a new run") from None
    if not isinstance(saved, dict) or "spec" not in saved:
        raise TrainError(f"cannot resume {run_dir}: its config.json holds no run spec (written by an older "
                         "jaxnat, or not by jaxnat train)")
    try:
        spec = RunSpec.from_json(saved["spec"])
        check_resume_args(args, saved["spec"])
        spec = extended(spec, args.total_timesteps, run_dir)
    except (KeyError, TypeError, ValueError, AttributeError) as err:
        raise TrainError(f"cannot resume {run_dir}: its config.json's run spec is damaged ({type(err).__name__}: "
                         f"{err}); restore it from a copy, or start a new run") from None
    reason = unwritable(run_dir)  # checkpoints and records are written there: refused now, not after compiling
    if reason is not None:
        raise TrainError(f"cannot resume {run_dir}: it is not writable ({reason}); make it writable, or copy the "
                         "run to a writable folder and resume the copy")
    return spec, run_dir, saved


def extended(spec: RunSpec, total_timesteps: int | None, run_dir: Path) -> RunSpec:
    """The resumed run's spec, with `--total-timesteps` (None: not given) as its new length
    when it adds updates: training continues from the latest checkpoint up to it. Chunks keep
    their length (`eval_every`), evaluations their cadence. A count that would shorten the run
    or add no update is refused, showing both values.

    The learning-rate schedule (PPO's and ACKTR's anneal_lr) is a function of the run's length:
    the extended run continues on the new length's schedule from the update it has reached, so
    the rate rises from the old schedule's end (0) to lr x (1 - done / new updates) and anneals
    to 0 over the new end. Keeping the old schedule instead would train at rate 0 (nothing
    learned), or at a negative one past its end (the schedule's `1 - done/updates`), and redoing
    the past is not resuming; so the run is not the one that N steps from the start would give.
    `write_extension` records the change in config.json once the programs are ready."""
    old = spec.config.total_timesteps
    if total_timesteps is None or total_timesteps == old:
        return spec
    new_updates = total_timesteps // spec.steps_per_update
    if total_timesteps < old or new_updates <= spec.num_updates:
        why = ("cannot shorten a run" if total_timesteps < old else
               f"adds no update of {spec.steps_per_update} env steps (num_envs x num_steps)")
        raise TrainError(f"cannot resume {run_dir} with --total-timesteps {total_timesteps} (the run: {old}, "
                         f"{spec.num_updates} updates): it {why}; give at least "
                         f"{(spec.num_updates + 1) * spec.steps_per_update} to extend the run, or leave it out")
    config = dataclasses.replace(spec.config, total_timesteps=total_timesteps)
    return dataclasses.replace(spec, config=config)


def write_extension(run_dir: Path, saved: dict, spec: RunSpec) -> dict:
    """Record in `run_dir/config.json` the new length `extended` gave `spec`: the spec's
    total_timesteps and num_updates, and an `extensions` entry (from, to, when) per extension.
    Written whole to a temporary file, then renamed over the old one: a crash leaves either."""
    old = saved["spec"]["config"]["total_timesteps"]
    if spec.config.total_timesteps == old:
        return saved
    saved = json.loads(json.dumps(saved))
    saved["spec"]["config"]["total_timesteps"] = spec.config.total_timesteps
    saved["spec"]["num_updates"] = spec.num_updates
    if isinstance(saved["spec"].get("config_sources"), dict):
        saved["spec"]["config_sources"]["total_timesteps"] = "given"
    saved.setdefault("extensions", []).append({
        "total_timesteps": [old, spec.config.total_timesteps],
        "at": datetime.datetime.now().isoformat(timespec="seconds")})
    path = run_dir / "config.json"
    partial = path.with_name("config.json.partial")
    partial.write_text(json.dumps(saved, indent=2, default=str) + "\n")
    partial.replace(path)
    return saved


def check_counts(args: TrainArgs) -> None:
    """Refuse counts below 1 (a new run's, before anything is built): the loop's sizes."""
    counts = {name: getattr(args, name) for name in ("seeds", "eval_episodes", "env_parts", "eval_every",
                                                      "total_timesteps", "num_envs")}
    counts["num_steps"] = args.config.num_steps
    for name, value in counts.items():
        if value is not None and value < 1:
            raise TrainError(f"--{name.replace('_', '-')} must be at least 1 (got {value})")


def with_eval_every(spec: RunSpec, args: TrainArgs) -> RunSpec:
    """`spec` with its chunk length (`--eval-every`, else about 20 evaluations over the run);
    refuses a run shorter than one rollout (`count_updates`)."""
    try:
        count_updates(spec.config)  # at least one
    except ValueError:
        config = spec.config
        rollout = config.num_envs * config.num_steps
        raise TrainError(f"--total-timesteps {config.total_timesteps} is less than one rollout of {rollout} env "
                         f"steps (num_envs {config.num_envs} x num_steps {config.num_steps}): give "
                         f"--total-timesteps {rollout} or more, or fewer --num-envs or --num-steps") from None
    eval_every = args.eval_every or auto_eval_every(spec.num_updates)
    return dataclasses.replace(spec, eval_every=min(eval_every, spec.num_updates))


def new_run_dir(args: TrainArgs) -> Path:
    """A new run's directory (`--run-dir`, else `default_run_dir`): refused if it holds a run, or
    cannot be created and written (checked now, before anything is built; nothing is left)."""
    run_dir = Path(args.run_dir) if args.run_dir is not None else default_run_dir(args.env_id, args.algo)
    if (run_dir / "config.json").exists():
        raise TrainError(f"{run_dir} already holds a run; continue it with --resume {run_dir} "
                         "or choose another --run-dir")
    reason = unwritable(run_dir)
    if reason is not None:
        where = "--run-dir" if args.run_dir is not None else "the default run directory"
        raise TrainError(f"{where} {run_dir} is not writable ({reason}); choose another --run-dir")
    return run_dir


def args_json(args: TrainArgs) -> dict:
    return json.loads(json.dumps(dataclasses.asdict(args), default=str))


@dataclasses.dataclass
class RunRecord:
    """What a run directory holds, read back: `config.json`, the metric rows, `summary.json`."""

    run_dir: Path
    config: dict
    metrics: list[dict]  # metrics.jsonl: one row per (update, seed)
    evals: list[dict]  # eval.jsonl: one row per (evaluation, seed)
    summary: dict | None  # None until the run has written one


def run_status(run_dir) -> str:
    """`"new"` (no run there), `"finished"` (its summary says complete) or `"partial"`."""
    run_dir = Path(run_dir)
    if not (run_dir / "config.json").is_file():
        return "new"
    try:
        summary = json.loads((run_dir / "summary.json").read_text())
    except (OSError, ValueError):
        return "partial"
    return "finished" if isinstance(summary, dict) and summary.get("complete") else "partial"


def read_run(run_dir) -> RunRecord:
    """The run in `run_dir` (raises `TrainError` when there is none or its files are damaged)."""
    from jaxnat.training.records import read_jsonl

    run_dir = Path(run_dir)
    try:
        config = json.loads((run_dir / "config.json").read_text())
        summary_path = run_dir / "summary.json"
        summary = json.loads(summary_path.read_text()) if summary_path.is_file() else None
        return RunRecord(run_dir, config, read_jsonl(run_dir / "metrics.jsonl"), read_jsonl(run_dir / "eval.jsonl"),
                         summary)
    except (OSError, ValueError) as err:
        raise TrainError(f"cannot read the run in {run_dir}: {err}") from None
