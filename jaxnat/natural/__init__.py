"""Natural signal sources: video and photo frame banks, a frame sampler, and noise backgrounds.

    import jax
    from jaxnat import natural

    bank = natural.load_videos(shape=(84, 84), split="train")   # FrameBank, numpy, on the host
    print(bank.describe())           # "3 videos, 1080 frames of 84x84x3 uint8 = 21.8 MiB"
    dev = bank.to_device()           # jax arrays, to carry in env params
    cursor = natural.cursor_reset(jax.random.key(0), dev)
    frame = natural.cursor_frame(dev, cursor)                 # uint8 [84, 84, 3]
    cursor = natural.cursor_step(jax.random.key(1), cursor, dev)

- Sources (`sources.py`): None = the natural videos (or photos) of Debian's `opencv-doc`, else a
  file, a directory, a glob, or a list of these (e.g. a Kinetics download).
- Split: by whole files, by content hash, disjoint by construction; near-duplicate files (the
  same footage under different bytes, `near_duplicates.py`) kept on one side with a
  `NearDuplicateWarning`; `split="all"` uses every file for both, as the paper did.
- Decoding (`decode.py`): OpenCV, PyAV where OpenCV fails; gzipped files handled; frames resized
  to (H, W), RGB or grayscale.
- `FrameBank` (`bank.py`): uint8 [N, H, W, C] with per-video `starts` and `lengths`; cached on
  disk by content, shape and colour mode; `max_frames` bounds memory.
- Sampling (`sampler.py`): `VideoCursor` with `cursor_reset` / `cursor_step` / `cursor_frame`
  (jit, vmap) and `HostVideoSampler` for batched host envs.
- Noise (`noise.py`): the noise controls' named laws (`NOISE_LAWS`: `"authors"`, N(0,1)*50
  clipped at 0, the paper repository's law and `DEFAULT_NOISE`; `"centred"`, N(127.5, 50)
  rounded), `gaussian_noise` and `constant_color`, each with a NumPy twin.
- Clutter scenes (`clutter.py`, imported on its own: `from jaxnat.natural import clutter`):
  digits and Fashion-MNIST items pasted on these backgrounds, the data of `Localize/Clutter-v0`.

This package builds on `jaxnat.datasets` (its cache, errors and loaders); `jaxnat.datasets`
never imports it.
"""

from jaxnat.natural.bank import (
    DEFAULT_SHAPE,
    DEFAULT_TEST_FRACTION,
    FrameBank,
    bank_manifests,
    load_images,
    load_videos,
)
from jaxnat.natural.decode import VideoDecodeWarning
from jaxnat.natural.near_duplicates import NearDuplicateWarning
from jaxnat.natural.noise import (
    DEFAULT_NOISE,
    NOISE_LAWS,
    NOISE_SCALE,
    NoiseLaw,
    constant_color,
    constant_color_np,
    gaussian_noise,
    gaussian_noise_np,
    noise_law,
)
from jaxnat.natural.sampler import (
    HostVideoSampler,
    VideoCursor,
    cursor_frame,
    cursor_index,
    cursor_reset,
    cursor_step,
)
from jaxnat.natural.sources import default_image_paths, default_video_paths, write_manifest

__all__ = [
    "FrameBank",
    "bank_manifests",
    "load_videos",
    "load_images",
    "default_video_paths",
    "default_image_paths",
    "write_manifest",
    "DEFAULT_SHAPE",
    "DEFAULT_TEST_FRACTION",
    "VideoDecodeWarning",
    "NearDuplicateWarning",
    "VideoCursor",
    "cursor_reset",
    "cursor_step",
    "cursor_frame",
    "cursor_index",
    "HostVideoSampler",
    "NOISE_SCALE",
    "NoiseLaw",
    "NOISE_LAWS",
    "DEFAULT_NOISE",
    "noise_law",
    "gaussian_noise",
    "gaussian_noise_np",
    "constant_color",
    "constant_color_np",
]
