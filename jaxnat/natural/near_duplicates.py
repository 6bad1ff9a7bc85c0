"""Near-duplicate source files: the same footage under different bytes.

The split (`sources.split_files`) identifies files by a hash of their bytes, so two encodings of
one clip (opencv-doc ships `Megamind.avi` and a damaged re-encoding, `Megamind_bugy.avi`) are
two files, and the split could put one in train and the other in test: the test set would then
hold footage the agent trained on. Files are compared by what they show instead:

- a file's fingerprint is up to `FRAMES` of its first frames (every `STRIDE`-th of the first
  `FRAMES * STRIDE` decoded; a photo is one frame), each as a difference hash (64 bits: is
  each pixel of a 9x8 gray thumbnail brighter than its left neighbour) and its mean colour.
  Flat frames (a thumbnail's gray levels spread less than `MIN_SPREAD`: black fade-ins, blank
  title cards) are skipped: every flat frame hashes alike, so they would tie unrelated clips;
- two files are near-duplicates when, over the frames both fingerprints have (paired in
  order, so a truncated copy matches the start of the whole one), the hashes differ in at
  most `MAX_BITS` bits on average and the mean colours by at most `MAX_LEVELS` gray levels
  (the hash alone ignores brightness, which tells apart clips of one scene in other light);
- near-duplicate groups are the connected components of that relation.

Re-encoding, recompression, a few damaged frames and small resizes leave the hashes within a
few bits; unrelated footage differs in about half of them (~32). A file that decodes no
informative frame has no fingerprint and is near no other file.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence
from pathlib import Path

import cv2
import numpy as np

from jaxnat.natural import decode

__all__ = ["FRAMES", "STRIDE", "MAX_BITS", "MAX_LEVELS", "MIN_SPREAD", "NearDuplicateWarning",
           "fingerprint", "near_duplicate_groups"]

FRAMES = 8
STRIDE = 3
MAX_BITS = 10.0
MAX_LEVELS = 16.0
MIN_SPREAD = 4.0


class NearDuplicateWarning(UserWarning):
    """Source files show the same footage under different bytes; the message names them."""


# content digest -> fingerprint: a folder is fingerprinted on every load of a split, and a
# file's fingerprint depends on its bytes only.
_FINGERPRINTS: dict[str, tuple[np.ndarray, np.ndarray] | None] = {}


def _frame_print(frame: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """(bool[64] difference hash, float[3] mean colour) of a BGR or gray frame, or None when
    the frame is flat."""
    if frame.ndim == 2:
        frame = cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR)
    frame = frame[..., :3]
    thumb = cv2.resize(cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY), (9, 8),
                       interpolation=cv2.INTER_AREA).astype(np.float32)
    if thumb.std() < MIN_SPREAD:
        return None
    return (thumb[:, 1:] > thumb[:, :-1]).ravel(), frame.reshape(-1, 3).mean(0)


def _frames(plain: Path, image: bool):
    if image:
        frame = cv2.imread(str(plain), cv2.IMREAD_COLOR)
        return [] if frame is None else [frame]
    for reader in decode.READERS:
        _, frames = reader(plain)
        try:
            picked = list(itertools.islice(frames, 0, FRAMES * STRIDE, STRIDE))
        finally:
            if hasattr(frames, "close"):
                frames.close()
        if picked:
            return picked
    return []


def fingerprint(path: Path, digest: str | None = None, *, image: bool = False
                ) -> tuple[np.ndarray, np.ndarray] | None:
    """(bool[n, 64] hashes, float[n, 3] mean colours) of the file's informative first frames
    (`image`: the file is a photo, its one frame), or None (nothing decodes, or every sampled
    frame is flat). `digest`: the file's content digest, the key of a cache of fingerprints."""
    if digest is not None and digest in _FINGERPRINTS:
        return _FINGERPRINTS[digest]
    try:
        with decode.plain_file(Path(path)) as plain:
            frames = _frames(plain, image)
    except (OSError, EOFError):  # unreadable: the decoder says so when the bank is built
        frames = []
    prints = [p for p in map(_frame_print, frames) if p is not None]
    result = (np.stack([b for b, _ in prints]), np.stack([m for _, m in prints])) if prints else None
    if digest is not None:
        _FINGERPRINTS[digest] = result
    return result


def near_duplicate_groups(files: Sequence[Path], digests: Sequence[str] | None = None, *,
                          image: Callable[[Path], bool] | None = None) -> list[list[int]]:
    """Groups (of two or more) of indices into `files` that are near-duplicates, each group
    in ascending order, the groups ordered by their first member. `digests`: the files'
    content digests (cache keys); `image`: which files are photos (None: none)."""
    prints = [fingerprint(f, None if digests is None else digests[i],
                          image=image is not None and image(Path(f)))
              for i, f in enumerate(files)]
    # Padded arrays, so each file is compared with all later ones in one vectorised pass.
    count = np.array([0 if p is None else len(p[0]) for p in prints])
    bits = np.zeros((len(files), FRAMES, 64), bool)
    colours = np.zeros((len(files), FRAMES, 3))
    for i, p in enumerate(prints):
        if p is not None:
            bits[i, :count[i]], colours[i, :count[i]] = p[0][:FRAMES], p[1][:FRAMES]
    parent = list(range(len(files)))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i in range(len(files) - 1):
        if not count[i]:
            continue
        common = np.minimum(count[i], count[i + 1:])  # frames paired with each later file
        used = np.arange(FRAMES) < common[:, None]
        weight = used / np.maximum(common, 1)[:, None]
        mean_bits = (np.count_nonzero(bits[i + 1:] != bits[i], axis=2) * weight).sum(1)
        mean_levels = (np.abs(colours[i + 1:] - colours[i]).max(axis=2) * weight).sum(1)
        near = (common > 0) & (mean_bits <= MAX_BITS) & (mean_levels <= MAX_LEVELS)
        for j in np.flatnonzero(near) + i + 1:
            ri, rj = root(i), root(int(j))
            parent[max(ri, rj)] = min(ri, rj)
    groups: dict[int, list[int]] = {}
    for i in range(len(files)):
        groups.setdefault(root(i), []).append(i)
    return sorted(g for g in groups.values() if len(g) > 1)
