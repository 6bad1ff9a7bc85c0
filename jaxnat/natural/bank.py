"""`FrameBank`: every frame of a set of videos in one uint8 array, and the loaders that build it.

    bank = load_videos(shape=(84, 84), split="train")   # opencv-doc's videos, 3 of 5
    bank.frames      # uint8 [N, 84, 84, 3], the videos one after another
    bank.starts      # int32 [V], where video v begins in `frames`
    bank.lengths     # int32 [V], how many frames it has
    bank.to_device() # the same with jax arrays, to carry into jitted code

Decoded banks are cached on disk (`jaxnat.datasets.cache.cache_dir()`, `$JAXNAT_CACHE_DIR`),
keyed by the content hash of each source file, the shape, the colour mode, `max_frames` and the
decoder version, so a second start skips decoding and a changed file is decoded afresh.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
from collections.abc import Callable, Iterable
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxnat.datasets import cache as _cache
from jaxnat.datasets.base import DatasetFormatError
from jaxnat.natural import decode, sources as _sources

__all__ = ["FrameBank", "bank_manifests", "load_videos", "load_images", "DEFAULT_SHAPE", "DEFAULT_TEST_FRACTION",
           "FORMAT_VERSION"]

logger = logging.getLogger("jaxnat.natural")

DEFAULT_SHAPE = (84, 84)
# With opencv-doc's 5 videos this puts 2 in test (Megamind.avi, box.mp4.gz: 725 frames) and 3 in
# train (vtest.avi, tree.avi, cup.mp4.gz: 1,080 frames); with the 3 of its 4.6 package, Megamind.avi
# in test (270) and vtest.avi, tree.avi in train (863); see docs/design.md.
DEFAULT_TEST_FRACTION = 0.4
# Bump when decoding changes what a bank holds for the same files (invalidates cache entries).
FORMAT_VERSION = 1

Sources = str | os.PathLike | Iterable[str | os.PathLike] | None


@struct.dataclass
class FrameBank:
    """Frames of V videos back to back: video v is `frames[starts[v] : starts[v] + lengths[v]]`.

    `frames` uint8 [N, H, W, C] (C = 3 RGB or 1 gray), `starts`/`lengths` int32 [V], every video
    at least one frame long; `names` (static) are the source files' names, in bank order, and
    `digests` (static) their contents' SHA-256 (hex; empty for a bank not loaded from files).
    Numpy on the host (as loaded); `to_device()` gives the same pytree with jax arrays.
    `manifest()` says exactly which data a bank holds.
    """

    frames: np.ndarray | jax.Array
    starts: np.ndarray | jax.Array
    lengths: np.ndarray | jax.Array
    names: tuple[str, ...] = struct.field(pytree_node=False, default=())
    digests: tuple[str, ...] = struct.field(pytree_node=False, default=())

    def manifest(self) -> list[dict]:
        """One entry per video (or photo), in bank order: its file `name`, the `sha256` of the
        file's bytes ("" if unknown) and the `frames` the bank holds of it (after any cap)."""
        digests = self.digests or ("",) * self.num_videos
        return [{"name": name, "sha256": digest, "frames": int(length)}
                for name, digest, length in zip(self.names, digests, np.asarray(self.lengths))]

    @property
    def num_videos(self) -> int:
        return int(self.lengths.shape[0])

    @property
    def num_frames(self) -> int:
        return int(self.frames.shape[0])

    @property
    def frame_shape(self) -> tuple[int, int, int]:
        return tuple(self.frames.shape[1:])

    @property
    def nbytes(self) -> int:
        """Memory held by the frames (the index is negligible)."""
        return int(self.frames.size) * self.frames.dtype.itemsize

    def to_device(self, device=None) -> FrameBank:
        """The bank as jax arrays (on `device`, default the default device)."""
        return jax.tree.map(lambda x: jax.device_put(jnp.asarray(x), device), self)

    def to_host(self) -> FrameBank:
        return jax.tree.map(np.asarray, self)

    @staticmethod
    def concatenate(banks: Iterable[FrameBank]) -> FrameBank:
        """One host bank holding the videos of `banks` in order (e.g. videos and photos as one
        pool of backgrounds); their frames must share one shape."""
        banks = [b.to_host() for b in banks]
        shapes = {b.frame_shape for b in banks}
        if len(shapes) != 1:
            raise ValueError(f"cannot concatenate banks with different frame shapes: "
                             f"{sorted(shapes)}; load them with the same shape and grayscale")
        clips = [b.frames[s:s + n] for b in banks for s, n in zip(b.starts, b.lengths)]
        digests = [d for b in banks for d in (b.digests or ("",) * b.num_videos)]
        return _from_clips(clips, [name for b in banks for name in b.names], digests)

    def describe(self) -> str:
        """One line: videos, frames, shape and memory."""
        h, w, c = self.frame_shape
        return (f"{self.num_videos} videos, {self.num_frames} frames of {h}x{w}x{c} uint8 = "
                f"{self.nbytes / 2**20:.1f} MiB")


def bank_manifests(*trees) -> list[list[dict]]:
    """The `FrameBank.manifest()` of every bank inside `trees` (env params, envs, any pytree or
    object with a `background_bank`), in order, each bank once (equal manifests count once): what a run records of the
    videos and photos it saw (`jaxnat train` writes them to `config.json` as `data`)."""
    manifests = []
    for tree in trees:
        found = getattr(tree, "background_bank", None)
        leaves = [found] if found is not None else jax.tree.leaves(tree, is_leaf=lambda x: isinstance(x, FrameBank))
        for manifest in (leaf.manifest() for leaf in leaves if isinstance(leaf, FrameBank)):
            if manifest not in manifests:
                manifests.append(manifest)
    return manifests


def _from_clips(clips: list[np.ndarray], names: list[str], digests: list[str] = ()) -> FrameBank:
    lengths = np.array([len(c) for c in clips], dtype=np.int32)
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int32)
    return FrameBank(frames=np.ascontiguousarray(np.concatenate(clips)), starts=starts,
                     lengths=lengths, names=tuple(names), digests=tuple(digests))


def _per_video_cap(lengths: list[int], max_frames: int) -> int:
    """The largest c with sum(min(length, c)) <= max_frames: short videos stay whole, long ones
    are cut to their first c frames, so every video keeps a share of the budget."""
    lengths_sorted = sorted(lengths)
    remaining, count = max_frames, len(lengths_sorted)
    for i, length in enumerate(lengths_sorted):
        if length * (count - i) > remaining:
            return remaining // (count - i)
        remaining -= length
    return max(lengths_sorted)


def _check_args(shape, max_frames) -> tuple[int, int]:
    if (not isinstance(shape, (tuple, list)) or len(shape) != 2
            or not all(isinstance(s, (int, np.integer)) and s > 0 for s in shape)):
        raise ValueError(f"shape must be (height, width) with positive ints, got {shape!r}")
    if max_frames is not None and (not isinstance(max_frames, (int, np.integer))
                                   or max_frames < 1):
        raise ValueError(f"max_frames must be a positive int or None, got {max_frames!r}")
    return int(shape[0]), int(shape[1])


def _cache_path(kind: str, split: str, digests: list[str], extra: dict) -> Path:
    key = json.dumps([FORMAT_VERSION, kind, digests, extra], sort_keys=True)
    digest = hashlib.sha256(key.encode()).hexdigest()[:24]
    return _cache.cache_dir() / f"natural-{kind}-{split}-{digest}.npz"


def _check_consistent(bank: FrameBank) -> FrameBank:
    """`bank`, or ValueError when its arrays do not describe a bank: uint8 frames
    [N, H, W, 1 or 3], int32 index [V] of positive lengths tiling the frames in order."""
    frames, starts, lengths = bank.frames, bank.starts, bank.lengths
    if not (frames.dtype == np.uint8 and frames.ndim == 4 and frames.shape[-1] in (1, 3)
            and starts.dtype == lengths.dtype == np.int32 and starts.ndim == lengths.ndim == 1
            and len(starts) == len(lengths) == len(bank.names) >= 1
            and bool(np.all(lengths > 0)) and np.array_equal(starts, np.cumsum(lengths) - lengths)
            and int(lengths.sum()) == frames.shape[0]):
        raise ValueError("inconsistent frame bank arrays")
    return bank


def _read_cached(path: Path, names_by_digest: dict[str, str]) -> FrameBank | None:
    """The cached bank at `path`, its videos named by today's file names (a renamed file keeps
    its entry: the key is its content)."""

    def build(frames, starts, lengths, digests):
        names = tuple(names_by_digest.get(str(d), "") for d in digests)
        if "" in names:
            raise ValueError("the entry's videos are not the requested files")
        return _check_consistent(FrameBank(frames=frames, starts=starts, lengths=lengths,
                                           names=names, digests=tuple(str(d) for d in digests)))

    return _cache.read_arrays(path, ("frames", "starts", "lengths", "digests"), build)


def _write_cached(path: Path, bank: FrameBank, digests: list[str]) -> None:
    _cache.write_arrays(path, {"frames": bank.frames, "starts": bank.starts,
                               "lengths": bank.lengths, "digests": np.array(digests, dtype=str)})


def _load(kind: str, files: list[Path], split: str, test_fraction: float, shape, grayscale: bool,
          max_frames: int | None, cache: bool,
          decode_one: Callable[[Path, int | None], np.ndarray | None]) -> FrameBank:
    chosen = _sources.split_files(files, split, test_fraction)
    # Whether PyAV is installed is in the key: a file skipped without it may decode with it.
    path = _cache_path(kind, split, [d for _, d in chosen],
                       {"shape": list(shape), "grayscale": grayscale, "max_frames": max_frames,
                        "pyav": decode.pyav_available()})
    bank = _read_cached(path, {d: f.name for f, d in chosen}) if cache else None
    if bank is None:
        clips, names, digests = [], [], []
        for file, digest in chosen:
            clip = decode_one(file, max_frames)
            if clip is not None:
                clips.append(clip)
                names.append(file.name)
                digests.append(digest)
        if not clips:
            raise DatasetFormatError(
                f"none of the {len(chosen)} source file(s) of split {split!r} could be decoded "
                f"({', '.join(str(f) for f, _ in chosen)}); see the warnings above for each file")
        if max_frames is not None:
            # More videos than the budget has frames: keep the first ones (content-hash order).
            clips, names, digests = clips[:max_frames], names[:max_frames], digests[:max_frames]
            cap = _per_video_cap([len(c) for c in clips], max_frames)
            clips = [c[:cap] for c in clips]
        bank = _from_clips(clips, names, digests)
        if cache:
            _write_cached(path, bank, digests)
    logger.info("natural %s (%s): %s", kind, split, bank.describe())
    return bank


def load_videos(sources: Sources = None, *, shape: tuple[int, int] = DEFAULT_SHAPE,
                grayscale: bool = False, split: str = "train",
                test_fraction: float = DEFAULT_TEST_FRACTION, max_frames: int | None = None,
                cache: bool = True) -> FrameBank:
    """Decode the videos of `split` into a `FrameBank` of frames resized to `shape` (H, W).

    `sources`: None (opencv-doc's natural videos), a file, a directory, a glob pattern, or a list
    of these. `split`: "train", "test" (disjoint by whole videos, by content hash; see
    `jaxnat.natural.sources`) or "all" (every video, for both, as the paper). `max_frames` bounds
    the bank's total frame count (memory = frames x H x W x C bytes): short videos are kept whole
    and long ones cut to a common length. Unreadable videos are skipped with a warning; when none
    decodes, `DatasetFormatError`.
    """
    shape = _check_args(shape, max_frames)
    files = (_sources.default_video_paths() if sources is None
             else _sources.resolve(sources, _sources.VIDEO_EXTENSIONS))
    return _load("videos", files, split, test_fraction, shape, grayscale, max_frames, cache,
                 lambda f, m: decode.decode_video(f, shape, grayscale, m))


def load_images(sources: Sources = None, *, shape: tuple[int, int] = DEFAULT_SHAPE,
                grayscale: bool = False, split: str = "train",
                test_fraction: float = DEFAULT_TEST_FRACTION, max_frames: int | None = None,
                cache: bool = True) -> FrameBank:
    """Decode still photos into a `FrameBank` where each photo is a one-frame video.

    As `load_videos`; `sources=None` is opencv-doc's natural photos; `max_frames` keeps that
    many photos. Stepping a cursor on this bank moves to a new random photo every step; for one
    still photo per episode, keep the cursor from `cursor_reset` and do not step it.
    """
    shape = _check_args(shape, max_frames)
    files = (_sources.default_image_paths() if sources is None
             else _sources.resolve(sources, _sources.IMAGE_EXTENSIONS))
    return _load("images", files, split, test_fraction, shape, grayscale, max_frames, cache,
                 lambda f, m: decode.decode_image(f, shape, grayscale))
