"""`jaxnat sweep RUN_DIR --param P --values V...`: a generalisation curve. Play episodes with one
seed of a `jaxnat train` run at every strength of a distraction dial (issue 43's "distraction as
a dial"), all strengths in one jitted program, and print per strength the mean return with its
95% bootstrap interval over episodes (and the accuracy for Classify and Localize); the table is
also written as JSON.

    jaxnat sweep runs/Classify_Digits-v0-ppo-20250101-120000 --param noise_sigma --values 0 16 32 64
    # -> runs/.../sweeps/noise_sigma-test-seed0-update2-key0.json

The policy is `trained.load_policy`'s, the episodes `trained.sweep_episodes`' (vmapped over the
strengths and the episodes; every strength plays the same episode keys, so the strengths differ
only in the dial), the interval `jaxnat eval`'s (`reproduce.stats.bootstrap_ci`). At a strength
equal to the run's own, a row is what `jaxnat eval` prints with the same `--key`.

A folder without a run, a run on an env without a dial, a field the dial lacks, and (after the
policy is loaded, before the sweep compiles) a value out of the dial's range are refused in one
line.
"""

from __future__ import annotations

import dataclasses
import inspect
import json
import math
import sys
from pathlib import Path
from typing import Annotated

import jax
import numpy as np
import tyro

from jaxnat.trained import SPLITS, LoadError, load_policy, sweep_episodes

__all__ = ["SweepArgs", "sweep", "main"]

PROG = "jaxnat sweep"


@dataclasses.dataclass
class SweepArgs:
    """Play episodes with one seed of a `jaxnat train` run at every strength of a distraction dial,
    in one jitted program, and print per strength the mean return with its 95% bootstrap interval
    (and the accuracy for Classify and Localize); writes the table as JSON."""

    run_dir: Annotated[Path, tyro.conf.Positional, tyro.conf.arg(metavar="RUN_DIR")]
    """A run directory that jaxnat train wrote."""
    param: str
    """The dial's field to sweep, e.g. noise_sigma (Classify, Localize, PixelMuJoCo) or video_alpha,
    sky_alpha, frame_rate, num_videos (PixelMuJoCo with floor=video)."""
    values: tuple[float, ...]
    """The strengths, e.g. 0 16 32 64."""
    split: Annotated[str, tyro.conf.arg(metavar="{" + ",".join(SPLITS) + "}")] = "test"
    """The env's data: test (the held-out split, as the trainer evaluates) or train."""
    episodes: int = 100
    """Episodes per strength, each one env's first episode (the same keys at every strength)."""
    seed_index: int = 0
    """Which of the run's seeds: 0 .. seeds - 1."""
    greedy: bool = False
    """Take the most likely action (a Gaussian's mean) instead of sampling the policy."""
    key: int = 0
    """The PRNG seed of the episodes: the same key plays the same episodes at every strength."""
    out: Path | None = None
    """The JSON file; default RUN_DIR/sweeps/<param>-<split>-seed<S>-update<U>[-greedy]-key<K>.json."""


def _dial_of(env_id: str) -> tuple[str, ...]:
    """The dial's field names of `env_id`'s params class (`params_type.distraction`), read from
    the registry without building the env; () where it has none."""
    from jaxnat import registration

    try:
        params_type = getattr(registration._load_entry_point(registration.spec(env_id)), "params_type", None)
    except (ImportError, LookupError):
        return ()
    if params_type is None or not hasattr(params_type, "sweep"):
        return ()
    field = {f.name: f for f in dataclasses.fields(params_type)}.get("distraction")
    if field is None or field.default_factory is dataclasses.MISSING:
        return ()
    return tuple(f.name for f in dataclasses.fields(field.default_factory))


def check_args(args: SweepArgs) -> None:
    """Refuse, in one line (`LoadError`), what can be known wrong before loading: the numbers,
    the run folder, an env without a dial, a field the dial lacks, an unwritable `--out`."""
    from jaxnat.cli import unwritable
    from jaxnat.trained import _read_spec
    from jaxnat.training.host_backend import is_host_env

    if args.episodes < 1:
        raise LoadError(f"--episodes must be at least 1 (got {args.episodes})")
    if not args.values:
        raise LoadError("--values needs at least one strength")
    if not all(math.isfinite(v) for v in args.values):
        raise LoadError(f"--values must be finite numbers (got {' '.join(map(str, args.values))})")
    if args.split not in SPLITS:
        raise LoadError(f"split {args.split!r} is not one of {', '.join(SPLITS)}")
    if args.out is not None and args.out.is_dir():
        raise LoadError(f"--out {args.out} is a folder: name a file in it, e.g. {args.out / (args.param + '.json')}")
    spec = _read_spec(Path(args.run_dir))
    if is_host_env(spec.env_id):
        raise LoadError(f"{args.run_dir} trained on {spec.env_id}, emulated on the host: jaxnat sweep "
                        "supports runs on JAX envs only, not yet Natural Atari")
    fields = _dial_of(spec.env_id)
    if not fields:
        raise LoadError(f"{args.run_dir} trained on {spec.env_id}, which has no distraction dial: jaxnat sweep "
                        "needs PixelMuJoCo, Classify or Localize")
    if args.param not in fields:
        raise LoadError(f"{spec.env_id}'s distraction dial has no {args.param!r}; its fields: {', '.join(fields)}")
    folder = args.out.parent if args.out is not None else Path(args.run_dir) / "sweeps"
    why = unwritable(folder)
    if why:
        raise LoadError(f"cannot write the sweep in {folder} ({why}): pass --out with a writable path")


def _strengths(policy, param: str, values) -> np.ndarray:
    """`values` as the dial field's kind: whole numbers for an int field (e.g. frame_rate), where
    they are whole (else floats, which the sweep's own check refuses)."""
    distraction = policy.env_params.distraction
    default = getattr(distraction, param)
    kind = next((str(f.type) for f in dataclasses.fields(distraction) if f.name == param), "")
    whole = isinstance(default, (int, np.integer)) or kind.startswith("int")  # num_videos: int | None
    array = np.asarray(values, np.float32)
    if whole and np.all(array == np.round(array)):
        return array.astype(np.int32)
    return array


def _interval(ci) -> dict:
    return {"mean": ci.mean, "low": ci.low, "high": ci.high, "n": ci.n}


def sweep(args: SweepArgs, *, console=None, compiler_options: dict | None = None) -> dict:
    """`jaxnat sweep`: check the arguments, load the policy, play `args.episodes` episodes at
    every strength (`trained.sweep_episodes`), print the table and write it as JSON. Returns the
    JSON's content plus `path` (where it was written) and `per_episode` (`sweep_episodes`'
    arrays, [strengths, episodes]).
    Raises `LoadError` (one line)."""
    from rich.console import Console

    from jaxnat.reproduce.stats import bootstrap_ci
    from jaxnat.trained import sweep_params
    from jaxnat.training.device_backend import split_argument
    from jaxnat.training.records import terminated_label

    console = console or Console()
    check_args(args)
    console.print(f"loading seed index {args.seed_index} of {args.run_dir} ...")
    policy = load_policy(args.run_dir, seed=args.seed_index, split=args.split, compiler_options=compiler_options)
    strengths = _strengths(policy, args.param, args.values)
    try:  # the sweep's own range checks, before anything compiles
        sweep_params(policy, **{args.param: strengths})
    except ValueError as err:
        raise LoadError(f"--values: {err}") from None
    where = (f"{args.split} split" if split_argument(policy.env_id, policy.env_kwargs)
             else "its one env (no test split)")
    mode = "greedy" if args.greedy else "sampled"
    own = getattr(policy.env_params.distraction, args.param)
    console.print(f"{policy.algo} on {policy.env_id} · seed {policy.seed_value} · checkpoint at update "
                  f"{policy.update} · {where} · trained at "
                  f"{f'{args.param}={own}' if own is not None else f'{args.param} off (the plain env)'}")
    with console.status(f"compiling and playing {args.episodes} episodes at each of {len(strengths)} "
                        f"strengths, in one program ({mode} actions)..."):
        episodes = sweep_episodes(policy, jax.random.key(args.key), args.episodes, greedy=args.greedy,
                                  **{args.param: strengths})
    key = "accuracy" if policy.env_id.split("/")[0] in ("Classify", "Localize") else "terminated"
    rows = []
    for i, value in enumerate(strengths.tolist()):
        rows.append({args.param: value, "return": _interval(bootstrap_ci(episodes["return"][i])),
                     key: _interval(bootstrap_ci(episodes["terminated"][i])),
                     "length": float(episodes["length"][i].mean()),
                     "unfinished": int(episodes["unfinished"][i].sum()),
                     "episode_returns": [float(r) for r in episodes["return"][i]]})
    label = terminated_label(policy.env_id)
    width = max(len(args.param), 8)
    console.print(f"{args.episodes} episodes per strength, {mode} actions, the same episode keys at every "
                  f"strength (mean [95% bootstrap interval]):")
    console.print(f"  {args.param:>{width}}  {'return':<28}  {label}")
    for row in rows:
        r, t = row["return"], row[key]
        console.print(f"  {row[args.param]:>{width}g}  {r['mean']:+.4f} [{r['low']:+.4f}, {r['high']:+.4f}]  "
                      f"{t['mean']:.1%} [{t['low']:.1%}, {t['high']:.1%}]")
    unfinished = sum(row["unfinished"] for row in rows)
    if unfinished:
        console.print(f"[dim]{unfinished} episodes reached no end within "
                      f"{int(policy.env_params.max_steps_in_episode)} steps; their return is what they earned[/dim]")
    result = {"run_dir": str(args.run_dir), "env_id": policy.env_id, "algo": policy.algo,
              "seed_index": policy.seed_index, "seed": policy.seed_value, "update": policy.update,
              "split": args.split, "param": args.param,
              # The run's own strength (None: the dial was off, the plain env).
              "trained_at": float(np.asarray(own)) if own is not None and np.ndim(own) == 0 else None,
              "values": strengths.tolist(), "episodes": args.episodes, "greedy": args.greedy, "key": args.key,
              "common_random_numbers": True, "confidence": 0.95, "rows": rows}
    path = args.out or (Path(args.run_dir) / "sweeps" / (f"{args.param}-{args.split}-seed{policy.seed_value}-update"
                                                         f"{policy.update}{'-greedy' * args.greedy}-key{args.key}.json"))
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(result, indent=1) + "\n")
    print(path)  # the one line a script reads (not wrapped by rich)
    return {**result, "path": path, "per_episode": episodes}


def main(argv=None, **options) -> int:
    """`jaxnat sweep` with `argv` (default: sys.argv[1:]); returns the exit status. Keyword
    arguments go to `sweep` (e.g. `compiler_options`)."""
    from jaxnat.cli import exit_status

    argv = sys.argv[1:] if argv is None else list(argv)
    args = tyro.cli(SweepArgs, args=argv, prog=PROG, description=inspect.cleandoc(SweepArgs.__doc__))
    return exit_status(lambda: sweep(args, **options), LoadError, PROG)


if __name__ == "__main__":
    sys.exit(main())
