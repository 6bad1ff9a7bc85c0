"""The training loop: set up or resume a run directory, train chunk by chunk, evaluate, checkpoint, report."""

from __future__ import annotations

import dataclasses
import datetime
import importlib
import json
import platform
import sys
import time
from pathlib import Path
from typing import Any

import jax
import numpy as np

import jaxnat
from jaxnat.training.args import PROG, TrainArgs, TrainError, parse_args, parse_env_kwargs
from jaxnat.training.checkpoints import Checkpoints
from jaxnat.training.host import is_host_run, train_on_host
from jaxnat.training.programs import accepts, compiled_program, make_envs, set_progress_sink
from jaxnat.training.progress import Progress
from jaxnat.training.records import (
    History, json_value, mean_std, nanmean, plot, print_summary, read_jsonl, run_summary, write_jsonl,
)
from jaxnat.training.spec import RunSpec, auto_eval_every, check_algo, resolve_config


@dataclasses.dataclass
class TrainResult:
    run_dir: Path
    runner: Any  # the vmapped RunnerState
    summary: dict
    complete: bool


def _versions() -> dict:
    versions = {"jaxnat": jaxnat.__version__, "jax": jax.__version__, "python": platform.python_version()}
    for name in ("jaxlib", "flax", "optax", "orbax.checkpoint"):
        try:
            versions[name] = importlib.import_module(name).__version__
        except Exception:  # noqa: BLE001 (versions are informative only)
            pass
    versions["device"] = str(jax.devices()[0].device_kind)
    return versions


def _default_run_dir(env_id: str, algo: str) -> Path:
    stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
    return Path("runs") / f"{env_id.replace('/', '_')}-{algo}-{stamp}"


def _check_resume_args(args: TrainArgs, saved: dict) -> None:
    """Arguments given with --resume must match the run's; defaults count as left out."""
    defaults = TrainArgs()
    conflicts = []
    for field in dataclasses.fields(TrainArgs):
        if field.name in ("resume", "run_dir", "config"):
            continue
        value, default = getattr(args, field.name), getattr(defaults, field.name)
        if field.name == "env_kwargs":
            value, default = parse_env_kwargs(value), parse_env_kwargs(default)
        if value != default and value != saved.get(field.name, saved["config"].get(field.name)):
            conflicts.append(f"--{field.name.replace('_', '-')}")
    for field in dataclasses.fields(args.config):
        value = getattr(args.config, field.name)
        if value is not None and value != saved["config"].get(field.name):
            conflicts.append(f"--{field.name.replace('_', '-')}")
    if args.run_dir is not None and Path(args.run_dir).absolute() != Path(args.resume).absolute():
        conflicts.append("--run-dir")
    if conflicts:
        verb = "conflicts" if len(conflicts) == 1 else "conflict"
        raise TrainError(f"{', '.join(conflicts)} {verb} with the config of the run being resumed "
                         f"({Path(args.resume) / 'config.json'}); leave them out")


def _resume(args: TrainArgs):
    """The run `--resume` names: (spec, run_dir, its saved config.json)."""
    run_dir = Path(args.resume)
    config_path = run_dir / "config.json"
    if not config_path.is_file():
        raise TrainError(f"cannot resume {run_dir}: no config.json there")
    saved = json.loads(config_path.read_text())
    if "spec" not in saved:
        raise TrainError(f"cannot resume {run_dir}: it was written without checkpoints (an older jaxnat)")
    _check_resume_args(args, saved["spec"])
    return RunSpec.from_json(saved["spec"]), run_dir, saved


def _check_counts(args: TrainArgs) -> None:
    for name in ("seeds", "eval_episodes"):
        if getattr(args, name) < 1:
            raise TrainError(f"--{name.replace('_', '-')} must be at least 1")
    if args.eval_every is not None and args.eval_every < 1:
        raise TrainError("--eval-every must be at least 1")


def _with_eval_every(spec: RunSpec, args: TrainArgs) -> RunSpec:
    """`spec` with its chunk length (`--eval-every`, else about 20 evaluations over the run)."""
    if spec.num_updates < 1:
        raise TrainError(f"total_timesteps={spec.config.total_timesteps} is less than one rollout "
                         f"(num_envs * num_steps = {spec.steps_per_update})")
    eval_every = args.eval_every or auto_eval_every(spec.num_updates)
    return dataclasses.replace(spec, eval_every=min(eval_every, spec.num_updates))


def _new_run_dir(args: TrainArgs) -> Path:
    run_dir = Path(args.run_dir) if args.run_dir is not None else _default_run_dir(args.env_id, args.algo)
    if (run_dir / "config.json").exists():
        raise TrainError(f"{run_dir} already holds a run; continue it with --resume {run_dir} "
                         "or choose another --run-dir")
    return run_dir


def _setup(args: TrainArgs):
    """(spec, run_dir, the saved config.json when resuming else None)."""
    if args.resume is not None:
        return _resume(args)
    check_algo(args.algo)
    _check_counts(args)
    env_kwargs = parse_env_kwargs(args.env_kwargs)
    # Resolving the trunk needs the observation space: build the env once (cheap; cached data).
    probe = RunSpec(args.env_id, env_kwargs, args.algo, None, args.seeds, args.seed, 1, args.eval_episodes)
    env, params, *_ = make_envs(probe)
    try:
        config = resolve_config(args, env.observation_space(params))
    except TypeError as err:
        raise TrainError(str(err)) from None
    spec = _with_eval_every(dataclasses.replace(probe, config=config), args)
    return spec, _new_run_dir(args), None


def _print_config(console, spec: RunSpec, run_dir: Path) -> None:
    from rich.table import Table

    table = Table(title=f"jaxnat train · {spec.algo} on {spec.env_id}", show_header=False, box=None)
    table.add_column(style="dim")
    table.add_column()
    table.add_row("env kwargs", json.dumps(spec.env_kwargs) if spec.env_kwargs else "—")
    table.add_row("evaluation", f"{spec.eval_episodes} episodes per seed on "
                  f"{'split=test' if accepts(spec.env_id, 'split') else 'the training env (no test split)'}, "
                  f"every {spec.eval_every} updates")
    table.add_row("seeds", f"{spec.seed_values}")
    table.add_row("updates", f"{spec.num_updates} x {spec.steps_per_update} env steps per seed")
    static = {f.name for f in dataclasses.fields(spec.config) if not f.metadata.get("pytree_node", True)}
    for field in dataclasses.fields(spec.config):
        tag = " (static)" if field.name in static else ""
        table.add_row(f"{field.name}{tag}", repr(getattr(spec.config, field.name)))
    table.add_row("run dir", str(run_dir))
    console.print(table)


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

    console = console or Console()
    if is_host_run(args):  # NaturalAtari/*: emulated on the host, a host loop trains
        return train_on_host(args, console, compiler_options, stop_after_chunks)
    session_start = time.perf_counter()
    spec, run_dir, saved = _setup(args)
    _print_config(console, spec, run_dir)
    with console.status("compiling init, training chunk and evaluation programs..."):
        compile_start = time.perf_counter()
        program = compiled_program(spec, compiler_options)
        for length in {spec.eval_every, spec.num_updates % spec.eval_every} - {0}:
            program.chunk(length)
        compile_seconds = time.perf_counter() - compile_start
    console.print(f"[dim]programs ready in {compile_seconds:.1f} s[/dim]")

    run_dir.mkdir(parents=True, exist_ok=True)
    metrics_path, eval_path = run_dir / "metrics.jsonl", run_dir / "eval.jsonl"
    checkpoints = Checkpoints(run_dir / "checkpoints")
    runner = program.init(program.keys())
    prior_wall = 0.0
    if saved is None:
        config_json = {"spec": spec.to_json(), "args": _args_json(args), "versions": _versions(),
                       "created": datetime.datetime.now().isoformat(timespec="seconds"),
                       "command": sys.argv}
        (run_dir / "config.json").write_text(json.dumps(config_json, indent=2) + "\n")
        metrics_path.write_text("")
        eval_path.write_text("")
    if checkpoints.latest_step() is not None:
        runner, meta = checkpoints.restore(runner)
        prior_wall = float(meta.get("wall_time_s", 0.0))
        console.print(f"resumed from checkpoint at update {meta['update']} (chunk {meta['chunk']})")
    update = int(np.asarray(runner.update)[0])
    # Drop records written after the checkpoint (a run stopped between writing and saving).
    metrics_rows = [r for r in read_jsonl(metrics_path) if r["update"] <= update]
    eval_rows = [r for r in read_jsonl(eval_path) if r["update"] <= update]
    write_jsonl(metrics_path, metrics_rows, "w")
    write_jsonl(eval_path, eval_rows, "w")
    history = History.load(spec, metrics_rows, eval_rows)

    seeds = spec.seed_values
    eval_keys = program.eval_keys()

    def evaluate(update: int, chunk_seconds: float | None) -> dict:
        scores = jax.device_get(program.evaluate(runner.train_state.params, eval_keys))
        sps = None if chunk_seconds is None else \
            (update - previous_update) * spec.steps_per_update * spec.seeds / chunk_seconds
        rows = [{"chunk": -(-update // spec.eval_every), "update": update,
                 "env_steps": update * spec.steps_per_update, "seed": seed,
                 **{k: json_value(v[i]) for k, v in scores.items()},
                 "chunk_seconds": chunk_seconds, "steps_per_second": sps}
                for i, seed in enumerate(seeds)]
        write_jsonl(eval_path, rows)
        history.add_eval(update, scores, sps)
        return scores

    previous_update = update
    if not history.evals:  # the untrained policy: the curve's first point
        evaluate(update, None)

    progress = Progress(console, spec, update)
    chunks_done = 0
    interrupted = False
    set_progress_sink(progress)
    try:
        with progress.progress:
            last = history.evals[-1]
            progress.sync(update, _test_field(last))
            while update < spec.num_updates:
                if stop_after_chunks is not None and chunks_done >= stop_after_chunks:
                    break
                n = min(spec.eval_every, spec.num_updates - update)
                chunk = program.chunk(n)
                start = time.perf_counter()
                runner, metrics = chunk(runner)
                metrics = jax.device_get(metrics)
                seconds = time.perf_counter() - start
                previous_update, update = update, update + n
                write_jsonl(metrics_path, (
                    {"update": previous_update + j + 1,
                     "env_steps": (previous_update + j + 1) * spec.steps_per_update, "seed": seed,
                     **{k: json_value(v[i, j]) for k, v in metrics.items()}}
                    for j in range(n) for i, seed in enumerate(seeds)))
                history.add_train(previous_update, metrics)
                scores = evaluate(update, seconds)
                chunk_index = -(-update // spec.eval_every)
                wall = prior_wall + time.perf_counter() - session_start
                checkpoints.save(runner, {"chunk": chunk_index, "update": update,
                                          "env_steps": update * spec.steps_per_update,
                                          "wall_time_s": wall})
                plot(run_dir / "curve.png", spec, history)
                chunks_done += 1
                progress.sync(update, _test_field(history.evals[-1]))
                train_mean, train_std = mean_std(nanmean(metrics["episode_return"], 1))
                greedy, greedy_std = mean_std(scores["greedy_return"])
                accuracy, _ = mean_std(scores["greedy_terminated_fraction"])
                sampled, _ = mean_std(scores["sampled_return"])
                console.print(
                    f"chunk {chunk_index}/{-(-spec.num_updates // spec.eval_every)} · update "
                    f"{update}/{spec.num_updates} · {update * spec.steps_per_update:,} env steps/seed · "
                    f"train return {train_mean:+.3f} ± {train_std:.3f} · test greedy {greedy:+.3f} ± "
                    f"{greedy_std:.3f} (accuracy {accuracy:.1%}) · sampled {sampled:+.3f} · "
                    f"{history.chunk_sps[-1]:,.0f} steps/s")
    except KeyboardInterrupt:
        interrupted = True
    finally:
        set_progress_sink(None)
        checkpoints.close()

    complete = update >= spec.num_updates
    if not history.train["update"] or not (run_dir / "curve.png").exists():
        plot(run_dir / "curve.png", spec, history)
    summary = run_summary(spec, history, prior_wall + time.perf_counter() - session_start, complete)
    (run_dir / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    print_summary(console, summary)
    if not complete:
        why = "interrupted" if interrupted else "stopped"
        console.print(f"{why} at update {update}/{spec.num_updates}; continue with: "
                      f"jaxnat train --resume {run_dir}")
    else:
        console.print(f"run directory: {run_dir}\nlearning curve: {run_dir / 'curve.png'}")
    if interrupted:
        raise KeyboardInterrupt
    return TrainResult(run_dir, runner, summary, complete)


def _test_field(entry: dict) -> str:
    greedy, _ = mean_std(entry["greedy_return"])
    accuracy, _ = mean_std(entry["greedy_terminated_fraction"])
    return f"{greedy:+.3f} ({accuracy:.0%})"


def _args_json(args: TrainArgs) -> dict:
    data = dataclasses.asdict(args)
    return json.loads(json.dumps(data, default=str))




def main(argv=None, **train_options) -> int:
    """`jaxnat train` with `argv` (default: sys.argv[1:]); returns the exit status. Keyword
    arguments go to `train` (e.g. `compiler_options`, `stop_after_chunks`)."""
    args = parse_args(argv)
    try:
        train(args, **train_options)
    except TrainError as err:
        print(f"{PROG}: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
