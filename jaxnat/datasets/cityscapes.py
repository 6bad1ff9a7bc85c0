"""Cityscapes fine annotations as a `SegmentationDataset`, from the standard release layout.

Expected under the dataset folder (the two archives `leftImg8bit_trainvaltest.zip` and
`gtFine_trainvaltest.zip` from https://www.cityscapes-dataset.com unpack to exactly this)::

    leftImg8bit/{train,val}/<city>/<city>_<seq>_<frame>_leftImg8bit.png
    gtFine/{train,val}/<city>/<city>_<seq>_<frame>_gtFine_labelIds.png

The folder is the explicit `root`, else `$JAXNAT_DATA_DIR/cityscapes`, else
`~/.cache/jaxnat/data/cityscapes` (the first that holds `leftImg8bit/<split>`). Cityscapes
needs a (free) registration, so jaxnat cannot download it for you.

- **Splits**: `split="train"` reads `train` (2,975 photos); `"test"` (or `"val"`) reads `val`
  (500): Cityscapes' own `test` split has no public labels.
- **Photos** are resized to `shape` (default 256x256) with area interpolation (OpenCV
  `INTER_AREA`), RGB; **label maps** with nearest neighbour, so every pixel keeps a real label.
- **Classes** (`labels=`): `"train"` (default) maps label ids to Cityscapes' 19 training
  classes (its `trainId`s: road, sidewalk, building, ... bicycle); `"all"` keeps the 30 classes
  the Cityscapes site lists (label ids 4-33, class id = label id - 4; including ground, dynamic,
  static, parking, rail track, guard rail, bridge, tunnel, polegroup, caravan, trailer, which the
  benchmark treats as void). Pixels of unlabeled, ego vehicle, rectification border, out of ROI
  (ids 0-3), license plate, and in `"train"` every class without a trainId, become `VOID` (255)
  and are never goals.
- Decoded arrays are cached (`jaxnat.datasets.segmentation.cached`), keyed on every file's
  path, size and mtime, the shape and the label set; the first decode runs on all cores.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import cv2
import numpy as np

from jaxnat.datasets import locate
from jaxnat.datasets.base import DatasetFormatError, DatasetNotFoundError
from jaxnat.datasets.segmentation import VOID, SegmentationDataset, cached

__all__ = ["load", "find_files", "LABEL_NAMES", "TRAIN_IDS", "LABEL_SETS", "class_names",
           "label_table"]

# Cityscapes label id -> name, ids 0..33 (cityscapesscripts/helpers/labels.py).
LABEL_NAMES = (
    "unlabeled", "ego vehicle", "rectification border", "out of roi", "static", "dynamic",
    "ground", "road", "sidewalk", "parking", "rail track", "building", "wall", "fence",
    "guard rail", "bridge", "tunnel", "pole", "polegroup", "traffic light", "traffic sign",
    "vegetation", "terrain", "sky", "person", "rider", "car", "truck", "bus", "caravan",
    "trailer", "train", "motorcycle", "bicycle",
)
# The 19 training classes, in trainId order, as label ids.
TRAIN_IDS = (7, 8, 11, 12, 13, 17, 19, 20, 21, 22, 23, 24, 25, 26, 27, 28, 31, 32, 33)
_FIRST_ANNOTATED = 4  # ids 0-3 are unlabeled / ego vehicle / rectification border / out of roi
LABEL_SETS = ("train", "all")
_SPLIT_DIRS = {"train": "train", "test": "val", "val": "val"}
_PHOTO_SUFFIX = "_leftImg8bit.png"
_LABEL_SUFFIX = "_gtFine_labelIds.png"


def class_names(labels: str = "train") -> tuple[str, ...]:
    """The class names of a label set, in class-id order."""
    _check_labels(labels)
    ids = TRAIN_IDS if labels == "train" else range(_FIRST_ANNOTATED, len(LABEL_NAMES))
    return tuple(LABEL_NAMES[i] for i in ids)


def label_table(labels: str = "train") -> np.ndarray:
    """uint8 [256]: label id -> class id of the label set, VOID for everything that is no class
    (`load` maps every label map through it)."""
    _check_labels(labels)
    table = np.full(256, VOID, np.uint8)
    ids = TRAIN_IDS if labels == "train" else range(_FIRST_ANNOTATED, len(LABEL_NAMES))
    table[list(ids)] = np.arange(len(ids), dtype=np.uint8)
    return table


def _check_labels(labels: str) -> None:
    if labels not in LABEL_SETS:
        raise ValueError(f"labels must be one of {LABEL_SETS} (19 training classes, or all 30), "
                         f"got {labels!r}")


def _dataset_dir(root) -> Path:
    searched = []
    for folder, why in locate.search_dirs("cityscapes", root):
        if (folder / "leftImg8bit").is_dir() and (folder / "gtFine").is_dir():
            return folder
        searched.append(f"  {folder}  ({why})")
    raise DatasetNotFoundError("\n".join([
        "dataset 'cityscapes' not found. Searched these folders:", *searched,
        "Expected in one of them: leftImg8bit/{train,val}/<city>/*" + _PHOTO_SUFFIX + " and",
        "  gtFine/{train,val}/<city>/*" + _LABEL_SUFFIX,
        "To get the files: register at https://www.cityscapes-dataset.com, download",
        "  leftImg8bit_trainvaltest.zip and gtFine_trainvaltest.zip and unzip both into one folder;",
        "  then pass root=<that folder>, or set JAXNAT_DATA_DIR=/some/dir and unzip them into "
        "/some/dir/cityscapes.",
        "For a localization task without Cityscapes, use Localize/Clutter-v0 (embedded data).",
    ]))


def find_files(split: str, root=None) -> list[tuple[Path, Path]]:
    """(photo, label map) pairs of `split`, sorted by city and file name; checks the layout."""
    if split not in _SPLIT_DIRS:
        raise ValueError(f"unknown split {split!r}; valid splits: train, test (= val), val")
    folder = _dataset_dir(root)
    photo_dir = folder / "leftImg8bit" / _SPLIT_DIRS[split]
    label_dir = folder / "gtFine" / _SPLIT_DIRS[split]
    photos = sorted(photo_dir.glob(f"*/*{_PHOTO_SUFFIX}"))
    if not photos:
        raise DatasetNotFoundError(f"{photo_dir}: no photos <city>/*{_PHOTO_SUFFIX}; unzip "
                                   "leftImg8bit_trainvaltest.zip into " + str(folder))
    pairs = []
    for photo in photos:
        stem = photo.name[: -len(_PHOTO_SUFFIX)]
        label = label_dir / photo.parent.name / (stem + _LABEL_SUFFIX)
        if not label.is_file():
            raise DatasetNotFoundError(
                f"{label} is missing: every photo needs its label map ({photo} has none); unzip "
                f"gtFine_trainvaltest.zip into {folder}, or remove the photo")
        pairs.append((photo, label))
    return pairs


def _decode_pair(pair, shape, table) -> tuple[np.ndarray, np.ndarray]:
    photo_path, label_path = pair
    photo = cv2.imdecode(np.fromfile(photo_path, np.uint8), cv2.IMREAD_COLOR)
    label = cv2.imdecode(np.fromfile(label_path, np.uint8), cv2.IMREAD_UNCHANGED)
    if photo is None:
        raise DatasetFormatError(f"{photo_path}: cannot decode as an image; the file is corrupt")
    if label is None or label.ndim != 2 or label.dtype != np.uint8:
        raise DatasetFormatError(
            f"{label_path}: a labelIds map must be a one-channel 8-bit PNG, got "
            f"{'an undecodable file' if label is None else f'{label.dtype} {label.shape}'}")
    if label.shape != photo.shape[:2]:
        raise DatasetFormatError(f"{label_path} is {label.shape[1]}x{label.shape[0]} but its photo "
                                 f"is {photo.shape[1]}x{photo.shape[0]}; they must match")
    h, w = shape
    photo = cv2.resize(photo, (w, h), interpolation=cv2.INTER_AREA)
    label = cv2.resize(label, (w, h), interpolation=cv2.INTER_NEAREST)
    return cv2.cvtColor(photo, cv2.COLOR_BGR2RGB), table[label]


def load(split: str = "train", *, root=None, shape: tuple[int, int] = (256, 256),
         labels: str = "train", cache: bool = True) -> SegmentationDataset:
    """Load one split of Cityscapes (see the module docstring)."""
    _check_labels(labels)
    shape = tuple(int(s) for s in shape)
    pairs = find_files(split, root)
    table = label_table(labels)

    def decode() -> SegmentationDataset:
        with ThreadPoolExecutor(os.cpu_count() or 1) as pool:  # OpenCV releases the GIL
            decoded = list(pool.map(lambda p: _decode_pair(p, shape, table), pairs))
        return SegmentationDataset(
            name="cityscapes", split=split,
            images=np.stack([d[0] for d in decoded]), class_maps=np.stack([d[1] for d in decoded]),
            class_names=class_names(labels))

    if not cache:
        return decode()
    files = [f for pair in pairs for f in pair]
    return cached("cityscapes", split, files, decode, extra=[labels, f"{shape[0]}x{shape[1]}"])
