"""Write RGB frames to an MP4 (H.264) or GIF file with PyAV (`jaxnat[video]`): `VideoWriter`.

PyAV is FFmpeg's binding, already the natural-video decoder (`jaxnat.natural`), so one library
both writes the videos and, in the tests, reads them back. Frames stream in as they are drawn:
a long episode is never held whole, upscaled, in memory. The file appears only when complete
(written beside it under a `.partial` name, then renamed), so an interrupted `jaxnat play`
leaves no truncated video behind.
"""

from __future__ import annotations

import os
from fractions import Fraction
from pathlib import Path

import numpy as np

__all__ = ["FORMATS", "VideoWriter", "require_av", "upscale"]

# format -> (FFmpeg encoder, pixel format). H.264 in yuv420p is what browsers, players and
# slide decks play; it needs an even width and height. GIF: FFmpeg's fixed 3-3-2 bit palette,
# coarse but dependency-free and looping in any viewer.
FORMATS = {"mp4": ("libx264", "yuv420p"), "gif": ("gif", "rgb8")}


def require_av():
    """`av`, or ImportError with the one-line fix."""
    try:
        import av
    except ImportError:
        raise ImportError("writing videos needs PyAV: pip install 'jaxnat[video]'") from None
    return av


def upscale(frames: np.ndarray, scale: int) -> np.ndarray:
    """`[..., H, W, 3]` -> `[..., H*scale, W*scale, 3]`, each pixel a `scale`-square block
    (nearest neighbour: an 8-pixel glimpse stays 8 crisp blocks, not a blur)."""
    if scale == 1:
        return frames
    return np.repeat(np.repeat(frames, scale, axis=-3), scale, axis=-2)


class VideoWriter:
    """`with VideoWriter(path, "mp4", fps, (height, width)) as video: video.write(frames)`,
    `frames` uint8 `[n, height, width, 3]`; `count` is the frames written."""

    def __init__(self, path, fmt: str, fps: int, size: tuple[int, int]):
        av = require_av()
        codec, pix_fmt = FORMATS[fmt]
        self.path = Path(path)
        self.size = tuple(size)
        self.count = 0
        self._partial = self.path.with_name(f"{self.path.stem}.partial{self.path.suffix}")
        self._container = av.open(str(self._partial), mode="w", format=fmt)
        self._stream = self._container.add_stream(codec, rate=Fraction(fps))
        self._stream.height, self._stream.width = self.size
        self._stream.pix_fmt = pix_fmt
        if fmt == "mp4":
            self._stream.options = {"crf": "18"}  # visually lossless for flat, blocky frames
        self._av = av

    def write(self, frames: np.ndarray) -> None:
        frames = np.ascontiguousarray(frames, np.uint8)
        if frames.shape[1:] != (*self.size, 3):
            raise ValueError(f"frames of shape {frames.shape[1:]}, the video is {self.size} RGB")
        for frame in frames:
            image = self._av.VideoFrame.from_ndarray(frame, format="rgb24")
            self._container.mux(self._stream.encode(image))
        self.count += len(frames)

    def __enter__(self):
        return self

    def __exit__(self, kind, error, traceback):
        try:
            if kind is None:
                self._container.mux(self._stream.encode(None))  # flush the encoder
        finally:
            self._container.close()
        if kind is None:
            os.replace(self._partial, self.path)
        else:
            self._partial.unlink(missing_ok=True)
        return False
