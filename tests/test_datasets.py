"""Tests for jaxnat.datasets: small files in the official layouts, written to tmp_path.

Every test runs with JAXNAT_DATA_DIR, JAXNAT_CACHE_DIR and HOME pointing into tmp_path and the
Debian search locations emptied, so nothing on the machine leaks in; the two real-data tests
restore the Debian locations and skip when the packages are not installed. The download tests
talk only to an http.server on 127.0.0.1.
"""

from __future__ import annotations

import gzip
import hashlib
import http.server
import importlib
import io
import os
import pickle
import re
import struct
import tarfile
import threading
from pathlib import Path

import cv2
import numpy as np
import pytest

import jaxnat.datasets as d
from jaxnat.datasets import DatasetFormatError, DatasetNotFoundError, ImageDataset
from jaxnat.datasets import cifar, idx, locate

# `jaxnat.datasets.download` is the function (the public API); the module is this one.
download_module = importlib.import_module("jaxnat.datasets.download")

REAL_SYSTEM_DIRS = dict(locate.SYSTEM_DIRS)
REAL_DIGITS = Path("/usr/share/doc/opencv-doc/examples/data/digits.png")
REAL_FASHION = Path("/usr/share/datasets/fashion-mnist")
MNIST_FILES = {
    "train": ("train-images-idx3-ubyte", "train-labels-idx1-ubyte"),
    "test": ("t10k-images-idx3-ubyte", "t10k-labels-idx1-ubyte"),
}
CIFAR10_NAMES = ("airplane", "automobile", "bird", "cat", "deer",
                 "dog", "frog", "horse", "ship", "truck")


@pytest.fixture(autouse=True)
def isolated(tmp_path, monkeypatch):
    """Point every location the package reads or writes into tmp_path."""
    monkeypatch.setenv("JAXNAT_DATA_DIR", str(tmp_path / "data"))
    monkeypatch.setenv("JAXNAT_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    monkeypatch.setattr(locate, "SYSTEM_DIRS", {})
    # urllib would send even 127.0.0.1 requests through a proxy named in the environment.
    for var in ("http_proxy", "HTTP_PROXY", "https_proxy", "HTTPS_PROXY", "all_proxy",
                "ALL_PROXY"):
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setenv("no_proxy", "*")
    monkeypatch.setenv("NO_PROXY", "*")
    return tmp_path


@pytest.fixture
def data_dir(tmp_path) -> Path:
    return tmp_path / "data"


# ----------------------------------------------------------------------------- file writers

_IDX_CODES = {np.dtype(np.uint8): 0x08, np.dtype(np.int16): 0x0B, np.dtype(np.float32): 0x0D}


def idx_bytes(array: np.ndarray) -> bytes:
    array = np.asarray(array)
    header = bytes([0, 0, _IDX_CODES[array.dtype], array.ndim])
    header += struct.pack(f">{array.ndim}I", *array.shape)
    return header + array.astype(array.dtype.newbyteorder(">")).tobytes()


def write_idx(path: Path, array: np.ndarray) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    raw = idx_bytes(array)
    path.write_bytes(gzip.compress(raw) if path.name.endswith(".gz") else raw)
    return path


def make_mnist(folder: Path, *, gz: bool, n: int = 7, seed: int = 0):
    """Write both splits of an MNIST-layout dataset; return {split: (images, labels)}."""
    rng = np.random.default_rng(seed)
    out = {}
    for split, (images_name, labels_name) in MNIST_FILES.items():
        images = rng.integers(0, 256, (n, 28, 28), dtype=np.uint8)
        labels = rng.integers(0, 10, n, dtype=np.uint8)
        suffix = ".gz" if gz else ""
        write_idx(folder / (images_name + suffix), images)
        write_idx(folder / (labels_name + suffix), labels)
        out[split] = (images, labels)
    return out


def hwc_images(n: int, seed: int) -> np.ndarray:
    """Images whose three planes differ, so a CHW/HWC mix-up cannot go unnoticed."""
    rng = np.random.default_rng(seed)
    return rng.integers(0, 256, (n, 32, 32, 3), dtype=np.uint8)


def chw_rows(images: np.ndarray) -> np.ndarray:
    """The CIFAR on-disk pixel order: per image, the R plane, then G, then B, row-major."""
    return images.transpose(0, 3, 1, 2).reshape(len(images), 3072)


def make_cifar_binary(folder: Path, name: str):
    """Write a tiny binary release; return {split: (images, labels)} and the class names."""
    num_classes = cifar.NUM_CLASSES[name]
    class_names = CIFAR10_NAMES if name == "cifar10" else tuple(f"class_{i}" for i in range(100))
    rng = np.random.default_rng(1)
    folder.mkdir(parents=True, exist_ok=True)
    if name == "cifar10":
        batches = {"train": [f"data_batch_{i}.bin" for i in range(1, 6)],
                   "test": ["test_batch.bin"]}
        (folder / "batches.meta.txt").write_text("\n".join(class_names) + "\n\n")
    else:
        batches = {"train": ["train.bin"], "test": ["test.bin"]}
        (folder / "fine_label_names.txt").write_text("\n".join(class_names) + "\n")
    out = {}
    for split, files in batches.items():
        all_images, all_labels = [], []
        for i, file in enumerate(files):
            images = hwc_images(3, seed=10 * i + (split == "test"))
            labels = rng.integers(0, num_classes, 3).astype(np.uint8)
            if name == "cifar10":
                prefix = labels[:, None]
            else:  # (coarse, fine): a coarse label that differs from the fine one
                prefix = np.stack([(labels + 1) % 20, labels], axis=1).astype(np.uint8)
            (folder / file).write_bytes(np.concatenate([prefix, chw_rows(images)], 1).tobytes())
            all_images.append(images)
            all_labels.append(labels)
        out[split] = (np.concatenate(all_images), np.concatenate(all_labels))
    return out, class_names


def cifar_pickle(obj, numpy_module: str) -> bytes:
    """Protocol 2 as in the official files, naming numpy's array module `numpy_module`:
    numpy.core (numpy 1, the official files) or numpy._core (numpy 2)."""
    raw = pickle.dumps(obj, protocol=2)
    for module in (b"numpy.core.multiarray\n", b"numpy._core.multiarray\n"):
        raw = raw.replace(module, numpy_module.encode() + b".multiarray\n")
    return raw


def make_cifar_python(folder: Path, name: str, numpy_module: str = "numpy.core"):
    """Write a tiny python release (byte-keyed dicts, pickle protocol 2 like the original)."""
    num_classes = cifar.NUM_CLASSES[name]
    class_names = CIFAR10_NAMES if name == "cifar10" else tuple(f"class_{i}" for i in range(100))
    rng = np.random.default_rng(2)
    folder.mkdir(parents=True, exist_ok=True)
    if name == "cifar10":
        batches = {"train": [f"data_batch_{i}" for i in range(1, 6)], "test": ["test_batch"]}
        labels_key, meta_file, meta = b"labels", "batches.meta", {
            b"label_names": [n.encode() for n in class_names], b"num_cases_per_batch": 3}
    else:
        batches = {"train": ["train"], "test": ["test"]}
        labels_key, meta_file, meta = b"fine_labels", "meta", {
            b"fine_label_names": [n.encode() for n in class_names],
            b"coarse_label_names": [b"x"] * 20}
    (folder / meta_file).write_bytes(cifar_pickle(meta, numpy_module))
    out = {}
    for split, files in batches.items():
        all_images, all_labels = [], []
        for i, file in enumerate(files):
            images = hwc_images(2, seed=100 + i + (split == "test") * 50)
            labels = [int(x) for x in rng.integers(0, num_classes, 2)]
            batch = {b"batch_label": b"batch", b"data": chw_rows(images), labels_key: labels,
                     b"filenames": [b"a.png", b""]}
            if name == "cifar100":
                batch[b"coarse_labels"] = [(x + 1) % 20 for x in labels]
            (folder / file).write_bytes(cifar_pickle(batch, numpy_module))
            all_images.append(images)
            all_labels.append(np.asarray(labels))
        out[split] = (np.concatenate(all_images), np.concatenate(all_labels))
    return out, class_names


def write_png(path: Path, rgb_or_gray: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    image = rgb_or_gray if rgb_or_gray.ndim == 2 else cv2.cvtColor(rgb_or_gray, cv2.COLOR_RGB2BGR)
    assert cv2.imwrite(str(path), image)


def assert_dataset(ds: ImageDataset, images: np.ndarray, labels: np.ndarray) -> None:
    assert ds.images.dtype == np.uint8 and ds.images.flags.c_contiguous
    assert ds.labels.dtype == np.int32
    np.testing.assert_array_equal(ds.images, images)
    np.testing.assert_array_equal(ds.labels, labels)


# ----------------------------------------------------------------------------- IDX


@pytest.mark.parametrize("gz", [True, False], ids=["gz", "raw"])
def test_idx_round_trip(data_dir, gz):
    written = make_mnist(data_dir / "mnist", gz=gz)
    for split, (images, labels) in written.items():
        ds = d.load("mnist", split, cache=False)
        assert (ds.name, ds.split, ds.num_classes) == ("mnist", split, 10)
        assert ds.images.shape == (7, 28, 28, 1)
        assert_dataset(ds, images[..., None], labels)


def test_read_idx_multibyte_dtypes_are_big_endian(tmp_path):
    for dtype in (np.int16, np.float32):
        array = (np.arange(24).reshape(2, 3, 4) * 300 - 1000).astype(dtype)
        read = idx.read_idx(write_idx(tmp_path / f"a-{np.dtype(dtype).name}", array))
        assert read.dtype == dtype
        np.testing.assert_array_equal(read, array)


@pytest.mark.parametrize("gz", [True, False], ids=["gz", "raw"])
def test_idx_truncated_file_is_named(data_dir, gz):
    make_mnist(data_dir / "mnist", gz=gz)
    path = data_dir / "mnist" / ("train-images-idx3-ubyte" + (".gz" if gz else ""))
    path.write_bytes(path.read_bytes()[:-100])
    with pytest.raises(DatasetFormatError, match=re.escape(str(path))):
        d.load("mnist", "train", cache=False)


@pytest.mark.parametrize("corrupt, problem", [
    (lambda raw: b"\x12\x34" + raw[2:], "bad magic"),
    (lambda raw: raw[:2] + b"\x42" + raw[3:], "dtype code"),
    (lambda raw: raw + b"\0", "more data"),
    (lambda raw: b"", "bad magic"),
])
def test_idx_corrupt_header_or_length(tmp_path, corrupt, problem):
    path = tmp_path / "x-idx1-ubyte"
    path.write_bytes(corrupt(idx_bytes(np.arange(5, dtype=np.uint8))))
    with pytest.raises(DatasetFormatError, match=problem) as info:
        idx.read_idx(path)
    assert str(path) in str(info.value)


def test_idx_image_and_label_counts_must_match(data_dir):
    make_mnist(data_dir / "mnist", gz=True)
    write_idx(data_dir / "mnist" / "train-labels-idx1-ubyte.gz", np.zeros(6, np.uint8))
    with pytest.raises(DatasetFormatError, match="7 images but .* 6 labels"):
        d.load("mnist", "train", cache=False)


# ----------------------------------------------------------------------------- CIFAR


@pytest.mark.parametrize("name, subdir", [("cifar10", "cifar-10-batches-bin"),
                                          ("cifar100", "cifar-100-binary")])
def test_cifar_binary_round_trip(data_dir, name, subdir):
    written, class_names = make_cifar_binary(data_dir / name / subdir, name)
    for split, (images, labels) in written.items():
        ds = d.load(name, split, cache=False)
        assert ds.images.shape == (len(images), 32, 32, 3)
        assert ds.class_names == class_names
        assert_dataset(ds, images, labels)  # for CIFAR-100: the fine label, not the coarse


@pytest.mark.parametrize("numpy_module", ["numpy.core", "numpy._core"])
@pytest.mark.parametrize("name, subdir", [("cifar10", "cifar-10-batches-py"),
                                          ("cifar100", "cifar-100-python")])
def test_cifar_python_round_trip(data_dir, name, subdir, numpy_module):
    written, class_names = make_cifar_python(data_dir / name / subdir, name, numpy_module)
    for split, (images, labels) in written.items():
        ds = d.load(name, split, cache=False)
        assert ds.class_names == class_names
        assert_dataset(ds, images, labels)


def test_cifar_files_directly_in_dataset_folder_and_binary_preferred(data_dir):
    written, _ = make_cifar_binary(data_dir / "cifar10", "cifar10")
    # A broken python release beside it must not be read: binary comes first.
    for file in ["batches.meta", "test_batch", *(f"data_batch_{i}" for i in range(1, 6))]:
        (data_dir / "cifar10" / file).write_bytes(b"not a pickle")
    assert_dataset(d.load("cifar10", "test", cache=False), *written["test"])


def test_cifar_binary_truncated_is_named(data_dir):
    folder = data_dir / "cifar10" / "cifar-10-batches-bin"
    make_cifar_binary(folder, "cifar10")
    path = folder / "test_batch.bin"
    path.write_bytes(path.read_bytes()[:-1])
    with pytest.raises(DatasetFormatError, match=re.escape(str(path))):
        d.load("cifar10", "test", cache=False)


class _RunsAShellCommand:
    def __init__(self, command: str):
        self.command = command

    def __reduce__(self):
        return (os.system, (self.command,))


def test_cifar_pickle_with_code_is_refused_and_not_run(data_dir, tmp_path):
    folder = data_dir / "cifar10" / "cifar-10-batches-py"
    make_cifar_python(folder, "cifar10")
    marker = tmp_path / "pwned"
    evil = {b"data": _RunsAShellCommand(f"touch {marker}"), b"labels": [0]}
    (folder / "test_batch").write_bytes(pickle.dumps(evil, protocol=2))
    with pytest.raises(DatasetFormatError, match=r"refusing to unpickle \w+\.system") as info:
        d.load("cifar10", "test", cache=False)
    assert str(folder / "test_batch") in str(info.value)
    assert not marker.exists()


def test_cifar_corrupt_pickle_is_a_format_error(data_dir):
    folder = data_dir / "cifar100" / "cifar-100-python"
    make_cifar_python(folder, "cifar100")
    (folder / "test").write_bytes(pickle.dumps({b"data": 1}, protocol=2)[:-3])
    with pytest.raises(DatasetFormatError, match=re.escape(str(folder / "test"))):
        d.load("cifar100", "test", cache=False)


# ----------------------------------------------------------------------------- digits sheet


def synthetic_sheet() -> np.ndarray:
    """A 2000x1000 sheet whose tile i (row-major) stores i in its top-left two pixels."""
    tiles = np.full((5000, 20, 20), 255, dtype=np.uint8)
    index = np.arange(5000)
    tiles[:, 0, 0] = index % 256
    tiles[:, 0, 1] = index // 256
    return tiles.reshape(50, 100, 20, 20).swapaxes(1, 2).reshape(1000, 2000)


def decoded_index(images: np.ndarray) -> np.ndarray:
    return images[:, 4, 4, 0].astype(int) + 256 * images[:, 4, 5, 0].astype(int)


def test_digits_split_shapes_padding_labels(data_dir):
    (data_dir / "digits").mkdir(parents=True)
    assert cv2.imwrite(str(data_dir / "digits" / "digits.png"), synthetic_sheet())
    splits = {s: d.load("digits", s, cache=False) for s in ("train", "test")}
    assert splits["train"].images.shape == (4000, 28, 28, 1)
    assert splits["test"].images.shape == (1000, 28, 28, 1)
    indices = {}
    for split, ds in splits.items():
        border = ds.images.copy()
        border[:, 4:24, 4:24] = 0
        assert not border.any(), "the 4-pixel border must be zero"
        assert (ds.images[:, 5:24, 4:24] == 255).all(), "the tile must sit at rows/cols 4..23"
        indices[split] = decoded_index(ds.images)
        np.testing.assert_array_equal(ds.labels, indices[split] // 500)
        counts = np.bincount(ds.labels, minlength=10)
        assert (counts == (400 if split == "train" else 100)).all()
    assert not set(indices["train"]) & set(indices["test"])
    assert set(indices["train"]) | set(indices["test"]) == set(range(5000))
    assert ((indices["test"] % 500) % 5 == 4).all()
    assert (np.diff(indices["train"]) > 0).all(), "sheet order is kept"


def test_digits_wrong_sheet_size(data_dir):
    (data_dir / "digits").mkdir(parents=True)
    assert cv2.imwrite(str(data_dir / "digits" / "digits.png"), np.zeros((1000, 1980), np.uint8))
    with pytest.raises(DatasetFormatError, match="2000x1000.*got 1980x1000"):
        d.load("digits", cache=False)


@pytest.mark.skipif(not REAL_DIGITS.is_file(), reason="opencv-doc is not installed")
def test_real_opencv_digits_sheet(monkeypatch):
    monkeypatch.setattr(locate, "SYSTEM_DIRS", REAL_SYSTEM_DIRS)
    for split, n in (("train", 4000), ("test", 1000)):
        ds = d.load("digits", split, cache=False)
        assert ds.images.shape == (n, 28, 28, 1)
        assert (np.bincount(ds.labels, minlength=10) == n // 10).all()
        assert ds.images[:, :4].max() == 0 and ds.images.max() == 255


# ----------------------------------------------------------------------------- Fashion-MNIST


@pytest.mark.skipif(not (REAL_FASHION / "t10k-labels-idx1-ubyte.gz").is_file(),
                    reason="dataset-fashion-mnist is not installed")
def test_real_fashion_mnist_from_debian_package(monkeypatch):
    monkeypatch.setattr(locate, "SYSTEM_DIRS", REAL_SYSTEM_DIRS)
    for split, n in (("train", 60000), ("test", 10000)):
        ds = d.load("fashion_mnist", split, cache=False)
        assert ds.images.shape == (n, 28, 28, 1) and ds.labels.shape == (n,)
        assert ds.num_classes == 10 and ds.class_names[:2] == ("T-shirt/top", "Trouser")
        assert ds.class_names[-1] == "Ankle boot"
        assert (np.bincount(ds.labels) == n // 10).all()  # Fashion-MNIST is balanced


# ----------------------------------------------------------------------------- image folder


def make_image_folder(root: Path, channels: int) -> dict:
    rng = np.random.default_rng(3)
    out = {}
    for split in ("train", "test"):
        images, labels = [], []
        for label, cls in enumerate(("cat", "dog")):
            for i in range(2):
                shape = (5, 6) if channels == 1 else (5, 6, 3)
                image = rng.integers(0, 256, shape, dtype=np.uint8)
                write_png(root / split / cls / f"{i}.png", image)
                images.append(image.reshape(5, 6, channels))
                labels.append(label)
        out[split] = (np.stack(images), np.asarray(labels))
    return out


@pytest.mark.parametrize("channels", [1, 3])
def test_image_folder_exact_pixels(tmp_path, channels):
    written = make_image_folder(tmp_path / "imgs", channels)
    (tmp_path / "imgs" / "train" / "cat" / "notes.txt").write_text("ignored")
    for split, (images, labels) in written.items():
        ds = d.load("image_folder", split, root=tmp_path / "imgs", cache=False)
        assert ds.class_names == ("cat", "dog")
        assert_dataset(ds, images, labels)  # RGB order for colour


def test_image_folder_mismatched_size_names_file(tmp_path):
    make_image_folder(tmp_path / "imgs", 3)
    odd = tmp_path / "imgs" / "train" / "dog" / "1.png"
    write_png(odd, np.zeros((7, 6, 3), np.uint8))
    with pytest.raises(DatasetFormatError, match=re.escape(str(odd)) + ".*resize"):
        d.load("image_folder", "train", root=tmp_path / "imgs", cache=False)


@pytest.mark.parametrize("content", [b"", b"not an image at all"])
def test_image_folder_undecodable_file_names_it(tmp_path, content):
    """A zero-byte or non-image file with an image's name: one error naming the file (a
    zero-byte one made OpenCV's imdecode raise its own assertion, without the name)."""
    make_image_folder(tmp_path / "imgs", 3)
    bad = tmp_path / "imgs" / "train" / "dog" / "1.png"
    bad.write_bytes(content)
    with pytest.raises(DatasetFormatError, match="cannot decode " + re.escape(str(bad))):
        d.load("image_folder", "train", root=tmp_path / "imgs", cache=False)


@pytest.mark.parametrize("image_size", [0, (0, 5), -3, (4, 2.5)])
def test_classify_image_size_must_be_positive(tmp_path, image_size):
    from jaxnat.vision_envs.classify import Classify

    make_image_folder(tmp_path / "imgs", 3)
    with pytest.raises(ValueError, match="image_size must be a positive int"):
        Classify("image_folder", root=tmp_path / "imgs", image_size=image_size, w=1)


def test_image_folder_layout_errors(tmp_path):
    make_image_folder(tmp_path / "imgs", 1)
    (tmp_path / "imgs" / "test" / "dog").rename(tmp_path / "imgs" / "test" / "bird")
    with pytest.raises(DatasetFormatError, match=r"only in train: \['dog'\].*\['bird'\]"):
        d.load("image_folder", "train", root=tmp_path / "imgs", cache=False)
    (tmp_path / "imgs" / "test").rename(tmp_path / "imgs" / "elsewhere")
    with pytest.raises(DatasetNotFoundError, match="no 'test' folder.*expected layout"):
        d.load("image_folder", "train", root=tmp_path / "imgs", cache=False)
    with pytest.raises(ValueError, match="needs root"):
        d.load("image_folder")


# ----------------------------------------------------------------------------- names, resolution


def test_unknown_name_or_split_lists_valid_ones():
    with pytest.raises(ValueError, match="fashion_mnist.*image_folder"):
        d.load("imagenet")
    with pytest.raises(ValueError, match="train, test"):
        d.load("mnist", "validation")


def test_explicit_root_beats_data_dir_and_is_exclusive(data_dir, tmp_path):
    from_env = make_mnist(data_dir / "mnist", gz=True, seed=1)
    from_root = make_mnist(tmp_path / "mine", gz=False, seed=2)
    assert_dataset(d.load("mnist", "test", root=tmp_path / "mine", cache=False),
                   from_root["test"][0][..., None], from_root["test"][1])
    assert_dataset(d.load("mnist", "test", cache=False),
                   from_env["test"][0][..., None], from_env["test"][1])
    with pytest.raises(DatasetNotFoundError, match="root argument"):
        d.load("mnist", "test", root=tmp_path / "typo", cache=False)


def test_search_order_data_dir_then_download_dir_then_debian(data_dir, tmp_path, monkeypatch):
    system = make_mnist(tmp_path / "usr-share-mnist", gz=True, seed=3)
    monkeypatch.setattr(locate, "SYSTEM_DIRS", {"mnist": (tmp_path / "usr-share-mnist",)})
    assert_dataset(d.load("mnist", "test", cache=False), system["test"][0][..., None],
                   system["test"][1])
    home = make_mnist(tmp_path / "home" / ".cache" / "jaxnat" / "data" / "mnist", gz=True, seed=4)
    assert_dataset(d.load("mnist", "test", cache=False), home["test"][0][..., None],
                   home["test"][1])
    env = make_mnist(data_dir / "mnist", gz=True, seed=5)
    assert_dataset(d.load("mnist", "test", cache=False), env["test"][0][..., None],
                   env["test"][1])


def test_missing_dataset_message(data_dir):
    with pytest.raises(DatasetNotFoundError) as info:
        d.load("mnist", "test")
    message = str(info.value)
    assert isinstance(info.value, FileNotFoundError)
    for needle in ("t10k-images-idx3-ubyte", "t10k-labels-idx1-ubyte.gz", str(data_dir / "mnist"),
                   "JAXNAT_DATA_DIR", "d.download('mnist')", "Classify/Digits-v0", "a stand-in, not MNIST"):
        assert needle in message
    with pytest.raises(DatasetNotFoundError, match="apt-get install dataset-fashion-mnist"):
        d.load("fashion_mnist")
    with pytest.raises(DatasetNotFoundError, match="apt-get install opencv-doc"):
        d.load("digits")


def test_data_dir_follows_environment(monkeypatch, data_dir):
    assert d.data_dir() == data_dir
    monkeypatch.delenv("JAXNAT_DATA_DIR")
    assert d.data_dir() is None


def test_image_dataset_checks_its_contract():
    ok = dict(name="x", split="train", images=np.zeros((2, 3, 3, 1), np.uint8),
              labels=np.zeros(2, np.int32), class_names=("a", "b"))
    assert ImageDataset(**ok).num_classes == 2
    for bad in (dict(images=np.zeros((2, 3, 3, 1), np.float32)),
                dict(images=np.zeros((2, 3, 3, 2), np.uint8)),
                dict(labels=np.zeros(3, np.int32)),
                dict(labels=np.array([0, 2], np.int32)),
                dict(labels=np.zeros(2, np.int64))):
        with pytest.raises(ValueError):
            ImageDataset(**{**ok, **bad})


# ----------------------------------------------------------------------------- cache


def test_cache_hit_skips_decoding_and_is_identical(data_dir, tmp_path, monkeypatch):
    make_mnist(data_dir / "mnist", gz=True)
    first = d.load("mnist", "train")
    assert len(list((tmp_path / "cache").glob("mnist-train-*.npz"))) == 1

    def must_not_decode(path):
        raise AssertionError(f"decoded {path} despite the cache")

    monkeypatch.setattr(idx, "read_idx", must_not_decode)
    second = d.load("mnist", "train")
    np.testing.assert_array_equal(second.images, first.images)
    np.testing.assert_array_equal(second.labels, first.labels)
    assert second.class_names == first.class_names
    assert second.images.dtype == np.uint8 and second.labels.dtype == np.int32
    with pytest.raises(AssertionError, match="despite the cache"):
        d.load("mnist", "train", cache=False)


def test_cache_invalidated_when_source_changes(data_dir):
    make_mnist(data_dir / "mnist", gz=False, seed=1)
    d.load("mnist", "test")
    replaced = make_mnist(data_dir / "mnist", gz=False, seed=2)
    os.utime(data_dir / "mnist" / "t10k-images-idx3-ubyte", ns=(1, 1))  # mtime surely differs
    assert_dataset(d.load("mnist", "test"), replaced["test"][0][..., None], replaced["test"][1])


def test_cache_keyed_on_content_not_size_and_mtime(data_dir):
    """New bytes under the old size and modification time (`cp -p`, a re-extracted tarball)
    still make a new entry."""
    make_mnist(data_dir / "mnist", gz=False, seed=1)
    for path in (data_dir / "mnist").iterdir():
        os.utime(path, ns=(5, 5))
    d.load("mnist", "test")
    replaced = make_mnist(data_dir / "mnist", gz=False, seed=2)  # same shapes: same sizes
    for path in (data_dir / "mnist").iterdir():
        os.utime(path, ns=(5, 5))
    assert_dataset(d.load("mnist", "test"), replaced["test"][0][..., None], replaced["test"][1])


def test_corrupt_cache_entry_is_ignored_and_rewritten(data_dir, tmp_path):
    written = make_mnist(data_dir / "mnist", gz=True)
    d.load("mnist", "test")
    (entry,) = (tmp_path / "cache").glob("mnist-test-*.npz")
    entry.write_bytes(b"PK\x03\x04 this is not a zip any more")
    with pytest.warns(UserWarning, match="ignoring unreadable dataset cache entry"):
        ds = d.load("mnist", "test")
    assert_dataset(ds, written["test"][0][..., None], written["test"][1])
    with np.load(entry, allow_pickle=False) as repaired:
        np.testing.assert_array_equal(repaired["labels"], written["test"][1])


def test_image_folder_is_cached_too(tmp_path, monkeypatch):
    written = make_image_folder(tmp_path / "imgs", 3)
    d.load("image_folder", "test", root=tmp_path / "imgs")
    monkeypatch.setattr(cv2, "imdecode", lambda *a: pytest.fail("decoded despite the cache"))
    assert_dataset(d.load("image_folder", "test", root=tmp_path / "imgs"), *written["test"])


# ----------------------------------------------------------------------------- download


class _Handler(http.server.BaseHTTPRequestHandler):
    """Serves `server.files`; honours `Range: bytes=N-`; cuts files in `server.drop` short."""

    def do_GET(self):
        server = self.server
        server.requests.append((self.path, self.headers.get("Range")))
        name = self.path.lstrip("/")
        if name not in server.files:
            self.send_error(404)
            return
        data = server.files[name]
        start = 0
        match = re.fullmatch(r"bytes=(\d+)-", self.headers.get("Range") or "")
        if match:
            start = int(match.group(1))
            self.send_response(206)
            self.send_header("Content-Range", f"bytes {start}-{len(data) - 1}/{len(data)}")
        else:
            self.send_response(200)
        body = data[start:]
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        # A dropped connection: promise len(body) bytes, send half, close.
        self.wfile.write(body[: len(body) // 2] if name in server.drop else body)

    def log_message(self, *args):
        pass


@pytest.fixture
def server():
    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), _Handler)
    httpd.files, httpd.drop, httpd.requests = {}, set(), []
    httpd.url = lambda name: f"http://127.0.0.1:{httpd.server_address[1]}/{name}"
    thread = threading.Thread(target=httpd.serve_forever, args=(0.05,), daemon=True)
    thread.start()
    yield httpd
    httpd.shutdown()
    httpd.server_close()
    thread.join()


def sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def serve_mnist(server, tmp_path) -> dict[str, tuple[str, str]]:
    make_mnist(tmp_path / "served", gz=True)
    urls = {}
    for path in (tmp_path / "served").iterdir():
        server.files[path.name] = path.read_bytes()
        urls[path.name] = (server.url(path.name), sha256(path.read_bytes()))
    return urls


def test_download_then_load(server, tmp_path, data_dir):
    urls = serve_mnist(server, tmp_path)
    dest = d.download("mnist", urls=urls)
    assert dest == data_dir / "mnist"  # the default: $JAXNAT_DATA_DIR/<name>
    for name in urls:
        assert (dest / name).read_bytes() == server.files[name]
    assert not list(dest.glob("*.part"))
    expected = d.load("mnist", "train", root=tmp_path / "served", cache=False)
    np.testing.assert_array_equal(d.load("mnist", "train", cache=False).images, expected.images)
    # Present and verified: nothing is fetched again.
    before = len(server.requests)
    d.download("mnist", urls=urls)
    assert len(server.requests) == before


def test_download_wrong_checksum_leaves_nothing(server, tmp_path):
    server.files["f.gz"] = b"payload"
    dest = tmp_path / "dest"
    with pytest.raises(OSError, match="sha256 mismatch"):
        d.download("mnist", dest, urls={"f.gz": (server.url("f.gz"), sha256(b"other"))})
    assert list(dest.iterdir()) == []


def test_download_dropped_connection_leaves_nothing(server, tmp_path):
    data = gzip.compress(idx_bytes(np.arange(4000, dtype=np.uint8) % 7))
    server.files["f.gz"] = data
    server.drop.add("f.gz")
    dest = tmp_path / "dest"
    with pytest.raises(OSError, match=f"closed after {len(data) // 2} of {len(data)} bytes"):
        d.download("mnist", dest, urls={"f.gz": (server.url("f.gz"), sha256(data))})
    assert list(dest.iterdir()) == []


def test_download_http_error_leaves_nothing(server, tmp_path):
    dest = tmp_path / "dest"
    with pytest.raises(OSError, match="404"):
        d.download("mnist", dest, urls={"gone.gz": (server.url("gone.gz"), sha256(b""))})
    assert list(dest.iterdir()) == []


def test_download_failure_removes_a_corrupt_existing_file(server, tmp_path):
    """A damaged file at the target (wrong hash) is not left in place when the new fetch fails:
    the target is either absent or verified."""
    dest = tmp_path / "dest"
    dest.mkdir()
    (dest / "f.gz").write_bytes(b"damaged")
    with pytest.raises(OSError, match="404"):
        d.download("mnist", dest, urls={"f.gz": (server.url("missing.gz"), sha256(b"good"))})
    assert list(dest.iterdir()) == []


def test_download_resumes_a_part_file(server, tmp_path):
    data = bytes(range(256)) * 40
    server.files["f.bin"] = data
    dest = tmp_path / "dest"
    dest.mkdir()
    (dest / "f.bin.part").write_bytes(data[:1000])  # left by an interrupted run
    d.download("mnist", dest, urls={"f.bin": (server.url("f.bin"), sha256(data))})
    assert (dest / "f.bin").read_bytes() == data
    assert server.requests == [("/f.bin", "bytes=1000-")]
    assert not (dest / "f.bin.part").exists()


def tarball(members: dict[str, bytes]) -> bytes:
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w:gz") as tar:
        for name, content in members.items():
            info = tarfile.TarInfo(name)
            info.size = len(content)
            tar.addfile(info, io.BytesIO(content))
    return buffer.getvalue()


def test_download_unpacks_cifar_tarball(server, tmp_path):
    written, _ = make_cifar_binary(tmp_path / "src" / "cifar-10-batches-bin", "cifar10")
    data = tarball({f"cifar-10-batches-bin/{p.name}": p.read_bytes()
                    for p in (tmp_path / "src" / "cifar-10-batches-bin").iterdir()})
    server.files["cifar-10-binary.tar.gz"] = data
    dest = d.download("cifar10", tmp_path / "dest", urls={
        "cifar-10-binary.tar.gz": (server.url("cifar-10-binary.tar.gz"), sha256(data))})
    assert sorted(p.name for p in dest.iterdir()) == ["cifar-10-batches-bin",
                                                      "cifar-10-binary.tar.gz"]
    assert_dataset(d.load("cifar10", "test", root=dest, cache=False), *written["test"])


@pytest.mark.parametrize("member", ["../escaped.txt", "/tmp/jaxnat-absolute.txt"])
def test_download_refuses_unsafe_tarball(server, tmp_path, member):
    data = tarball({"ok/file.txt": b"fine", member: b"evil"})
    server.files["x.tar.gz"] = data
    dest = tmp_path / "dest"
    with pytest.raises(DatasetFormatError, match="refusing to extract"):
        d.download("cifar10", dest, urls={"x.tar.gz": (server.url("x.tar.gz"), sha256(data))})
    assert not (tmp_path / "escaped.txt").exists()
    assert sorted(p.name for p in dest.iterdir()) == ["x.tar.gz"]


def test_download_refuses_non_downloadable_and_unknown():
    with pytest.raises(ValueError, match="apt-get install opencv-doc"):
        d.download("digits")
    with pytest.raises(ValueError, match="unknown dataset"):
        d.download("imagenet")


def test_official_sources_are_pinned():
    assert set(download_module.REMOTES) == {"mnist", "fashion_mnist", "cifar10", "cifar100"}
    for files in download_module.REMOTES.values():
        for file, remote in files.items():
            assert remote.url.endswith("/" + file)
            assert re.fullmatch(r"[0-9a-f]{64}", remote.sha256)
    assert download_module.REMOTES["mnist"]["t10k-labels-idx1-ubyte.gz"].url.startswith(
        "https://ossci-datasets.s3.amazonaws.com/mnist/")
