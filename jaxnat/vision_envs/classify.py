"""Image classification by navigation: `Classify/*`.

The agent sees a masked image and uncovers it one square window at a time while guessing the
class. Semantics: `docs/environments.md` section 1.

- **Data**: uint8 images `[N, H, W, C]` and int32 labels `[N]` of one official split
  (`split="train"` or `"test"`), held on the device in `params.images` / `params.labels`.
  One trace serves any image of the split.
- **Reset**: an image drawn uniformly from the split. The window (side `w = params.window`,
  always fully inside the image, top-left in `[0, H-w] x [0, W-w]`) starts at a uniformly
  random position (`start="random"`, the paper) or at top-left `(H//2 - w, W//2 - w)`
  (`start="center"`, the authors' code: `(16-w, 16-w)` on 32x32). The window is revealed.
- **Action**: `int32[2] = (move, label)`, space `MultiDiscrete([4, num_classes])`; a value
  outside its range is clipped into it (move 7 is RIGHT, -1 is UP; label 10 of 10 classes is 9).
  `move`: 0 UP, 1 DOWN, 2 LEFT, 3 RIGHT shifts the window by `w` pixels, clamped inside the
  image (UP and LEFT work: the authors' code had them as no-ops). `label`: the guessed class.
- **Step order**: apply the move, reveal the new window, `t += 1`, then judge the label.
- **Reward**: `params.correct_reward` (+1.0) and `terminated` when the label is right, else
  `params.wrong_reward` (-0.1). A perfect agent scores 1.0; an always-wrong one -0.1 * M.
- **Time limit**: `truncated` when `t >= params.max_steps_in_episode` (M, default 20) and the
  step did not terminate. The time limit is never reported as termination.
- **Observation**: uint8 `[H, W, C + 2]`: the image where revealed and 0 elsewhere (channels
  `0..C-1`), the revealed mask (255/0, channel `C`) and the current window (255/0, channel
  `C+1`). The mask channel tells an unrevealed pixel from a black one (the authors used -1).
- **Info**: `{}` (`terminated` already says the label was right).
- **Distraction** (`ClassifyParams.distraction`, `jaxnat.vision_envs.distraction`): additive
  pixel noise `noise_sigma` (default None: off, the plain env bit for bit; 0 draws noise at
  zero strength, the same observations) on the revealed image,
  fresh every step, as a traced param; `params.sweep(noise_sigma=...)` vmaps a difficulty curve.
  `background_alpha` (default None: off, no photos loaded) puts a natural frame behind the
  image: `clip(round(v + (1 - v / 255) * alpha * frame), 0, 255)` per image value `v`, one frame
  per episode from the split's own photos and video frames (`backgrounds=`), drawn at reset
  with the key folded apart (`distraction.BACKGROUND_STREAM`); 0 is the plain env bit for bit.

Example::

    import jax, jaxnat
    env, params = jaxnat.make("Classify/Digits-v0", w=5)
    obs, state = env.reset(jax.random.key(0), params)
    action = env.action_space(params).sample(jax.random.key(1))
    obs, state, reward, terminated, truncated, info = env.step(
        jax.random.key(2), state, action, params)
"""

from __future__ import annotations

import os
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxnat import spaces
from jaxnat.core import Environment, EnvParams, EnvState, is_concrete
from jaxnat.vision_envs.distraction import (
    BACKGROUND_STREAM, ClassifyDistraction, DistractionSweep, background_image, check_distraction, noise_key_data,
    observe_with_noise,
)
from jaxnat.vision_envs.observation import WRITERS, masked_image_observation

__all__ = [
    "Classify", "ClassifyState", "ClassifyParams", "pack_mask", "unpack_mask", "window_mask",
    "UP", "DOWN", "LEFT", "RIGHT", "MOVES",
]

UP, DOWN, LEFT, RIGHT = 0, 1, 2, 3
# (dy, dx) per move, in units of the window side (Localize moves its footprint the same way).
MOVES = np.array([[-1, 0], [1, 0], [0, -1], [0, 1]], dtype=np.int32)
_STARTS = ("random", "center")


@struct.dataclass
class ClassifyState(EnvState):
    image_index: jax.Array  # int32: which image of the split
    label: jax.Array  # int32: its class
    top_left: jax.Array  # int32[2]: (row, col) of the window
    # Pixels uncovered so far, one bit per pixel: bit (c % 32) of word [r, c // 32] is pixel
    # (r, c). Packing cuts the state a step reads and writes from H*W bytes to H*W/8, which
    # matters because a batched step is memory bound. `pack_mask`/`unpack_mask` convert.
    revealed: jax.Array  # uint32[H, ceil(W / 32)]
    # uint32 data of the key of this observation's noise (`distraction.noise_key_data`).
    noise_key: jax.Array = struct.field(default_factory=lambda: jnp.zeros(2, jnp.uint32))
    # int32: the episode's background frame (`params.background`), or None with the background
    # dial off (no leaf: the plain env's state, and its checkpoints, are unchanged).
    background_index: jax.Array | None = None


@struct.dataclass(kw_only=True)
class ClassifyParams(DistractionSweep, EnvParams):
    images: jax.Array  # uint8 [N, H, W, C]
    labels: jax.Array  # int32 [N]
    window: int = 5
    max_steps_in_episode: int = 20
    correct_reward: float = 1.0
    wrong_reward: float = -0.1
    distraction: ClassifyDistraction = struct.field(default_factory=ClassifyDistraction)
    # The natural frames behind the image (`ClassifyDistraction.background_alpha`): a
    # `jaxnat.natural.FrameBank` of uint8 [F, H, W, C] frames, whose manifest a run records; None
    # with that dial off.
    background: Any = None


class Classify(Environment[ClassifyState, ClassifyParams]):
    """Classify an image by moving a window over it (see the module docstring for the spec).

    Args:
        dataset: a name from `jaxnat.datasets.DATASETS` ("mnist", "fashion_mnist", "digits",
            "cifar10", "cifar100", "image_folder") or a loaded `jaxnat.datasets.ImageDataset`.
        split: "train" or "test" (the dataset's official split; train envs never see test
            images).
        start: "random" (the paper) or "center" (the authors' code).
        root: where the dataset lives (else `$JAXNAT_DATA_DIR`, then the Debian packages'
            locations); required for "image_folder".
        image_size: optional `(H, W)` or int to resize every image to at load time.
        w, M: shortcuts accepted by `jaxnat.make`; see `ClassifyParams.window` and
            `max_steps_in_episode`.
        observation_writer: how observations are written, "auto" (the default), "wordwise" or
            "bytewise" (`jaxnat.vision_envs.observation`); the bytes are the same, only the
            speed differs (`bench/classify_throughput.py` compares them).
        noise_sigma: the default `Distraction.noise_sigma`, additive pixel noise (None: the dial
            off, no noise in the program; a number, 0 included: on, sweepable).
        background_alpha: the default `ClassifyDistraction.background_alpha`, a natural photo
            behind the image, in [0, 1] (None: off, no photos loaded; a number, 0 included: on,
            sweepable, the split's photos and video frames loaded).
        backgrounds: where those frames come from: None for Debian's opencv-doc photos and
            video frames (the Clutter scenes' backgrounds, split by whole file: the test split's
            never appear in training), a folder, glob or list of photos and videos, or a
            `jaxnat.natural.FrameBank` of frames already at the image's size.
    """

    params_type = ClassifyParams

    def __init__(
        self,
        dataset="mnist",
        split: str = "train",
        start: str = "random",
        root: str | os.PathLike | None = None,
        image_size: int | tuple[int, int] | None = None,
        w: int | None = None,
        M: int | None = None,
        observation_writer: str = "auto",
        noise_sigma: float | None = None,
        background_alpha: float | None = None,
        backgrounds=None,
    ):
        check_distraction(ClassifyDistraction(noise_sigma=noise_sigma, background_alpha=background_alpha))
        if backgrounds is not None and background_alpha is None:
            raise ValueError("backgrounds= is used by the background dial: pass background_alpha= (0 to 1) too")
        if start not in _STARTS:
            raise ValueError(f"start must be one of {_STARTS}, got {start!r}")
        if observation_writer not in WRITERS:
            raise ValueError(f"observation_writer must be one of {WRITERS}, got "
                             f"{observation_writer!r}")
        if isinstance(dataset, str):
            from jaxnat import datasets

            dataset = datasets.load(dataset, split, root=root)
        images = np.asarray(dataset.images)
        if image_size is not None:
            images = _resize(images, image_size)
        if images.dtype != np.uint8 or images.ndim != 4:
            raise ValueError(f"images must be uint8 [N, H, W, C], got {images.dtype} {images.shape}")
        labels = np.asarray(dataset.labels, dtype=np.int32)
        if labels.shape != images.shape[:1]:
            raise ValueError(f"{labels.shape[0]} labels for {images.shape[0]} images")
        self.dataset_name = dataset.name
        self.split = dataset.split
        self.class_names = tuple(dataset.class_names)
        self.num_classes = len(self.class_names)
        self.start = start
        self.observation_writer = observation_writer
        self.image_shape = images.shape[1:]
        self._window = 5 if w is None else int(w)
        self._max_steps = 20 if M is None else int(M)
        _check_window(self._window, self.image_shape)
        if self._max_steps < 1:
            raise ValueError(f"max_steps_in_episode M={self._max_steps} must be at least 1")
        # Device-resident once; params hand the same buffers to every trace.
        self._images = jnp.asarray(images)
        self._labels = jnp.asarray(labels)
        self._distraction = ClassifyDistraction(noise_sigma=None if noise_sigma is None else float(noise_sigma),
                                                background_alpha=None if background_alpha is None
                                                else float(background_alpha))
        self._background = None if background_alpha is None else _background_bank(
            backgrounds, self.split, self.image_shape).to_device()

    @property
    def name(self) -> str:
        return f"Classify[{self.dataset_name}/{self.split}]"

    def check_params(self, params: ClassifyParams) -> None:
        super().check_params(params)
        if is_concrete(params.window):
            _check_window(int(params.window), self.image_shape)
        check_distraction(params.distraction)
        _check_background(params)

    @property
    def default_params(self) -> ClassifyParams:
        return ClassifyParams(
            images=self._images,
            labels=self._labels,
            window=self._window,
            max_steps_in_episode=self._max_steps,
            distraction=self._distraction,
            background=self._background,
        )

    def observation_space(self, params: ClassifyParams) -> spaces.Box:
        h, w, c = self.image_shape
        return spaces.Box(0, 255, (h, w, c + 2), jnp.uint8)

    def action_space(self, params: ClassifyParams) -> spaces.MultiDiscrete:
        return spaces.MultiDiscrete([4, self.num_classes])

    def reset_env(self, key, params: ClassifyParams):
        key_image, key_pos = jax.random.split(key)
        h, w = self.image_shape[:2]
        side = params.window
        image_index = jax.random.randint(key_image, (), 0, params.images.shape[0])
        if self.start == "random":
            top_left = jax.random.randint(key_pos, (2,), 0, jnp.array([h, w]) - side + 1)
        else:
            top_left = jnp.maximum(jnp.array([h // 2, w // 2]) - side, 0)
        top_left = top_left.astype(jnp.int32)
        state = ClassifyState(
            time=jnp.zeros((), jnp.int32),
            image_index=image_index,
            label=params.labels[image_index],
            top_left=top_left,
            revealed=self._window_bits(top_left, side),
            noise_key=noise_key_data(key),
            background_index=_draw_background(key, params),
        )
        return self.get_obs(state, params), state

    def step_env(self, key, state: ClassifyState, action, params: ClassifyParams):
        # Out-of-range actions are clipped into range per factor (jaxnat's rule for every
        # discrete env: under jit an env cannot raise).
        move, label = jnp.clip(action[0], 0, len(MOVES) - 1), jnp.clip(action[1], 0, self.num_classes - 1)
        h, w = self.image_shape[:2]
        side = params.window
        limit = jnp.array([h, w]) - side
        top_left = jnp.clip(state.top_left + jnp.asarray(MOVES)[move] * side, 0, limit)
        revealed = state.revealed | self._window_bits(top_left, side)
        state = state.replace(top_left=top_left, revealed=revealed, noise_key=noise_key_data(key))
        correct = label == state.label
        reward = jnp.where(correct, params.correct_reward, params.wrong_reward)
        return self.get_obs(state, params), state, reward, correct, {}

    def get_obs(self, state: ClassifyState, params: ClassifyParams) -> jax.Array:
        """uint8 `[H, W, C+2]`: image where revealed (else 0), revealed mask, window."""
        h, w = self.image_shape[:2]
        revealed = unpack_mask(state.revealed, w)
        window = window_mask(state.top_left, params.window, h, w)
        images, index = params.images, state.image_index
        if params.distraction.background_alpha is not None:  # the image over its natural frame
            _check_background(params)
            images = background_image(images[index], params.background.frames[state.background_index],
                                      params.distraction.background_alpha)[None]
            index = 0
        return observe_with_noise(
            lambda images, index: masked_image_observation(
                images, index, revealed, [revealed, window], writer=self.observation_writer),
            images, index, state.noise_key, params.distraction.noise_sigma)

    def _window_bits(self, top_left, side) -> jax.Array:
        """`pack_mask(window_mask(...))`, computed word by word without a reduction."""
        h, w = self.image_shape[:2]
        word_start = 32 * jnp.arange(-(-w // 32))
        low = jnp.clip(top_left[1] - word_start, 0, 32).astype(jnp.uint32)
        high = jnp.clip(top_left[1] + side - word_start, 0, 32).astype(jnp.uint32)
        columns = _low_bits(high) & ~_low_bits(low)
        rows = jnp.arange(h)
        in_rows = (rows >= top_left[0]) & (rows < top_left[0] + side)
        return jnp.where(in_rows[:, None], columns[None, :], jnp.uint32(0))


def _draw_background(key, params: ClassifyParams):
    """The episode's background frame index, from the reset key folded with `BACKGROUND_STREAM`
    (the plain env's draws are untouched), or None with the dial off."""
    if params.distraction.background_alpha is None:
        return None
    _check_background(params)
    return jax.random.randint(jax.random.fold_in(key, BACKGROUND_STREAM), (), 0,
                              params.background.frames.shape[0])


def _check_background(params: ClassifyParams) -> None:
    if params.distraction.background_alpha is not None and params.background is None:
        raise ValueError("background_alpha needs the env's background frames: make the env with "
                         "background_alpha=<0 to 1> (it loads them), then sweep it")


def _background_bank(backgrounds, split: str, image_shape):
    """The `FrameBank` of natural frames behind a split's images, at the images' size and
    channels (grey from RGB by ITU-R 601 luma), its manifest the source files'."""
    import dataclasses

    from jaxnat.natural import FrameBank

    h, w, c = image_shape
    if not isinstance(backgrounds, FrameBank):
        from jaxnat.natural.clutter import background_frames

        backgrounds = background_frames(split, (h, w), backgrounds)
    bank = backgrounds.to_host()
    return dataclasses.replace(bank, frames=_as_channels(np.asarray(bank.frames), image_shape))


def _as_channels(frames: np.ndarray, image_shape) -> np.ndarray:
    """`frames` [F, H, W, 1 or 3] checked against the images' `(H, W, C)` and given C channels."""
    h, w, c = image_shape
    if frames.shape[1:3] != (h, w) or frames.shape[3] not in (1, 3):
        raise ValueError(f"background frames of shape {frames.shape[1:]} for images of {image_shape}: "
                         "give frames at the images' height and width")
    if c == 1 and frames.shape[3] == 3:
        luma = frames.astype(np.float32) @ np.array([0.299, 0.587, 0.114], np.float32)
        frames = np.clip(np.round(luma), 0, 255).astype(np.uint8)[..., None]
    elif c == 3 and frames.shape[3] == 1:
        frames = np.repeat(frames, 3, axis=3)
    elif frames.shape[3] != c:
        raise ValueError(f"background frames have {frames.shape[3]} channels, the images {c}")
    return frames


def _low_bits(n):
    """uint32 with the lowest n bits set, n in 0..32 (XLA shifts by >= 32 give 0, so 32 works)."""
    return jnp.left_shift(jnp.uint32(1), n) - jnp.uint32(1)


def window_mask(top_left, side, height: int, width: int) -> jax.Array:
    """bool[H, W]: True inside the `side` x `side` window whose top-left is `top_left`."""
    rows = jnp.arange(height)[:, None]
    cols = jnp.arange(width)[None, :]
    row0, col0 = top_left[0], top_left[1]
    return (rows >= row0) & (rows < row0 + side) & (cols >= col0) & (cols < col0 + side)


def pack_mask(mask: jax.Array) -> jax.Array:
    """bool[H, W] -> uint32[H, ceil(W/32)], pixel (r, c) at bit c % 32 of word [r, c // 32]."""
    h, w = mask.shape
    words = -(-w // 32)
    padded = jnp.pad(mask, ((0, 0), (0, words * 32 - w))).reshape(h, words, 32)
    weights = jnp.left_shift(jnp.uint32(1), jnp.arange(32, dtype=jnp.uint32))
    # Bits are disjoint, so the sum is the bitwise OR.
    return jnp.sum(padded.astype(jnp.uint32) * weights, axis=-1, dtype=jnp.uint32)


def unpack_mask(bits: jax.Array, width: int) -> jax.Array:
    """uint32[H, ceil(W/32)] -> bool[H, W]; the inverse of `pack_mask`."""
    cols = jnp.arange(width)
    words = bits[:, cols // 32]
    return (jnp.right_shift(words, (cols % 32).astype(jnp.uint32)) & 1).astype(jnp.bool_)


def _check_window(side: int, image_shape) -> None:
    h, w = image_shape[:2]
    if not 1 <= side <= min(h, w):
        raise ValueError(f"window w={side} must be in [1, {min(h, w)}] for {h}x{w} images")


def _resize(images: np.ndarray, image_size) -> np.ndarray:
    import cv2

    h, w = (image_size, image_size) if isinstance(image_size, int) else tuple(image_size)
    if not (isinstance(h, (int, np.integer)) and isinstance(w, (int, np.integer)) and h >= 1 and w >= 1):
        raise ValueError(f"image_size must be a positive int or (H, W) of positive ints, got {image_size!r}")
    out = np.stack([cv2.resize(im, (w, h), interpolation=cv2.INTER_AREA) for im in images])
    return out.reshape(len(images), h, w, images.shape[-1])
