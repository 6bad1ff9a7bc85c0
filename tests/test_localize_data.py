"""The localization datasets: the Cityscapes loader on a tiny tree in the release layout, and the
embedded clutter scenes (real digits and Fashion-MNIST items on opencv-doc photos)."""

import hashlib

import cv2
import numpy as np
import pytest

from jaxnat import natural
from jaxnat.datasets import DatasetNotFoundError, cityscapes, locate
from jaxnat.datasets.segmentation import VOID, SegmentationDataset
from jaxnat.testing import check_env
from jaxnat.vision_envs.localize import Localize


@pytest.fixture(autouse=True)
def private_dirs(tmp_path, monkeypatch):
    monkeypatch.setenv("JAXNAT_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("JAXNAT_DATA_DIR", str(tmp_path / "data"))


# ---------------------------------------------------------------------------------------------
# Cityscapes

# A 32x64 (h x w) label map of 8x8 blocks: block (i, j) holds label id LABEL_BLOCKS[i][j].
LABEL_BLOCKS = [
    [7, 8, 11, 26, 24, 23, 0, 4],
    [33, 32, 31, 21, 22, 1, 2, 3],
    [29, 30, 9, 10, 14, 15, 16, 18],
    [5, 6, 17, 19, 20, 25, 27, 28],
]


def label_map(shift=0):
    blocks = np.array(LABEL_BLOCKS, np.uint8)
    return np.roll(np.kron(blocks, np.ones((8, 8), np.uint8)), shift, axis=1)


def photo(seed):
    rng = np.random.default_rng(seed)
    return rng.integers(0, 256, (32, 64, 3), dtype=np.uint8)  # RGB


def write_tree(root, layout):
    """`layout` = {split: {city: number of photos}}; returns {(split, city, i): (photo, map)}."""
    written = {}
    for split, cities in layout.items():
        for city, count in cities.items():
            for i in range(count):
                stem = f"{city}_{i:06d}_000019"
                image, labels = photo(hash((split, city, i)) % 1000), label_map(8 * i)
                pdir = root / "leftImg8bit" / split / city
                ldir = root / "gtFine" / split / city
                pdir.mkdir(parents=True, exist_ok=True)
                ldir.mkdir(parents=True, exist_ok=True)
                assert cv2.imwrite(str(pdir / f"{stem}_leftImg8bit.png"),
                                   cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
                assert cv2.imwrite(str(ldir / f"{stem}_gtFine_labelIds.png"), labels)
                # Other gtFine files of the release sit beside the label ids and are ignored.
                assert cv2.imwrite(str(ldir / f"{stem}_gtFine_color.png"), image)
                written[split, city, i] = image, labels
    return written


@pytest.fixture
def tree(tmp_path):
    root = tmp_path / "cityscapes"
    written = write_tree(root, {"train": {"aachen": 2, "bochum": 1}, "val": {"lindau": 2}})
    return root, written


def test_cityscapes_reads_the_release_layout(tree):
    root, written = tree
    ds = cityscapes.load("train", root=root, shape=(32, 64))
    assert isinstance(ds, SegmentationDataset)
    assert ds.images.shape == (3, 32, 64, 3) and ds.class_maps.shape == (3, 32, 64)
    # Sorted by city, then file name; photos in RGB.
    order = [("train", "aachen", 0), ("train", "aachen", 1), ("train", "bochum", 0)]
    for n, key in enumerate(order):
        np.testing.assert_array_equal(ds.images[n], written[key][0])
    assert ds.class_names == cityscapes.class_names("train") and len(ds.class_names) == 19
    assert ds.class_names[:3] == ("road", "sidewalk", "building")
    assert ds.class_names[-1] == "bicycle"


def test_cityscapes_maps_label_ids_to_train_ids(tree):
    root, _ = tree
    ds = cityscapes.load("train", root=root, shape=(32, 64))
    blocks = ds.class_maps[0, ::8, ::8]
    expected_train = {7: 0, 8: 1, 11: 2, 12: 3, 13: 4, 17: 5, 19: 6, 20: 7, 21: 8, 22: 9, 23: 10,
                      24: 11, 25: 12, 26: 13, 27: 14, 28: 15, 31: 16, 32: 17, 33: 18}
    for i, row in enumerate(LABEL_BLOCKS):
        for j, label_id in enumerate(row):
            assert blocks[i, j] == expected_train.get(label_id, VOID), (label_id, blocks[i, j])


def test_cityscapes_all_30_classes(tree):
    root, _ = tree
    ds = cityscapes.load("train", root=root, shape=(32, 64), labels="all")
    assert len(ds.class_names) == 30 and ds.class_names[0] == "static"
    blocks = ds.class_maps[0, ::8, ::8]
    for i, row in enumerate(LABEL_BLOCKS):
        for j, label_id in enumerate(row):
            want = label_id - 4 if label_id >= 4 else VOID  # unlabeled .. out of roi are void
            assert blocks[i, j] == want
            if want != VOID:
                assert ds.class_names[want] == cityscapes.LABEL_NAMES[label_id]


def test_cityscapes_resizes_photos_by_area_and_labels_by_nearest(tree):
    root, written = tree
    ds = cityscapes.load("train", root=root, shape=(16, 16))
    image, labels = written["train", "aachen", 0]
    expected = cv2.resize(image, (16, 16), interpolation=cv2.INTER_AREA)
    np.testing.assert_array_equal(ds.images[0], expected)
    # Nearest neighbour: every resized value is one of the original's, no blending.
    table = cityscapes.label_table("train")
    assert set(np.unique(ds.class_maps[0])) <= set(np.unique(table[labels]))
    np.testing.assert_array_equal(
        ds.class_maps[0], table[cv2.resize(labels, (16, 16), interpolation=cv2.INTER_NEAREST)])


def test_cityscapes_test_split_is_val(tree):
    root, written = tree
    for split in ("test", "val"):
        ds = cityscapes.load(split, root=root, shape=(32, 64))
        assert len(ds.images) == 2
        np.testing.assert_array_equal(ds.images[1], written["val", "lindau", 1][0])


def test_cityscapes_is_cached(tree, tmp_path):
    root, _ = tree
    first = cityscapes.load("train", root=root, shape=(32, 64))
    entries = list((tmp_path / "cache").glob("cityscapes-train-*.npz"))
    assert len(entries) == 1
    second = cityscapes.load("train", root=root, shape=(32, 64))
    np.testing.assert_array_equal(first.class_maps, second.class_maps)
    cityscapes.load("train", root=root, shape=(16, 16))  # other settings: another entry
    assert len(list((tmp_path / "cache").glob("cityscapes-train-*.npz"))) == 2


def test_cityscapes_found_in_jaxnat_data_dir(tmp_path):
    write_tree(tmp_path / "data" / "cityscapes", {"val": {"munster": 1}})
    assert len(cityscapes.load("test", shape=(32, 64)).images) == 1


def test_cityscapes_missing_directory_says_how_to_get_it(tmp_path):
    with pytest.raises(DatasetNotFoundError) as err:
        cityscapes.load("train", root=tmp_path / "nowhere")
    message = str(err.value)
    assert str(tmp_path / "nowhere") in message
    assert "leftImg8bit/{train,val}/<city>/*_leftImg8bit.png" in message
    assert "gtFine_trainvaltest.zip" in message and "Localize/Clutter-v0" in message


def test_cityscapes_missing_label_file_is_named(tree):
    root, _ = tree
    missing = root / "gtFine" / "train" / "bochum" / "bochum_000000_000019_gtFine_labelIds.png"
    missing.unlink()
    with pytest.raises(DatasetNotFoundError, match="bochum_000000_000019_gtFine_labelIds.png"):
        cityscapes.load("train", root=root)


def test_cityscapes_bad_arguments(tree):
    root, _ = tree
    with pytest.raises(ValueError, match="labels"):
        cityscapes.load("train", root=root, labels="coarse")
    with pytest.raises(ValueError, match="split"):
        cityscapes.load("extra", root=root)


def test_localize_env_on_the_tiny_tree(tree):
    root, _ = tree
    env = Localize("cityscapes", split="test", root=root, image_size=(32, 64), w=4)
    params = env.default_params
    assert env.split == "test" and env.num_classes == 19
    check_env(env, params, num_steps=5)


# ---------------------------------------------------------------------------------------------
# Clutter

clutter = pytest.importorskip("jaxnat.natural.clutter")


def _require_embedded_data():
    try:
        locate.find("digits", "train")
        locate.find("fashion_mnist", "train")
        clutter.background_files()
    except DatasetNotFoundError as err:
        pytest.skip(f"embedded data not present: {str(err).splitlines()[0]}")


@pytest.fixture
def scenes():
    _require_embedded_data()
    return {s: clutter.build(s, shape=(64, 64), num_images=24, seed=3) for s in ("train", "test")}


def _digest(array):
    return hashlib.sha256(np.ascontiguousarray(array).tobytes()).hexdigest()


def test_clutter_backgrounds_are_disjoint_natural_photos_and_videos():
    _require_embedded_data()
    banks = {s: clutter.background_frames(s, (32, 32)) for s in ("train", "test")}
    names = {s: set(b.names) for s, b in banks.items()}
    assert names["train"] and names["test"] and not names["train"] & names["test"]
    for bank in banks.values():  # photos (one frame) and videos (many) in each split
        lengths = np.asarray(bank.lengths)
        assert (lengths == 1).any() and (lengths > 1).any()
    assert not ({_digest(f) for f in banks["train"].frames}
                & {_digest(f) for f in banks["test"].frames})


def test_clutter_backgrounds_from_your_own_files(tmp_path):
    """`backgrounds=` replaces opencv-doc's photos and videos (here: four of its photos, copied)."""
    _require_embedded_data()
    folder = tmp_path / "mine"
    folder.mkdir()
    for path in natural.default_image_paths()[:4]:
        (folder / path.name).write_bytes(path.read_bytes())
    banks = {s: clutter.background_frames(s, (32, 32), folder) for s in ("train", "test")}
    names = [set(b.names) for b in banks.values()]
    assert names[0] | names[1] == {p.name for p in folder.iterdir()} and not names[0] & names[1]
    scenes = clutter.load("test", shape=(32, 32), num_images=3, backgrounds=folder)
    assert scenes.images.shape == (3, 32, 32, 3)
    with pytest.raises(DatasetNotFoundError, match="empty"):
        (tmp_path / "empty").mkdir()
        clutter.background_frames("train", (32, 32), tmp_path / "empty")


def test_clutter_objects_are_disjoint_between_splits():
    _require_embedded_data()
    (train_items, train_classes), (test_items, test_classes) = (
        clutter.object_items("train"), clutter.object_items("test"))
    assert set(np.unique(train_classes)) == set(np.unique(test_classes)) == set(range(20))
    # Digits come from the sheet's fixed split; Fashion-MNIST from its train / t10k files.
    assert len(train_items) == 4000 + 60000 and len(test_items) == 1000 + 10000
    train_digits = {_digest(x) for x in train_items[train_classes < 10]}
    assert not train_digits & {_digest(x) for x in test_items[test_classes < 10]}


def test_clutter_scenes_are_deterministic_from_the_seed(scenes):
    again = clutter.build("train", shape=(64, 64), num_images=24, seed=3)
    np.testing.assert_array_equal(again.images, scenes["train"].images)
    np.testing.assert_array_equal(again.class_maps, scenes["train"].class_maps)
    other = clutter.build("train", shape=(64, 64), num_images=24, seed=4)
    assert not np.array_equal(other.images, scenes["train"].images)


def test_clutter_scenes_hold_several_objects_of_distinct_classes(scenes):
    ds = scenes["train"]
    assert ds.class_names == clutter.CLASS_NAMES and len(ds.class_names) == 20
    assert ds.class_names[0] == "digit 0" and ds.class_names[10] == "T-shirt/top"
    counts = ds.presence().sum(axis=1)
    assert counts.min() >= 1 and counts.max() <= 5 and counts.mean() > 2
    assert set(np.unique(ds.class_maps)) <= set(range(20)) | {VOID}
    assert (ds.class_maps == VOID).mean() > 0.5  # mostly background


def test_clutter_mask_is_exactly_the_pasted_pixels():
    """On a black background, void pixels stay black and every object pixel is brighter than
    the threshold (pixel = colour * intensity / 255 with a colour of value 255)."""
    _require_embedded_data()
    items, classes = clutter.object_items("test")
    by_class = [np.flatnonzero(classes == c) for c in range(20)]
    black = natural.FrameBank(np.zeros((1, 64, 64, 3), np.uint8), np.array([0], np.int32),
                              np.array([1], np.int32), ("black",))
    rng = np.random.default_rng(0)
    for _ in range(20):
        image, class_map = clutter.scene(rng, black, items, classes, by_class, (3, 5))
        void = class_map == VOID
        assert (image[void] == 0).all()
        assert (image[~void].max(axis=-1) > clutter.THRESHOLD * 0.99).all()


def test_clutter_is_cached(tmp_path):
    _require_embedded_data()
    first = clutter.load("test", shape=(32, 32), num_images=4)
    assert len(list((tmp_path / "cache").glob("clutter-test-*.npz"))) == 1
    second = clutter.load("test", shape=(32, 32), num_images=4)
    np.testing.assert_array_equal(first.images, second.images)


def test_clutter_bad_arguments():
    with pytest.raises(ValueError, match="split"):
        clutter.build("val")
    with pytest.raises(ValueError, match="objects"):
        clutter.build("train", objects=(3, 2))
    with pytest.raises(ValueError, match="num_images"):
        clutter.build("train", num_images=0)
