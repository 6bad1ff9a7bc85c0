"""Background sources for the compositor: one background frame per env per agent step.

`make_background(kind, num_envs, ...)` gives an object with

- `reset(envs=None)`: envs (a bool mask, or all) start a new background: a new random video at
  a random offset (video), a new random photo (image); nothing for noise and none;
- `frames()`: this step's background of every env as gray levels `uint8[B, H, W]` (through the
  compositor's grayscale law: the compositor composites in gray), or None (black);
- `advance()`: move every env's video on by one frame (called once per agent step);
- `seed(seed)`: restart the random draws (videos, offsets, noise) from `seed`;
- `close()`: stop worker threads.

Videos and images come from the natural-sources module (`jaxnat.natural`), resized to the
emulator's 210x160 and split into train and test by whole files.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np

from jaxnat.atari.compositor import GrayNoiseSampler, grayscale

__all__ = ["BACKGROUNDS", "make_background"]

BACKGROUNDS = ("none", "noise", "video", "image")


class NoBackground:
    """Black, the baseline: the compositor leaves frames as they are. Also the base class: its
    methods are the do-nothing defaults."""

    def reset(self, envs=None) -> None:
        pass

    def frames(self) -> np.ndarray | None:
        return None

    def advance(self) -> None:
        pass

    def seed(self, seed: int) -> None:
        pass

    def close(self) -> None:
        pass


class NoiseBackground(NoBackground):
    """Fresh i.i.d. `clip(N(0,1) * scale, 0)` per pixel and channel, every frame, drawn directly
    as its gray level (`GrayNoiseSampler`: the same law as graying RGB noise).

    The next frame's noise is drawn on a worker thread while the emulator runs (numpy releases
    the GIL), so drawing costs little wall time; one worker draws them in order, so a seed
    gives one sequence.
    """

    def __init__(self, num_envs: int, shape: tuple[int, int], seed: int, scale: float = 50.0):
        self._shape = (num_envs, *shape)
        self._scale = scale
        self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="jaxnat-noise")
        self.seed(seed)

    def frames(self) -> np.ndarray:
        return self._current

    def advance(self) -> None:
        self._current = self._next.result()
        self._next = self._worker.submit(self._sampler.sample, self._shape)

    def seed(self, seed: int) -> None:
        if getattr(self, "_next", None) is not None:
            self._next.result()  # let the worker finish with the old generator
        self._sampler = GrayNoiseSampler(np.random.default_rng(seed), self._scale)
        self._current = self._sampler.sample(self._shape)
        self._next = self._worker.submit(self._sampler.sample, self._shape)

    def close(self) -> None:
        self._worker.shutdown(wait=True)


class BankBackground(NoBackground):
    """Consecutive frames of natural videos, or one still photo per episode (`still`), gray,
    from a `FrameBank` through `jaxnat.natural.HostVideoSampler`."""

    def __init__(self, bank, num_envs: int, seed: int, still: bool = False):
        from jaxnat.natural import HostVideoSampler

        # Gray once, with the compositor's law, so compositing in gray equals compositing in RGB.
        frames = np.asarray(bank.frames)
        gray_frames = np.concatenate(
            [grayscale(frames[i : i + 256]) for i in range(0, len(frames), 256)]
        )[..., None]
        self.bank = bank.replace(frames=gray_frames)
        self.still = still  # photos: one per episode, not a new one every step
        self._sampler = HostVideoSampler(self.bank, num_envs, seed)
        self._current = self._sampler.frames()[..., 0]

    def reset(self, envs=None) -> None:
        self._current = self._sampler.reset(envs)[..., 0]

    def frames(self) -> np.ndarray:
        return self._current

    def advance(self) -> None:
        if not self.still:
            self._current = self._sampler.step()[..., 0]

    def seed(self, seed: int) -> None:
        self._sampler.rng = np.random.default_rng(seed)  # the env's reset() then redraws videos


def make_background(
    kind: str,
    num_envs: int,
    shape: tuple[int, int],
    *,
    split: str = "train",
    sources=None,
    seed: int = 0,
    noise_scale: float = 50.0,
):
    """The background source `kind` (one of `BACKGROUNDS`) for `num_envs` envs of frame `shape`."""
    if kind == "none":
        return NoBackground()
    if kind == "noise":
        return NoiseBackground(num_envs, shape, seed, noise_scale)
    if kind in ("video", "image"):
        from jaxnat import natural

        load = natural.load_videos if kind == "video" else natural.load_images
        bank = load(sources, shape=shape, grayscale=False, split=split)
        return BankBackground(bank, num_envs, seed, still=kind == "image")
    raise ValueError(f"background must be one of {BACKGROUNDS}, got {kind!r}")
