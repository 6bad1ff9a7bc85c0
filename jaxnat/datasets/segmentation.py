"""`SegmentationDataset`: photos with a class per pixel, the data behind `Localize/*`.

Both localization datasets return one: Cityscapes (`cityscapes.py`) and the embedded clutter
scenes (`jaxnat.natural.clutter`). Decoded datasets are cached on disk like the image datasets
(`cache.py`), keyed on their source files and build settings.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np

from jaxnat.datasets import cache as _cache

__all__ = ["SegmentationDataset", "VOID", "cached"]

# The class-map value of pixels that belong to no class (void / ignore): never a goal.
VOID = 255


@dataclasses.dataclass(frozen=True, eq=False)
class SegmentationDataset:
    """One split of photos with per-pixel classes, fully decoded in host memory.

    Contract (checked on construction): `images` is uint8 `[N, H, W, 3]` (RGB), C-contiguous;
    `class_maps` is uint8 `[N, H, W]` with values in `[0, len(class_names))` or `VOID` (255).
    """

    name: str
    split: str
    images: np.ndarray
    class_maps: np.ndarray
    class_names: tuple[str, ...]

    def __post_init__(self) -> None:
        images, maps = self.images, self.class_maps
        where = f"SegmentationDataset({self.name!r}, {self.split!r})"
        if not isinstance(images, np.ndarray) or images.dtype != np.uint8 or images.ndim != 4 \
                or images.shape[-1] != 3:
            raise ValueError(f"{where}: images must be a uint8 RGB array [N, H, W, 3], got "
                             f"{getattr(images, 'dtype', type(images))} {np.shape(images)}")
        if not images.flags.c_contiguous:
            raise ValueError(f"{where}: images must be C-contiguous (use np.ascontiguousarray)")
        if not isinstance(maps, np.ndarray) or maps.dtype != np.uint8 or maps.shape != images.shape[:3]:
            raise ValueError(f"{where}: class_maps must be uint8 [N, H, W] = {images.shape[:3]}, "
                             f"got {getattr(maps, 'dtype', type(maps))} {np.shape(maps)}")
        if not isinstance(self.class_names, tuple) or not 0 < len(self.class_names) < VOID:
            raise ValueError(f"{where}: class_names must be a tuple of 1 to {VOID - 1} names")
        bad = (maps >= len(self.class_names)) & (maps != VOID)
        if bad.any():
            raise ValueError(f"{where}: class map value {maps[bad].max()} is neither a class "
                             f"(0..{len(self.class_names) - 1}) nor VOID ({VOID})")

    @property
    def num_classes(self) -> int:
        return len(self.class_names)

    def presence(self) -> np.ndarray:
        """bool `[N, K]`: whether class k has at least one pixel in image n."""
        k = self.num_classes
        present = np.zeros((len(self.images), k), bool)
        for n, labels in enumerate(self.class_maps):
            counts = np.bincount(labels.ravel(), minlength=VOID + 1)
            present[n] = counts[:k] > 0
        return present


def cached(name: str, split: str, files: Iterable[Path], decode: Callable[[], SegmentationDataset],
           extra: Iterable[str] = ()) -> SegmentationDataset:
    """Return the cached `decode()` of `files` (plus `extra` settings), else decode and cache it."""
    path = _cache.entry_path(name, split, files, ["segmentation", *extra])

    def build(images, class_maps, class_names):
        return SegmentationDataset(name, split, images, class_maps,
                                   tuple(str(c) for c in class_names))

    dataset = _cache.read_arrays(path, ("images", "class_maps", "class_names"), build)
    if dataset is None:
        dataset = decode()
        _cache.write_arrays(path, {"images": dataset.images, "class_maps": dataset.class_maps,
                                   "class_names": np.array(dataset.class_names, dtype=str)})
    return dataset
