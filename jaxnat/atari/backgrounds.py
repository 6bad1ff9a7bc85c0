"""Background sources for the compositor: one gray background frame per env per agent step.

`make_background(kind, num_envs, ...)` gives an object with

- `advance()`: move every env on to its next step's background (the next video frame, fresh
  noise). Called once per agent step right after the actions go to ALE, so the work overlaps
  the emulation: it does not depend on how the step ends;
- `reset(envs)`: envs (a bool mask, or every env for None, the env's `reset()`) start a new
  background: a new random video at a random offset (video), a new random photo (image); for
  every env, fresh noise (noise). Returns the backgrounds those envs showed before (gray
  `[n, H, W]`, for the frames that ended their episodes) where a reset changes them, else None;
- `frames()`: this step's gray backgrounds of the whole batch, `uint8[B, H, W]`, or None
  (black); waits for draws still running;
- `seed(seed)`: restart the random draws (videos, offsets, noise) from `seed`, or from one seed
  per group (a sequence: the batch as that many equal groups of envs, each drawing what a
  batch of its envs alone seeded so draws, as the seeds of a run side by side on one batch);
- `close()`.

Backgrounds are gray levels (through the compositor's grayscale law: the compositor composites
in gray). Videos and images come from the natural-sources module (`jaxnat.natural`), resized to
the emulator's 210x160, grayed once when loaded (a step is then one gather of the batch's
frames) and split into train and test by whole files.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from jaxnat.atari.compositor import GrayNoiseSampler, grayscale
from jaxnat.natural.noise import DEFAULT_NOISE, noise_law
from jaxnat.natural.sampler import per_env_values, seed_groups

__all__ = ["BACKGROUNDS", "BACKGROUND_KWARGS", "PER_ENV_KWARGS", "make_background"]

BACKGROUNDS = ("none", "noise", "video", "image")
# The env kwargs that only a background other than "none" takes (its source and its dial).
BACKGROUND_KWARGS = ("video_sources", "noise", "noise_sigma", "video_alpha", "frame_rate", "num_videos")
# Of those, the dial: one value for every env, or a sequence of one per env of the batch.
PER_ENV_KWARGS = ("noise_sigma", "video_alpha", "frame_rate", "num_videos")


class NoBackground:
    """Black, the baseline: the compositor leaves frames as they are. Also the base class: its
    methods are the do-nothing defaults."""

    def advance(self) -> None:
        pass

    def reset(self, envs=None) -> np.ndarray | None:
        return None

    def frames(self) -> np.ndarray | None:
        return None

    def seed(self, seed) -> None:
        pass

    def close(self) -> None:
        pass


class NoiseBackground(NoBackground):
    """Fresh i.i.d. noise per pixel and channel from a pixel-noise law (`law`, a
    `jaxnat.natural.NoiseLaw`; the default `clip(N(0,1) * 50, 0)`), every step, drawn directly
    as its gray level (`GrayNoiseSampler`: the same law as graying RGB noise). Env `i` draws
    from its own generator (seeded from `seed` and `i`), once per step and once per `reset()`,
    so a seed gives one sequence however the batch is chunked.

    The draws cost about as much host time as OpenCV's resize ("noise draws" and "resize" in
    the host pieces of bench/results/natural_atari.md), so they start in `advance`, while ALE
    emulates: on the `runner`'s pool threads, one chunk of envs each, or on the calling thread
    without a pool; `frames` waits for them."""

    def __init__(self, num_envs: int, shape: tuple[int, int], seed: int, law=DEFAULT_NOISE,
                 runner=None, scales=None):
        self.buffer = np.empty((num_envs, *shape), np.uint8)
        self.law = noise_law(law)
        # `scales`: one spread per env (None: the law's own for all), one sampler per value.
        scales = np.broadcast_to(self.law.scale if scales is None else scales, (num_envs,))
        samplers = {float(v): GrayNoiseSampler(scale=float(v), mean=self.law.mean) for v in np.unique(scales)}
        self._samplers = [samplers[float(v)] for v in scales]
        self._runner = runner
        self._drawing = []  # futures of the draws started by advance()
        self.seed(seed)

    def advance(self) -> None:
        self._drawing = self._runner.submit(self._draw) if self._runner is not None else []
        if not self._drawing:  # no pool: draw here, still while ALE emulates
            self._draw(0, len(self.buffer))

    def reset(self, envs=None) -> None:
        if envs is None:  # the env's reset(): a first noise field
            self.advance()

    def frames(self) -> np.ndarray:
        for future in self._drawing:
            future.result()
        self._drawing = []
        return self.buffer

    def _draw(self, lo: int, hi: int) -> None:
        for i in range(lo, hi):
            self._samplers[i].sample(self.buffer.shape[1:], self._rngs[i], out=self.buffer[i])

    def seed(self, seed) -> None:
        self.frames()  # never reseed under running draws
        seeds, size = seed_groups(seed, len(self.buffer))
        self._rngs = [np.random.default_rng(stream) for s in seeds for stream in np.random.SeedSequence(s).spawn(size)]


class BankBackground(NoBackground):
    """Consecutive frames of natural videos, or one still photo per episode (`still`), gray,
    from a `FrameBank` through `jaxnat.natural.HostVideoSampler`; this step's frames are
    gathered into `buffer` (one `np.take` of the batch) by `advance` and `reset`.

    The dial, per env (one number for all, or one per env): `video_alpha` in [0, 1] scales an
    env's frames to `round(alpha * frame)` (the video over black, ALE's background: 1 is the
    frames as they are, 0 black); `frame_rate` and `num_videos` are the sampler's."""

    def __init__(self, bank, num_envs: int, seed: int, still: bool = False, *, video_alpha=1.0,
                 frame_rate=1, num_videos=None):
        from jaxnat.natural import HostVideoSampler

        # Gray once, with the compositor's law, so compositing in gray equals compositing in RGB.
        frames = np.asarray(bank.frames)
        gray_frames = np.concatenate(
            [grayscale(frames[i : i + 256]) for i in range(0, len(frames), 256)]
        )[..., None]
        self.bank = bank.replace(frames=gray_frames)
        self.still = still  # photos: one per episode, not a new one every step
        self._sampler = HostVideoSampler(self.bank, num_envs, seed, frame_rate=frame_rate, num_videos=num_videos)
        alpha = np.broadcast_to(per_env_values("video_alpha", video_alpha, num_envs, low=0.0, high=1.0),
                                (num_envs,))
        self._dimmed = np.flatnonzero(alpha < 1.0)  # the envs whose frames are scaled
        self._alpha = alpha[self._dimmed].astype(np.float32)[:, None, None, None]
        self.buffer = self._dim(self._sampler.frames())  # uint8 [B, H, W, 1]

    def _dim(self, frames: np.ndarray) -> np.ndarray:
        if self._dimmed.size:  # round(alpha * frame); alpha 1 leaves the frames untouched
            frames[self._dimmed] = np.rint(frames[self._dimmed] * self._alpha).astype(np.uint8)
        return frames

    def advance(self) -> None:
        if not self.still:
            self._dim(self._sampler.step(out=self.buffer))

    def reset(self, envs=None) -> np.ndarray | None:
        before = None if envs is None else self.buffer[np.asarray(envs, bool), ..., 0]
        self._dim(self._sampler.reset(envs, out=self.buffer))
        return before

    def frames(self) -> np.ndarray:
        return self.buffer[..., 0]

    def seed(self, seed) -> None:
        self._sampler.seed(seed)  # the env's reset() then redraws videos


def make_background(kind: str, num_envs: int, shape: tuple[int, int], *, split: str = "train", sources=None,
                    seed: int = 0, noise=DEFAULT_NOISE, noise_sigma: float | None = None, runner=None,
                    video_alpha=1.0, frame_rate=1, num_videos=None):
    """The background source `kind` (one of `BACKGROUNDS`) for `num_envs` envs of frame `shape`;
    `noise`: the pixel-noise law of "noise" (a name in `jaxnat.natural.NOISE_LAWS` or a
    `NoiseLaw`), `noise_sigma` its scale when not None (one value, or one per env); `runner`: a `ChunkRunner` whose pool
    threads draw the noise while ALE emulates; `video_alpha`, `frame_rate` ("video" only) and
    `num_videos`: the dial of `BankBackground`, each one number or one per env."""
    if kind == "none":
        return NoBackground()
    if kind == "noise":
        law = noise_law(noise)
        scales = None
        if noise_sigma is not None:
            scales = per_env_values("noise_sigma", noise_sigma, num_envs, low=0.0)
            if np.ndim(scales) == 0:
                law, scales = dataclasses.replace(law, scale=float(scales)), None
        return NoiseBackground(num_envs, shape, seed, law, runner, scales)
    if kind in ("video", "image"):
        from jaxnat import natural

        load = natural.load_videos if kind == "video" else natural.load_images
        bank = load(sources, shape=shape, grayscale=False, split=split)
        return BankBackground(bank, num_envs, seed, still=kind == "image", video_alpha=video_alpha,
                              frame_rate=frame_rate, num_videos=num_videos)
    raise ValueError(f"background must be one of {BACKGROUNDS}, got {kind!r}")
