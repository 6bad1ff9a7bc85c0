"""The paper profile and the calibration (`jaxnat.reproduce.grid`, `calibration`), without
training: budgets at 100% of the paper's, the batch per family, the PixelMuJoCo references
trained with the pixel cells' settings, stand-ins never named as the paper's datasets, the
calibration's cells and its verdict on hand-made results, and `--trunks`."""

import dataclasses

import numpy as np
import pytest

from jaxnat import spaces
from jaxnat.agents import resolve_config
from jaxnat.reproduce import calibration, command, estimates, grid
from jaxnat.reproduce.report import CellResult

PAPER = grid.PROFILES["paper"]


@pytest.fixture(scope="module")
def paper_cells():
    return grid.build_grid(PAPER, grid.ONLY_NAMES)


def test_paper_profile_trains_every_finding_cell_at_the_papers_budget(paper_cells):
    for cell in paper_cells:
        if cell.experiment != grid.CALIBRATION:
            assert cell.budget.total_timesteps == grid.PAPER_BUDGETS[cell.experiment], cell.name
    assert grid.PAPER_BUDGETS["atari"] == 10_000_000  # agent steps: 40M frames


def test_paper_profile_batches_are_gpu_sized_except_host_atari_and_calibrated_algos(paper_cells):
    for cell in paper_cells:
        if cell.host or cell.experiment == grid.CALIBRATION:
            continue
        if cell.experiment in ("classify", "localize") and cell.algo in ("a2c", "acktr"):
            continue  # the authors' batch: the calibration cleared no larger one
        assert cell.overrides["num_envs"] >= 128, cell.name  # the authors: 8-32
    steps = {(c.experiment, c.algo): c.overrides.get("num_steps") for c in paper_cells if not c.host}
    assert steps[("classify", "ppo")] == 32 and steps[("classify", "a2c")] == 5 and steps[("classify", "acktr")] == 20
    assert steps[("mujoco", "ppo")] == 16 and steps[("mujoco", "a2c")] == 5
    # Natural Atari keeps the authors' envs per update (its cost is the host's cores).
    assert all("num_envs" not in c.overrides for c in paper_cells if c.host)


def test_pixelmujoco_grid_has_the_papers_observations_and_two_references(paper_cells):
    mujoco = [c for c in paper_cells if c.experiment == "mujoco"]
    assert len(mujoco) == 4 * 5 * 2  # robots x (checker, video, noise, state, constant) x (PPO, A2C)
    assert {c.labels["observation"] for c in mujoco} == {"checker", "video", "noise", "state", "constant"}
    assert {c.algo for c in mujoco} == {"ppo", "a2c"}


@pytest.mark.parametrize("algo", ["ppo", "a2c"])
def test_state_and_constant_references_train_with_the_pixel_cells_settings(paper_cells, algo):
    """A state-vector env would otherwise take the MuJoCo family defaults (1 env x 2048 steps,
    10 epochs, ...): the reference cells must resolve to the pixel cell's config, but for the
    trunk, the observation normalisation and the computation dtype (float32 for the MLP; the
    pixel trunk's PPO computes in bfloat16) the vector observation decides."""
    pixels, vector = spaces.Box(0, 255, (84, 84, 4), np.uint8), spaces.Box(-np.inf, np.inf, (17,), np.float32)
    action = spaces.Box(-1.0, 1.0, (6,), np.float32)
    cells = {c.labels["observation"]: c for c in paper_cells
             if c.experiment == "mujoco" and c.labels["robot"] == "HalfCheetah" and c.algo == algo}
    def settings(cell):  # the config fields (not `jaxnat train`'s run settings)
        return {k: v for k, v in cell.overrides.items() if k not in grid.RUN_SETTINGS}

    reference = resolve_config(algo, pixels, action, settings(cells["checker"])).config
    for observation in ("state", "constant"):
        config = resolve_config(algo, vector, action, settings(cells[observation])).config
        differ = {f.name for f in dataclasses.fields(config) if getattr(config, f.name) != getattr(reference, f.name)}
        assert differ <= {"normalize_observations", "trunk", "dtype"}, (observation, differ)
        assert config.normalize_rewards and config.num_envs == 1024 and config.dtype == "float32"
    assert reference.dtype == ("bfloat16" if algo == "ppo" else "float32")


def test_stand_in_cells_are_never_named_after_the_papers_dataset(paper_cells):
    for cell in paper_cells:
        if cell.note and "stands in for" in cell.note:
            paper_name = cell.labels["dataset"]  # the role: mnist, cifar10
            assert f"-{paper_name}-" not in cell.name and not cell.name.endswith(f"-{paper_name}"), cell.name
    assert grid.data_name("mnist", "Digits stands in for MNIST") == "digits"
    assert grid.data_name("cifar10", "Fashion-MNIST stands in for CIFAR-10") == "fashionmnist"
    assert grid.data_name("mnist", "") == "mnist"


def test_calibration_is_named_only_on_request_and_matches_steps(paper_cells):
    plan = command.make_plan(command.ReproduceArgs(profile="paper", out="/tmp/unused-jaxnat-plan"))
    assert not any(c.experiment == grid.CALIBRATION for c in plan.cells)
    cal = [c for c in paper_cells if c.experiment == grid.CALIBRATION]
    assert {c.budget.total_timesteps for c in cal} == {grid.CALIBRATION_STEPS}
    assert len({c.name for c in cal}) == len(cal)
    by = {(c.labels["group"], c.algo, c.labels["variant"]): c for c in cal}
    assert calibration.optimizer_steps(by["classify", "ppo", "authors"]) == (8, 128, 1000 * 16 / 1024)
    assert calibration.optimizer_steps(by["classify", "a2c", "authors"]) == (16, 5, 1000 / 80)
    assert calibration.optimizer_steps(by["classify", "acktr", "authors"]) == (32, 20, 1000 / 640)
    profile = next(c for c in paper_cells if c.name.startswith("classify-") and c.algo == "ppo")
    assert by["classify", "ppo", grid.profile_variant("classify", "ppo")].overrides == profile.overrides
    assert by["mujoco", "ppo", "sign-clipped rewards"].overrides.get("clip_rewards") is True


def _calibrated(variant, mean, untrained=0.0):
    cell = grid.Cell(f"calibration-classify-ppo-{variant}", grid.CALIBRATION, grid.CALIBRATION, "X/Y-v0", {}, "ppo",
                     None, grid.Budget(grid.CALIBRATION_STEPS), {"num_envs": 8, "num_steps": 128},
                     {"group": "classify", "variant": variant})
    steps = np.linspace(2e5, 2e6, 10)
    train = np.full((10, 3), mean) + np.array([-0.05, 0.0, 0.05])
    sampled = np.stack([untrained + np.array([-0.05, 0.0, 0.05]), train[-1]])
    return CellResult(cell, True, 3, steps, train, np.array([0.0, 2e6]), sampled, sampled, None, 1.0)


def test_calibration_band_positions():
    authors = _calibrated("authors", 0.7)
    assert calibration.band_position(_calibrated("profile", 0.72), authors) == "inside"
    assert calibration.band_position(_calibrated("profile", 0.9), authors) == "above"
    assert calibration.band_position(_calibrated("profile", 0.4), authors) == "below"
    assert calibration.band_position(_calibrated("profile", 0.4, untrained=0.4), authors) == "did not learn"
    lines = calibration.calibration_section([authors, _calibrated("profile", 0.4)])
    row = next(line for line in lines if "| profile |" in line)
    assert row.endswith("| below |") and "| 8 x 128 | 15.6 |" in row


def test_trunks_option_selects_the_vision_tier_and_rejects_unknown_names(tmp_path):
    plan = command.make_plan(command.ReproduceArgs(profile="paper", only="classify", trunks="cnn", out=tmp_path))
    assert plan.cells and all(c.labels.get("trunk", "cnn") == "cnn" for c in plan.cells)
    assert any(c.figure == "sweep" for c in plan.cells)  # the sweep has no trunk label: always kept
    with pytest.raises(command.ReproduceError, match="unknown --trunks name 'resnet'"):
        command.make_plan(command.ReproduceArgs(profile="paper", trunks="resnet", out=tmp_path))


def test_gpu_estimate_grows_with_the_batch(paper_cells):
    cell = next(c for c in paper_cells if c.name.startswith("classify-") and c.algo == "ppo")
    small = dataclasses.replace(cell, overrides={**cell.overrides, "num_envs": 8})
    assert estimates.rate(small, 5, "gpu") < estimates.rate(cell, 5, "gpu") < estimates.GPU_RATES["classify"][0]
    assert estimates.rate(small, 5, "cpu") == estimates.rate(cell, 5, "cpu")


def test_a_cell_out_of_device_memory_fails_alone_and_the_stream_goes_on(tmp_path, monkeypatch):
    """On 4 GPUs two localisation cells ran out of memory and took their streams' other cells
    down with them: an XLA runtime error now fails its cell only, with the fix in one line."""
    import jax

    from jaxnat import training
    from jaxnat.reproduce import cells as cells_module
    from jaxnat.reproduce.board import Board  # noqa: F401 (the real board's interface)

    plan = command.make_plan(command.ReproduceArgs(profile="smoke", only="classify", out=tmp_path))
    first, second = plan.cells[:2]
    trained = []

    def train(args, **_):
        if args.run_dir.name == first.name:
            raise jax.errors.JaxRuntimeError("RESOURCE_EXHAUSTED: Out of memory while trying to allocate 73.73GiB")
        trained.append(args.run_dir.name)

    monkeypatch.setattr(training, "train", train)

    class Events:
        outcomes = {}

        def start(self, cell, resumed):
            pass

        def done(self, cell, outcome, seconds):
            self.outcomes[cell.name] = outcome

    board = Events()
    cells_module.train_cells([first, second], plan, {first.name: False, second.name: False}, board,
                             platform="cpu", compile_ahead=False, overlapped=False)
    assert trained == [second.name]
    assert board.outcomes[first.name].startswith("failed: out of device memory (RESOURCE_EXHAUSTED")
    assert "fewer envs per seed" in board.outcomes[first.name] and board.outcomes[second.name] == "finished"


def test_the_profile_trains_at_the_batch_the_calibration_cleared(paper_cells):
    """Sitting 2's calibration: at 512 envs only PPO with the authors' optimizer steps per env
    step stayed in the authors' band, so the profile trains classification PPO there and A2C
    and ACKTR (one optimizer step per update) at the authors' batch."""
    assert {(g, a): grid.profile_variant(g, a) for g, a in
            [("classify", "ppo"), ("classify", "a2c"), ("classify", "acktr"), ("mujoco", "ppo")]} == {
        ("classify", "ppo"): "512 envs, optimizer steps restored", ("classify", "a2c"): "authors",
        ("classify", "acktr"): "authors", ("mujoco", "ppo"): "profile"}
    cells = {(c.experiment, c.algo): c for c in paper_cells if c.labels.get("trunk", "cnn") == "cnn"
             and c.name.endswith(("-ppo", "-a2c", "-acktr"))}
    for experiment in ("classify", "localize"):
        assert calibration.optimizer_steps(cells[experiment, "ppo"])[2] == 1000 * 16 / 1024
        assert calibration.optimizer_steps(cells[experiment, "a2c"]) == (16, 5, 1000 / 80)
        assert calibration.optimizer_steps(cells[experiment, "acktr"]) == (32, 20, 1000 / 640)


def test_calibration_status_opens_the_report_with_each_profile_cell_against_the_band():
    chosen = grid.profile_variant("classify", "ppo")
    authors, profile = _calibrated("authors", 0.7), _calibrated(chosen, 0.4)
    lines = calibration.calibration_status([authors, profile])
    assert lines[0].startswith("> **Calibration of the batch**")
    assert (f"> - classify PPO: the profile's batch ({chosen}) 0.4 [0.35, 0.45] is below the authors' "
            "0.7 [0.65, 0.75].") in lines
    alone = calibration.calibration_status([authors])
    assert any(f"the profile's batch ({chosen}) has not run (other cells: authors 0.7" in line for line in alone)
    assert calibration.calibration_status([]) == []
    a2c = dataclasses.replace(authors.cell, algo="a2c")
    line = calibration.calibration_status([dataclasses.replace(authors, cell=a2c)])[2]
    assert line == "> - classify A2C: the profile trains at the authors' batch: 0.7 [0.65, 0.75]."
    # A group and algorithm of the grid's calibration with no cell run yet is named, not left out.
    grid_cells = [c for c in grid.build_grid(grid.PROFILES["paper"], ("calibration",))]
    lines = calibration.calibration_status([authors, profile], grid_cells)
    assert "> - mujoco A2C: not calibrated yet (none of its calibration cells has run): its verdicts depend " \
           "on the batch." in lines
    assert not any(line.startswith("> - classify PPO: not calibrated") for line in lines)
    assert calibration.calibration_status([], grid_cells) == []  # no calibration run: no banner


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    """The smoke profile's calibration, trained once (`tests/test_reproduce_shards.py` compares
    its sharded runs with it)."""
    out = tmp_path_factory.mktemp("calibration")
    assert command.main(["--profile", "smoke", "--only", "calibration", "--out", str(out)]) == 0
    return out


def test_smoke_calibration_trains_and_reports_its_band(calibrated):
    """The calibration end to end on a CPU (the smoke profile's tiny batch: PPO at the authors'
    and the profile's variants): its section, its status lines, its figure and its JSON rows."""
    import json

    tmp_path = calibrated
    text = (tmp_path / "report.md").read_text()
    assert "## Calibration: the batch against the authors'" in text
    assert "> - classify PPO: the profile's batch (512 envs, optimizer steps restored)" in text
    assert (tmp_path / "calibration.png").is_file()
    rows = [line for line in text.splitlines() if line.startswith("| classify | PPO |")]
    assert [row.split(" | ")[2] for row in rows] == ["authors", "512 envs, optimizer steps restored (the profile's)"]
    cells = json.loads((tmp_path / "results.json").read_text())["cells"]
    assert {c["name"] for c in cells} == {"calibration-classify-ppo-authors",
                                          "calibration-classify-ppo-512-envs-optimizer-steps-restored"}


def test_two_shards_into_one_folder_give_the_report_of_one_run(calibrated, tmp_path):
    """`--shard 0/2` and `--shard 1/2` into one folder, then `--report-only`: the same per-seed
    results and verdicts as the one run of `calibrated`; the first shard's report holds its share."""
    import json

    def numbers(out):
        cells = json.loads((out / "results.json").read_text())["cells"]
        return {c["name"]: {k: v for k, v in c.items() if k != "wall_time_s"} for c in cells}

    argv = ["--profile", "smoke", "--only", "calibration", "--out", str(tmp_path)]
    assert command.main([*argv, "--shard", "0/2"]) == 0
    assert 0 < len(numbers(tmp_path)) < len(numbers(calibrated))
    assert command.main([*argv, "--shard", "1/2"]) == 0
    assert command.main([*argv, "--report-only"]) == 0
    assert numbers(tmp_path) == numbers(calibrated)
    verdicts = lambda out: json.loads((out / "results.json").read_text())["verdicts"]  # noqa: E731
    assert verdicts(tmp_path) == verdicts(calibrated)


def test_a_finished_run_of_the_papers_budget_is_100_percent_though_it_ends_on_a_whole_update():
    cell = grid.Cell("classify-x", "classify", "classify-cnn", "X/Y-v0", {}, "ppo", None,
                     grid.Budget(grid.PAPER_BUDGETS["classify"]), {}, {})
    steps = np.array([16_384.0, 9_994_240.0])  # 610 updates of 16,384: the last whole one
    train = np.zeros((2, 3))

    def result(complete):
        return CellResult(cell, complete, 3, steps, train, np.array([0.0]), train[:1], train[:1], None, 1.0)

    assert result(True).budget_share == 1.0
    assert result(False).budget_share == pytest.approx(0.999424)
