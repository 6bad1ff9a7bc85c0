"""`jaxnat play RUN_DIR`: a video (MP4, or GIF with `--format gif`) of one seed of a `jaxnat
train` run playing episodes, to look at what the policy does, not only at its score.

    jaxnat play runs/Classify_Digits-v0-ppo-20250101-120000 --episodes 2 --greedy
    # -> runs/.../videos/test-seed0-update2-greedy-key0.mp4

The episodes are `jaxnat eval`'s: on the test split, `--episodes N --key K` plays the episodes
`jaxnat eval --episodes N --key K` scores (`trained.play_episodes`' keys; `--max-steps` cuts them
shorter). They are laid one after another, each from its first observation to its last: episode
`i` is `length_i + 1` frames (the reset, then one per step), so the video is
`sum(length_i + 1)` frames. A frame is the human view of `compat.frames.Frames` (Classify's
window and Localize's footprint in red on the image, the newest frame of a PixelMuJoCo stack, the
chase camera for a robot seen from its state), each pixel a `--scale`-square block.

A Natural Atari run plays whole games on its host emulator, one after another
(`trained.host_episodes`: the games `jaxnat eval --episodes N --key K` scores), each frame the
newest of the observation's stack, at 15 agent steps a second (4 emulator frames each).

Everything the command line can get wrong (the run folder, the format, an unwritable `--out`)
is refused in one line before the policy is loaded and compiled.
"""

from __future__ import annotations

import dataclasses
import inspect
import math
import sys
from pathlib import Path
from typing import Annotated

import jax
import numpy as np
import tyro

from jaxnat.trained import SPLITS, LoadError, episode_program, host_episodes, load_policy
from jaxnat.video import FORMATS, VideoWriter, require_av, upscale

__all__ = ["PlayArgs", "play", "record_episodes", "main", "MIN_SIDE", "STEP_FPS"]

PROG = "jaxnat play"
MIN_SIDE = 256  # the default --scale makes a frame's short side at least this many pixels
STEP_FPS = 5  # the default --fps of envs without a physical time step (a Classify step is a glance)
CHUNK = 64  # frames drawn at once by the chase camera (one compiled batch size)
ATARI_FPS = 15  # a Natural Atari agent step is 4 emulator frames at 60 per second


@dataclasses.dataclass
class PlayArgs:
    """Write a video of one seed of a `jaxnat train` run (its latest checkpoint) playing
    episodes, one after another, and print its path."""

    run_dir: Annotated[Path, tyro.conf.Positional, tyro.conf.arg(metavar="RUN_DIR")]
    """A run directory that jaxnat train wrote."""
    episodes: int = 2
    """Episodes to play, shown one after another (each one env's first episode)."""
    split: Annotated[str, tyro.conf.arg(metavar="{" + ",".join(SPLITS) + "}")] = "test"
    """The env's data: test (the held-out split, as jaxnat eval plays it) or train."""
    seed_index: int = 0
    """Which of the run's seeds: 0 .. seeds - 1."""
    greedy: bool = False
    """Take the most likely action (a Gaussian's mean) instead of sampling the policy."""
    key: int = 0
    """The PRNG seed of the episodes: the same key plays jaxnat eval's episodes."""
    format: Annotated[str | None, tyro.conf.arg(metavar="{" + ",".join(FORMATS) + "}")] = None
    """mp4 (H.264) or gif; default: --out's suffix, else mp4."""
    out: Path | None = None
    """The video file; default RUN_DIR/videos/<split>-seed<S>-update<U>[-greedy]-key<K>.<format>."""
    fps: int | None = None
    """Frames per second; default the env's simulated time (MuJoCo), else 5 steps a second."""
    max_steps: int | None = None
    """Cut each episode after this many steps; default the env's time limit."""
    scale: int | None = None
    """Each env pixel becomes a scale x scale block; default: a short side of at least 256."""


def _video_format(args: PlayArgs) -> str:
    """The format: `--format`, else `--out`'s suffix, else mp4; a mismatch is a LoadError."""
    suffix = args.out.suffix.lower().lstrip(".") if args.out is not None else ""
    fmt = args.format or (suffix if suffix in FORMATS else "mp4")
    if fmt not in FORMATS:
        raise LoadError(f"unknown format {fmt!r}: --format takes {' or '.join(FORMATS)}")
    if args.out is not None and suffix != fmt:
        raise LoadError(f"--out {args.out} does not end in .{fmt}: name the file .{fmt}"
                        + ("" if args.format else " or pass --format"))
    return fmt


def check_args(args: PlayArgs) -> str:
    """Refuse, in one line (`LoadError`), what can be known wrong before loading: returns the format."""
    from jaxnat.cli import unwritable
    from jaxnat.trained import _read_spec

    if args.out is not None and args.out.is_dir():
        example = args.out / f"episodes.{args.format or 'mp4'}"
        raise LoadError(f"--out {args.out} is a folder: name a file in it, e.g. {example}")
    fmt = _video_format(args)
    for name in ("episodes", "fps", "max_steps", "scale"):
        value = getattr(args, name)
        if value is not None and value < 1:
            raise LoadError(f"--{name.replace('_', '-')} must be at least 1 (got {value})")
    if args.split not in SPLITS:
        raise LoadError(f"split {args.split!r} is not one of {', '.join(SPLITS)}")
    _read_spec(Path(args.run_dir))  # a folder without a run: one line
    folder = args.out.parent if args.out is not None else Path(args.run_dir) / "videos"
    why = unwritable(folder)
    if why:
        raise LoadError(f"cannot write the video in {folder} ({why}): pass --out with a writable path")
    try:
        require_av()
    except ImportError as err:
        raise LoadError(str(err)) from None
    return fmt


def _without_autoreset(env):
    """The env without its outermost `AutoResetWrapper` (the train split's): a video shows an
    episode's last frame, not the next episode's first, and the chase camera reads the robot's
    own state. The test split has none (`autoreset=False`, as the trainer evaluates)."""
    from jaxnat.wrappers.autoreset import AutoResetWrapper

    return env._env if isinstance(env, AutoResetWrapper) else env


def record_episodes(policy, key, num_episodes: int, *, greedy: bool = False, max_steps: int | None = None,
                    reads_state: bool = False):
    """`(seen, episodes)`: each of `num_episodes` envs plays its first episode with `policy` as
    `trained.play_episodes` plays it (the same keys: the same episodes on the test split), in one
    jitted program. `seen[i, t]` is episode `i`'s observation at step `t` (its state when
    `reads_state`), `t = 0` the reset, valid for `t <= episodes["length"][i]`; `episodes` holds
    `play_episodes`' per-episode arrays (`return`, `length`, `terminated`, `unfinished`)."""
    env, env_params = _without_autoreset(policy.env), policy.env_params
    if max_steps is None:
        max_steps = int(env_params.max_steps_in_episode)
    episode = episode_program(policy, max_steps, greedy, env=env, record="state" if reads_state else "obs")
    run = jax.jit(jax.vmap(episode, in_axes=(None, None, None, 0)))
    return jax.device_get(run(policy.params, policy.normalization, env_params, jax.random.split(key, num_episodes)))


class HostFrames:
    """What `_frames_of` draws for a host (Natural Atari) game: the newest grey frame of each
    observation's stack (`[..., h, w, stack]`, oldest first), as RGB."""

    reads_state = False
    timed = True
    fps = ATARI_FPS

    def __call__(self, obs, _state):
        return np.repeat(np.asarray(obs)[..., -1:], 3, axis=-1)


def _frames_of(frames, seen, count: int):
    """The first `count` frames of one episode's `seen`, in chunks of at most `CHUNK` (the chase
    camera's batch is padded to `CHUNK`, so it compiles once)."""
    for start in range(0, count, CHUNK):
        part = jax.tree.map(lambda x: x[start:min(start + CHUNK, count)], seen)
        if not frames.reads_state:
            yield frames(part, None)
            continue
        n = min(CHUNK, count - start)
        padded = jax.tree.map(lambda x: np.concatenate([x, np.repeat(x[-1:], CHUNK - n, axis=0)]), part)
        yield frames(None, padded)[:n]


def default_scale(height: int, width: int, fmt: str) -> int:
    """The smallest scale giving a short side of at least `MIN_SIDE`, made even where the frame
    is odd-sized and the format is mp4 (H.264's yuv420p needs an even width and height)."""
    scale = max(1, math.ceil(MIN_SIDE / min(height, width)))
    if fmt == "mp4" and (height * scale % 2 or width * scale % 2):
        scale += scale % 2
    return scale


def play(args: PlayArgs, *, console=None, compiler_options: dict | None = None) -> dict:
    """`jaxnat play`: check the arguments, load the policy, play and record `args.episodes`
    episodes, write the video and print its path. Returns `path`, `format`, `fps`, `size`
    (height, width), `frames` (the count written) and `episodes` (`record_episodes`' arrays).
    Raises `LoadError` (one line)."""
    from rich.console import Console

    from jaxnat.compat.frames import Frames, RenderError

    console = console or Console()
    fmt = check_args(args)
    console.print(f"loading seed index {args.seed_index} of {args.run_dir} ...")
    policy = load_policy(args.run_dir, seed=args.seed_index, split=args.split, compiler_options=compiler_options)
    mode = "greedy" if args.greedy else "sampled"
    if policy.env_params is None:  # host-emulated (Natural Atari): whole games, one after another
        frames = HostFrames()
        with console.status(f"playing {args.episodes} games ({mode} actions)..."):
            games, episodes = host_episodes(policy, jax.random.key(args.key), args.episodes, greedy=args.greedy,
                                            max_steps=args.max_steps, record=True)
        policy.env.close()
        longest = max(len(game) for game in games)  # one array, as record_episodes': padded past each end
        seen = np.stack([np.concatenate([game, np.repeat(game[-1:], longest - len(game), axis=0)]) for game in games])
    else:
        env = _without_autoreset(policy.env)
        try:
            frames = Frames(env, policy.env_params, batched=True)
        except RenderError as err:
            raise LoadError(f"jaxnat play cannot show {policy.env_id}: {err}") from None
        with console.status(f"compiling and playing {args.episodes} episodes ({mode} actions)..."):
            seen, episodes = record_episodes(policy, jax.random.key(args.key), args.episodes, greedy=args.greedy,
                                             max_steps=args.max_steps, reads_state=frames.reads_state)
    lengths = [int(n) for n in episodes["length"]]
    first = next(_frames_of(frames, jax.tree.map(lambda x: x[0], seen), 1))[0]
    scale = args.scale or default_scale(*first.shape[:2], fmt)
    size = (first.shape[0] * scale, first.shape[1] * scale)
    if fmt == "mp4" and (size[0] % 2 or size[1] % 2):
        raise LoadError(f"--scale {scale} makes {size[0]}x{size[1]} frames; H.264 needs an even height and "
                        "width: pass an even --scale, or --format gif")
    fps = args.fps or (frames.fps if frames.timed else STEP_FPS)
    path = args.out or (Path(args.run_dir) / "videos" / (f"{args.split}-seed{policy.seed_value}-update{policy.update}"
                                                         f"{'-greedy' * args.greedy}-key{args.key}.{fmt}"))
    path.parent.mkdir(parents=True, exist_ok=True)
    with console.status(f"drawing and encoding {sum(lengths) + len(lengths)} frames..."):
        with VideoWriter(path, fmt, fps, size) as video:
            for i, length in enumerate(lengths):
                for part in _frames_of(frames, jax.tree.map(lambda x, i=i: x[i], seen), length + 1):
                    video.write(upscale(part, scale))
    returns = ", ".join(f"{r:+.3g}" for r in episodes["return"])
    console.print(f"{policy.algo} on {policy.env_id} · seed {policy.seed_value} · checkpoint at update "
                  f"{policy.update} · {args.split} split · {mode} actions")
    console.print(f"{len(lengths)} episodes one after another: lengths {', '.join(map(str, lengths))} steps, "
                  f"returns {returns}")
    console.print(f"{video.count} frames of {size[1]}x{size[0]} at {fps} fps")
    print(path)  # the one line a script reads (not wrapped by rich)
    return {"path": path, "format": fmt, "fps": fps, "size": size, "frames": video.count, "episodes": episodes}


def main(argv=None, **options) -> int:
    """`jaxnat play` with `argv` (default: sys.argv[1:]); returns the exit status. Keyword
    arguments go to `play` (e.g. `compiler_options`)."""
    from jaxnat.cli import exit_status

    argv = sys.argv[1:] if argv is None else list(argv)
    args = tyro.cli(PlayArgs, args=argv, prog=PROG, description=inspect.cleandoc(PlayArgs.__doc__))
    return exit_status(lambda: play(args, **options), LoadError, PROG)


if __name__ == "__main__":
    sys.exit(main())
