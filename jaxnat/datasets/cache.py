"""A disk cache of decoded datasets, so the second `load` skips gunzip / unpickle / PNG decoding.

Entries are `.npz` files (images, labels, class_names; no pickled objects, read with
allow_pickle=False) under `$JAXNAT_CACHE_DIR`, else `~/.cache/jaxnat/arrays`. An entry's name is
a hash of the dataset name, the split, `FORMAT_VERSION`, and the resolved path and a hash of the
contents of every source file, so changing a source file's bytes (even under the same size and
modification time: `cp -p`, a re-extracted tarball) or how files are decoded (bump
`FORMAT_VERSION`) makes a new entry instead of serving stale arrays.

Entries are written to a temporary file and renamed into place, so a reader never sees half an
entry; an entry that fails to load anyway (disk trouble, a killed writer on a filesystem without
atomic rename) is ignored and rewritten. The cache is an optimisation only: a failure to write it
is a warning, never an error.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
import warnings
import zipfile
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import numpy as np

from jaxnat.datasets.base import ImageDataset

__all__ = ["FORMAT_VERSION", "cache_dir", "entry_path", "cached", "read_arrays", "write_arrays"]

# Bump when a decoder's output changes for the same source files.
FORMAT_VERSION = 1


def cache_dir() -> Path:
    """`$JAXNAT_CACHE_DIR`, else ~/.cache/jaxnat/arrays."""
    value = os.environ.get("JAXNAT_CACHE_DIR")
    return Path(value).expanduser() if value else Path.home() / ".cache" / "jaxnat" / "arrays"


def entry_path(name: str, split: str, files: Iterable[Path], extra: Iterable[str] = ()) -> Path:
    """The cache file for `split` of `name` decoded from `files` (plus any `extra` key strings)."""
    sources = []
    for path in files:
        resolved = Path(path).resolve()
        sources.append([str(resolved), _content_digest(resolved)])
    key = json.dumps([FORMAT_VERSION, name, split, sources, list(extra)])
    digest = hashlib.sha256(key.encode()).hexdigest()[:24]
    return cache_dir() / f"{name}-{split}-{digest}.npz"


def _content_digest(path: Path) -> str:
    """A hash of the file's bytes (BLAKE2b: fast; reading is cheaper than the decoding it saves).
    Path, size and modification time are not enough: `cp -p` or a re-extracted tarball gives
    new bytes under the old size and time."""
    with open(path, "rb") as f:
        return hashlib.file_digest(f, "blake2b").hexdigest()


def read_arrays(path: Path, keys: Iterable[str], build: Callable[..., Any]) -> Any | None:
    """`build(**arrays)` of the entry at `path`, or None when it is absent or unreadable."""
    try:
        # Open the file ourselves: np.load leaks its own handle when the archive is corrupt.
        with open(path, "rb") as f:
            entry = np.load(f, allow_pickle=False)
            if not isinstance(entry, np.lib.npyio.NpzFile):
                raise ValueError("not an .npz archive")
            arrays = {k: entry[k] for k in keys}
        return build(**arrays)
    except FileNotFoundError:
        return None
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as e:
        # ValueError also covers an entry whose arrays break the dataset type's contract.
        warnings.warn(f"ignoring unreadable dataset cache entry {path} ({e}); rewriting it",
                      stacklevel=3)
        return None


def _read(path: Path, name: str, split: str) -> ImageDataset | None:
    def build(images, labels, class_names):
        return ImageDataset(name=name, split=split, images=images, labels=labels,
                            class_names=tuple(str(c) for c in class_names))

    return read_arrays(path, ("images", "labels", "class_names"), build)


def write_arrays(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """Store `arrays` at `path` atomically; a failure is a warning (the cache is optional)."""
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
        with os.fdopen(fd, "wb") as f:
            np.savez(f, **arrays)
        os.replace(tmp, path)
    except OSError as e:
        if tmp is not None:
            Path(tmp).unlink(missing_ok=True)
        warnings.warn(f"could not write dataset cache entry {path} ({e}); set JAXNAT_CACHE_DIR "
                      "to a writable folder to cache decoded datasets", stacklevel=3)


def _write(path: Path, dataset: ImageDataset) -> None:
    write_arrays(path, {"images": dataset.images, "labels": dataset.labels,
                        "class_names": np.array(dataset.class_names, dtype=str)})


def cached(name: str, split: str, files: Iterable[Path], decode: Callable[[], ImageDataset],
           extra: Iterable[str] = ()) -> ImageDataset:
    """Return the cached decode of `files`, or call `decode()` and cache its result."""
    path = entry_path(name, split, files, extra)
    dataset = _read(path, name, split)
    if dataset is None:
        dataset = decode()
        _write(path, dataset)
    return dataset
