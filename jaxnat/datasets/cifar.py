"""CIFAR-10 and CIFAR-100, from either official release: binary or python.

Binary release (read first: no unpickling involved)::

    cifar-10-batches-bin/data_batch_1.bin .. data_batch_5.bin   train, 10,000 records each
    cifar-10-batches-bin/test_batch.bin                          test, 10,000 records
    cifar-10-batches-bin/batches.meta.txt                        10 class names, one per line
    record = 1 label byte + 3072 pixel bytes

    cifar-100-binary/train.bin, test.bin                         50,000 / 10,000 records
    cifar-100-binary/fine_label_names.txt                        100 class names, one per line
    record = 1 coarse label byte + 1 fine label byte + 3072 pixel bytes (the fine label is used)

Python release: pickled dicts with byte-string keys (written by Python 2, so read with
encoding="bytes")::

    cifar-10-batches-py/data_batch_1 .. _5, test_batch  {b"data": uint8 [N, 3072], b"labels": [N]}
    cifar-10-batches-py/batches.meta                     {b"label_names": [10 bytes]}
    cifar-100-python/train, test                         {b"data": ..., b"fine_labels": [N]}
    cifar-100-python/meta                                {b"fine_label_names": [100 bytes]}

The pickles are read by `_RestrictedUnpickler`, which resolves only the handful of globals a
plain CIFAR pickle references (numpy array and dtype reconstruction, bytes) and refuses any other
with `DatasetFormatError`, so a tampered file cannot run code.

In both releases the 3072 pixel bytes of an image are its red, green and blue 32x32 planes
(CHW); they are returned as HWC RGB uint8 [N, 32, 32, 3].
"""

from __future__ import annotations

import codecs
import pickle
from collections.abc import Sequence
from pathlib import Path
from typing import BinaryIO

import numpy as np

from jaxnat.datasets.base import DatasetFormatError, ImageDataset

__all__ = ["load_binary", "load_python", "NUM_CLASSES"]

NUM_CLASSES = {"cifar10": 10, "cifar100": 100}
_PIXELS = 3 * 32 * 32
# Leading label bytes of a binary record: CIFAR-100 stores (coarse, fine).
_LABEL_BYTES = {"cifar10": 1, "cifar100": 2}
_PY_LABELS_KEY = {"cifar10": b"labels", "cifar100": b"fine_labels"}
_PY_NAMES_KEY = {"cifar10": b"label_names", "cifar100": b"fine_label_names"}

# numpy pickles an array as `_reconstruct(ndarray, (0,), b"b")` plus a state; the function lives
# in numpy.core.multiarray before numpy 2 and numpy._core.multiarray from numpy 2 on. Take this
# numpy's own function rather than importing whichever module name the file asks for.
_reconstruct = np.empty(0).__reduce__()[0]

# Everything a plain CIFAR pickle needs. Lists, dicts, ints and str are built by pickle opcodes
# and need no global; bytes written under protocol 2 by Python 3 go through _codecs.encode, and
# an empty bytes through bytes() (named __builtin__ in protocol-2 pickles).
_ALLOWED_GLOBALS = {
    ("numpy.core.multiarray", "_reconstruct"): _reconstruct,
    ("numpy._core.multiarray", "_reconstruct"): _reconstruct,
    ("numpy", "ndarray"): np.ndarray,
    ("numpy", "dtype"): np.dtype,
    ("_codecs", "encode"): codecs.encode,
    ("__builtin__", "bytes"): bytes,
    ("builtins", "bytes"): bytes,
}


class _RestrictedUnpickler(pickle.Unpickler):
    """An unpickler that resolves only `_ALLOWED_GLOBALS`; it never imports anything."""

    def __init__(self, file: BinaryIO, path: str):
        super().__init__(file, encoding="bytes")
        self._path = path

    def find_class(self, module: str, name: str):
        try:
            return _ALLOWED_GLOBALS[(module, name)]
        except KeyError:
            raise DatasetFormatError(
                f"{self._path}: refusing to unpickle {module}.{name}: a CIFAR pickle holds only "
                "numpy arrays, lists and bytes, so this file is not a genuine CIFAR file (it may "
                "be malicious); delete it and get the official release") from None


def _unpickle(path: Path) -> dict:
    try:
        with open(path, "rb") as f:
            obj = _RestrictedUnpickler(f, str(path)).load()
    except (DatasetFormatError, FileNotFoundError):
        raise
    except Exception as e:
        # A corrupt pickle can fail in many ways (UnpicklingError, EOFError, ValueError from numpy,
        # TypeError from a wrong reduce call); all mean the same thing to the caller.
        raise DatasetFormatError(f"{path}: not a readable CIFAR pickle ({type(e).__name__}: {e}); "
                                 "delete it and get it again") from e
    if not isinstance(obj, dict):
        raise DatasetFormatError(f"{path}: expected a pickled dict, got {type(obj).__name__}")
    return obj


def _to_hwc(pixels: np.ndarray) -> np.ndarray:
    """[N, 3072] CHW rows -> C-contiguous [N, 32, 32, 3]."""
    return np.ascontiguousarray(pixels.reshape(-1, 3, 32, 32).transpose(0, 2, 3, 1))


def _check_labels(labels: np.ndarray, num_classes: int, path: Path) -> None:
    if len(labels) and (labels.min() < 0 or labels.max() >= num_classes):
        raise DatasetFormatError(f"{path}: labels must lie in [0, {num_classes}), got "
                                 f"[{labels.min()}, {labels.max()}]")


def _check_names(names: list[str], num_classes: int, path: Path) -> tuple[str, ...]:
    if len(names) != num_classes:
        raise DatasetFormatError(f"{path}: expected {num_classes} class names, found {len(names)}")
    return tuple(names)


def load_binary(name: str, split: str, files: Sequence[Path]) -> ImageDataset:
    """Decode the binary release. `files` = (*batch files in order, class-names text file)."""
    *batches, names_file = map(Path, files)
    num_classes, label_bytes = NUM_CLASSES[name], _LABEL_BYTES[name]
    record = label_bytes + _PIXELS
    images, labels = [], []
    for path in batches:
        raw = np.fromfile(path, dtype=np.uint8)
        if raw.size == 0 or raw.size % record:
            raise DatasetFormatError(f"{path}: {raw.size} bytes is not a whole number of "
                                     f"{record}-byte CIFAR records; the file is truncated or "
                                     "not from the binary release")
        rows = raw.reshape(-1, record)
        batch_labels = rows[:, label_bytes - 1].astype(np.int32)  # the fine label for CIFAR-100
        _check_labels(batch_labels, num_classes, path)
        images.append(_to_hwc(rows[:, label_bytes:]))
        labels.append(batch_labels)
    # Names files have a trailing blank line or two; blank lines are never class names.
    names = [line.strip() for line in names_file.read_text(encoding="utf-8").splitlines()]
    class_names = _check_names([n for n in names if n], num_classes, names_file)
    return ImageDataset(name=name, split=split, images=np.concatenate(images),
                        labels=np.concatenate(labels), class_names=class_names)


def load_python(name: str, split: str, files: Sequence[Path]) -> ImageDataset:
    """Decode the python release. `files` = (*batch pickles in order, meta pickle)."""
    *batches, meta_file = map(Path, files)
    num_classes, labels_key = NUM_CLASSES[name], _PY_LABELS_KEY[name]
    images, labels = [], []
    for path in batches:
        batch = _unpickle(path)
        if b"data" not in batch or labels_key not in batch:
            raise DatasetFormatError(f"{path}: missing key b'data' or {labels_key!r}; found "
                                     f"{sorted(map(repr, batch))}")
        data = batch[b"data"]
        if not isinstance(data, np.ndarray) or data.dtype != np.uint8 or data.ndim != 2 \
                or data.shape[1] != _PIXELS:
            raise DatasetFormatError(f"{path}: b'data' must be a uint8 array [N, {_PIXELS}], got "
                                     f"{getattr(data, 'dtype', type(data).__name__)} "
                                     f"{getattr(data, 'shape', '')}")
        try:
            batch_labels = np.asarray(batch[labels_key], dtype=np.int64)
        except (TypeError, ValueError) as e:
            raise DatasetFormatError(f"{path}: {labels_key!r} is not a list of ints") from e
        if batch_labels.shape != (len(data),):
            raise DatasetFormatError(f"{path}: {len(data)} images but {batch_labels.shape} labels")
        _check_labels(batch_labels, num_classes, path)
        images.append(_to_hwc(data))
        labels.append(batch_labels.astype(np.int32))
    meta = _unpickle(meta_file)
    names_key = _PY_NAMES_KEY[name]
    raw_names = meta.get(names_key)
    if not isinstance(raw_names, list) or not all(isinstance(n, bytes) for n in raw_names):
        raise DatasetFormatError(f"{meta_file}: {names_key!r} must be a list of byte strings")
    class_names = _check_names([n.decode("utf-8") for n in raw_names], num_classes, meta_file)
    return ImageDataset(name=name, split=split, images=np.concatenate(images),
                        labels=np.concatenate(labels), class_names=class_names)
