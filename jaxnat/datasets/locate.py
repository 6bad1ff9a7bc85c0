"""Where each dataset's files are looked for, and the error that says so when they are not found.

Folders searched, first match wins:

1. the explicit `root` argument, if given (and then only it: a typo in `root` must not silently
   fall back to some other copy of the data);
2. `$JAXNAT_DATA_DIR/<name>/`, if `JAXNAT_DATA_DIR` is set;
3. `~/.cache/jaxnat/data/<name>/`, where `download(name)` puts files when JAXNAT_DATA_DIR is unset;
4. Debian package locations: `/usr/share/datasets/mnist/`, `/usr/share/datasets/fashion-mnist/`
   (package dataset-fashion-mnist), `/usr/share/doc/opencv-doc/examples/data/` (package
   opencv-doc, for the digits sheet).

In each folder the files may sit in their release's sub-folder (as the official archive unpacks,
e.g. `<folder>/cifar-10-batches-bin/data_batch_1.bin`) or directly in the folder. IDX files may be
gzipped or not (`train-images-idx3-ubyte` or `train-images-idx3-ubyte.gz`). A dataset with two
releases (CIFAR binary and python) is looked up in the order of `LAYOUTS`, binary first.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

from jaxnat.datasets.base import DatasetNotFoundError

__all__ = ["Source", "Layout", "LAYOUTS", "SYSTEM_DIRS", "data_dir", "default_download_dir",
           "search_dirs", "find"]


@dataclasses.dataclass(frozen=True)
class Layout:
    """One release of a dataset: its decoder, its sub-folder, and the files each split reads.

    `files[split]` lists the files in the order the decoder takes them; each entry is a tuple of
    acceptable names for that one file, the first present one being used.
    """

    format: str
    subdir: str
    files: dict[str, tuple[tuple[str, ...], ...]]


@dataclasses.dataclass(frozen=True)
class Source:
    """The resolved files of one split of a dataset, ready for the decoder named by `format`."""

    name: str
    split: str
    format: str
    files: tuple[Path, ...]


def _idx(prefix: str) -> tuple[tuple[str, ...], ...]:
    return tuple((f"{prefix}-{kind}-ubyte", f"{prefix}-{kind}-ubyte.gz")
                 for kind in ("images-idx3", "labels-idx1"))


def _exact(*names: str) -> tuple[tuple[str, ...], ...]:
    return tuple((n,) for n in names)


_IDX = Layout("idx", "", {"train": _idx("train"), "test": _idx("t10k")})
_CIFAR10_TRAIN = [f"data_batch_{i}" for i in range(1, 6)]

LAYOUTS: dict[str, tuple[Layout, ...]] = {
    "mnist": (_IDX,),
    "fashion_mnist": (_IDX,),
    "digits": (Layout("digits", "", {"train": _exact("digits.png"),
                                      "test": _exact("digits.png")}),),
    "cifar10": (
        Layout("cifar-bin", "cifar-10-batches-bin", {
            "train": _exact(*(f"{b}.bin" for b in _CIFAR10_TRAIN), "batches.meta.txt"),
            "test": _exact("test_batch.bin", "batches.meta.txt")}),
        Layout("cifar-py", "cifar-10-batches-py", {
            "train": _exact(*_CIFAR10_TRAIN, "batches.meta"),
            "test": _exact("test_batch", "batches.meta")}),
    ),
    "cifar100": (
        Layout("cifar-bin", "cifar-100-binary", {
            "train": _exact("train.bin", "fine_label_names.txt"),
            "test": _exact("test.bin", "fine_label_names.txt")}),
        Layout("cifar-py", "cifar-100-python", {
            "train": _exact("train", "meta"),
            "test": _exact("test", "meta")}),
    ),
}

# Where Debian packages install the data. A module constant so tests can point it elsewhere.
SYSTEM_DIRS: dict[str, tuple[Path, ...]] = {
    "mnist": (Path("/usr/share/datasets/mnist"),),
    "fashion_mnist": (Path("/usr/share/datasets/fashion-mnist"),),
    "digits": (Path("/usr/share/doc/opencv-doc/examples/data"),),
}

# The embedded data that can stand in for a dataset that is not here, named as what it is.
_EMBEDDED_STAND_INS = {
    "mnist": "the embedded digits (Classify/Digits-v0: OpenCV's 5,000 handwritten digits, a stand-in, not MNIST)",
}

# How to get each dataset, for the not-found message.
_HOW_TO_GET: dict[str, tuple[str, ...]] = {
    "mnist": ("download it: python -c \"import jaxnat.datasets as d; d.download('mnist')\"",),
    "fashion_mnist": (
        "install the Debian package: sudo apt-get install dataset-fashion-mnist",
        "or download it: python -c \"import jaxnat.datasets as d; d.download('fashion_mnist')\""),
    "digits": ("install the Debian package: sudo apt-get install opencv-doc",
               "or copy OpenCV's samples/data/digits.png into one of the folders above"),
    "cifar10": ("download it: python -c \"import jaxnat.datasets as d; d.download('cifar10')\"",
                "or unpack cifar-10-binary.tar.gz or cifar-10-python.tar.gz from "
                "https://www.cs.toronto.edu/~kriz/cifar.html into one of the folders above"),
    "cifar100": ("download it: python -c \"import jaxnat.datasets as d; d.download('cifar100')\"",
                 "or unpack cifar-100-binary.tar.gz or cifar-100-python.tar.gz from "
                 "https://www.cs.toronto.edu/~kriz/cifar.html into one of the folders above"),
}


def data_dir() -> Path | None:
    """`$JAXNAT_DATA_DIR` as a path, or None when it is unset or empty."""
    value = os.environ.get("JAXNAT_DATA_DIR")
    return Path(value).expanduser() if value else None


def _home_data_dir() -> Path:
    return Path.home() / ".cache" / "jaxnat" / "data"


def default_download_dir(name: str) -> Path:
    """Where `download(name)` puts files: `$JAXNAT_DATA_DIR/<name>`, else
    `~/.cache/jaxnat/data/<name>`."""
    base = data_dir()
    return (base if base is not None else _home_data_dir()) / name


def search_dirs(name: str, root: str | os.PathLike | None) -> list[tuple[Path, str]]:
    """(folder, why it is searched), in search order (the module docstring's list), for a
    dataset `name`; datasets with their own layout (Cityscapes) search the same folders."""
    if root is not None:
        return [(Path(root).expanduser(), "root argument")]
    dirs = []
    base = data_dir()
    if base is not None:
        dirs.append((base / name, f"$JAXNAT_DATA_DIR/{name}"))
    # Searched even when JAXNAT_DATA_DIR is set: data downloaded before it was set is still good.
    home = _home_data_dir() / name
    if base is None or base / name != home:
        dirs.append((home, "default download folder"))
    dirs += [(d, "Debian package location") for d in SYSTEM_DIRS.get(name, ())]
    return dirs


def _resolve(folder: Path, names: tuple[tuple[str, ...], ...]) -> tuple[Path, ...] | None:
    """The files `names` asks for in `folder`, or None if any is missing."""
    found = []
    for alternatives in names:
        path = next((folder / n for n in alternatives if (folder / n).is_file()), None)
        if path is None:
            return None
        found.append(path)
    return tuple(found)


def find(name: str, split: str, root: str | os.PathLike | None = None) -> Source:
    """Resolve the files of `split` of dataset `name`, or raise `DatasetNotFoundError`."""
    searched = []
    for folder, why in search_dirs(name, root):
        for layout in LAYOUTS[name]:
            candidates = [folder / layout.subdir, folder] if layout.subdir else [folder]
            for candidate in candidates:
                files = _resolve(candidate, layout.files[split])
                if files is not None:
                    return Source(name=name, split=split, format=layout.format, files=files)
        searched.append(f"  {folder}  ({why})")
    raise DatasetNotFoundError(_not_found_message(name, split, searched, root))


def _not_found_message(name: str, split: str, searched: list[str],
                       root: str | os.PathLike | None) -> str:
    expected = []
    for layout in LAYOUTS[name]:
        names = ", ".join(" or ".join(alternatives) for alternatives in layout.files[split])
        where = f" (in <folder>/{layout.subdir}/ or directly in <folder>)" if layout.subdir else ""
        expected.append(f"  {names}{where}")
    base = data_dir()
    env = (f"JAXNAT_DATA_DIR is {base}, so put them in {base / name}" if base is not None
           else f"or set JAXNAT_DATA_DIR=/some/dir and put them in /some/dir/{name}")
    how = [f"  - {h}" for h in _HOW_TO_GET[name]] + [f"  - {env}"]
    if name in _EMBEDDED_STAND_INS:
        how.append(f"  - or train without it on {_EMBEDDED_STAND_INS[name]}")
    if root is not None:
        how.append("  - or pass a different root=, or none to search the default places")
    return "\n".join([
        f"dataset {name!r} (split {split!r}) not found. Searched these folders:", *searched,
        "Expected in one of them" + (" (either release)" if len(expected) > 1 else "") + ":",
        *expected, "To get the files:", *how])
