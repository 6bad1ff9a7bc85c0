"""scripts/gallery.py, the README's pictures: its layout, a Classify strip end to end, and the
README showing every committed picture (so the script cannot rot unnoticed)."""

import importlib.util
import re
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


def _gallery():
    spec = importlib.util.spec_from_file_location("gallery", ROOT / "scripts" / "gallery.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


gallery = _gallery()


def test_layout_shape_and_placement():
    red = np.zeros((28, 28, 3), np.uint8)
    red[..., 0] = 255
    rows = [("one", [("t=0", red), ("t=1", np.full((84, 84), 128, np.uint8))]),
            ("two", [("t=0", red), ("", None), ("t=2", red)])]
    image = gallery.layout(rows, "title", cell=40)
    assert image.dtype == np.uint8
    assert image.shape == (gallery.TITLE_H + 2 * (gallery.CAPTION_H + 40), gallery.LABEL_W + 3 * 40, 3)
    assert gallery.layout(rows, cell=40).shape[0] == 2 * (gallery.CAPTION_H + 40)
    # the first panel's centre is red, the empty cell white
    y = gallery.TITLE_H + gallery.CAPTION_H + 20
    assert tuple(image[y, gallery.LABEL_W + 20]) == (255, 0, 0)
    assert tuple(image[y + gallery.CAPTION_H + 40, gallery.LABEL_W + 40 + 20]) == gallery.BACKGROUND


def test_classify_strip(tmp_path):
    """Digits: two rows (observation, human view) of the shown steps, the human view showing
    more of the image than the agent has revealed; saved under the size budget."""
    from jaxnat.datasets import DatasetNotFoundError

    shown = (0, 1, 3)
    try:
        rows = gallery.classify_rows("Classify/Digits-v0", shown, w=7)
    except DatasetNotFoundError:
        pytest.skip("Classify/Digits-v0 data not installed")
    assert len(rows) == 2 and all(len(panels) == len(shown) for _, panels in rows)
    (_, agent), (_, human) = rows
    for (_, seen), (_, whole) in zip(agent, human):
        assert seen.shape == whole.shape == (28, 28, 3)
        assert (whole >= seen).all() and whole.sum() > seen.sum()
    image = gallery.layout(rows, "Classify", cell=32)
    assert image.shape == (gallery.TITLE_H + 2 * (gallery.CAPTION_H + 32), gallery.LABEL_W + 3 * 32, 3)
    size = gallery.save(image, tmp_path / "classify.png")
    assert 0 < size <= gallery.MAX_BYTES


def test_readme_shows_the_gallery():
    """Every committed picture is in the README, every picture the README names exists, and
    each is under the size budget."""
    readme = (ROOT / "README.md").read_text()
    named = set(re.findall(r"\((docs/gallery/[\w.-]+\.png)\)", readme))
    committed = {str(p.relative_to(ROOT)) for p in (ROOT / "docs" / "gallery").glob("*.png")}
    assert committed, "docs/gallery/ has no pictures: run scripts/gallery.py"
    assert named == committed
    for path in committed:
        assert (ROOT / path).stat().st_size <= gallery.MAX_BYTES
