"""Which files feed a frame bank: the embedded defaults, user sources, and the train/test split.

Sources are a file, a directory (searched recursively for files with a known extension), a glob
pattern (`**` allowed), or a list of these. Files are identified by a SHA-256 of their bytes, so
the split and the cache follow the content, not the path: renaming or moving a video changes
nothing, and the same clip under two names is used once.

The split is by whole files: sort the files by content hash; the first `test_fraction * n`
(rounded half up) are `test`, the rest `train` (with at least one of each when there are two or
more files and 0 < test_fraction < 1). Both splits come from one partition of one sorted list,
so they are disjoint by construction, and they are the same on every machine. `split="all"` uses
every file, as the paper did (it trained and tested on one set of Kinetics clips).

Different bytes can hold the same footage (a re-encoded or damaged copy: opencv-doc's
`Megamind.avi` and `Megamind_bugy.avi`). Such near-duplicates (`near_duplicates.py`: matching
perceptual hashes of their first frames) stay on one side: every file of a group takes the side
of its first member in content-hash order, with a `NearDuplicateWarning` naming the files. Every
other file keeps the side the rule above gives it.
"""

from __future__ import annotations

import glob
import hashlib
import json
import os
import warnings
from collections.abc import Iterable, Sequence
from pathlib import Path

from jaxnat.datasets.base import DatasetFormatError, DatasetNotFoundError
from jaxnat.natural.near_duplicates import NearDuplicateWarning, near_duplicate_groups

__all__ = ["VIDEO_EXTENSIONS", "IMAGE_EXTENSIONS", "SPLITS", "OPENCV_DOC_DIRS",
           "DEFAULT_VIDEOS", "DEFAULT_IMAGES", "default_video_paths", "default_image_paths",
           "resolve", "content_digest", "split_files", "MANIFEST_NAME", "write_manifest"]

VIDEO_EXTENSIONS = (".avi", ".mp4", ".m4v", ".mkv", ".mov", ".webm", ".mpg", ".mpeg", ".wmv",
                    ".flv", ".ogv")
IMAGE_EXTENSIONS = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp")
SPLITS = ("train", "test", "all")

# Where Debian's opencv-doc puts its sample data. A module constant so tests can point it
# elsewhere.
OPENCV_DOC_DIRS = (Path("/usr/share/doc/opencv-doc/examples/data"),
                   Path("/usr/share/doc/opencv-doc/opencv4/html"))

# The natural videos of opencv-doc (Megamind_bugy.avi, a deliberately broken copy, is left out).
DEFAULT_VIDEOS = ("vtest.avi", "tree.avi", "Megamind.avi", "box.mp4.gz", "cup.mp4.gz")
# Its camera photos of natural scenes and objects (logos, drawings, charts, calibration boards,
# text and synthetic test patterns left out; of each stereo or sequence pair, one image).
DEFAULT_IMAGES = ("aero1.jpg", "aloeL.jpg", "apple.jpg", "baboon.jpg", "basketball1.png",
                  "board.jpg", "building.jpg", "butterfly.jpg", "chicky_512.png",
                  "ela_original.jpg", "fruits.jpg", "graf1.png", "home.jpg", "leuvenA.jpg",
                  "licenseplate_motion.jpg", "messi5.jpg", "orange.jpg", "rubberwhale1.png",
                  "smarties.png", "squirrel_cls.jpg")

_MISSING_OPENCV_DOC = (
    "the default natural {kind} come from Debian's opencv-doc package, which is not installed "
    "(looked in {dirs} for {names}).\n"
    "  - install it: sudo apt-get install opencv-doc (or run `make data` as root)\n"
    "  - or pass your own files: sources='/path/to/clips/' (a folder), '/path/**/*.mp4' (a glob) "
    "or a list of files")


def _default_paths(names: Sequence[str], kind: str) -> list[Path]:
    found = []
    for name in names:
        path = next((d / name for d in OPENCV_DOC_DIRS if (d / name).is_file()), None)
        if path is not None:
            found.append(path)
    if not found:
        raise DatasetNotFoundError(_MISSING_OPENCV_DOC.format(
            kind=kind, dirs=", ".join(map(str, OPENCV_DOC_DIRS)), names=", ".join(names)))
    return found


def default_video_paths() -> list[Path]:
    """The natural videos shipped by Debian's opencv-doc (`DEFAULT_VIDEOS`) that are present;
    `DatasetNotFoundError` saying how to install them when none is."""
    return _default_paths(DEFAULT_VIDEOS, "videos")


def default_image_paths() -> list[Path]:
    """The natural photos shipped by Debian's opencv-doc (`DEFAULT_IMAGES`) that are present;
    `DatasetNotFoundError` saying how to install them when none is."""
    return _default_paths(DEFAULT_IMAGES, "images")


def _has_extension(path: Path, extensions: Sequence[str]) -> bool:
    name = path.name.lower()
    if name.endswith(".gz"):
        name = name[:-3]
    return name.endswith(tuple(extensions)) and not path.name.startswith(".")


# A video or photo set's manifest, at the top of its folder: the files that are the set and
# their contents' SHA-256 (`write_manifest`). A folder with one is read as the manifest says.
MANIFEST_NAME = "manifest.json"
MANIFEST_FORMAT = 1


def write_manifest(folder: str | os.PathLike, extensions: Sequence[str] = ()) -> Path:
    """Describe the set of files under `folder` (a Kinetics-style folder: class folders of
    clips; recursive; with `extensions`, only those) in `folder/manifest.json`: each file's path
    relative to the folder, its size and the SHA-256 of its bytes, sorted by path. From then
    on `resolve` reads that folder as exactly those files, and refuses one that changed.
    Returns the manifest's path."""
    folder = Path(folder).expanduser()
    files = sorted(p for p in folder.rglob("*") if p.is_file() and p.name != MANIFEST_NAME
                   and (not extensions or _has_extension(p, extensions)))
    if not files:
        raise DatasetNotFoundError(f"no files to describe in {folder}")
    entries = [{"path": p.relative_to(folder).as_posix(), "bytes": p.stat().st_size, "sha256": content_digest(p)}
               for p in files]
    path = folder / MANIFEST_NAME
    partial = path.with_name(MANIFEST_NAME + ".partial")
    partial.write_text(json.dumps({"format": MANIFEST_FORMAT, "files": entries}, indent=1) + "\n")
    partial.replace(path)
    return path


def _manifest_files(folder: Path) -> list[Path]:
    """The files `folder/manifest.json` lists, each checked against its SHA-256."""
    path = folder / MANIFEST_NAME
    try:
        document = json.loads(path.read_text())
        entries = [(str(e["path"]), str(e["sha256"])) for e in document["files"]]
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise DatasetFormatError(f"{path} is not a jaxnat manifest ({type(err).__name__}: {err}); rewrite it "
                                 "with jaxnat.natural.write_manifest") from None
    files = []
    for name, digest in entries:
        file = folder / name
        if not file.is_file():
            raise DatasetNotFoundError(f"{file} is listed in {path} but missing: restore it, or rewrite the "
                                       "manifest with jaxnat.natural.write_manifest")
        if content_digest(file) != digest:
            raise DatasetFormatError(f"{file} changed since {path} was written (its SHA-256 is not the "
                                     "manifest's): restore it, or rewrite the manifest")
        files.append(file)
    if not files:
        raise DatasetNotFoundError(f"{path} lists no files")
    return files


def _is_glob(text: str) -> bool:
    return any(c in text for c in "*?[")


def resolve(sources: str | os.PathLike | Iterable[str | os.PathLike],
            extensions: Sequence[str]) -> list[Path]:
    """The files named by `sources` (files, directories, glob patterns), in a stable order.

    A directory contributes its files with one of `extensions` (optionally gzipped), searched
    recursively, or, when it holds a `manifest.json` (`write_manifest`), exactly the files that
    lists, each checked against its SHA-256; a glob contributes every file it matches. A named file that does not exist, a
    directory without such files, or a glob matching nothing raises `DatasetNotFoundError`
    naming it.
    """
    if isinstance(sources, (str, os.PathLike)):
        sources = [sources]
    files: list[Path] = []
    for source in sources:
        text = os.fspath(source)
        path = Path(text).expanduser()
        if path.is_dir() and (path / MANIFEST_NAME).is_file():
            found = _manifest_files(path)
        elif path.is_dir():
            found = sorted(p for p in path.rglob("*") if p.is_file()
                           and _has_extension(p, extensions))
            if not found:
                raise DatasetNotFoundError(
                    f"no files with extension {', '.join(extensions)} (or the same + .gz) in "
                    f"directory {path}")
        elif path.is_file():
            found = [path]
        elif _is_glob(text):
            found = sorted(Path(p) for p in glob.glob(os.path.expanduser(text), recursive=True)
                           if Path(p).is_file())
            if not found:
                raise DatasetNotFoundError(f"the glob pattern {text!r} matches no file")
        else:
            raise DatasetNotFoundError(f"no such file or directory: {text!r}")
        files += found
    if not files:
        raise DatasetNotFoundError("no source files given (an empty list)")
    return files


# (resolved path, size, mtime) -> digest: the split hashes every file on every load; a
# Kinetics folder is gigabytes, so remember each file's digest while the file is unchanged.
_DIGESTS: dict[tuple[str, int, int], str] = {}


def content_digest(path: Path) -> str:
    """SHA-256 of the file's bytes (hex)."""
    stat = path.stat()
    key = (str(path.resolve()), stat.st_size, stat.st_mtime_ns)
    if key not in _DIGESTS:
        with open(path, "rb") as f:
            _DIGESTS[key] = hashlib.file_digest(f, "sha256").hexdigest()
    return _DIGESTS[key]


def split_files(files: Sequence[Path], split: str, test_fraction: float
                ) -> list[tuple[Path, str]]:
    """The (file, content digest) pairs of `split`, in content-hash order, duplicates dropped
    and near-duplicates kept on one side (with a `NearDuplicateWarning`).

    See the module docstring for the rule.
    """
    if split not in SPLITS:
        raise ValueError(f"unknown split {split!r}; valid splits: {', '.join(SPLITS)}")
    if not 0.0 <= test_fraction <= 1.0:
        raise ValueError(f"test_fraction must be in [0, 1], got {test_fraction}")
    unique: dict[str, Path] = {}
    for path in files:
        unique.setdefault(content_digest(path), path)
    ranked = sorted((digest, path) for digest, path in unique.items())
    num_test = int(test_fraction * len(ranked) + 0.5)  # rounded half up
    if len(ranked) >= 2 and 0.0 < test_fraction < 1.0:
        num_test = min(max(num_test, 1), len(ranked) - 1)
    sides = ["test" if i < num_test else "train" for i in range(len(ranked))]
    groups = near_duplicate_groups([p for _, p in ranked], [d for d, _ in ranked],
                                   image=_is_image) if split != "all" and len(ranked) > 1 else []
    for group in groups:
        side = sides[group[0]]
        for i in group:
            sides[i] = side
        warnings.warn(
            f"near-duplicate files (the same footage under different bytes) kept together in "
            f"the {side!r} split: {', '.join(str(ranked[i][1]) for i in group)}",
            NearDuplicateWarning, stacklevel=3)
    chosen = ranked if split == "all" else [r for r, s in zip(ranked, sides) if s == split]
    if not chosen:
        grouped = (f" ({sum(map(len, groups))} of them near-duplicates kept on one side)"
                   if groups else "")
        raise DatasetNotFoundError(
            f"split {split!r} is empty: {len(ranked)} distinct file(s){grouped} with "
            f"test_fraction={test_fraction}; add files, change test_fraction, or use "
            "split='all' to use every file for both training and testing")
    return [(path, digest) for digest, path in chosen]


def _is_image(path: Path) -> bool:
    name = path.name.lower()
    return any(name.endswith(ext) or name.endswith(ext + ".gz") for ext in IMAGE_EXTENSIONS)
