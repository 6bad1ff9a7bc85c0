"""Object localization by navigation: `Localize/Cityscapes-v0`, `Localize/Clutter-v0`.

The agent starts at the centre of a natural photo, is told which object class to find, and must
move its footprint onto an object of that class. Semantics: `docs/environments.md`
section 2 (the paper's task; where the authors' code differs, this env follows the paper).

- **Data**: uint8 RGB photos `[N, H, W, 3]` and uint8 class maps `[N, H, W]` (a class id per
  pixel, 255 = void / ignore) of one split, held on the device in `params.images` and
  `params.class_maps`. Cityscapes: `split="train"` is Cityscapes `train`, `split="test"` its
  `val` (Cityscapes `test` has no public labels); 19 training classes by default, or the 30
  annotated classes with `labels="all"` (`jaxnat.datasets.cityscapes`). Clutter: real digits
  and Fashion-MNIST items pasted on natural photos, classes 0-9 digits and 10-19 fashion items
  (`jaxnat.natural.clutter`).
- **Goal**: `params.goals` is bool `[N, K]`: the classes that may be asked for in each image,
  i.e. present in it (at least one pixel), not void, in the `classes` subset, and with no pixel
  under the start footprint (so no episode is won before the first move). Images without such
  a class are dropped when the env is built (`num_dropped` says how many).
- **Reset**: an image drawn uniformly from the split, a goal drawn uniformly among its valid
  classes, the footprint (a `w` x `w` square, `w=10` by default) centred: top-left
  `((H - w) // 2, (W - w) // 2)`.
- **Action**: `Discrete(4)`: 0 UP, 1 DOWN, 2 LEFT, 3 RIGHT moves the footprint by `w` pixels,
  clamped so it stays fully inside the image; an action outside 0..3 is clipped into that range
  (the rule of every discrete jaxnat env: under jit an env cannot raise).
- **Reward**: `params.success_reward` (1.0) and `terminated` when, after the move, the footprint
  covers at least one pixel of the goal class (a one-pixel overlap counts; a goal pixel that
  only touches the footprint's edge or corner from outside does not), else 0.0. The test reads
  exactly the footprint's pixels of the class map (the authors tested a fixed 20x20 box
  against a mis-shaped mask).
- **Time limit**: `truncated` when `t >= params.max_steps_in_episode` (M, default 200) and the
  step did not terminate.
- **Observation**: `{"pixels": uint8[H, W, 4], "goal": int32[]}`: the photo (channels 0-2) and
  the footprint (channel 3, 255 inside, 0 outside), and the goal class id. The paper gives the
  agent the goal; the authors' code never did.
- **Info**: `{}`.
- **Distraction** (`LocalizeParams.distraction`, `jaxnat.vision_envs.distraction`): additive
  pixel noise `noise_sigma` (default None: off, the plain env bit for bit; 0 draws noise at
  zero strength, the same observations) on the photo channels, fresh
  every step, as a traced param; `params.sweep(noise_sigma=...)` vmaps a difficulty curve.
  `background_alpha` (default None: off) scales the scene's background, the class map's void
  pixels, to `round(alpha * value)` (the objects unchanged): 1 is the plain env bit for bit, 0
  the objects on black.

`w` is a constructor argument (static), not a traced param: the footprint's pixels are read
with a `w` x `w` slice, and which images have a valid goal depends on where the start
footprint is.

Example::

    import jax, jaxnat
    env, params = jaxnat.make("Localize/Clutter-v0")
    obs, state = env.reset(jax.random.key(0), params)   # obs["pixels"]: uint8[256, 256, 4]
    obs, state, reward, terminated, truncated, info = env.step(
        jax.random.key(1), state, jax.numpy.int32(3), params)
"""

from __future__ import annotations

import os
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxnat import spaces
from jaxnat.core import Environment, EnvParams, EnvState
from jaxnat.datasets.segmentation import VOID, SegmentationDataset
from jaxnat.vision_envs.classify import DOWN, LEFT, MOVES, RIGHT, UP, window_mask
from jaxnat.vision_envs.distraction import (
    DistractionSweep, LocalizeDistraction, check_distraction, dimmed_background, noise_key_data, observe_with_noise,
)
from jaxnat.vision_envs.observation import WRITERS, masked_image_observation

__all__ = ["Localize", "LocalizeState", "LocalizeParams", "valid_goals",
           "UP", "DOWN", "LEFT", "RIGHT"]

DATASETS = ("cityscapes", "clutter")


@struct.dataclass
class LocalizeState(EnvState):
    image_index: jax.Array  # int32: which image of the split
    goal: jax.Array  # int32: the class to find
    top_left: jax.Array  # int32[2]: (row, col) of the footprint
    # uint32 data of the key of this observation's noise (`distraction.noise_key_data`).
    noise_key: jax.Array = struct.field(default_factory=lambda: jnp.zeros(2, jnp.uint32))


@struct.dataclass(kw_only=True)
class LocalizeParams(DistractionSweep, EnvParams):
    images: jax.Array  # uint8 [N, H, W, 3]
    class_maps: jax.Array  # uint8 [N, H, W], VOID = 255
    goals: jax.Array  # bool [N, K]: classes that may be the goal in each image
    max_steps_in_episode: int = 200
    success_reward: float = 1.0
    distraction: LocalizeDistraction = struct.field(default_factory=LocalizeDistraction)


class Localize(Environment[LocalizeState, LocalizeParams]):
    """Find an object of the goal class by moving a footprint (the module docstring is the spec).

    Args:
        dataset: "cityscapes", "clutter", or a loaded `SegmentationDataset`.
        split: "train" or "test" (Cityscapes: `val`; "val" is accepted too).
        w: side of the footprint and length of a move, in pixels (static).
        M: shortcut for `LocalizeParams.max_steps_in_episode` (default 200).
        classes: optional subset of goal classes (names or ids); others are never asked for.
        root: Cityscapes: the folder holding `leftImg8bit/` and `gtFine/` (else
            `$JAXNAT_DATA_DIR/cityscapes`).
        image_size: int or `(H, W)` of the photos of a named dataset (default 256x256).
        labels: Cityscapes only: "train" (19 training classes, the default) or "all" (30).
        num_images, objects, seed: Clutter only: how many scenes to build for the split
            (default 1024 train, 256 test), (min, max) objects per scene (default (2, 5)), and
            the seed they are built from.
        backgrounds: Clutter only: photos and/or videos (a folder, glob or list) to paste the
            objects on, instead of opencv-doc's.
        observation_writer: how `pixels` is written, "auto" (the default), "wordwise" or
            "bytewise" (`jaxnat.vision_envs.observation`); the bytes are the same, only the
            speed differs (`bench/localize_throughput.py` compares them).
        noise_sigma: the default `Distraction.noise_sigma`, additive pixel noise (None: the dial
            off, no noise in the program; a number, 0 included: on, sweepable).
        background_alpha: the default `LocalizeDistraction.background_alpha`, how much of the
            scene's natural background shows, in [0, 1] (None: off, the plain scene; 1 the
            same; 0 the objects on black; a number: on, sweepable).
    """

    params_type = LocalizeParams

    def __init__(
        self,
        dataset="clutter",
        split: str = "train",
        w: int = 10,
        M: int | None = None,
        classes: Sequence[str | int] | None = None,
        root: str | os.PathLike | None = None,
        image_size: int | tuple[int, int] | None = None,
        labels: str | None = None,
        num_images: int | None = None,
        objects: tuple[int, int] | None = None,
        seed: int | None = None,
        backgrounds: str | os.PathLike | Sequence[str | os.PathLike] | None = None,
        observation_writer: str = "auto",
        noise_sigma: float | None = None,
        background_alpha: float | None = None,
    ):
        check_distraction(LocalizeDistraction(noise_sigma=noise_sigma, background_alpha=background_alpha))
        if observation_writer not in WRITERS:
            raise ValueError(f"observation_writer must be one of {WRITERS}, got "
                             f"{observation_writer!r}")
        if isinstance(dataset, str):
            image_size = 256 if image_size is None else image_size
            dataset = _load(dataset, split, root=root, image_size=image_size, labels=labels,
                            num_images=num_images, objects=objects, seed=seed,
                            backgrounds=backgrounds)
        elif not isinstance(dataset, SegmentationDataset):
            raise TypeError(f"dataset must be one of {DATASETS} or a SegmentationDataset, got "
                            f"{type(dataset).__name__}")
        elif image_size is not None:
            raise ValueError("image_size applies to the named datasets; a SegmentationDataset is "
                             "used at its own size")
        h, width = dataset.images.shape[1:3]
        self.footprint = int(w)
        if not 1 <= self.footprint <= min(h, width):
            raise ValueError(f"footprint w={w} must be in [1, {min(h, width)}] for {h}x{width} images")
        self.dataset_name = dataset.name
        self.split = dataset.split
        self.class_names = dataset.class_names
        self.num_classes = dataset.num_classes
        self.image_shape = (h, width)
        self.start = ((h - self.footprint) // 2, (width - self.footprint) // 2)
        goals = valid_goals(dataset, self.start, self.footprint, _class_subset(classes, dataset))
        keep = goals.any(axis=1)
        if not keep.any():
            raise ValueError(f"no image of {dataset.name}/{dataset.split} has a goal class "
                             f"{'among ' + repr(classes) + ' ' if classes else ''}outside the "
                             f"start footprint; choose other classes or a smaller w")
        self.num_dropped = int((~keep).sum())
        self._max_steps = 200 if M is None else int(M)
        self.observation_writer = observation_writer
        self._images = jnp.asarray(dataset.images[keep])
        self._class_maps = jnp.asarray(dataset.class_maps[keep])
        self._goals = jnp.asarray(goals[keep])
        self._distraction = LocalizeDistraction(noise_sigma=None if noise_sigma is None else float(noise_sigma),
                                                background_alpha=None if background_alpha is None
                                                else float(background_alpha))

    @property
    def name(self) -> str:
        return f"Localize[{self.dataset_name}/{self.split}]"

    @property
    def default_params(self) -> LocalizeParams:
        return LocalizeParams(images=self._images, class_maps=self._class_maps, goals=self._goals,
                              max_steps_in_episode=self._max_steps, distraction=self._distraction)

    def check_params(self, params: LocalizeParams) -> None:
        super().check_params(params)
        check_distraction(params.distraction)

    def observation_space(self, params: LocalizeParams) -> spaces.Dict:
        h, w = self.image_shape
        return spaces.Dict({"pixels": spaces.Box(0, 255, (h, w, 4), jnp.uint8),
                            "goal": spaces.Discrete(self.num_classes)})

    def action_space(self, params: LocalizeParams) -> spaces.Discrete:
        return spaces.Discrete(4)

    def reset_env(self, key, params: LocalizeParams):
        key_image, key_goal = jax.random.split(key)
        image_index = jax.random.randint(key_image, (), 0, params.images.shape[0])
        valid = params.goals[image_index]
        goal = jax.random.categorical(key_goal, jnp.where(valid, 0.0, -jnp.inf))
        state = LocalizeState(
            time=jnp.zeros((), jnp.int32),
            image_index=image_index,
            goal=goal.astype(jnp.int32),
            top_left=jnp.array(self.start, jnp.int32),
            noise_key=noise_key_data(key),
        )
        return self.get_obs(state, params), state

    def step_env(self, key, state: LocalizeState, action, params: LocalizeParams):
        side = self.footprint
        limit = jnp.array(self.image_shape) - side
        move = jnp.clip(action, 0, len(MOVES) - 1)  # out of range: clipped (every discrete env's rule)
        top_left = jnp.clip(state.top_left + jnp.asarray(MOVES)[move] * side, 0, limit)
        state = state.replace(top_left=top_left, noise_key=noise_key_data(key))
        under = jax.lax.dynamic_slice(params.class_maps[state.image_index], top_left, (side, side))
        found = jnp.any(under == state.goal)
        reward = jnp.where(found, params.success_reward, 0.0)
        return self.get_obs(state, params), state, reward, found, {}

    def get_obs(self, state: LocalizeState, params: LocalizeParams) -> dict:
        """`{"pixels": uint8[H, W, 4] (photo, footprint 255/0), "goal": int32[]}`."""
        h, w = self.image_shape
        footprint = window_mask(state.top_left, self.footprint, h, w)
        everywhere = jnp.ones((h, w), jnp.bool_)
        images, index = params.images, state.image_index
        if params.distraction.background_alpha is not None:  # the scene's background dimmed
            images = dimmed_background(images[index], params.class_maps[index] == VOID,
                                       params.distraction.background_alpha)[None]
            index = 0
        pixels = observe_with_noise(
            lambda images, index: masked_image_observation(
                images, index, everywhere, [footprint], writer=self.observation_writer),
            images, index, state.noise_key, params.distraction.noise_sigma)
        return {"pixels": pixels, "goal": state.goal}


def valid_goals(dataset: SegmentationDataset, start: tuple[int, int], side: int,
                subset: np.ndarray | None = None) -> np.ndarray:
    """bool `[N, K]`: class k may be the goal in image n: present, not under the `side` x `side`
    start footprint at `start`, and in `subset` (bool `[K]`, default all). Void is no class."""
    k = dataset.num_classes
    goals = dataset.presence()
    r, c = start
    for n, patch in enumerate(dataset.class_maps[:, r:r + side, c:c + side]):
        under = np.unique(patch)
        goals[n, under[under < k]] = False
    if subset is not None:
        goals &= subset[None, :]
    return goals


def _class_subset(classes, dataset: SegmentationDataset) -> np.ndarray | None:
    if classes is None:
        return None
    if isinstance(classes, (str, int)):
        classes = [classes]
    subset = np.zeros(dataset.num_classes, bool)
    for c in classes:
        if isinstance(c, str) and c in dataset.class_names:
            subset[dataset.class_names.index(c)] = True
        elif isinstance(c, (int, np.integer)) and not isinstance(c, bool) and 0 <= c < dataset.num_classes:
            subset[int(c)] = True
        else:
            raise ValueError(f"unknown class {c!r} for {dataset.name}; classes are names or ids "
                             f"0..{dataset.num_classes - 1}: {', '.join(dataset.class_names)}")
    return subset


def _load(name: str, split: str, *, root, image_size, labels, num_images, objects, seed,
          backgrounds) -> SegmentationDataset:
    if name not in DATASETS:
        raise ValueError(f"unknown localization dataset {name!r}; choose one of {DATASETS} or "
                         "pass a SegmentationDataset")
    size = (image_size, image_size) if isinstance(image_size, int) else tuple(image_size)
    if name == "cityscapes":
        if any(x is not None for x in (num_images, objects, seed, backgrounds)):
            raise ValueError("num_images, objects, seed and backgrounds are options of the clutter "
                             "dataset; Cityscapes is a fixed release")
        from jaxnat.datasets import cityscapes

        return cityscapes.load(split, root=root, shape=size, labels=labels or "train")
    if labels is not None or root is not None:
        raise ValueError("labels and root are options of Cityscapes; the clutter scenes are built "
                         "from the embedded opencv-doc and Fashion-MNIST data")
    from jaxnat.natural import clutter

    options = {k: v for k, v in [("num_images", num_images), ("objects", objects), ("seed", seed),
                                 ("backgrounds", backgrounds)] if v is not None}
    return clutter.load(split, shape=size, **options)

