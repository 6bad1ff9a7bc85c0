"""`jaxnat reproduce --shard I/N` and `--dry-run`: a grid split into disjoint shares that any
number of jobs train into one folder, the same split on every machine (two shards trained into
one folder and merged: `tests/test_paper_profile.py`, beside the one run they are compared with)."""

import pytest

from jaxnat.reproduce import command, estimates, grid

def test_shards_are_disjoint_cover_the_grid_and_ignore_the_machine():
    cells = [c for c in grid.build_grid(grid.PROFILES["paper"], grid.ONLY_NAMES) if not c.skip]
    shares = [estimates.shard_cells(cells, i, 7, 5) for i in range(7)]
    names = [c.name for share in shares for c in share]
    assert sorted(names) == sorted(c.name for c in cells) and len(set(names)) == len(names)
    loads = [sum(estimates.estimate_seconds(c, 5, "gpu") for c in share) for share in shares]
    assert max(loads) <= 4 / 3 * sum(loads) / 7 + max(estimates.estimate_seconds(c, 5, "gpu") for c in cells)


@pytest.mark.parametrize("text", ["2/2", "1", "a/b", "0/0", "-1/2"])
def test_bad_shard_is_a_one_line_error(text, tmp_path, capsys):
    assert command.main(["--profile", "smoke", "--out", str(tmp_path), "--shard", text]) == 2
    err = capsys.readouterr().err
    assert "--shard takes I/N with 0 <= I < N" in err and err.count("\n") == 1


def test_dry_run_prints_each_share_and_trains_nothing(tmp_path, capsys):
    assert command.main(["--profile", "paper", "--only", "atari,classify", "--out", str(tmp_path), "--dry-run",
                         "--shard", "1/3"]) == 0
    text = capsys.readouterr().out
    assert "1/3" in text and "GPU-hours" in text and "host-hours" in text and "0/3" not in text
    assert not any(p.is_dir() for p in tmp_path.iterdir())  # no cell folder


def test_cells_patterns_pick_the_cells_a_run_trains(tmp_path, capsys):
    """`--cells` keeps the matching cells (shell patterns, any of several) and nothing else."""
    args = command.parse_args(["--profile", "paper", "--only", "classify,mujoco", "--trunks", "cnn", "--out",
                               str(tmp_path), "--cells", "mujoco-*-state-ppo, classify-sweep-w7-*"])
    plan = command.make_plan(args)
    picked = command.pick_plan(plan, command.cell_patterns(args, plan))
    assert [c.name for c in picked.cells] == ["classify-sweep-w7-M20", "mujoco-swimmer-state-ppo",
                                              "mujoco-ant-state-ppo", "mujoco-halfcheetah-state-ppo",
                                              "mujoco-hopper-state-ppo"]
    assert len(plan.cells) > len(picked.cells)  # the report still covers the whole grid
    assert command.main(["--profile", "paper", "--only", "classify", "--out", str(tmp_path), "--dry-run",
                         "--cells", "classify-sweep-*"]) == 0
    text = capsys.readouterr().out
    assert "classify-sweep-w5-M40" in text and "classify-digits-cnn-ppo" not in text


@pytest.mark.parametrize("cells, expected", [
    ("mujoco-*", "--cells pattern 'mujoco-*' matches no cell of --only classify; --dry-run lists the cells"),
    ("classify-digits-cnn-pp", "--cells pattern 'classify-digits-cnn-pp' matches no cell of --only classify "
                               "(did you mean 'classify-digits-cnn-ppo'?)"),
    (" , ", "--cells names no pattern"),
])
def test_cells_pattern_matching_nothing_is_a_one_line_error(cells, expected, tmp_path, capsys):
    assert command.main(["--profile", "paper", "--only", "classify", "--out", str(tmp_path), "--cells", cells]) == 2
    err = capsys.readouterr().err
    assert expected in err and err.count("\n") == 1
    assert not any(p.is_dir() for p in tmp_path.iterdir())  # nothing trained
