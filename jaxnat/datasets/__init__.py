"""Labelled image datasets as numpy arrays: the natural signals behind jaxnat's benchmarks.

    import jaxnat.datasets as d
    ds = d.load("mnist", "train")   # ImageDataset: images uint8 [N, H, W, C], labels int32 [N]

Datasets (`DATASETS`) and their splits ("train", "test"):

- "mnist", "fashion_mnist": the official IDX files (`idx`), 60,000 / 10,000 images, 28x28x1.
- "digits": the 5,000 MNIST digits on OpenCV's sample sheet (`digits`, package opencv-doc),
  padded to 28x28x1, with a fixed stratified 4,000 / 1,000 split.
- "cifar10", "cifar100": the binary or python release (`cifar`), 50,000 / 10,000, 32x32x3.
- "image_folder": your own `root/{train,test}/<class>/*.png` (`image_folder`); needs `root`.

Localization data (photos with a class per pixel, `segmentation.SegmentationDataset`) has its own
loaders: `cityscapes.load(split, root=...)` (the release layout) here, and
`jaxnat.natural.clutter.load(split)` (real objects pasted on natural backgrounds, built from the
embedded data), which lives above this package: `jaxnat.natural` builds on `jaxnat.datasets`,
never the reverse.

Files are found by `locate` (explicit `root`, then `$JAXNAT_DATA_DIR/<name>`, then
~/.cache/jaxnat/data/<name>, then Debian package locations) and fetched by `download`. Decoded
arrays are cached on disk by `cache` (`$JAXNAT_CACHE_DIR`); `load(..., cache=False)` skips it.
Missing files raise `DatasetNotFoundError`, bad files `DatasetFormatError`, each saying what is
wrong and how to fix it.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Callable, Sequence
from pathlib import Path

from jaxnat.datasets import cache as _cache
from jaxnat.datasets import cifar, digits, idx, image_folder, locate
from jaxnat.datasets.base import DatasetFormatError, DatasetNotFoundError, ImageDataset
from jaxnat.datasets.download import download
from jaxnat.datasets.locate import data_dir

__all__ = ["ImageDataset", "DatasetNotFoundError", "DatasetFormatError", "DATASETS", "SPLITS",
           "load", "download", "data_dir"]

DATASETS: tuple[str, ...] = ("mnist", "fashion_mnist", "digits", "cifar10", "cifar100",
                             "image_folder")
SPLITS: tuple[str, ...] = ("train", "test")

# Source.format -> decoder(name, split, files) -> ImageDataset
_DECODERS: dict[str, Callable[[str, str, Sequence[Path]], ImageDataset]] = {
    "idx": idx.load_split,
    "digits": digits.load_split,
    "cifar-bin": cifar.load_binary,
    "cifar-py": cifar.load_python,
}


def load(name: str, split: str = "train", *, root: str | os.PathLike | None = None,
         cache: bool = True) -> ImageDataset:
    """Load one split of a dataset as host numpy arrays.

    `root` is the folder holding the dataset's files (for "image_folder", the folder holding
    `train/` and `test/`); when given, only it is searched. With `cache=True` the decoded arrays
    are stored in, and on later calls read from, the disk cache.
    """
    if name not in DATASETS:
        raise ValueError(f"unknown dataset {name!r}; valid names: {', '.join(DATASETS)}")
    if split not in SPLITS:
        raise ValueError(f"unknown split {split!r}; valid splits: {', '.join(SPLITS)}")
    if name == "image_folder":
        if root is None:
            raise ValueError("load('image_folder') needs root=, the folder holding train/<class>/ "
                             "and test/<class>/ image folders")
        found = image_folder.scan(root, split)
        files, extra = found.files, found.class_names
        decode = functools.partial(image_folder.decode, found)
    else:
        source = locate.find(name, split, root)
        files, extra = source.files, ()
        decode = functools.partial(_DECODERS[source.format], name, split, source.files)
    return _cache.cached(name, split, files, decode, extra) if cache else decode()
