"""OpenCV's digits sheet: 5,000 handwritten MNIST digits in one PNG (package `opencv-doc`).

Layout of `digits.png`: a 2000x1000 (width x height) grayscale image of 20x20 tiles, 100 tiles a
row and 50 rows. Class c (0..9) fills rows 5c..5c+4, i.e. 500 consecutive digits, so the label of
a tile is `row // 5`.

Each tile is padded with a 4-pixel zero border to MNIST's 28x28, the digit centred, giving
uint8 [N, 28, 28, 1].

Split (the sheet ships none; this one is fixed, stratified and reproducible): number the digits
of each class k = 0..499 in sheet order (row-major). Digit k goes to **test when k % 5 == 4**,
else to train. That is every fifth digit of each class: 4,000 train / 1,000 test, 400 / 100 per
class, spread evenly over each class's five rows.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from jaxnat.datasets.base import DatasetFormatError, ImageDataset

__all__ = ["load_split", "split_mask", "CLASS_NAMES", "SHEET_SHAPE"]

CLASS_NAMES = tuple(str(d) for d in range(10))
SHEET_SHAPE = (1000, 2000)  # (height, width): 50 rows x 100 columns of 20x20 tiles
_TILE, _PAD = 20, 4
_ROWS, _COLS = SHEET_SHAPE[0] // _TILE, SHEET_SHAPE[1] // _TILE
_PER_CLASS = _ROWS * _COLS // len(CLASS_NAMES)


def _read_sheet(path: Path) -> np.ndarray:
    # imdecode from bytes rather than imread: imread returns None for any failure, including a
    # path it cannot encode, and says nothing about why.
    sheet = cv2.imdecode(np.fromfile(path, dtype=np.uint8), cv2.IMREAD_GRAYSCALE)
    if sheet is None:
        raise DatasetFormatError(f"{path}: cannot decode as an image; the file is corrupt, "
                                 "reinstall it (sudo apt-get install --reinstall opencv-doc)")
    if sheet.shape != SHEET_SHAPE:
        raise DatasetFormatError(
            f"{path}: the digits sheet must be {SHEET_SHAPE[1]}x{SHEET_SHAPE[0]} pixels (width x "
            f"height: {_COLS}x{_ROWS} tiles of {_TILE}x{_TILE}), got "
            f"{sheet.shape[1]}x{sheet.shape[0]}; use OpenCV's samples/data/digits.png unmodified")
    return sheet


def split_mask(split: str) -> np.ndarray:
    """bool [5000] over tiles in sheet order: True where the tile belongs to `split`."""
    k = np.arange(_ROWS * _COLS) % _PER_CLASS  # index of the digit within its class
    is_test = k % 5 == 4
    return is_test if split == "test" else ~is_test


def load_split(name: str, split: str, files: Sequence[Path]) -> ImageDataset:
    """Decode `files` = (digits.png,) and return the `split` half described in the docstring."""
    (path,) = files
    sheet = _read_sheet(Path(path))
    # [rows*20, cols*20] -> [rows, cols, 20, 20] -> [rows*cols, 20, 20], row-major sheet order.
    tiles = sheet.reshape(_ROWS, _TILE, _COLS, _TILE).swapaxes(1, 2).reshape(-1, _TILE, _TILE)
    labels = np.arange(len(tiles), dtype=np.int32) // _PER_CLASS
    keep = split_mask(split)
    size = _TILE + 2 * _PAD
    images = np.zeros((int(keep.sum()), size, size, 1), dtype=np.uint8)
    images[:, _PAD:_PAD + _TILE, _PAD:_PAD + _TILE, 0] = tiles[keep]
    return ImageDataset(name=name, split=split, images=images, labels=labels[keep],
                        class_names=CLASS_NAMES)
