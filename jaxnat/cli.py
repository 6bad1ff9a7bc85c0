"""The `jaxnat` command: `jaxnat <command> [args]`, one module per command.

    jaxnat train --env-id Classify/Digits-v0 --algo ppo --seeds 5
    jaxnat train --help

Commands are imported only when run, so `jaxnat --help` starts without importing JAX.
"""

from __future__ import annotations

import difflib
import importlib
import sys
from typing import Callable

# name -> (module with `main(argv) -> int | None`, one-line description)
COMMANDS = {
    "train": ("jaxnat.train", "train PPO, A2C, ACKTR or DQN over several seeds; metrics, curves, checkpoints"),
    "eval": ("jaxnat.eval_run", "play a trained run's policy: mean return with a 95% interval, accuracy"),
    "sweep": ("jaxnat.sweep_run", "a generalisation curve: a trained run's return over a grid of distraction strengths"),
    "play": ("jaxnat.play_run", "write a video (MP4 or GIF) of a trained run's policy playing test episodes"),
    "reproduce": ("jaxnat.reproduce.command", "run the paper's experiments (a grid of train runs) and write a findings report"),
    "demo": ("jaxnat.demo", "a random policy over many vmapped Classify/Digits-v0 envs"),
    "envs": ("jaxnat.list_envs", "list the registered env ids by family (also: jaxnat list)"),
}


# Other names users type for a command (`jaxnat list`: what other tools call listing envs).
ALIASES = {"list": "envs"}


def _usage() -> str:
    width = max(map(len, COMMANDS))
    lines = ["usage: jaxnat <command> [args]", "", "commands:"]
    lines += [f"  {name:<{width}}  {description}" for name, (_, description) in COMMANDS.items()]
    lines += ["", "Run `jaxnat <command> --help` for a command's arguments."]
    return "\n".join(lines)


def exit_status(command: Callable[[], object], user_error: type[Exception], prog: str) -> int:
    """Run a command's `command()` and return its exit status: 0; 2 for a `user_error`, printed
    as one line `<prog>: error: <message>`; 130 when interrupted."""
    try:
        command()
    except user_error as err:
        print(f"{prog}: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    return 0


def unwritable(folder) -> str | None:
    """Why `folder` cannot be created and written to (e.g. "Not a directory"), or None when it
    can: creates what is missing of it, writes and deletes a file there, then removes the
    folders it created. What a command checks of its output folder before it starts, so that a
    long run does not fail at its first write."""
    from pathlib import Path

    folder = Path(folder)
    missing = []
    parent = folder
    while not parent.exists() and parent != parent.parent:
        missing.append(parent)
        parent = parent.parent
    created = []
    try:
        for path in reversed(missing):
            path.mkdir()
            created.append(path)
        probe = folder / ".write-test"
        probe.write_text("")
        probe.unlink()
    except OSError as err:
        return err.strerror or str(err)
    finally:
        for path in reversed(created):
            path.rmdir()
    return None


def main(argv=None) -> int:
    """Dispatch `argv` (default: sys.argv[1:]) to a command; returns the exit status."""
    argv = sys.argv[1:] if argv is None else list(argv)
    if not argv or argv[0] in ("-h", "--help", "help"):
        print(_usage(), file=sys.stdout if argv else sys.stderr)
        return 0 if argv else 2
    if argv[0] == "--version":
        from jaxnat import __version__

        print(f"jaxnat {__version__}")
        return 0
    name, rest = ALIASES.get(argv[0], argv[0]), argv[1:]
    if name not in COMMANDS:
        close = difflib.get_close_matches(name, COMMANDS, n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        print(f"jaxnat: error: unknown command {name!r}{hint}; commands: {', '.join(COMMANDS)}",
              file=sys.stderr)
        return 2
    module = importlib.import_module(COMMANDS[name][0])
    status = module.main(rest)
    return 0 if status is None else int(status)


if __name__ == "__main__":
    sys.exit(main())
