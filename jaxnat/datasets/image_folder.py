"""Your own images, one folder per class:

    root/train/<class>/*.png|jpg|jpeg|bmp
    root/test/<class>/*.png|jpg|jpeg|bmp

Both `train` and `test` must exist and hold the same set of class folders; class names are the
sorted folder names and a label is the index of its folder's name. Within a split, images are
ordered by class, then by file name. Extensions match case-insensitively; other files and names
starting with "." are ignored.

Images are decoded with OpenCV: a grayscale file gives C = 1, a colour file C = 3 in RGB order
(an alpha channel is dropped, 16-bit files are reduced to 8 bits). All images of a split must
share one height, width and channel count; batching them into one array needs that, and
resizing silently would change the data behind your back.

`scan` checks the layout without decoding anything, so `load` can validate the folder and key
its cache on the file list before deciding whether to decode.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import cv2
import numpy as np

from jaxnat.datasets.base import DatasetFormatError, DatasetNotFoundError, ImageDataset

__all__ = ["Scan", "scan", "decode", "EXTENSIONS"]

EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp")
_SPLITS = ("train", "test")
_LAYOUT = ("expected layout: <root>/train/<class>/*.png and <root>/test/<class>/*.png (also "
           ".jpg, .jpeg, .bmp), with the same class folders in train and test")


@dataclasses.dataclass(frozen=True)
class Scan:
    """The files of one split, found by `scan`, in load order, with their labels."""

    root: Path
    split: str
    class_names: tuple[str, ...]
    files: tuple[Path, ...]
    labels: np.ndarray  # int32 [len(files)]


def _visible(path: Path) -> bool:
    return not path.name.startswith(".")


def _class_dirs(split_dir: Path) -> list[str]:
    return sorted(p.name for p in split_dir.iterdir() if p.is_dir() and _visible(p))


def scan(root: str | os.PathLike, split: str) -> Scan:
    """List the images of `split` under `root` and check the layout; decodes nothing."""
    root = Path(root)
    missing = [s for s in _SPLITS if not (root / s).is_dir()]
    if missing:
        raise DatasetNotFoundError(
            f"image_folder: {root} has no {' or '.join(repr(s) for s in missing)} folder; "
            f"{_LAYOUT}")
    classes = {s: _class_dirs(root / s) for s in _SPLITS}
    if classes["train"] != classes["test"]:
        only_train = sorted(set(classes["train"]) - set(classes["test"]))
        only_test = sorted(set(classes["test"]) - set(classes["train"]))
        raise DatasetFormatError(
            f"image_folder: {root}/train and {root}/test must hold the same class folders; "
            f"only in train: {only_train}, only in test: {only_test}")
    class_names = tuple(classes[split])
    if not class_names:
        raise DatasetFormatError(f"image_folder: {root / split} has no class folders; {_LAYOUT}")
    files, labels = [], []
    for label, name in enumerate(class_names):
        found = sorted(p for p in (root / split / name).iterdir()
                       if p.suffix.lower() in EXTENSIONS and p.is_file() and _visible(p))
        files += found
        labels += [label] * len(found)
    if not files:
        raise DatasetFormatError(f"image_folder: no images under {root / split}; {_LAYOUT}")
    return Scan(root=root, split=split, class_names=class_names, files=tuple(files),
                labels=np.asarray(labels, dtype=np.int32))


def _read(path: Path) -> np.ndarray:
    """Decode one file to uint8 [H, W, C] with C = 1 (gray) or 3 (RGB)."""
    # IMREAD_ANYCOLOR keeps grayscale files single-channel and always yields 8-bit data;
    # imdecode (not imread) because imread also fails silently on paths it cannot encode.
    data = np.fromfile(path, dtype=np.uint8)
    image = cv2.imdecode(data, cv2.IMREAD_ANYCOLOR) if data.size else None  # (imdecode asserts on empty input)
    if image is None:
        raise DatasetFormatError(f"image_folder: cannot decode {path} as an image; the file is "
                                 "corrupt or not really a PNG/JPEG/BMP; remove or replace it")
    if image.ndim == 2:
        return image[..., np.newaxis]
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


def decode(found: Scan) -> ImageDataset:
    """Decode every file of `found` into one `ImageDataset` named "image_folder"."""
    first = _read(found.files[0])
    images = np.empty((len(found.files), *first.shape), dtype=np.uint8)
    images[0] = first
    for i, path in enumerate(found.files[1:], start=1):
        image = _read(path)
        if image.shape != first.shape:
            raise DatasetFormatError(
                f"image_folder: {path} is {_describe(image.shape)} but {found.files[0]} (the "
                f"first image) is {_describe(first.shape)}; all images must share one size and "
                "colour mode: resize them (e.g. cv2.resize) and convert them to one mode first")
        images[i] = image
    return ImageDataset(name="image_folder", split=found.split, images=images,
                        labels=found.labels, class_names=found.class_names)


def _describe(shape: tuple[int, ...]) -> str:
    height, width, channels = shape
    return f"{width}x{height} {'grayscale' if channels == 1 else 'RGB'}"
