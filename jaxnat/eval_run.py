"""`jaxnat eval RUN_DIR`: play episodes with one seed of a `jaxnat train` run and print the mean
return with its 95% bootstrap interval over episodes (and the accuracy for Classify and
Localize), on the test split by default, as the trainer's evaluation.

    jaxnat eval runs/Classify_Digits-v0-ppo-20250101-120000 --episodes 100 --greedy

The policy is `trained.load_policy`'s; the episodes are `trained.play_episodes`' (each env's
first episode, vmapped, one jitted program); the interval is the report's
(`reproduce.stats.bootstrap_ci`), here over episodes rather than seeds.
"""

from __future__ import annotations

import dataclasses
import inspect
import sys
from pathlib import Path
from typing import Annotated

import jax
import tyro

from jaxnat.trained import SPLITS, LoadError, episode_limit, load_policy, play_episodes

__all__ = ["EvalArgs", "evaluate", "main"]

PROG = "jaxnat eval"


@dataclasses.dataclass
class EvalArgs:
    """Play episodes with one seed of a `jaxnat train` run (its latest checkpoint) and print the
    mean return with its 95% bootstrap interval, and the accuracy for Classify and Localize."""

    run_dir: Annotated[Path, tyro.conf.Positional, tyro.conf.arg(metavar="RUN_DIR")]
    """A run directory that jaxnat train wrote."""
    split: Annotated[str, tyro.conf.arg(metavar="{" + ",".join(SPLITS) + "}")] = "test"
    """The env's data: test (the held-out split, as the trainer evaluates) or train."""
    episodes: int = 100
    """Episodes to play, each one env's first episode (vmapped, in one program)."""
    seed_index: int = 0
    """Which of the run's seeds: 0 .. seeds - 1."""
    greedy: bool = False
    """Take the most likely action (a Gaussian's mean) instead of sampling the policy."""
    key: int = 0
    """The PRNG seed of the episodes: the same key plays the same episodes."""


def evaluate(args: EvalArgs, *, console=None, compiler_options: dict | None = None) -> dict:
    """`jaxnat eval`: load the policy, play `args.episodes` episodes, print and return the mean
    return and terminated fraction (the accuracy for Classify and Localize), each a
    `reproduce.stats.Interval` (the mean with its 95% percentile-bootstrap interval over
    episodes), for Classify `first_guess_accuracy` (the first guess right, chance 1/classes), and
    the mean length. Raises `LoadError`."""
    from rich.console import Console

    from jaxnat.reproduce.stats import bootstrap_ci
    from jaxnat.training.device_backend import split_argument
    from jaxnat.training.records import FIRST_GUESS, shows_first_guess, terminated_label

    console = console or Console()
    if args.episodes < 1:
        raise LoadError(f"--episodes must be at least 1 (got {args.episodes})")
    console.print(f"loading seed index {args.seed_index} of {args.run_dir} ...")
    policy = load_policy(args.run_dir, seed=args.seed_index, split=args.split, compiler_options=compiler_options)
    where = (f"{args.split} split" if split_argument(policy.env_id, policy.env_kwargs)
             else "its one env (no test split)")
    mode = "greedy" if args.greedy else "sampled"
    console.print(f"{policy.algo} on {policy.env_id} · seed {policy.seed_value} · checkpoint at update "
                  f"{policy.update} · {where}")
    with console.status(f"compiling and playing {args.episodes} episodes ({mode} actions)..."):
        episodes = play_episodes(policy, jax.random.key(args.key), args.episodes, greedy=args.greedy)
    label = terminated_label(policy.env_id)
    # The result's keys stay "accuracy" (Classify, Localize) or "terminated"; the display names
    # them plainly (`records.terminated_label`, `records.FIRST_GUESS`).
    key = "accuracy" if policy.env_id.split("/")[0] in ("Classify", "Localize") else "terminated"
    result = {"return": bootstrap_ci(episodes["return"]), key: bootstrap_ci(episodes["terminated"]),
              "length": float(episodes["length"].mean())}
    rows = [("return", result["return"], "+.4f"), (label, result[key], ".1%")]
    if shows_first_guess(policy.env_id):  # right at the first step: an episode of length 1 that terminated
        result["first_guess_accuracy"] = bootstrap_ci(episodes["terminated"] & (episodes["length"] == 1))
        rows.append((FIRST_GUESS, result["first_guess_accuracy"], ".1%"))
    width = max(len(name) for name, *_ in rows)
    console.print(f"{args.episodes} episodes, {mode} actions (mean [95% bootstrap interval]):")
    for name, ci, pattern in rows:
        console.print(f"  {name:<{width}} {ci.mean:{pattern}} [{ci.low:{pattern}}, {ci.high:{pattern}}]")
    console.print(f"  {'length':<{width}} {result['length']:.1f}")
    unfinished = int(episodes["unfinished"].sum())
    if unfinished:
        console.print(f"[dim]{unfinished} of {args.episodes} episodes reached no end within "
                      f"{episode_limit(policy)} steps; their return is what they earned[/dim]")
    return result


def main(argv=None, **options) -> int:
    """`jaxnat eval` with `argv` (default: sys.argv[1:]); returns the exit status. Keyword
    arguments go to `evaluate` (e.g. `compiler_options`)."""
    from jaxnat.cli import exit_status

    argv = sys.argv[1:] if argv is None else list(argv)
    args = tyro.cli(EvalArgs, args=argv, prog=PROG, description=inspect.cleandoc(EvalArgs.__doc__))
    return exit_status(lambda: evaluate(args, **options), LoadError, PROG)


if __name__ == "__main__":
    sys.exit(main())
