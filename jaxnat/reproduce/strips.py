"""What the agent sees, per family, for the report: a strip of frames from a cell's own env.

For each experiment of a report (Classify, Localize, PixelMuJoCo, Natural Atari) one cell's env
is built on its test split exactly as the cell trains it (its env id and kwargs), reset with a
fixed key and stepped by a uniformly random policy (on Classify, one that never names the right
label, so that the window walks over the image); `STRIP_FRAMES` of its observations, `GAP[x]`
steps apart, are drawn as the human view `jaxnat play` shows (`compat.frames.Frames`: Classify's
window and Localize's footprint in red, the newest frame of a PixelMuJoCo or Natural Atari stack)
and laid side by side in `frames-<experiment>.png`. The frames show the env, not a trained
policy: the same picture for every run of the grid.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from jaxnat.reproduce.grid import Cell

__all__ = ["STRIP_FRAMES", "strip_cell", "draw_strip", "strips_section"]

STRIP_FRAMES = 6
GAP = {"classify": 3, "localize": 1, "mujoco": 10, "atari": 8}  # env steps between two frames shown
MIN_SIDE = 112  # each frame is upscaled (whole pixels) to at least this short side
# A strip shows the natural signal where the grid has it: PixelMuJoCo's video floor, Natural
# Atari's video background (label, values in order of preference).
_PREFERRED = {"mujoco": ("observation", ("video", "checker", "noise")),
              "atari": ("background", ("video", "image", "noise", "none"))}


def strip_cell(cells: list[Cell], experiment: str) -> Cell | None:
    """The cell of `experiment` whose env a strip shows: the first runnable one, for PixelMuJoCo
    the first seen from pixels and for Natural Atari the first on a background (the videos
    first); None when there is none."""
    runnable = [c for c in cells if c.experiment == experiment and not c.skip]
    if experiment in _PREFERRED:
        label, values = _PREFERRED[experiment]
        for value in values:
            chosen = [c for c in runnable if c.labels.get(label) == value]
            if chosen:
                return chosen[0]
        return None
    return runnable[0] if runnable else None


def _device_frames(cell: Cell, count: int, gap: int) -> np.ndarray:
    import jax

    import jaxnat
    from jaxnat.compat.frames import Frames
    from jaxnat.training.device_backend import split_argument

    kwargs = dict(cell.env_kwargs)
    split = split_argument(cell.env_id, kwargs)
    if split is not None:
        kwargs[split] = "test"
    env, params = jaxnat.make(cell.env_id, **kwargs)
    frames = Frames(env, params, batched=True)
    space = env.action_space(params)

    @jax.jit
    def observations(key):
        key_reset, key_steps = jax.random.split(key)
        obs, state = env.reset(key_reset, params)

        def body(carry, key):
            obs, state = carry
            key_act, key_env = jax.random.split(key)
            action = space.sample(key_act)
            if cell.experiment == "classify":  # never the right label: the window walks over the image
                action = action.at[1].set((state.label + 1) % space.nvec[1])
            obs, state, *_ = env.step(key_env, state, action, params)
            return (obs, state), obs

        _, seen = jax.lax.scan(body, (obs, state), jax.random.split(key_steps, (count - 1) * gap))
        return jax.tree.map(lambda first, rest: jax.numpy.concatenate([first[None], rest])[::gap], obs, seen)

    return np.asarray(frames(jax.device_get(observations(jax.random.key(0))), None))


def _host_frames(cell: Cell, count: int, gap: int) -> np.ndarray:
    import jaxnat

    env = jaxnat.make_vec(cell.env_id, 1, split="test", **cell.env_kwargs)
    try:
        rng = np.random.default_rng(0)
        obs, _ = env.reset(seed=0)
        shown = [obs[0]]
        for step in range(1, (count - 1) * gap + 1):
            obs, *_ = env.step(rng.integers(0, env.single_action_space.n, size=1))
            if step % gap == 0:
                shown.append(obs[0])
    finally:
        env.close()
    return np.repeat(np.stack(shown)[..., -1:], 3, axis=-1)  # the newest frame of each stack, grey as RGB


def draw_strip(cell: Cell, path: Path, count: int = STRIP_FRAMES) -> None:
    """Write the strip of `cell`'s env (module docstring) to `path` (PNG). Raises whatever
    building or stepping the env raises (missing data, ale-py)."""
    import matplotlib.image

    gap = GAP[cell.experiment]
    frames = _host_frames(cell, count, gap) if cell.host else _device_frames(cell, count, gap)
    scale = max(1, -(-MIN_SIDE // min(frames.shape[1:3])))
    frames = np.repeat(np.repeat(frames, scale, axis=1), scale, axis=2)
    gutter = np.full((frames.shape[1], 4, 3), 255, np.uint8)
    row = np.concatenate([part for frame in frames for part in (frame, gutter)][:-1], axis=1)
    matplotlib.image.imsave(path, row)


def strips_section(cells: list[Cell], only: tuple[str, ...], out: Path) -> list[str]:
    """The report's "What the agent sees" lines, drawing `frames-<experiment>.png` in `out` for
    each experiment of `only` that has a cell; a strip that cannot be drawn here (its data or
    ale-py missing) is a line saying why."""
    lines = ["## What the agent sees", "",
             f"{STRIP_FRAMES} observations of one cell's env per experiment, on its test split, from a fixed key "
             "under a uniformly random policy (the env, not a trained policy), as `jaxnat play` draws them.", ""]
    drawn = False
    for experiment in only:
        cell = strip_cell(cells, experiment) if experiment in GAP else None
        if cell is None:
            continue
        name = f"frames-{experiment}.png"
        kwargs = " ".join(f"{k}={v}" for k, v in cell.env_kwargs.items())
        caption = f"{cell.env_id}{' (' + kwargs + ')' if kwargs else ''}, every {GAP[experiment]} step" + \
                  ("s" if GAP[experiment] > 1 else "")
        try:
            draw_strip(cell, out / name)
        except Exception as err:  # noqa: BLE001 (a picture must not cost the report)
            lines += [f"- {caption}: not drawn here ({type(err).__name__}: {str(err).splitlines()[0][:200]})"]
            continue
        lines += [f"**{caption}** (`{cell.name}`)", "", f"![{cell.env_id}]({name})", ""]
        drawn = True
    return lines + [""] if drawn or len(lines) > 4 else []
