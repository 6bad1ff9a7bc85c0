"""The report's "What the agent sees": which cell's env each experiment's strip shows, and the
strip itself (`jaxnat.reproduce.strips`)."""

import matplotlib.image
import numpy as np

from jaxnat.reproduce import grid, strips

from test_train import needs_digits


def test_each_experiment_shows_its_natural_signal():
    cells = grid.build_grid(grid.PROFILES["paper"], grid.ONLY_NAMES)
    picked = {e: strips.strip_cell(cells, e).name for e in ("classify", "localize", "mujoco", "atari")}
    assert picked["classify"] == "classify-digits-cnn-ppo"
    assert picked["mujoco"] == "mujoco-swimmer-video-ppo"  # pixels on the video floor, not the state references
    assert picked["atari"] == "atari-alien-video-ppo"  # the video background, not the plain game
    assert picked["localize"].startswith("localize-") and "skip" not in picked["localize"]
    states = [c for c in cells if c.experiment == "mujoco" and c.labels["observation"] in ("state", "constant")]
    assert strips.strip_cell(states, "mujoco") is None  # no pixels: no strip
    assert "calibration" not in strips.GAP  # the calibration repeats the experiments' envs: no strip of its own


@needs_digits
def test_a_classify_strip_is_six_frames_side_by_side(tmp_path):
    cells = grid.build_grid(grid.PROFILES["paper"], ("classify",))
    path = tmp_path / "frames-classify.png"
    strips.draw_strip(strips.strip_cell(cells, "classify"), path)
    image = matplotlib.image.imread(path)
    assert image.shape[:2] == (112, 6 * 112 + 5 * 4)  # 28x28 at 4x, 4-pixel white gutters
    assert np.all(image[:, 112:116, :3] == 1.0)  # a gutter
    frames = [image[:, i * 116:i * 116 + 112, :3] for i in range(6)]
    assert all(f.max() > 0 for f in frames)  # each shows its window (tinted red)
    assert not all(np.array_equal(frames[0], f) for f in frames[1:])  # the window moves
