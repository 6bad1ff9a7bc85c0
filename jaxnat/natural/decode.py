"""Decode one video or photo into uint8 frames `[n, H, W, C]` at a target shape.

Videos are read with OpenCV; when OpenCV cannot open a file or decodes no frame from it, PyAV
(`pip install av`, the `video` extra) is tried. A gzipped file (`clip.mp4.gz`) is unpacked to a
temporary file first: decoders need a seekable file with the real extension.

Frames are resized to (H, W) without keeping the aspect ratio (as the authors did: a background
fills the whole frame), with area averaging when shrinking and bilinear interpolation when
enlarging; colour frames are RGB, grayscale frames have C = 1 (ITU-R 601 luma, OpenCV's).

Real files are imperfect: a container may claim more frames than its stream holds (opencv-doc's
`tree.avi` claims 444 and ends after 68). The frames that decode are used, and the shortfall is
reported once per file with a `VideoDecodeWarning` (a shortfall of one frame, common in MP4
files whose count is an estimate, is not reported, nor is the embedded data's one known case:
`KNOWN_SHORT`). FFmpeg's own messages about recoverable stream errors, which OpenCV lets it print
on every decode of the embedded clips, are silenced (`OPENCV_FFMPEG_LOGLEVEL`, unless set).
"""

from __future__ import annotations

import contextlib
import gzip
import itertools
import os
import shutil
import tempfile
import warnings
from collections.abc import Iterator
from pathlib import Path

# FFmpeg logs recoverable decoding errors to stderr ("[h264 @ 0x...] A non-intra slice in an
# IDR NAL unit.") on each open of some embedded clips; what matters reaches the caller as frames
# or a `VideoDecodeWarning`. Set before OpenCV's FFmpeg backend reads it; a user's value wins.
os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")

import cv2  # noqa: E402
import numpy as np  # noqa: E402

__all__ = ["VideoDecodeWarning", "decode_video", "decode_image", "resize_frame",
           "pyav_available", "READERS", "opencv_reader", "pyav_reader", "plain_file"]


class VideoDecodeWarning(UserWarning):
    """A source file was skipped or only partly decoded; the message names the file."""


# Files whose frame-count shortfall has been reported (report once per process).
_REPORTED_SHORT: set[str] = set()


def resize_frame(frame: np.ndarray, shape: tuple[int, int], grayscale: bool,
                 bgr: bool = True) -> np.ndarray:
    """One decoded frame (uint8 [h, w, 3] in BGR order if `bgr`, else RGB; or [h, w]) as uint8
    [H, W, C] with C = 1 if `grayscale` else 3, RGB order."""
    height, width = shape
    if frame.ndim == 2:
        frame = cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR)
    elif frame.shape[2] == 4:
        frame = cv2.cvtColor(frame, cv2.COLOR_BGRA2BGR if bgr else cv2.COLOR_RGBA2RGB)
    shrink = height * width <= frame.shape[0] * frame.shape[1]
    frame = cv2.resize(frame, (width, height),
                       interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)
    if grayscale:
        gray = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY if bgr else cv2.COLOR_RGB2GRAY)
        return gray[..., None]
    return cv2.cvtColor(frame, cv2.COLOR_BGR2RGB) if bgr else np.ascontiguousarray(frame)


@contextlib.contextmanager
def plain_file(path: Path) -> Iterator[Path]:
    """`path` itself, or a temporary unpacked copy when it is gzipped."""
    if path.suffix.lower() != ".gz":
        yield path
        return
    fd, tmp = tempfile.mkstemp(suffix=Path(path.stem).suffix or ".bin", prefix="jaxnat-video-")
    try:
        with os.fdopen(fd, "wb") as out, gzip.open(path, "rb") as src:
            shutil.copyfileobj(src, out, length=1 << 20)
        yield Path(tmp)
    finally:
        Path(tmp).unlink(missing_ok=True)


def opencv_reader(path: Path) -> tuple[int, Iterator[np.ndarray]]:
    """(frame count the container claims, BGR frames as they decode)."""
    capture = cv2.VideoCapture(str(path))
    if not capture.isOpened():
        capture.release()
        return 0, iter(())

    def frames():
        try:
            while True:
                ok, frame = capture.read()
                if not ok:
                    return
                yield frame
        finally:
            capture.release()

    return int(capture.get(cv2.CAP_PROP_FRAME_COUNT)), frames()


def pyav_reader(path: Path) -> tuple[int, Iterator[np.ndarray]]:
    """As `opencv_reader`, through PyAV; nothing when PyAV is not installed. A decoding error
    mid-stream ends the frames (those before it are kept)."""
    try:
        import av
    except ImportError:
        return 0, iter(())
    try:
        container = av.open(str(path))
    except (av.FFmpegError, ValueError, OSError):
        return 0, iter(())
    if not container.streams.video:  # audio only, or not a media file at all
        container.close()
        return 0, iter(())
    stream = container.streams.video[0]

    def frames():
        with container:
            try:
                for frame in container.decode(stream):
                    yield frame.to_ndarray(format="bgr24")
            except (av.FFmpegError, ValueError, OSError):
                return

    return int(stream.frames or 0), frames()


def pyav_available() -> bool:
    """Whether PyAV (`pip install av`) can be imported."""
    try:
        import av  # noqa: F401
    except ImportError:
        return False
    return True


# Tried in order; the first that decodes at least one frame wins.
READERS = (opencv_reader, pyav_reader)


def _decode_resized(plain: Path, shape: tuple[int, int], grayscale: bool,
                    max_frames: int | None) -> tuple[list[np.ndarray], int]:
    """(resized frames, claimed count) from the first reader that decodes a frame. Each frame is
    resized as it arrives, so memory holds at most one full-size frame (a long HD video would
    not fit otherwise)."""
    for reader in READERS:
        claimed, frames = reader(plain)
        try:
            clip = [resize_frame(f, shape, grayscale)
                    for f in itertools.islice(frames, max_frames)]
        finally:
            if hasattr(frames, "close"):
                frames.close()  # releases the decoder when max_frames stopped early
        if clip:
            return clip, claimed
    return [], 0


# Files of the embedded data (Debian's opencv-doc) whose container claims more frames than it
# holds, documented here instead of warned about on every run: name -> (claimed, decoded).
KNOWN_SHORT = {"tree.avi": (444, 68)}


def decode_video(path: Path, shape: tuple[int, int], grayscale: bool,
                 max_frames: int | None = None) -> np.ndarray | None:
    """Frames uint8 [n, H, W, C] of the video at `path` (at most `max_frames`), or None, with a
    `VideoDecodeWarning` naming the file, when neither OpenCV nor PyAV decodes a frame."""
    try:
        with plain_file(path) as plain:
            frames, claimed = _decode_resized(plain, shape, grayscale, max_frames)
    except (OSError, EOFError, gzip.BadGzipFile) as e:
        warnings.warn(f"skipping video {path}: cannot read it ({e})", VideoDecodeWarning,
                      stacklevel=3)
        return None
    if not frames:
        hint = "" if pyav_available() else " (PyAV is not installed: pip install av)"
        warnings.warn(f"skipping video {path}: no frame could be decoded by OpenCV or PyAV; "
                      f"the file is corrupt or in an unsupported format{hint}",
                      VideoDecodeWarning, stacklevel=3)
        return None
    wanted = claimed if max_frames is None else min(claimed, max_frames)
    # Containers' counts are often estimates one frame too high (box.mp4 claims 456, holds 455):
    # only a larger shortfall is worth a warning.
    known = KNOWN_SHORT.get(Path(path).name) == (claimed, len(frames))
    if len(frames) < wanted - 1 and str(path) not in _REPORTED_SHORT and not known:
        _REPORTED_SHORT.add(str(path))
        warnings.warn(f"video {path} claims {claimed} frames but only {len(frames)} decode; "
                      f"using those {len(frames)}", VideoDecodeWarning, stacklevel=3)
    return np.stack(frames)


def decode_image(path: Path, shape: tuple[int, int], grayscale: bool) -> np.ndarray | None:
    """The photo at `path` as uint8 [1, H, W, C], or None with a `VideoDecodeWarning` naming
    the file when OpenCV cannot decode it."""
    try:
        with plain_file(path) as plain:
            image = cv2.imread(str(plain), cv2.IMREAD_COLOR)
    except (OSError, EOFError, gzip.BadGzipFile) as e:
        image, reason = None, f"cannot read it ({e})"
    else:
        reason = "OpenCV cannot decode it (corrupt or not an image)"
    if image is None:
        warnings.warn(f"skipping image {path}: {reason}", VideoDecodeWarning, stacklevel=3)
        return None
    return resize_frame(image, shape, grayscale)[None]
