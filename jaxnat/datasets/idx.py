"""IDX files: the format of MNIST and Fashion-MNIST, read gzipped or not.

An IDX file is a header and a big-endian array:

    bytes 0-1  zero
    byte  2    dtype code: 0x08 uint8, 0x09 int8, 0x0B int16, 0x0C int32, 0x0D float32, 0x0E float64
    byte  3    number of dimensions D
    then       D big-endian uint32 sizes, then prod(sizes) items, row-major

A file is accepted only if it holds exactly as many bytes as its header promises; a short file
(an interrupted download) or a longer one (a wrong file) raises `DatasetFormatError` naming it.

The official split of both datasets: train = `train-images-idx3-ubyte` + `train-labels-idx1-ubyte`
(60,000 images), test = `t10k-images-idx3-ubyte` + `t10k-labels-idx1-ubyte` (10,000), each
optionally `.gz`. Images are [N, 28, 28] uint8, labels [N] uint8 in 0..9.
"""

from __future__ import annotations

import gzip
import math
import os
import struct
import zlib
from collections.abc import Sequence

import numpy as np

from jaxnat.datasets.base import DatasetFormatError, ImageDataset

__all__ = ["read_idx", "load_split", "CLASS_NAMES"]

CLASS_NAMES: dict[str, tuple[str, ...]] = {
    "mnist": tuple(str(d) for d in range(10)),
    "fashion_mnist": ("T-shirt/top", "Trouser", "Pullover", "Dress", "Coat",
                      "Sandal", "Shirt", "Sneaker", "Bag", "Ankle boot"),
}

_DTYPES = {
    0x08: np.dtype(np.uint8),
    0x09: np.dtype(np.int8),
    0x0B: np.dtype(">i2"),
    0x0C: np.dtype(">i4"),
    0x0D: np.dtype(">f4"),
    0x0E: np.dtype(">f8"),
}

# Read in bounded chunks: a corrupt header may promise terabytes, and asking the file object
# for that many bytes at once would try to allocate them before noticing the file is short.
_CHUNK = 1 << 24


def read_idx(path: str | os.PathLike) -> np.ndarray:
    """Read one IDX file (gzipped if its name ends in `.gz`) into a native-endian array."""
    path = os.fspath(path)
    opener = gzip.open if path.endswith(".gz") else open
    try:
        with opener(path, "rb") as f:
            header = f.read(4)
            if len(header) < 4 or header[:2] != b"\0\0":
                raise DatasetFormatError(
                    f"{path}: not an IDX file (bad magic number {header.hex() or 'empty'}; "
                    f"expected 0000 followed by a dtype code and a dimension count)")
            code, ndim = header[2], header[3]
            if code not in _DTYPES:
                raise DatasetFormatError(f"{path}: unknown IDX dtype code 0x{code:02x}")
            if ndim == 0:
                raise DatasetFormatError(f"{path}: IDX header declares 0 dimensions")
            dims_raw = f.read(4 * ndim)
            if len(dims_raw) < 4 * ndim:
                raise DatasetFormatError(f"{path}: truncated IDX header")
            shape = struct.unpack(f">{ndim}I", dims_raw)
            dtype = _DTYPES[code]
            expected = math.prod(shape) * dtype.itemsize
            data = bytearray()
            # Ask for one byte more than promised so trailing garbage is detected too.
            while len(data) <= expected:
                chunk = f.read(min(_CHUNK, expected + 1 - len(data)))
                if not chunk:
                    break
                data += chunk
    except FileNotFoundError:
        raise
    except (OSError, EOFError, zlib.error) as e:
        # gzip raises BadGzipFile (an OSError) or EOFError for a cut-off stream.
        raise DatasetFormatError(f"{path}: cannot read IDX data ({e}); the file is corrupt or "
                                 "truncated, delete it and get it again") from e
    if len(data) < expected:
        raise DatasetFormatError(f"{path}: truncated: the header declares shape {shape} "
                                 f"({expected} data bytes) but the file holds {len(data)}; "
                                 "delete it and get it again")
    if len(data) > expected:
        raise DatasetFormatError(f"{path}: more data than the header's shape {shape} declares; "
                                 "this is not a valid IDX file")
    array = np.frombuffer(data, dtype=dtype).reshape(shape)
    return array.astype(dtype.newbyteorder("="), copy=False)


def load_split(name: str, split: str, files: Sequence[os.PathLike]) -> ImageDataset:
    """Decode `files` = (images file, labels file) of MNIST or Fashion-MNIST into a dataset."""
    images_path, labels_path = files
    images = read_idx(images_path)
    labels = read_idx(labels_path)
    if images.dtype != np.uint8 or images.ndim != 3:
        raise DatasetFormatError(f"{os.fspath(images_path)}: expected uint8 images [N, H, W], "
                                 f"got {images.dtype} {images.shape}")
    if labels.dtype != np.uint8 or labels.ndim != 1:
        raise DatasetFormatError(f"{os.fspath(labels_path)}: expected uint8 labels [N], "
                                 f"got {labels.dtype} {labels.shape}")
    if len(images) != len(labels):
        raise DatasetFormatError(f"{os.fspath(images_path)} holds {len(images)} images but "
                                 f"{os.fspath(labels_path)} holds {len(labels)} labels")
    class_names = CLASS_NAMES[name]
    if len(labels) and labels.max() >= len(class_names):
        raise DatasetFormatError(f"{os.fspath(labels_path)}: label {labels.max()} is out of "
                                 f"range for {len(class_names)} classes")
    return ImageDataset(name=name, split=split, images=images[..., np.newaxis],
                        labels=labels.astype(np.int32), class_names=class_names)
