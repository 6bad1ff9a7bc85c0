"""Tests for jaxnat.natural: small videos written here with OpenCV's lossless FFV1 codec.

Frame f of a test video is uniform with RGB = (3 + 7 f, 50 + 30 v, 255 - f) for the video's id
v, so every decoded frame says which video and which frame it is (`identity`). Every test runs
with JAXNAT_CACHE_DIR in tmp_path; the real-data tests use Debian's opencv-doc and skip when it
is missing.
"""

from __future__ import annotations

import gzip
import hashlib
import os
import shutil
import sys
import warnings
from pathlib import Path

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnat import natural
from jaxnat.datasets.base import DatasetFormatError, DatasetNotFoundError
from jaxnat.natural import decode, sources

REAL_DOC_DIRS = sources.OPENCV_DOC_DIRS
HAVE_OPENCV_DOC = (REAL_DOC_DIRS[0] / "vtest.avi").is_file()
needs_opencv_doc = pytest.mark.skipif(not HAVE_OPENCV_DOC, reason="Debian opencv-doc missing")


@pytest.fixture(autouse=True)
def isolated(tmp_path, monkeypatch):
    monkeypatch.setenv("JAXNAT_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(decode, "_REPORTED_SHORT", set())
    return tmp_path


def rgb(video: int, frame: int) -> tuple[int, int, int]:
    return (3 + 7 * frame, 50 + 30 * video, 255 - frame)


def identity(frame: np.ndarray) -> tuple[int, int]:
    """(video id, frame index) of a decoded uniform test frame."""
    r, g, _ = (int(x) for x in frame[0, 0])
    return (g - 50) // 30, (r - 3) // 7


def write_video(path: Path, video: int, num_frames: int, size=(24, 32)) -> Path:
    """An FFV1 .avi of `num_frames` uniform frames coloured `rgb(video, f)`."""
    path.parent.mkdir(parents=True, exist_ok=True)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"FFV1"), 10, size[::-1])
    assert writer.isOpened()
    for f in range(num_frames):
        writer.write(np.full((*size, 3), rgb(video, f)[::-1], np.uint8))  # OpenCV writes BGR
    writer.release()
    return path


def expected_frames(video: int, num_frames: int, shape=(12, 16)) -> np.ndarray:
    return np.stack([np.full((*shape, 3), rgb(video, f), np.uint8) for f in range(num_frames)])


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture
def videos(tmp_path) -> list[Path]:
    """Five videos of 3, 5, 4, 6, 2 frames, ids 0..4."""
    return [write_video(tmp_path / "clips" / f"clip{v}.avi", v, n)
            for v, n in enumerate((3, 5, 4, 6, 2))]


def load(sources_, **kw):
    kw.setdefault("shape", (12, 16))
    kw.setdefault("split", "all")
    return natural.load_videos(sources_, **kw)


# ----------------------------------------------------------------------------- decoding


def test_frames_are_decoded_exactly_in_order(videos):
    bank = load(videos[:2])
    assert bank.frames.dtype == np.uint8 and bank.frames.shape == (8, 12, 16, 3)
    assert bank.starts.dtype == np.int32 and bank.lengths.dtype == np.int32
    by_name = dict(zip(bank.names, zip(bank.starts.tolist(), bank.lengths.tolist())))
    assert by_name == {"clip0.avi": (by_name["clip0.avi"][0], 3),
                       "clip1.avi": (by_name["clip1.avi"][0], 5)}
    assert sorted(s for s, _ in by_name.values()) == [0, by_name[bank.names[0]][1]]
    for v, name in enumerate(("clip0.avi", "clip1.avi")):
        start, length = by_name[name]
        np.testing.assert_array_equal(bank.frames[start:start + length],
                                      expected_frames(v, length))
    assert bank.nbytes == 8 * 12 * 16 * 3
    assert "2 videos, 8 frames of 12x16x3" in bank.describe()


def test_resize_keeps_orientation_and_rgb_order(tmp_path):
    path = tmp_path / "halves.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"FFV1"), 10, (32, 24))
    frame = np.zeros((24, 32, 3), np.uint8)
    frame[:, :16] = (255, 0, 0)   # BGR blue on the left
    frame[:12, 16:] = (0, 0, 255)  # BGR red top right, black bottom right
    writer.write(frame)
    writer.release()
    bank = load([path], shape=(6, 8))
    out = bank.frames[0]
    assert out.shape == (6, 8, 3)
    np.testing.assert_array_equal(out[:, :4], np.broadcast_to([0, 0, 255], (6, 4, 3)))
    np.testing.assert_array_equal(out[:3, 4:], np.broadcast_to([255, 0, 0], (3, 4, 3)))
    np.testing.assert_array_equal(out[3:, 4:], 0)
    gray = load([path], shape=(6, 8), grayscale=True).frames[0]
    assert gray.shape == (6, 8, 1)
    assert gray[0, 0, 0] == cv2.cvtColor(np.uint8([[[255, 0, 0]]]), cv2.COLOR_BGR2GRAY)[0, 0]


def test_gzipped_video_decodes_like_the_plain_one(videos, tmp_path):
    packed = tmp_path / "packed" / "clip1.avi.gz"
    packed.parent.mkdir()
    with open(videos[1], "rb") as src, gzip.open(packed, "wb") as dst:
        shutil.copyfileobj(src, dst)
    bank = load(packed.parent)
    assert bank.names == ("clip1.avi.gz",)
    np.testing.assert_array_equal(bank.frames, expected_frames(1, 5))


def test_short_video_uses_what_decodes_and_says_so_once(videos, tmp_path):
    full = write_video(tmp_path / "long.avi", 0, 20).read_bytes()
    cut = tmp_path / "short" / "cut.avi"
    cut.parent.mkdir()
    cut.write_bytes(full[: int(len(full) * 0.9)])  # the index still claims 20 frames
    with pytest.warns(natural.VideoDecodeWarning, match=r"cut\.avi claims 20 frames but only"):
        bank = load([cut], cache=False)
    assert 0 < bank.num_frames < 20
    np.testing.assert_array_equal(bank.frames, expected_frames(0, bank.num_frames))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load([cut], cache=False)  # reported once per process


def test_unreadable_video_is_skipped_with_a_warning_naming_it(videos, tmp_path):
    bad = tmp_path / "clips" / "broken.avi"
    bad.write_bytes(b"RIFF" + b"\x00garbage" * 200)
    with pytest.warns(natural.VideoDecodeWarning, match=r"skipping video .*broken\.avi"):
        bank = load(tmp_path / "clips")
    assert "broken.avi" not in bank.names and bank.num_videos == 5


def test_no_decodable_video_is_a_clear_error(tmp_path):
    bad = tmp_path / "bad"
    bad.mkdir()
    for name in ("a.avi", "b.mp4.gz"):
        (bad / name).write_bytes(name.encode() * 300)
    with pytest.warns(natural.VideoDecodeWarning), \
            pytest.raises(DatasetFormatError, match=r"none of the 2 source file\(s\)"):
        load(bad)


def test_pyav_decodes_what_opencv_cannot(videos, monkeypatch):
    pytest.importorskip("av")
    opened = []

    def opencv_fails(path):
        opened.append(path)
        return 0, iter(())

    monkeypatch.setattr(decode, "READERS", (opencv_fails, decode.pyav_reader))
    bank = load(videos[3:4], cache=False)
    assert opened and bank.names == ("clip3.avi",)
    np.testing.assert_array_equal(bank.frames, expected_frames(3, 6))
    assert load(videos[3:4], cache=False, max_frames=2).num_frames == 2


def test_without_pyav_the_warning_says_how_to_get_it(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "av", None)  # import av -> ImportError
    bad = tmp_path / "odd.mkv"
    bad.write_bytes(b"\x1a\x45\xdf\xa3 not really matroska" * 50)
    with pytest.warns(natural.VideoDecodeWarning, match=r"odd\.mkv.*pip install av"), \
            pytest.raises(DatasetFormatError):
        load([bad])


# ----------------------------------------------------------------------------- sources


def test_directory_glob_and_list_sources(videos, tmp_path):
    (tmp_path / "clips" / "notes.txt").write_text("not a video")
    nested = write_video(tmp_path / "clips" / "deeper" / "clip9.avi", 9, 2)
    by_dir = load(tmp_path / "clips")
    assert sorted(by_dir.names) == sorted([p.name for p in videos] + [nested.name])
    by_glob = load(str(tmp_path / "clips" / "clip[12].avi"))
    assert sorted(by_glob.names) == ["clip1.avi", "clip2.avi"]
    by_list = load([videos[0], str(tmp_path / "clips" / "**" / "clip9.avi")])
    assert sorted(by_list.names) == ["clip0.avi", "clip9.avi"]


def test_bad_sources_are_clear_errors(tmp_path):
    with pytest.raises(DatasetNotFoundError, match=r"glob pattern '.*nothing\*\.mp4' matches"):
        load(str(tmp_path / "nothing*.mp4"))
    with pytest.raises(DatasetNotFoundError, match="no such file or directory: .*typo.avi"):
        load(tmp_path / "typo.avi")
    (tmp_path / "empty").mkdir()
    with pytest.raises(DatasetNotFoundError, match=r"no files with extension .*\.avi.* in "
                                                   r"directory .*empty"):
        load(tmp_path / "empty")
    with pytest.raises(DatasetNotFoundError, match="empty list"):
        load([])


@pytest.mark.parametrize("kwargs, message", [
    ({"shape": (0, 4)}, "shape must be"), ({"shape": 84}, "shape must be"),
    ({"max_frames": 0}, "max_frames must be"), ({"split": "val"}, "unknown split 'val'"),
    ({"test_fraction": 1.5}, r"test_fraction must be in \[0, 1\]")])
def test_bad_arguments_are_clear_errors(videos, kwargs, message):
    with pytest.raises(ValueError, match=message):
        load(videos, **kwargs)


def test_missing_opencv_doc_says_how_to_install_it(monkeypatch, tmp_path):
    monkeypatch.setattr(sources, "OPENCV_DOC_DIRS", (tmp_path / "nowhere",))
    for loader in (natural.load_videos, natural.load_images):
        with pytest.raises(DatasetNotFoundError, match="apt-get install opencv-doc"):
            loader()


# ----------------------------------------------------------------------------- split


def test_split_is_disjoint_deterministic_and_follows_content(videos, tmp_path, monkeypatch):
    train = load(videos, split="train", test_fraction=0.4)
    test = load(videos, split="test", test_fraction=0.4)
    assert set(train.names).isdisjoint(test.names)
    assert sorted(train.names + test.names) == sorted(p.name for p in videos)
    # The rule: the round(0.4 * 5) = 2 files with the smallest content hashes are test.
    ranked = sorted(videos, key=digest)
    assert test.names == tuple(p.name for p in ranked[:2])
    assert train.names == tuple(p.name for p in ranked[2:])
    # Renaming and reordering change nothing: the split follows content.
    moved = [shutil.copy(p, tmp_path / f"renamed_{i}.avi") for i, p in enumerate(videos)]
    again = load([Path(p) for p in reversed(moved)], split="test", test_fraction=0.4,
                 cache=False)
    assert again.names == tuple(f"renamed_{videos.index(p)}.avi" for p in ranked[:2])
    np.testing.assert_array_equal(again.frames, test.frames)
    monkeypatch.setattr(decode, "decode_video", None)  # a cache hit must not decode
    cached = load([Path(p) for p in moved], split="test", test_fraction=0.4)
    assert cached.names == again.names  # named by today's files


def test_split_keeps_one_video_each_side_and_all_uses_everything(videos):
    assert load(videos[:2], split="test", test_fraction=0.01).num_videos == 1
    assert load(videos[:2], split="train", test_fraction=0.99).num_videos == 1
    assert load(videos, split="all").num_videos == 5
    assert load(videos, split="train", test_fraction=0.0).num_videos == 5
    with pytest.raises(DatasetNotFoundError, match=r"split 'test' is empty.*split='all'"):
        load(videos, split="test", test_fraction=0.0)
    with pytest.raises(DatasetNotFoundError, match="split 'train' is empty"):
        load(videos[:1], split="train", test_fraction=0.5)  # one video goes to test


def test_identical_files_count_once(videos, tmp_path):
    twin = Path(shutil.copy(videos[0], tmp_path / "clips" / "twin_of_0.avi"))
    train = load(tmp_path / "clips", split="train")
    test = load(tmp_path / "clips", split="test")
    names = train.names + test.names
    assert len(names) == 5 and ({"clip0.avi", twin.name} & set(names)) == {"clip0.avi"}


def test_max_frames_keeps_short_videos_whole_and_cuts_long_ones(videos):
    bank = load(videos[:3], max_frames=10)  # lengths 3, 5, 4: a common cut at 3
    got = dict(zip(bank.names, bank.lengths.tolist()))
    assert got == {"clip0.avi": 3, "clip1.avi": 3, "clip2.avi": 3}
    for name, start, length in zip(bank.names, bank.starts, bank.lengths):
        v = int(name[4])
        np.testing.assert_array_equal(bank.frames[start:start + length],
                                      expected_frames(v, length))  # the first frames
    bank = load(videos[:3], max_frames=11)
    assert dict(zip(bank.names, bank.lengths.tolist())) == {"clip0.avi": 3, "clip1.avi": 4,
                                                            "clip2.avi": 4}
    assert load(videos[:3], max_frames=2).lengths.tolist() == [1, 1]
    assert load(videos[:3], max_frames=100).num_frames == 12


def write_scene(path: Path, seed: int, num_frames: int, *, codec: str = "FFV1",
                brighten: int = 0) -> Path:
    """A textured clip: a smooth random picture (from `seed`) panning right 2 px a frame.
    The same seed with another codec, brightness or length is the same footage re-encoded,
    slightly altered or truncated."""
    rng = np.random.default_rng(seed)
    world = cv2.resize(rng.uniform(0, 255, (6, 12, 3)).astype(np.float32), (128, 48),
                       interpolation=cv2.INTER_CUBIC)
    path.parent.mkdir(parents=True, exist_ok=True)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*codec), 10, (64, 48))
    assert writer.isOpened()
    for f in range(num_frames):
        frame = np.clip(world[:, 2 * f:2 * f + 64] + brighten, 0, 255).astype(np.uint8)
        writer.write(frame)
    writer.release()
    return path


def test_near_duplicate_videos_stay_on_one_side(tmp_path):
    folder = tmp_path / "footage"
    original = write_scene(folder / "scene.avi", 7, 24)
    # Re-encoded lossily, a little brighter, and cut short: other bytes, the same footage.
    copy = write_scene(folder / "scene_copy.avi", 7, 15, codec="MJPG", brighten=4)
    others = [write_scene(folder / f"other{s}.avi", s, 20) for s in (1, 2, 3)]
    while True:  # unrelated clips until one hashes after both copies (train keeps a file)
        ranked = sorted([original, copy, *others], key=digest)
        # A test fraction whose content-hash cut falls between the two copies (as it may in
        # any real folder): the later copy is the first train file.
        first, later = sorted((ranked.index(original), ranked.index(copy)))
        if later < len(ranked) - 1:
            break
        others.append(write_scene(folder / f"other{len(others) + 1}.avi", len(others) + 1, 20))
    fraction = later / len(ranked)
    today = {p.name: "test" if i < later else "train" for i, p in enumerate(ranked)}
    assert today[original.name] != today[copy.name]
    banks = {}
    for split in ("train", "test"):
        with pytest.warns(natural.NearDuplicateWarning,
                          match=r"kept together in the 'test' split: .*scene.*scene"):
            banks[split] = load(folder, split=split, test_fraction=fraction, shape=(12, 16))
    sides = {name: split for split, bank in banks.items() for name in bank.names}
    assert sides[original.name] == sides[copy.name] == today[ranked[first].name] == "test"
    for p in others:  # unrelated footage keeps today's side
        assert sides[p.name] == today[p.name]
    # Without near-duplicates nothing is said and nothing moves.
    copy.unlink()
    with warnings.catch_warnings():
        warnings.simplefilter("error", natural.NearDuplicateWarning)
        test = load(folder, split="test", test_fraction=0.4, shape=(12, 16))
    assert test.names == tuple(p.name for p in sorted([original, *others], key=digest)[:2])


@needs_opencv_doc
def test_opencv_doc_megamind_copies_stay_on_one_side():
    folder = REAL_DOC_DIRS[0]
    if not (folder / "Megamind_bugy.avi").is_file():
        pytest.skip("opencv-doc without Megamind_bugy.avi")
    files = sources.resolve(folder, sources.VIDEO_EXTENSIONS)
    with pytest.warns(natural.NearDuplicateWarning, match="Megamind.avi.*Megamind_bugy.avi"):
        test = [p.name for p, _ in sources.split_files(files, "test", 0.4)]
    with pytest.warns(natural.NearDuplicateWarning):
        train = [p.name for p, _ in sources.split_files(files, "train", 0.4)]
    assert ("Megamind.avi" in test) == ("Megamind_bugy.avi" in test)
    assert ("Megamind.avi" in train) == ("Megamind_bugy.avi" in train)
    assert not set(test) & set(train)


# ----------------------------------------------------------------------------- cache


def test_second_load_is_served_from_the_cache(videos, tmp_path, monkeypatch):
    first = load(videos)
    assert len(list((tmp_path / "cache").glob("natural-videos-all-*.npz"))) == 1

    def no_decoding(*args, **kwargs):
        raise AssertionError("decoded although cached")

    monkeypatch.setattr(decode, "decode_video", no_decoding)
    second = load(videos)
    np.testing.assert_array_equal(second.frames, first.frames)
    assert second.names == first.names
    np.testing.assert_array_equal(second.starts, first.starts)
    np.testing.assert_array_equal(second.lengths, first.lengths)
    with pytest.raises(AssertionError, match="decoded although cached"):
        load(videos, shape=(6, 8))  # another shape is another entry
    with pytest.raises(AssertionError, match="decoded although cached"):
        load(videos, grayscale=True)


def test_changed_content_invalidates_the_cache(videos, tmp_path):
    load(videos[:2])
    write_video(videos[1], 3, 2)  # same path, new content
    bank = load(videos[:2])
    assert dict(zip(bank.names, bank.lengths.tolist())) == {"clip0.avi": 3, "clip1.avi": 2}
    start = bank.starts[bank.names.index("clip1.avi")]
    np.testing.assert_array_equal(bank.frames[start:start + 2], expected_frames(3, 2))
    assert len(list((tmp_path / "cache").glob("natural-videos-*.npz"))) == 2


def test_cache_false_writes_nothing_and_corrupt_entries_are_rewritten(videos, tmp_path):
    load(videos, cache=False)
    assert not (tmp_path / "cache").exists()
    expected = load(videos)
    (entry,) = (tmp_path / "cache").glob("natural-videos-*.npz")
    entry.write_bytes(b"PK\x03\x04 not a zip")
    with pytest.warns(UserWarning, match="ignoring unreadable dataset cache entry"):
        again = load(videos)
    np.testing.assert_array_equal(again.frames, expected.frames)
    np.testing.assert_array_equal(load(videos).frames, expected.frames)  # rewritten, readable


def test_inconsistent_cache_entry_is_rewritten(videos, tmp_path):
    expected = load(videos)
    (entry,) = (tmp_path / "cache").glob("natural-videos-*.npz")
    with np.load(entry) as arrays:
        broken = dict(arrays)
    broken["lengths"] = broken["lengths"] + 1  # no longer tiles the frames
    with open(entry, "wb") as f:
        np.savez(f, **broken)
    with pytest.warns(UserWarning, match="unreadable dataset cache entry .*inconsistent"):
        again = load(videos)
    np.testing.assert_array_equal(again.lengths, expected.lengths)
    np.testing.assert_array_equal(again.frames, expected.frames)


def test_banks_concatenate_in_order(videos):
    a, b = load(videos[:2]), load(videos[2:3])
    both = natural.FrameBank.concatenate([a, b.to_device()])
    assert both.names == a.names + b.names
    np.testing.assert_array_equal(both.frames, np.concatenate([a.frames, b.frames]))
    assert both.lengths.tolist() == a.lengths.tolist() + b.lengths.tolist()
    assert both.starts.tolist() == [0, int(a.lengths[0]), a.num_frames]
    with pytest.raises(ValueError, match="different frame shapes"):
        natural.FrameBank.concatenate([a, load(videos[2:3], shape=(6, 8))])


# ----------------------------------------------------------------------------- images


def test_each_photo_is_a_one_frame_video(tmp_path):
    folder = tmp_path / "photos"
    folder.mkdir()
    for v in range(4):
        cv2.imwrite(str(folder / f"p{v}.png"), np.full((20, 30, 3), rgb(v, 0)[::-1], np.uint8))
    (folder / "broken.jpg").write_bytes(b"\xff\xd8 not really")
    with pytest.warns(natural.VideoDecodeWarning, match=r"skipping image .*broken\.jpg"):
        bank = natural.load_images(folder, shape=(12, 16), split="all")
    assert bank.lengths.tolist() == [1, 1, 1, 1]
    assert bank.starts.tolist() == [0, 1, 2, 3]
    for name, frame in zip(bank.names, bank.frames):
        np.testing.assert_array_equal(frame, expected_frames(int(name[1]), 1)[0])
    with pytest.warns(natural.VideoDecodeWarning, match="broken"):
        assert natural.load_images(folder, shape=(12, 16), split="all", max_frames=2,
                                   cache=False).num_frames == 2


# ----------------------------------------------------------------------------- sampling


@pytest.fixture
def small_bank(videos):
    """Videos of 3 and 5 frames."""
    return load(videos[:2])


def cursor_identity(bank, cursor) -> tuple[int, int]:
    """(video id written in the file, frame index) of the frame under a scalar cursor."""
    return identity(np.asarray(natural.cursor_frame(bank, cursor)))


def test_cursor_plays_consecutive_frames_and_wraps_to_a_new_video(small_bank):
    bank = small_bank.to_device()
    assert isinstance(bank.frames, jax.Array) and bank.names == small_bank.names
    file_id = [int(n[4]) for n in bank.names]
    step = jax.jit(natural.cursor_step)
    cursor = natural.VideoCursor(video=jnp.int32(0), offset=jnp.int32(0))
    key = jax.random.key(0)
    seen_videos = set()
    for _ in range(60):
        video, offset = int(cursor.video), int(cursor.offset)
        assert cursor_identity(bank, cursor) == (file_id[video], offset)
        key, sub = jax.random.split(key)
        cursor = step(sub, cursor, bank)
        if offset + 1 < int(bank.lengths[video]):
            assert (int(cursor.video), int(cursor.offset)) == (video, offset + 1)
        else:
            assert int(cursor.offset) == 0
            seen_videos.add(int(cursor.video))
    assert seen_videos == {0, 1}  # the next video is random, both occur
    assert step._cache_size() == 1


def test_cursor_vmaps_and_reset_covers_every_video_and_start(small_bank):
    bank = small_bank.to_device()
    num = 2000
    reset = jax.jit(jax.vmap(natural.cursor_reset, in_axes=(0, None)))
    step = jax.jit(jax.vmap(natural.cursor_step, in_axes=(0, 0, None)))
    frame = jax.jit(jax.vmap(natural.cursor_frame, in_axes=(None, 0)))
    cursors = reset(jax.random.split(jax.random.key(1), num), bank)
    assert cursors.video.shape == (num,) and cursors.video.dtype == jnp.int32
    pairs = set(zip(np.asarray(cursors.video).tolist(), np.asarray(cursors.offset).tolist()))
    assert pairs == {(v, o) for v in range(2) for o in range(int(bank.lengths[v]))}
    # Uniform over videos, not frames: about half the envs start in the 3-frame video.
    assert 0.45 < float(np.mean(np.asarray(cursors.video) == 0)) < 0.55
    moved = step(jax.random.split(jax.random.key(2), num), cursors, bank)
    frames = np.asarray(frame(bank, moved))
    index = np.asarray(bank.starts)[np.asarray(moved.video)] + np.asarray(moved.offset)
    np.testing.assert_array_equal(frames, small_bank.frames[index])
    continued = np.asarray(moved.offset) == np.asarray(cursors.offset) + 1
    np.testing.assert_array_equal(np.asarray(moved.video)[continued],
                                  np.asarray(cursors.video)[continued])
    assert np.all(np.asarray(moved.offset)[~continued] == 0) and (~continued).any()


def test_host_sampler_follows_the_same_law(small_bank):
    sampler = natural.HostVideoSampler(small_bank, num_envs=64, seed=3)
    file_id = [int(n[4]) for n in small_bank.names]
    frames = sampler.frames()
    assert frames.shape == (64, 12, 16, 3) and frames.dtype == np.uint8
    previous = [identity(f) for f in frames]
    wrapped = 0
    out = np.empty_like(frames)
    for _ in range(12):
        result = sampler.step(out=out)
        assert result is out
        for env, frame in enumerate(out):
            video_id, index = identity(frame)
            prev_id, prev_index = previous[env]
            if index == prev_index + 1 and video_id == prev_id:
                continue
            assert index == 0  # wrapped: a (random) new video from its first frame
            prev_length = int(small_bank.lengths[file_id.index(prev_id)])
            assert prev_index == prev_length - 1
            wrapped += 1
        previous = [identity(f) for f in out]
    assert wrapped > 64  # every env wrapped at least once in 12 steps of <= 5-frame videos
    before = (sampler.video.copy(), sampler.offset.copy())
    mask = np.arange(64) % 2 == 0
    sampler.reset(mask)
    np.testing.assert_array_equal(sampler.video[~mask], before[0][~mask])
    np.testing.assert_array_equal(sampler.offset[~mask], before[1][~mask])
    assert not np.array_equal(sampler.offset[mask], before[1][mask])


def test_host_sampler_is_reproducible_under_its_seed(small_bank):
    a = natural.HostVideoSampler(small_bank, 8, seed=5)
    b = natural.HostVideoSampler(small_bank, 8, seed=5)
    for _ in range(7):
        np.testing.assert_array_equal(a.step(), b.step())
    with pytest.raises(ValueError, match="num_envs must be >= 1"):
        natural.HostVideoSampler(small_bank, 0)


def test_host_sampler_seeded_per_group_draws_as_each_group_alone(small_bank):
    """`HostVideoSampler(seed=[...])` (and `seed([...])`): the batch as equal groups, each
    drawing its videos and starts, hand-overs and partial resets included, exactly as a sampler
    of its envs alone seeded with its seed; per-env dials follow their envs; groups that do not
    divide the batch are a one-line error."""
    dial = dict(frame_rate=[1, 2, 1, 3, 0, 1], num_videos=[2, 1, 2, 2, 1, 2])
    whole = natural.HostVideoSampler(small_bank, 6, seed=[4, 9, 4], **dial)
    lone = [natural.HostVideoSampler(small_bank, 2, seed=s, frame_rate=dial["frame_rate"][2 * g:2 * g + 2],
                                     num_videos=dial["num_videos"][2 * g:2 * g + 2]) for g, s in enumerate([4, 9, 4])]
    masks = np.random.default_rng(0).random((10, 6)) < 0.3
    for mask in masks:
        np.testing.assert_array_equal(whole.step(), np.concatenate([s.step() for s in lone]))
        np.testing.assert_array_equal(whole.reset(mask), np.concatenate([s.reset(m) for s, m in
                                                                         zip(lone, np.split(mask, 3))]))
    whole.seed([1, 2, 3])
    for s, seed in zip(lone, [1, 2, 3]):
        s.seed(seed)
    np.testing.assert_array_equal(whole.reset(), np.concatenate([s.reset() for s in lone]))
    with pytest.raises(ValueError, match="4 groups do not divide num_envs=6"):
        whole.seed([1, 2, 3, 4])


def test_a_bank_names_its_data_by_content_hash(videos, monkeypatch, tmp_path):
    """`FrameBank.manifest()`: per video its file name, the SHA-256 of the file's bytes and the
    frames held, in bank order, the same from the cache; `bank_manifests` finds the banks in a
    pytree (env params) or an env's `background_bank`, each once."""
    import hashlib

    monkeypatch.setenv("JAXNAT_CACHE_DIR", str(tmp_path / "cache"))
    bank = load(videos[:2])
    manifest = bank.manifest()
    by_name = {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in videos[:2]}
    assert [m["name"] for m in manifest] == list(bank.names)
    assert [m["sha256"] for m in manifest] == [by_name[n] for n in bank.names]
    assert [m["frames"] for m in manifest] == [int(n) for n in bank.lengths]
    assert load(videos[:2]).manifest() == manifest  # read back from the cache
    capped = load(videos[:2], max_frames=4).manifest()
    assert [m["sha256"] for m in capped] == [m["sha256"] for m in manifest] and sum(m["frames"] for m in capped) <= 4
    device = bank.to_device()
    assert natural.bank_manifests({"video": device, "other": 3, "again": device}) == [manifest]

    class Env:
        background_bank = bank

    assert natural.bank_manifests(Env(), {"x": 1}) == [manifest]
    merged = natural.FrameBank.concatenate([bank, load(videos[2:3])])
    assert [m["name"] for m in merged.manifest()] == [*bank.names, videos[2].name]


def test_a_set_with_a_manifest_is_read_as_it_says(videos):
    """`write_manifest(folder)` lists a Kinetics-style folder's files (path, bytes, SHA-256);
    from then on the folder is exactly those files: a file added later is not read, one
    changed or missing is a one-line error, and a damaged manifest says how to rewrite it."""
    import json

    from jaxnat.datasets import DatasetFormatError, DatasetNotFoundError
    from jaxnat.natural import sources

    folder = videos[0].parent
    kinetics = folder / "driving car"
    kinetics.mkdir()
    moved = kinetics / videos[4].name
    videos[4].rename(moved)
    path = natural.write_manifest(folder, sources.VIDEO_EXTENSIONS)
    listed = json.loads(path.read_text())["files"]
    assert [e["path"] for e in listed] == sorted([*(v.name for v in videos[:4]), f"driving car/{moved.name}"])
    assert all(e["sha256"] == hashlib.sha256((folder / e["path"]).read_bytes()).hexdigest() for e in listed)
    (folder / "extra.avi").write_bytes(videos[0].read_bytes() + b"x")
    files = sources.resolve(folder, sources.VIDEO_EXTENSIONS)
    assert [f.relative_to(folder).as_posix() for f in files] == [e["path"] for e in listed]
    assert load(folder).num_videos == 5  # decoded through the manifest
    videos[1].write_bytes(videos[1].read_bytes() + b"changed")
    with pytest.raises(DatasetFormatError, match="changed since .*manifest.json was written"):
        sources.resolve(folder, sources.VIDEO_EXTENSIONS)
    videos[1].unlink()
    with pytest.raises(DatasetNotFoundError, match="is listed in .* but missing"):
        sources.resolve(folder, sources.VIDEO_EXTENSIONS)
    path.write_text("{not json")
    with pytest.raises(DatasetFormatError, match="is not a jaxnat manifest .*write_manifest"):
        sources.resolve(folder, sources.VIDEO_EXTENSIONS)


def test_host_sampler_dial(small_bank):
    """`frame_rate` and `num_videos`, one for all or one per env: the defaults (and every
    video) draw as the plain sampler; rate 0 freezes, rate 3 jumps three frames (a video that
    ends inside a jump hands over at its first frame); `num_videos=1` plays video 0 only."""
    plain = natural.HostVideoSampler(small_bank, 16, seed=2)
    dialled = natural.HostVideoSampler(small_bank, 16, seed=2, frame_rate=1, num_videos=small_bank.num_videos)
    for _ in range(9):
        np.testing.assert_array_equal(plain.step(), dialled.step())
    lengths = small_bank.lengths
    sampler = natural.HostVideoSampler(small_bank, 3, seed=1, frame_rate=[0, 1, 3])
    for _ in range(6):
        video, offset = sampler.video.copy(), sampler.offset.copy()
        sampler.step()
        assert (sampler.video[0], sampler.offset[0]) == (video[0], offset[0])
        for env, rate in ((1, 1), (2, 3)):
            moved = offset[env] + rate
            assert sampler.offset[env] == (moved if moved < lengths[video[env]] else 0)
    one = natural.HostVideoSampler(small_bank, 32, seed=4, num_videos=1, frame_rate=2)
    mixed = natural.HostVideoSampler(small_bank, 32, seed=4, num_videos=[1] * 16 + [2] * 16, frame_rate=2)
    seen = set()
    for _ in range(8):
        one.step()
        assert np.all(one.video == 0)
        mixed.step()
        assert np.all(mixed.video[:16] == 0)
        seen |= set(mixed.video[16:].tolist())
    assert seen == {0, 1}
    for kwargs, match in [(dict(frame_rate=-1), "frame_rate must be >= 0"),
                          (dict(frame_rate=1.5), "frame_rate must be a whole number"),
                          (dict(frame_rate=[1, 2]), r"one number or one per env \(4\)"),
                          (dict(num_videos=0), r"num_videos must be in \[1, 2\]"),
                          (dict(num_videos=3), r"num_videos must be in \[1, 2\]")]:
        with pytest.raises(ValueError, match=match):
            natural.HostVideoSampler(small_bank, 4, **kwargs)


# ----------------------------------------------------------------------------- noise


def test_gaussian_noise_follows_the_repository_law():
    n = 400_000
    # E[max(0, 50 z)] = 50 / sqrt(2 pi) = 19.95; truncation to integers takes off about 0.5.
    expected_mean = 50 / np.sqrt(2 * np.pi) - 0.5
    jax_noise = np.asarray(jax.jit(natural.gaussian_noise, static_argnums=1)(
        jax.random.key(0), (n,)))
    np_noise = natural.gaussian_noise_np(np.random.default_rng(0), (n,))
    for noise in (jax_noise, np_noise):
        assert noise.dtype == np.uint8
        assert abs(np.mean(noise == 0) - 0.5) < 0.01
        assert abs(noise.mean() - expected_mean) < 0.3
        assert noise.max() > 150
    strong = natural.gaussian_noise_np(np.random.default_rng(1), (n,), scale=255.0, mean=10.0)
    assert np.mean(strong == 255) > 0.1
    keys = jax.random.split(jax.random.key(2), 3)
    batch = jax.jit(jax.vmap(lambda k, s: natural.gaussian_noise(k, (4, 5, 3), s)))(
        keys, jnp.array([0.0, 50.0, 100.0]))
    assert batch.shape == (3, 4, 5, 3) and int(batch[0].max()) == 0 and int(batch[2].max()) > 0


def exact_noise_law(scale: float, mean: float) -> np.ndarray:
    """P(value = k), k = 0..255, of clip(floor(mean + N(0,1) * scale), 0, 255)."""
    from statistics import NormalDist

    cdf = NormalDist(mean, scale).cdf
    upper = np.array([cdf(k + 1) for k in range(255)] + [1.0])  # P(value <= k)
    return np.diff(np.concatenate([[0.0], upper]))


@pytest.mark.parametrize("scale, mean", [(50.0, 0.0), (255.0, 10.0), (20.0, 128.0)])
def test_noise_table_is_the_law_to_within_its_resolution(scale, mean):
    table = natural.noise.noise_table(scale, mean)
    assert table.shape == (65536,) and table.dtype == np.uint8
    assert np.all(np.diff(table.astype(int)) >= 0)  # quantiles ascend
    probabilities = np.bincount(table, minlength=256) / 65536
    np.testing.assert_allclose(probabilities, exact_noise_law(scale, mean), atol=1.01 / 65536)
    with pytest.raises(ValueError, match="scale >= 0"):
        natural.noise.noise_table(-1.0, 0.0)


def test_traced_and_table_noise_agree_in_law():
    n = 300_000
    table_route = np.asarray(natural.gaussian_noise(jax.random.key(3), (n,), 50.0))
    traced_route = np.asarray(jax.jit(lambda k, s: natural.gaussian_noise(k, (n,), s))(
        jax.random.key(4), jnp.float32(50.0)))
    law = exact_noise_law(50.0, 0.0)
    for noise in (table_route, traced_route):
        counts = np.bincount(noise, minlength=256)
        # P(0) and P(1..10) each within 5 standard errors of the exact law.
        assert abs(counts[0] / n - law[0]) < 5 * np.sqrt(law[0] / n)
        low = counts[1:11].sum() / n
        assert abs(low - law[1:11].sum()) < 5 * np.sqrt(law[1:11].sum() / n)


def test_named_noise_laws():
    """"authors": the public repository's clip(N(0, 1) * 50, 0) truncated (half the pixels
    black); "centred": N(127.5, 50) rounded, symmetric in [0, 255]; the default is the
    authors'."""
    assert natural.DEFAULT_NOISE == "authors"
    authors, centred = natural.NOISE_LAWS["authors"], natural.NOISE_LAWS["centred"]
    np.testing.assert_allclose(authors.probabilities(), exact_noise_law(50.0, 0.0), atol=1e-15)
    assert abs(authors.probabilities()[0] - 0.508) < 1e-3  # P(50 z < 1)
    mean, std = authors.moments()
    assert abs(mean - (50 / np.sqrt(2 * np.pi) - 0.5)) < 0.3 and 28 < std < 30
    p = centred.probabilities()
    np.testing.assert_allclose(p, p[::-1], atol=1e-12)  # symmetric about 127.5
    assert centred.moments()[0] == pytest.approx(127.5) and 49 < centred.moments()[1] < 50
    assert natural.noise_law("centred") is centred and natural.noise_law(authors) is authors
    with pytest.raises(ValueError, match="noise must be one of"):
        natural.noise_law("uniform")


def test_every_family_defaults_to_one_noise_law():
    """Each family's noise control takes `DEFAULT_NOISE` when not told otherwise (the tests of
    each family check that the draws follow it)."""
    import inspect

    from jaxnat.wrappers import NoiseObservationWrapper

    defaults = {"NoiseObservationWrapper": inspect.signature(NoiseObservationWrapper).parameters["noise"].default}
    try:
        from jaxnat.mjx_pixel.floor import floor_rgb
        from jaxnat.mjx_pixel.pixel import PixelMuJoCo

        defaults["PixelMuJoCo"] = inspect.signature(PixelMuJoCo).parameters["noise"].default
        assert inspect.signature(floor_rgb).parameters["noise"].default is None  # DEFAULT_NOISE
    except ImportError:  # the mujoco extra
        pass
    from jaxnat.atari.backgrounds import make_background
    from jaxnat.atari.env import NaturalAtariVecEnv

    defaults["NaturalAtariVecEnv"] = inspect.signature(NaturalAtariVecEnv).parameters["noise"].default
    defaults["make_background"] = inspect.signature(make_background).parameters["noise"].default
    assert make_background("noise", 1, (4, 4)).law == natural.noise_law()
    assert set(defaults.values()) == {natural.DEFAULT_NOISE}, defaults


def test_constant_color():
    np.testing.assert_array_equal(natural.constant_color((2, 3, 3), (10, 20, 300)),
                                  np.broadcast_to([10, 20, 255], (2, 3, 3)))
    gray = natural.constant_color_np((2, 3, 1), 7)
    assert gray.dtype == np.uint8 and gray.flags.writeable and np.all(gray == 7)
    traced = jax.jit(lambda c: natural.constant_color((2, 2, 3), c))(jnp.array([1, 2, 3]))
    np.testing.assert_array_equal(traced[1, 1], [1, 2, 3])
    with pytest.raises(ValueError, match="color must have 3 values"):
        natural.constant_color_np((2, 3, 3), (1, 2))


# ----------------------------------------------------------------------------- real data


@needs_opencv_doc
def test_default_videos_and_their_documented_split():
    names = [p.name for p in natural.default_video_paths()]
    assert names == ["vtest.avi", "tree.avi", "Megamind.avi", "box.mp4.gz", "cup.mp4.gz"]
    train = natural.load_videos(shape=(16, 16), max_frames=40, cache=False)
    test = natural.load_videos(shape=(16, 16), split="test", max_frames=40, cache=False)
    assert train.names == ("vtest.avi", "tree.avi", "cup.mp4.gz")
    assert test.names == ("Megamind.avi", "box.mp4.gz")
    assert train.num_frames <= 40 and train.frames.shape[1:] == (16, 16, 3)
    assert train.frames.std() > 10  # real pictures, not blank frames


@needs_opencv_doc
def test_tree_avi_is_short_and_known_the_same_file_elsewhere_reported(tmp_path):
    """opencv-doc's tree.avi claims 444 frames and holds 68: the embedded data's known case is
    documented, not warned about on every run; the same shortfall in any other file is."""
    import shutil
    import warnings

    tree = REAL_DOC_DIRS[0] / "tree.avi"
    with warnings.catch_warnings():
        warnings.simplefilter("error", natural.VideoDecodeWarning)
        bank = natural.load_videos([tree], shape=(8, 8), split="all", cache=False)
    assert bank.lengths.tolist() == [68]
    copy = shutil.copy(tree, tmp_path / "forest.avi")
    with pytest.warns(natural.VideoDecodeWarning, match="claims 444 frames but only 68"):
        natural.load_videos([copy], shape=(8, 8), split="all", cache=False)


@needs_opencv_doc
def test_embedded_videos_decode_without_ffmpeg_noise():
    """FFmpeg's messages on the embedded clips ("[h264 @ 0x...] A non-intra slice ...") are
    silenced: a fresh process decoding every default video prints nothing to stderr."""
    import subprocess
    import sys

    code = ("from jaxnat.natural import decode, default_video_paths\n"
            "for p in default_video_paths(): decode.decode_video(p, (16, 16), True, max_frames=50)")
    env = {k: v for k, v in os.environ.items() if k != "OPENCV_FFMPEG_LOGLEVEL"}
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert done.returncode == 0 and done.stderr == "", done.stderr[-500:]


@needs_opencv_doc
def test_default_photos():
    bank = natural.load_images(shape=(8, 8), split="all", cache=False)
    assert bank.num_videos == len(natural.default_image_paths()) == 20
    assert set(bank.lengths.tolist()) == {1}
