"""Shared test set-up: CPU JAX, and a small hand-built image dataset."""

import ctypes.util
import os
import tempfile

os.environ.setdefault("JAX_PLATFORMS", "cpu")
# A persistent XLA compilation cache, shared by the xdist workers: MJX envs take tens of
# seconds to compile on a small CPU, and the same program (e.g. check_env's jitted step and a
# test's) is then compiled once per run. Keys are hashes of the program and versions.
os.environ.setdefault(
    "JAX_COMPILATION_CACHE_DIR", os.path.join(tempfile.gettempdir(), "jaxnat-tests-xla-cache")
)
# mujoco.Renderer (the PixelMuJoCo renderer's reference) draws off-screen with OSMesa on a CPU
# machine (scripts/install_data.sh installs libosmesa6); mujoco reads the variable on import.
if ctypes.util.find_library("OSMesa"):
    os.environ.setdefault("MUJOCO_GL", "osmesa")

import numpy as np
import pytest


@pytest.fixture
def toy_dataset():
    """Three 12x10 grayscale images, labels 0, 1, 2; pixel (r, c) of image i is 1 + i*120 + r*10 + c
    so every pixel value is distinct and non-zero (0 in an observation means unrevealed)."""
    from jaxnat.datasets import ImageDataset

    r, c = np.meshgrid(np.arange(12), np.arange(10), indexing="ij")
    images = np.stack([1 + i * 120 + r * 10 + c for i in range(3)]).astype(np.uint8)[..., None]
    return ImageDataset(
        name="toy",
        split="train",
        images=images,
        labels=np.array([0, 1, 2], dtype=np.int32),
        class_names=("zero", "one", "two"),
    )
