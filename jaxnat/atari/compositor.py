"""The background compositor and the frame preprocessing, vectorised over a batch (numba, OpenCV).

Semantics (docs/environments.md section 3): a pixel of the max-pooled RGB frame is background
when all three of its channels are 0; background pixels take the background frame's pixels, on
the RGB frame, before grayscale and resize. A (200, 0, 0) pixel is never replaced (the authors
compared channels separately, which replaced it).

Grayscale is ALE's own law, `round(0.2989 R + 0.5870 G + 0.1140 B)` (the palette grayscale that
ale-py's `grayscale=True` uses); OpenCV's `COLOR_RGB2GRAY` uses 0.299/0.587/0.114 and differs by 1
on about 1% of colours. Grayscale acts pixel by pixel, so `gray(where(mask, bg, frame))` equals
`where(mask, gray(bg), gray(frame))`: backgrounds are turned gray (videos once, when loaded) and
composited in gray, which is exact.

Two pooling orders (the env's `pool`; `docs/design.md`, "Pooling order", says why the mask is
exact): "gray" (default), ale-py pools ALE's gray screens, `max(gray(a), gray(b))`, and the mask
is `gray == 0`, which in ALE's palettes is exactly the all-channels-black RGB mask
(`tests/test_atari.py` checks the palettes and real screens); "rgb", ale-py returns the
max-pooled RGB screen and we turn it gray with the RGB mask (`background_mask`).

Compositing and resizing run fused in one pass (`composite_and_resize`): jaxnat.atari.area's
numba kernel, bit-identical to OpenCV's INTER_AREA; `cv2.resize` for sizes it has no plan for.

The OpenCV calls take a batch `[B, H, W(, C)]` as one tall image `[B*H, W(, C)]`: the
operations are per pixel, or a shrinking resize that keeps the images apart (`resize_area`).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from jaxnat.atari.area import area_plan, check_out, composite_resize
from jaxnat.natural.noise import NoiseLaw

__all__ = [
    "ALE_GRAY_WEIGHTS",
    "background_mask",
    "composite",
    "composite_and_resize",
    "composite_gray",
    "composite_pooled_gray",
    "grayscale",
    "resize_area",
    "FrameStack",
    "GrayNoiseSampler",
]

ALE_GRAY_WEIGHTS = np.array([[0.2989, 0.5870, 0.1140]])  # ALE's ColourPalette::convertGrayscale


def _tall(frames: np.ndarray) -> np.ndarray:
    """`[B, H, W, ...]` -> `[B*H, W, ...]` without copying (frames must be C-contiguous)."""
    frames = np.ascontiguousarray(frames)
    return frames.reshape(-1, *frames.shape[2:])


def background_mask(frames: np.ndarray) -> np.ndarray:
    """`uint8[B, H, W, 3]` RGB -> `bool[B, H, W]`, True where all three channels are 0."""
    b, h, w, _ = frames.shape
    mask = cv2.inRange(_tall(frames), (0, 0, 0), (0, 0, 0))  # 255 where every channel is 0
    return mask.reshape(b, h, w) != 0


def composite(frames: np.ndarray, backgrounds: np.ndarray) -> np.ndarray:
    """RGB compositing, the definition: background pixels of `frames` take `backgrounds`' pixels.

    `frames` and `backgrounds` are `uint8[B, H, W, 3]` (a single `[H, W, 3]` background is shared).
    Returns a new array.
    """
    mask = background_mask(frames)
    return np.where(mask[..., None], backgrounds, frames)


def grayscale(frames: np.ndarray) -> np.ndarray:
    """`uint8[B, H, W, 3]` RGB -> `uint8[B, H, W]` with ALE's grayscale law."""
    b, h, w, _ = frames.shape
    return cv2.transform(_tall(frames), ALE_GRAY_WEIGHTS).reshape(b, h, w)


def composite_gray(frames: np.ndarray, gray_backgrounds: np.ndarray | None = None) -> np.ndarray:
    """`grayscale(composite(frames, backgrounds))` from RGB `frames` `uint8[B, H, W, 3]` and the
    backgrounds' gray levels `gray_backgrounds` `uint8[B, H, W]` (`grayscale(backgrounds)`, or
    gray noise): composited in gray, which is exact because grayscale is per pixel. None: black
    background, plain grayscale."""
    gray = grayscale(frames)
    if gray_backgrounds is not None:
        mask = cv2.inRange(_tall(frames), (0, 0, 0), (0, 0, 0))
        cv2.copyTo(_tall(gray_backgrounds), mask, _tall(gray))  # in place: only masked pixels
    return gray


def composite_pooled_gray(gray: np.ndarray, gray_backgrounds: np.ndarray | None) -> np.ndarray:
    """Composite ale-py's max-pooled gray screens `uint8[B, H, W]` in place: pixels at gray level
    0 (exactly the all-channels-zero RGB pixels, see the module docstring) take
    `gray_backgrounds`' pixels. Returns `gray`."""
    if gray_backgrounds is not None:
        tall = _tall(gray)
        mask = cv2.compare(tall, 0, cv2.CMP_EQ)
        cv2.copyTo(_tall(gray_backgrounds), mask, tall)
    return gray


def _output(out: np.ndarray | None, shape: tuple[int, ...]) -> np.ndarray:
    """A new `uint8[shape]`, or `out` checked to be one that can be written in place."""
    return np.empty(shape, np.uint8) if out is None else check_out(out, shape)


def resize_area(gray: np.ndarray, size: tuple[int, int], out: np.ndarray | None = None) -> np.ndarray:
    """`uint8[B, H, W]` -> `uint8[B, h, w]` with INTER_AREA (as ale-py and Gymnasium resize),
    written into `out` (a C-contiguous `uint8[B, h, w]`, e.g. a frame stack's slot) when given.

    One OpenCV call over the tall image when shrinking rows: each output row then averages
    source rows of one image (image `i`'s rows `[iH, (i+1)H)` map onto output rows
    `[ih, (i+1)h)` exactly; checked against per-image resizing in the tests). Enlarging,
    INTER_AREA interpolates between neighbouring pixels, which would blend adjacent images at
    their edges: one call per image then.
    """
    b, h_in, w_in = gray.shape
    h, w = size
    out = _output(out, (b, h, w))
    if (h_in, w_in) == (h, w):
        np.copyto(out, gray)
        return out
    if h > h_in or w > w_in:  # enlarging: OpenCV interpolates (see above)
        for image, resized in zip(gray, out, strict=True):
            cv2.resize(image, (w, h), dst=resized, interpolation=cv2.INTER_AREA)
        return out
    cv2.resize(_tall(gray), (w, b * h), dst=out.reshape(b * h, w), interpolation=cv2.INTER_AREA)
    return out


def composite_and_resize(gray: np.ndarray, gray_backgrounds: np.ndarray | None,
                         size: tuple[int, int], out: np.ndarray | None = None) -> np.ndarray:
    """`resize_area(composite_pooled_gray(gray, gray_backgrounds), size, out)` without modifying
    `gray`: pixels of `gray` `uint8[B, H, W]` at level 0 take `gray_backgrounds`' (None: none
    do), then INTER_AREA to `size`, into `out` when given. One fused pass of
    `jaxnat.atari.area.composite_resize` where its plan applies (210x160 -> 84x84 does), else
    OpenCV on a copy."""
    plan = area_plan(gray.shape[1:], tuple(size))
    if plan is None:
        return resize_area(composite_pooled_gray(gray.copy(), gray_backgrounds), size, out=out)
    out = _output(out, (gray.shape[0], *plan.dst_shape))
    return composite_resize(gray, gray if gray_backgrounds is None else gray_backgrounds, out, plan)


class FrameStack:
    """The last `depth` frames of each env, handed out channels-last `uint8[B, h, w, depth]`,
    oldest first; a new episode's stack is zeros and then its first frame, as ale-py's.

    Kept in a ring buffer `ring[depth, B, h, w]` (no per-step allocation: each step writes its
    frames into the oldest slot, which becomes the newest) and interleaved with one `cv2.merge`
    of the batch instead of shifting a channels-last array, which would be a strided copy of
    every frame each step ("stack merge" in bench/results/natural_atari.md's host pieces).
    """

    def __init__(self, depth: int):
        self.depth = int(depth)
        self.ring: np.ndarray | None = None
        self.head = 0  # slot of the newest frame

    def allocate(self, num_envs: int, frame_shape: tuple[int, int]) -> None:
        """Zero stacks for `num_envs` envs of `frame_shape` frames."""
        shape = (self.depth, num_envs, *frame_shape)
        if self.ring is None or self.ring.shape != shape:
            self.ring = np.zeros(shape, np.uint8)
        else:
            self.ring.fill(0)
        self.head = self.depth - 1

    def slots(self) -> list[int]:
        """Ring slots, oldest first (the last one is the newest frame)."""
        return [(self.head + 1 + i) % self.depth for i in range(self.depth)]

    def rotate(self) -> np.ndarray:
        """Start a step: the oldest slot becomes the newest; returns it (`[B, h, w]`) for the
        step's frames to be written into."""
        self.head = (self.head + 1) % self.depth
        return self.ring[self.head]

    def clear_older(self, rows) -> None:
        """A new episode for `rows` (a bool mask or indices): every frame but the newest is 0."""
        for slot in self.slots()[:-1]:
            self.ring[slot, rows] = 0

    def observation(self, rows: slice = slice(None), out: np.ndarray | None = None) -> np.ndarray:
        """The stacks of `rows` (a slice of envs), channels-last `uint8[n, h, w, depth]`:
        written into `out[rows]` when given (threads may fill disjoint rows), else new."""
        return self._merge([self.ring[s, rows] for s in self.slots()],
                           None if out is None else out[rows])

    def with_newest(self, rows, frames: np.ndarray) -> np.ndarray:
        """The stacks of `rows` with `frames` (`[n, h, w]`) in place of their newest frame
        (final observations: the frame an episode ended on, after the step's `rotate`)."""
        return self._merge([self.ring[s, rows] for s in self.slots()[:-1]] + [frames])

    def _merge(self, frames: list[np.ndarray], out: np.ndarray | None = None) -> np.ndarray:
        b, h, w = frames[0].shape
        out = _output(out, (b, h, w, self.depth))
        if self.depth == 1:
            np.copyto(out[..., 0], frames[0])
        else:
            cv2.merge([np.ascontiguousarray(f).reshape(b * h, w) for f in frames],
                      out.reshape(b * h, w, self.depth))
        return out


class GrayNoiseSampler:
    """Fresh i.i.d. gray levels of RGB noise pixels, fast: the gray level (ALE's law) of a pixel
    whose three channels are i.i.d. `uint8(clip(mean + N(0, 1) * scale, 0, 255))`
    (`jaxnat.natural.NoiseLaw`; mean 0 and scale 50 are the paper repository's noise, the
    default law `jaxnat.natural.gaussian_noise_np` draws).

    Compositing RGB noise and then turning it gray gives exactly these values, so drawing the
    gray level directly is the same in law at a third of the random numbers and no RGB pass.
    Drawn like `jaxnat.natural`'s noise: 16-bit uniforms through a 65,536-entry table of the
    law's quantiles, so each level's probability is exact to within 2^-16. `law_probabilities`
    is the exact law (the tests compare both samplers with it).
    """

    def __init__(self, rng: np.random.Generator | None = None, scale: float = 50.0,
                 mean: float = 0.0):
        self.rng = rng  # the default generator of `sample`; None: every call passes its own
        cdf = np.cumsum(self.law_probabilities(float(scale), float(mean)))
        u = (np.arange(65536) + 0.5) / 65536
        self._table = np.minimum(np.searchsorted(cdf, u), 255).astype(np.uint8)

    @staticmethod
    def channel_probabilities(scale: float = 50.0, mean: float = 0.0) -> np.ndarray:
        """P(value = k), k = 0..255, of one channel, `uint8(clip(mean + N(0,1) * scale, 0, 255))`."""
        return NoiseLaw("channel", mean, scale).probabilities()

    @classmethod
    def law_probabilities(cls, scale: float = 50.0, mean: float = 0.0) -> np.ndarray:
        """P(gray level = k), k = 0..255, for three independent channels."""
        channel = cls.channel_probabilities(scale, mean)
        levels = np.arange(256, dtype=np.float64)
        g_b = levels[:, None] * 0.5870 + levels[None, :] * 0.1140  # G and B contributions
        p_gb = (channel[:, None] * channel[None, :]).ravel()
        law = np.zeros(256)
        for r in np.flatnonzero(channel > 1e-18):
            gray_levels = np.floor(r * 0.2989 + g_b + 0.5).astype(np.int64).ravel()
            law += channel[r] * np.bincount(gray_levels, weights=p_gb, minlength=256)[:256]
        return law / law.sum()

    def sample(self, shape: tuple[int, ...], rng: np.random.Generator | None = None,
               out: np.ndarray | None = None) -> np.ndarray:
        """Draws of `shape` from `rng` (default: the sampler's), into `out` when given.

        The 16-bit uniforms are the four quarters of the bit generator's raw 64-bit words (each
        uniform and independent), which skips `rng.integers`' bounded-integer work; both numpy
        steps release the GIL, so threads drawing from their own generators run in parallel."""
        rng = self.rng if rng is None else rng
        if rng is None:
            raise ValueError("GrayNoiseSampler.sample needs an rng: pass one, or give the sampler one")
        size = math.prod(shape)
        words = rng.bit_generator.random_raw((size + 3) // 4)
        u = words.view(np.uint16)[:size].reshape(shape)
        return np.take(self._table, u, out=out, mode="clip")  # "clip" writes `out` directly
