"""The types every dataset reader returns or raises: `ImageDataset` and the two errors.

They live here, not in the package `__init__`, so that the reader modules can import them
without importing each other.
"""

from __future__ import annotations

import dataclasses

import numpy as np

__all__ = ["ImageDataset", "DatasetNotFoundError", "DatasetFormatError"]


class DatasetNotFoundError(FileNotFoundError):
    """The files of a dataset are not where they were looked for.

    The message lists every place searched, the exact file names expected there, and how to get
    them (a Debian package, `jaxnat.datasets.download`, or `JAXNAT_DATA_DIR`).
    """


class DatasetFormatError(ValueError):
    """A dataset file exists but cannot be trusted: truncated, corrupt, inconsistent or unsafe.

    The message names the file and the problem.
    """


# eq=False: the fields are arrays, so a generated __eq__ would raise ("truth value of an array
# is ambiguous") and a generated __hash__ would fail; identity semantics are the honest ones.
@dataclasses.dataclass(frozen=True, eq=False)
class ImageDataset:
    """One split of a labelled image dataset, fully decoded in host memory.

    Contract (checked on construction, so a reader bug fails here, not in a jitted env):
    `images` is uint8 [N, H, W, C] with C in {1, 3} (RGB order when C = 3) and C-contiguous;
    `labels` is int32 [N] with values in [0, len(class_names)).
    """

    name: str
    split: str
    images: np.ndarray
    labels: np.ndarray
    class_names: tuple[str, ...]

    def __post_init__(self) -> None:
        images, labels = self.images, self.labels
        where = f"ImageDataset({self.name!r}, {self.split!r})"
        if not isinstance(images, np.ndarray) or images.dtype != np.uint8 or images.ndim != 4:
            raise ValueError(f"{where}: images must be a uint8 array [N, H, W, C], got "
                             f"{getattr(images, 'dtype', type(images))} {np.shape(images)}")
        if images.shape[-1] not in (1, 3):
            raise ValueError(f"{where}: images must have 1 or 3 channels, got {images.shape[-1]}")
        if not images.flags.c_contiguous:
            raise ValueError(f"{where}: images must be C-contiguous (use np.ascontiguousarray)")
        if not isinstance(labels, np.ndarray) or labels.dtype != np.int32 or labels.ndim != 1:
            raise ValueError(f"{where}: labels must be an int32 array [N], got "
                             f"{getattr(labels, 'dtype', type(labels))} {np.shape(labels)}")
        if len(labels) != len(images):
            raise ValueError(f"{where}: {len(images)} images but {len(labels)} labels")
        if not isinstance(self.class_names, tuple) or not self.class_names:
            raise ValueError(f"{where}: class_names must be a non-empty tuple of str")
        if len(labels) and (labels.min() < 0 or labels.max() >= len(self.class_names)):
            raise ValueError(f"{where}: labels must lie in [0, {len(self.class_names)}), got "
                             f"[{labels.min()}, {labels.max()}]")

    @property
    def num_classes(self) -> int:
        return len(self.class_names)
