"""Clutter scenes: real objects pasted with exact masks on natural photos and video frames.

The embedded default of the localization task: it needs no licence, only Debian's `opencv-doc`
and `dataset-fashion-mnist` (`scripts/install_data.sh`).

How a scene of split `split` is built (all draws from one NumPy generator seeded with
`(seed, split)`, so a scene set is a pure function of the seed, the settings and the files):

1. **Background**: a natural source of the split drawn uniformly (a photo or a video of
   `opencv-doc`), a random frame of it, mirrored left to right with probability 1/2, then a
   random crop of 60-100% of its side resized back to `shape` (OpenCV `INTER_AREA`).
2. **Objects**: 2 to 5 (`objects=`) of distinct classes, drawn uniformly among 20 classes:
   **0-9 the handwritten digits** of OpenCV's `digits.png` (`jaxnat.datasets.digits`) and
   **10-19 the Fashion-MNIST items** (T-shirt/top ... Ankle boot, class = 10 + label). Each is
   a random item of that class from the *split's own* part of its dataset (digits: the fixed
   4,000 / 1,000 split; Fashion-MNIST: its official train / t10k files), so train and test
   scenes share no object.
3. Each object's 28x28 intensity image is resized to a random side of 15-30% of the scene's
   short side (bilinear). **Its mask is exactly the pixels whose resized intensity is above
   `THRESHOLD` (= 48 of 255)**; only those pixels are pasted, tinted with a random saturated
   colour (pixel = colour * intensity / 255), and only those get the object's class in the
   class map. Every other pixel is `VOID` (255).
4. Objects never overlap: a position (object fully inside the scene) is drawn up to 50 times
   until its mask, grown by one pixel, touches no earlier object; an object that finds no place
   is left out. So every pasted mask is entirely visible.

Backgrounds (`background_frames`): the natural photos and videos of `opencv-doc` as
`jaxnat.natural` loads them (photos: one of each stereo or sequence pair; videos: at most 600
frames per split), split by whole files by content hash, so no photo or video is in both
splits. `backgrounds=` (a folder, glob or list of photos and/or videos) replaces them, e.g. a
copy of those files on a machine without opencv-doc, or your own clips.

Built scenes are cached on disk like the decoded datasets.

It sits in `jaxnat.natural`, above both the backgrounds and the dataset plumbing it composes
(`jaxnat.datasets` never imports `jaxnat.natural`).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from jaxnat import datasets, natural
from jaxnat.datasets import digits, locate
from jaxnat.datasets.base import DatasetNotFoundError
from jaxnat.datasets.idx import CLASS_NAMES as _IDX_CLASS_NAMES
from jaxnat.datasets.segmentation import VOID, SegmentationDataset, cached
from jaxnat.natural import sources as _natural_sources

__all__ = ["load", "build", "background_frames", "background_files", "object_items", "scene",
           "CLASS_NAMES", "THRESHOLD", "DEFAULT_NUM_IMAGES"]

CLASS_NAMES = tuple(f"digit {d}" for d in digits.CLASS_NAMES) + _IDX_CLASS_NAMES["fashion_mnist"]
THRESHOLD = 48  # object pixels: resized intensity > THRESHOLD (0..255)
DEFAULT_NUM_IMAGES = {"train": 1024, "test": 256}
_SPLITS = ("train", "test")
_ATTEMPTS = 50  # placements tried per object
_MAX_VIDEO_FRAMES = 600  # per split: bounds the memory the build holds (256x256: 112 MiB)


def background_files(sources=None) -> list[Path]:
    """Every file the backgrounds of either split may come from (for the cache key)."""
    if sources is None:
        return [*natural.default_image_paths(), *natural.default_video_paths()]
    return _natural_sources.resolve(
        sources, _natural_sources.IMAGE_EXTENSIONS + _natural_sources.VIDEO_EXTENSIONS)


def background_frames(split: str, shape: tuple[int, int], sources=None) -> natural.FrameBank:
    """The split's natural backgrounds at `shape`: photos (one-frame videos) and the frames of
    videos, split by whole files by content hash (`jaxnat.natural`). The one place they come
    from. `sources` (a folder, glob or list of files) replaces opencv-doc's photos and videos;
    it may hold photos, videos or both."""
    banks = []
    for load, extra in [(natural.load_images, {}),
                        (natural.load_videos, {"max_frames": _MAX_VIDEO_FRAMES})]:
        try:
            banks.append(load(sources, shape=shape, split=split, **extra))
        except DatasetNotFoundError:
            if sources is None:  # opencv-doc's photos and videos are both expected
                raise
    if not banks:
        raise DatasetNotFoundError(f"no background photos or videos of split {split!r} in "
                                   f"{sources!r}")
    return natural.FrameBank.concatenate(banks)


def object_items(split: str):
    """(uint8 [M, 28, 28] intensities, int32 [M] clutter classes) of the split's objects: the
    digits and Fashion-MNIST items its scenes paste (step 2 of the module docstring)."""
    sheet = datasets.load("digits", split)
    fashion = datasets.load("fashion_mnist", split)
    items = np.concatenate([sheet.images[..., 0], fashion.images[..., 0]])
    classes = np.concatenate([sheet.labels, fashion.labels + len(digits.CLASS_NAMES)])
    return items, classes.astype(np.int32)


def _random_colour(rng: np.random.Generator) -> np.ndarray:
    hsv = np.array([[[rng.integers(0, 180), rng.integers(160, 256), 255]]], np.uint8)
    return cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)[0, 0].astype(np.float32)


def _background(rng, bank: natural.FrameBank) -> np.ndarray:
    """A random frame of a random source (photo or video, equally likely), mirrored with
    probability 1/2, and a random crop of 60-100% of its side resized back."""
    source = rng.integers(bank.num_videos)
    frame = bank.frames[bank.starts[source] + rng.integers(bank.lengths[source])]
    if rng.random() < 0.5:
        frame = frame[:, ::-1]
    h, w = frame.shape[:2]
    crop = rng.uniform(0.6, 1.0)
    ch, cw = max(1, int(h * crop)), max(1, int(w * crop))
    top, left = rng.integers(0, h - ch + 1), rng.integers(0, w - cw + 1)
    return cv2.resize(np.ascontiguousarray(frame[top:top + ch, left:left + cw]), (w, h),
                      interpolation=cv2.INTER_AREA)


def scene(rng, bank, items, classes, by_class, objects):
    """One scene (steps 1-4 of the module docstring), drawn from `rng`: a background from `bank`
    (a `natural.FrameBank`) with `objects = (min, max)` items of distinct classes pasted on it.
    `items, classes` are `object_items(split)`; `by_class[c]` the indices of class c's items.
    Returns `(uint8 [H, W, 3] image, uint8 [H, W] class map)`."""
    image = _background(rng, bank)
    h, w = image.shape[:2]
    class_map = np.full((h, w), VOID, np.uint8)
    taken = np.zeros((h, w), bool)
    count = rng.integers(objects[0], objects[1] + 1)
    for cls in rng.choice(len(CLASS_NAMES), size=count, replace=False):
        item = items[rng.choice(by_class[cls])]
        side = int(rng.uniform(0.15, 0.30) * min(h, w))
        intensity = cv2.resize(item, (side, side), interpolation=cv2.INTER_LINEAR)
        mask = intensity > THRESHOLD
        grown = cv2.dilate(mask.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        colour = _random_colour(rng)
        for _ in range(_ATTEMPTS):
            top, left = rng.integers(0, h - side + 1), rng.integers(0, w - side + 1)
            window = (slice(top, top + side), slice(left, left + side))
            if not (taken[window] & grown).any():
                break
        else:
            continue
        tinted = (intensity[..., None].astype(np.float32) * colour / 255.0).round().astype(np.uint8)
        image[window][mask] = tinted[mask]
        class_map[window][mask] = cls
        taken[window] |= mask
    return image, class_map


def build(split: str, *, shape=(256, 256), num_images: int | None = None, objects=(2, 5),
          seed: int = 0, backgrounds=None) -> SegmentationDataset:
    """Build the scenes of `split` (see the module docstring); `load` caches this."""
    if split not in _SPLITS:
        raise ValueError(f"unknown split {split!r}; valid splits: {', '.join(_SPLITS)}")
    lo, hi = objects
    if not 1 <= lo <= hi <= len(CLASS_NAMES):
        raise ValueError(f"objects must be (min, max) with 1 <= min <= max <= {len(CLASS_NAMES)}, "
                         f"got {objects}")
    h, w = shape
    if min(h, w) < 16:
        raise ValueError(f"shape must be at least 16x16 for objects to fit, got {shape}")
    num_images = DEFAULT_NUM_IMAGES[split] if num_images is None else int(num_images)
    if num_images < 1:
        raise ValueError(f"num_images must be >= 1, got {num_images}")
    bank = background_frames(split, (h, w), backgrounds)
    items, classes = object_items(split)
    by_class = [np.flatnonzero(classes == c) for c in range(len(CLASS_NAMES))]
    rng = np.random.default_rng([seed, _SPLITS.index(split)])
    images = np.empty((num_images, h, w, 3), np.uint8)
    maps = np.empty((num_images, h, w), np.uint8)
    for n in range(num_images):
        images[n], maps[n] = scene(rng, bank, items, classes, by_class, (lo, hi))
    return SegmentationDataset("clutter", split, images, maps, CLASS_NAMES)


def load(split: str = "train", *, shape=(256, 256), num_images: int | None = None,
         objects=(2, 5), seed: int = 0, backgrounds=None, cache: bool = True) -> SegmentationDataset:
    """The clutter scenes of `split`, built once and then read from the disk cache.
    `backgrounds`: photos/videos to use instead of opencv-doc's (see `background_frames`)."""
    shape = tuple(int(s) for s in shape)
    objects = tuple(int(o) for o in objects)

    def decode():
        return build(split, shape=shape, num_images=num_images, objects=objects, seed=seed,
                     backgrounds=backgrounds)

    if not cache or split not in _SPLITS:
        return decode()
    files = [*background_files(backgrounds), *locate.find("digits", split).files,
             *locate.find("fashion_mnist", split).files]
    count = DEFAULT_NUM_IMAGES[split] if num_images is None else num_images
    settings = [f"{shape[0]}x{shape[1]}", f"n={count}", f"objects={objects}", f"seed={seed}",
                f"threshold={THRESHOLD}", f"video_frames={_MAX_VIDEO_FRAMES}", "v2"]
    return cached("clutter", split, files, decode, extra=settings)
