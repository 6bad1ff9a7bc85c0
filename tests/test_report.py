"""The report's machine-readable results (`results.json`), its aggregates computed with rliable,
its labels for stand-in datasets and its departures from the paper, on hand-made runs (no
training)."""

import dataclasses
import json
import re

import numpy as np
import pytest

from jaxnat.reproduce import aggregates, departures, findings, grid, report, results_json
from jaxnat.reproduce.report import CellResult, write_report

SEEDS = (0, 1, 2)
SPREAD = np.array([-0.05, 0.0, 0.05])


def _write_run(run_dir, steps, mean, untrained, seeds=SEEDS, complete=True):
    """A run directory as `jaxnat train` writes it: training returns at `mean` (+ SPREAD per seed)
    at every update of `steps`, evaluations at update 0 (`untrained`) and at the end (`mean`)."""
    run_dir.mkdir(parents=True)
    (run_dir / "config.json").write_text(json.dumps({"spec": {"seed_values": list(seeds)},
                                                     "versions": {"jaxnat": "test"}}))
    metrics = [{"update": i + 1, "env_steps": s, "seed": seed, "episode_return": mean + d}
               for i, s in enumerate(steps) for seed, d in zip(seeds, SPREAD)]
    evals = [{"update": u, "env_steps": s, "seed": seed, "greedy_return": v + d - 0.5, "sampled_return": v + d}
             for u, s, v in ((0, 0, untrained), (len(steps), steps[-1], mean)) for seed, d in zip(seeds, SPREAD)]
    for name, rows in (("metrics.jsonl", metrics), ("eval.jsonl", evals)):
        (run_dir / name).write_text("".join(json.dumps(r) + "\n" for r in rows))
    (run_dir / "summary.json").write_text(json.dumps({"complete": complete, "chance": {"return": -1.0},
                                                      "wall_time_s": 12.5}))


def _strict_json(path):
    """The file's JSON, refusing NaN and infinities (which `json.loads` accepts by default)."""
    def refuse(constant):
        raise ValueError(f"{path.name} holds {constant}, not strict JSON")

    return json.loads(path.read_text(), parse_constant=refuse)


def test_results_json_cell_entry_per_seed_values():
    steps = np.arange(1, 21) * 1_000_000.0  # 20 updates up to 20M env steps per seed
    train = np.stack([steps / 1e7, 2 * steps / 1e7, np.full(steps.size, np.nan)], axis=1)  # seed 2: no episode
    eval_steps = np.array([0.0, steps[-1]])
    greedy, sampled = np.array([[0.0, 0.1, 0.2], [0.5, 0.6, 0.7]]), np.array([[0.3, 0.2, 0.1], [1.0, 1.1, 1.2]])
    cell = grid.Cell("classify-mnist-cnn-ppo", "classify", "classify-cnn", "Classify/MNIST-v0", {"w": 5}, "ppo",
                     None, grid.Budget(20_000_000), {"num_envs": 64}, {"dataset": "mnist", "trunk": "cnn"})
    result = CellResult(cell, True, 3, steps, train, eval_steps, greedy, sampled, 0.05, 12.5, (10, 11, 12))
    entry = results_json.cell_entry(result)
    assert {"name", "experiment", "figure", "labels", "dataset", "env_id", "env_kwargs", "algo", "trunk", "overrides",
            "note", "complete", "seeds", "env_steps_per_seed", "budget_share", "wall_time_s",
            "random_policy_test_return", "train_final", "train_checkpoints", "untrained_test_sampled",
            "test_final"} <= set(entry)
    assert entry["seeds"] == [10, 11, 12] and entry["overrides"] == {"num_envs": 64} and entry["budget_share"] == 2.0
    document = results_json._plain(entry)  # NaN (the seed without episodes) as null
    # Each seed's mean over the last 10% of its updates up to the checkpoint: at 1M and 10M the
    # last update (1 and 10 updates), at the last step, 20M, the last two (updates 19 and 20).
    checkpoints = {c["env_steps"]: c["per_seed"] for c in document["train_checkpoints"]}
    assert list(checkpoints) == [1e6, 1e7, 2e7]
    np.testing.assert_allclose(checkpoints[1e6][:2], [0.1, 0.2])
    np.testing.assert_allclose(checkpoints[1e7][:2], [1.0, 2.0])
    np.testing.assert_allclose(checkpoints[2e7][:2], [1.95, 3.9])
    assert checkpoints[1e7][2] is None and document["train_final"]["per_seed"] == checkpoints[2e7]
    assert document["untrained_test_sampled"]["per_seed"] == [0.3, 0.2, 0.1]
    assert document["test_final"]["greedy"]["per_seed"] == [0.5, 0.6, 0.7]
    assert document["test_final"]["sampled"]["per_seed"] == [1.0, 1.1, 1.2]
    assert document["train_final"]["interval"]["n"] == 2
    # A run that stopped before 1M: its last step alone.
    short = CellResult(cell, False, 3, steps[:1] / 4, train[:1], eval_steps[:1], greedy[:1], sampled[:1], None, 1.0)
    entry = results_json._plain(results_json.cell_entry(short))
    assert [c["env_steps"] for c in entry["train_checkpoints"]] == [250_000.0]
    assert entry["untrained_test_sampled"]["per_seed"] == [0.3, 0.2, 0.1] and entry["complete"] is False
    # An untrained evaluation computed after the run (a lost record, recomputed) says so.
    assert entry["untrained_test_sampled"]["computed_after"] is None
    after = dataclasses.replace(short, untrained_after="cpu")
    assert results_json.cell_entry(after)["untrained_test_sampled"]["computed_after"] == "cpu"
    # Its one evaluation is the untrained policy's: never shown as the final test score.
    assert entry["test_final"] is None and short.final_eval is None
    assert str(short.final_greedy) == str(short.final_sampled) == str(report.bootstrap_ci([]))


def _plan(out, cells, only=("classify",), profile=None):
    profile = profile or grid.Profile("hand", "hand-made runs", len(SEEDS), {e: grid.Budget(1000) for e in only})
    return grid.Plan(profile, only, len(SEEDS), out, cells)


def _localize(trunk, algo="ppo"):
    return grid.Cell(f"localize-clutter-{trunk}-{algo}", "localize", f"localize-{trunk}", "Localize/Clutter-v0", {},
                     algo, None, grid.Budget(1000), {}, {"dataset": "clutter", "trunk": trunk})


def test_results_json_of_a_report(tmp_path):
    cells = [_localize("cnn"), _localize("resnet18"), _localize("cnn", "a2c")]
    for cell, mean in zip(cells, (0.85, 0.25, 0.5)):
        _write_run(tmp_path / cell.name, [500, 1000], mean, untrained=0.1, complete=cell.algo == "ppo")
    write_report(_plan(tmp_path, cells, ("localize",)), {})
    document = _strict_json(tmp_path / "results.json")
    assert {"schema", "written", "profile", "only", "seeds", "cells", "not_finished", "verdicts", "aggregates",
            "departures"} <= set(document)
    assert [c["name"] for c in document["cells"]] == [c.name for c in cells]  # the partial cell included
    first = document["cells"][0]
    np.testing.assert_allclose(first["train_final"]["per_seed"], 0.85 + SPREAD)
    np.testing.assert_allclose(first["untrained_test_sampled"]["per_seed"], 0.1 + SPREAD)
    np.testing.assert_allclose(first["test_final"]["greedy"]["per_seed"], 0.35 + SPREAD)
    assert first["wall_time_s"] == 12.5 and first["random_policy_test_return"] == -1.0
    assert document["not_finished"] == [{"cell": cells[2].name, "why": "incomplete (interrupted; rerun the command "
                                                                         "to finish it)"}]
    verdicts = {v["claim"]: v for v in document["verdicts"]}
    assert [v["claim"] for v in document["verdicts"]] == [f.claim for f in findings.FINDINGS]
    drop = verdicts[findings.FINDINGS[5].claim]
    assert drop["verdict"] == "reproduced" and drop["budget_share"] == [1e-4, 1e-4]
    # The aggregate pools the finished PPO cells, normalised against their untrained policy.
    (ppo,) = document["aggregates"]
    assert ppo["cells"] == [cells[0].name, cells[1].name] and ppo["seeds"] == 3
    assert ppo["mean"]["mean"] == pytest.approx(np.mean([(0.85 - 0.1) / 0.9, (0.25 - 0.1) / 0.9]))


def test_report_with_no_finished_cells_writes_valid_json(tmp_path):
    cells = [_localize("cnn"), dataclasses.replace(_localize("resnet18"), skip="no data here")]
    text = write_report(_plan(tmp_path, cells, ("localize",)), {}).read_text()
    document = _strict_json(tmp_path / "results.json")
    assert document["cells"] == [] and document["aggregates"] == []
    assert {v["verdict"] for v in document["verdicts"]} == {"not run"}
    assert [m["cell"] for m in document["not_finished"]] == [c.name for c in cells]
    assert "## Aggregate scores" not in text


@pytest.mark.filterwarnings("ignore:random_state is deprecated:FutureWarning")  # arch's, in rliable's own call
def test_iqm_matches_rliable_on_a_tiny_array():
    from rliable import library, metrics

    scores = np.array([[1.0, 5.0], [2.0, 6.0], [3.0, 7.0], [4.0, 80.0]])  # [runs, tasks]
    (iqm, mean), = aggregates.interval_estimates({"a": scores}, reps=500, seed=3).values()
    # The 25% trimmed mean of the 8 runs: 3, 4, 5, 6 remain.
    assert iqm.mean == pytest.approx(4.5) == metrics.aggregate_iqm(scores)
    assert mean.mean == pytest.approx(scores.mean()) and iqm.n == mean.n == 8
    # rliable's own computation, its resamples drawn from the global generator seeded alike
    np.random.seed(aggregates.bootstrap_seed(3, "a"))
    points, intervals = library.get_interval_estimates(
        {"a": scores}, lambda s: np.array([metrics.aggregate_iqm(s), metrics.aggregate_mean(s)]), reps=500,
        random_state=np.random.RandomState(aggregates.bootstrap_seed(3, "a")))
    assert points["a"][0] == iqm.mean
    assert (iqm.low, iqm.high, mean.low, mean.high) == pytest.approx(
        (intervals["a"][0, 0], intervals["a"][1, 0], intervals["a"][0, 1], intervals["a"][1, 1]))
    assert iqm.low <= iqm.mean <= iqm.high and iqm.high < mean.high  # the outlier moves the mean's interval more
    # Reproducible, and the global generator left as it was.
    state = np.random.get_state()[1].copy()
    assert aggregates.interval_estimates({"a": scores}, reps=500, seed=3)["a"] == (iqm, mean)
    assert (np.random.get_state()[1] == state).all()
    # A group's interval is its own: other groups before it (a later sitting's cells) leave it as it was.
    others = {"0": scores * 2.0, "b": scores + 1.0}
    assert aggregates.interval_estimates({**others, "a": scores}, reps=500, seed=3)["a"] == (iqm, mean)
    assert aggregates.interval_estimates({"c": scores}, reps=500, seed=3)["c"] != (iqm, mean)  # keys draw apart


def test_aggregates_group_and_leave_out(tmp_path):
    def result(cell, per_seed, untrained):
        steps = np.array([500.0, 1000.0])
        train = np.tile(np.asarray(per_seed, np.float64), (2, 1))
        sampled = np.stack([np.full(len(per_seed), untrained), train[-1]])
        return CellResult(cell, True, len(per_seed), steps, train, np.array([0.0, 1000.0]), sampled, sampled, None, 1.0)

    pooled = [result(_localize("cnn"), [0.55, 0.1, 1.0], 0.1), result(_localize("resnet18"), [0.3, 0.2, 0.4], 0.1)]
    stuck = result(_localize("cnn", "a2c"), [1.0, 1.0, 1.0], 1.0)  # its untrained policy already at the maximum
    rows = aggregates.aggregate([*pooled, stuck])
    ppo, a2c = rows
    assert (ppo.experiment, ppo.algo, ppo.score, ppo.cells, ppo.seeds) == (
        "localize", "ppo", "normalised", ("localize-clutter-cnn-ppo", "localize-clutter-resnet18-ppo"), 3)
    normalised = np.array([[0.5, 0.0, 1.0], [2 / 9, 1 / 9, 1 / 3]]).T
    from rliable import metrics

    assert ppo.iqm.mean == pytest.approx(metrics.aggregate_iqm(normalised))
    assert a2c.cells == () and a2c.left_out[0][1].startswith("its untrained policy")
    section = "\n".join(aggregates.aggregates_section(rows, pooled))
    assert "Left out of the aggregates: `localize-clutter-cnn-a2c`" in section and "| A2C |" not in section
    # Atari: raw returns, one cell per group.
    atari = grid.Cell("atari-breakout-video-ppo", "atari", "atari", "NaturalAtari/Breakout-v0",
                      {"background": "video"}, "ppo", None, grid.Budget(1000), {},
                      {"game": "Breakout", "background": "video"})
    (row,) = aggregates.aggregate([result(atari, [1.0, 2.0, 3.0, 30.0], 0.0)])  # the IQM of 4: the middle 2
    assert (row.group, row.score, row.iqm.mean) == ("Breakout, background video", "raw return", pytest.approx(2.5))


def _stand_in_cells():
    """A classification grid on the stand-ins, as `grid.build_grid` makes it without MNIST and CIFAR-10."""
    notes = {d: f"{grid.STAND_INS[d][2]} stands in for {grid.DATASET_NAMES[d]} (not found)" for d in grid.STAND_INS}
    envs = {d: grid.STAND_INS[d][1] for d in grid.STAND_INS}
    cells = [grid.Cell(f"classify-{d}-cnn-{algo}", "classify", "classify-cnn", envs[d], {}, algo, None,
                       grid.Budget(1000), {}, {"dataset": d, "trunk": "cnn"}, notes[d])
             for d in ("mnist", "cifar10") for algo in ("ppo", "a2c", "acktr")]
    cells.append(grid.Cell("classify-mnist-cnn-ppo-noise", "classify", "noise-control", envs["mnist"],
                           {"observation_noise": True}, "ppo", None, grid.Budget(1000), {},
                           {"dataset": "mnist", "trunk": "cnn", "observation": "noise"}, notes["mnist"]))
    cells += [grid.Cell(f"classify-sweep-w{w}-M{m}", "classify", "sweep", envs["cifar10"],
                        {"window": w, "max_steps_in_episode": m}, "ppo", None, grid.Budget(1000), {},
                        {"dataset": "cifar10", "w": w, "M": m}, notes["cifar10"]) for w, m in ((2, 20), (5, 20))]
    cells.append(grid.Cell("classify-cifar100-cnn-ppo", "classify", "classify-cnn", None, {}, "ppo", None,
                           grid.Budget(1000), {}, {"dataset": "cifar100", "trunk": "cnn"}, "", "CIFAR-100 not found"))
    return cells


# A paper dataset's bare name: not "Fashion-MNIST", not "CIFAR-100".
_BARE = re.compile(r"(?<![\w-])(MNIST|CIFAR-10)(?![\w-])")


def _bare_names(text: str) -> list[str]:
    """Each bare MNIST or CIFAR-10 of `text` that is not in "(for MNIST)" or "stands in for MNIST"."""
    return [text[max(0, m.start() - 40):m.end()] for m in _BARE.finditer(text)
            if not text[:m.start()].endswith(("(for ", "stands in for "))]


def test_stand_in_cells_never_carry_the_paper_dataset_name(tmp_path):
    cells = _stand_in_cells()
    for cell in cells:
        if not cell.skip:
            _write_run(tmp_path / cell.name, [500, 1000], 0.6 if "noise" not in cell.name else 0.1, untrained=0.0)
    plan = _plan(tmp_path, cells)
    text = write_report(plan, {}).read_text()
    for finding in findings.FINDINGS:  # the paper's own words, quoted as its claims
        text = text.replace(finding.claim, "")
    assert _bare_names(text) == []
    assert "Digits (for MNIST)" in text and "Fashion-MNIST (for CIFAR-10)" in text
    # Figures: every panel title and curve label.
    results = [report.load_result(c, tmp_path / c.name) for c in cells if not c.skip]
    labels = [t for stem in report.FIGURES for title, curves in report._panels(stem, results).items()
              for t in (title, *(label for label, _ in curves))]
    assert labels and _bare_names("\n".join(labels)) == []
    assert "Fashion-MNIST (for CIFAR-10): window w (M=20)" in labels
    document = _strict_json(tmp_path / "results.json")
    assert {c["dataset"] for c in document["cells"]} == {"Digits (for MNIST)", "Fashion-MNIST (for CIFAR-10)"}
    assert _bare_names(json.dumps([v["comparisons"] for v in document["verdicts"]])) == []
    # With a claim's cells missing (the smoke profile's one dataset), its not-run text too.
    text = write_report(_plan(tmp_path, cells[:1]), {}).read_text()
    for finding in findings.FINDINGS:
        text = text.replace(finding.claim, "")
    assert "**not run**" in text and _bare_names(text) == []


def test_departures_list_what_applies_to_the_cells(tmp_path):
    cells = _stand_in_cells()
    section = "\n".join(departures.departures_section(_plan(tmp_path, cells).profile, cells))
    assert "**Digits stands in for MNIST** (`classify-mnist-cnn-ppo`" in section
    assert "**Fashion-MNIST stands in for CIFAR-10**" in section
    assert "**3-layer CNN on Fashion-MNIST (for CIFAR-10)**" in section
    assert "**start of the classification window** (every cell)" in section
    assert "Not run (no data, no stand-in): CIFAR-100" in section
    for absent in ("ALE", "PixelMuJoCo", "natural videos", "localisation data", "Batch per update"):
        assert absent not in section
    # The quick profile's PixelMuJoCo and Natural Atari cells.
    profile = grid.PROFILES["quick"]
    quick = [c for c in grid.build_grid(profile, ("atari", "mujoco")) if not c.skip]
    section = "\n".join(departures.departures_section(profile, quick))
    for present in ("**ALE: sticky actions**", "**ALE: FIRE at reset and life loss**", "**ALE: rewards**",
                    "**natural videos** (`atari-breakout-video-ppo`)", "`physics=\"fast\"`",
                    "**PixelMuJoCo rewards**",
                    "unclipped and unscaled", "| mujoco | PPO | 128 x 32 = 4,096 | 8 x 128 = 1,024 | — |",
                    "| atari | PPO | 256 x 32 = 8,192 | 8 x 128 = 1,024 | — |",
                    "**atari env settings**: the paper: each env's defaults. jaxnat (profile `quick`): "
                    "`max_episode_steps=2000`."):
        assert present in section, present
    assert "Digits" not in section and "classification window" not in section
    assert "sign-clipped rewards (`clip_rewards`)" not in section
    normalised = [dataclasses.replace(c, overrides={**c.overrides, "normalize_rewards": True})
                  for c in quick if c.experiment == "mujoco"]
    assert "running estimate of the return's standard deviation" in "\n".join(
        departures.departures_section(profile, normalised))


def test_greedy_column_is_explained_under_the_table(tmp_path):
    cells = [_localize("cnn")]
    _write_run(tmp_path / cells[0].name, [500, 1000], 0.8, untrained=0.1)
    text = write_report(_plan(tmp_path, cells, ("localize",)), {}).read_text()
    table_end = text.index("| `localize-clutter-cnn-ppo` |")
    assert text.index(report.GREEDY_NOTE) > table_end
    assert "repeats one wrong label" in report.GREEDY_NOTE
    assert "computed after the run" not in text
    # An untrained evaluation recomputed after the run (its record lost) is marked where shown.
    evals = tmp_path / cells[0].name / "eval.jsonl"
    rows = [json.loads(line) for line in evals.read_text().splitlines()]
    evals.write_text("".join(json.dumps({**r, **({"computed_after": "cpu"} if r["update"] == 0 else {})}) + "\n"
                             for r in rows))
    text = write_report(_plan(tmp_path, cells, ("localize",)), {}).read_text()
    row = next(line for line in text.splitlines() if line.startswith("| `localize-clutter-cnn-ppo` |"))
    assert row.endswith("(computed after the run, on cpu) |")


def test_the_report_names_the_natural_data_the_cells_saw():
    """`data_section`: one row per split and file the cells' runs recorded (`config.json`'s
    `data`), with how many cells saw it; nothing when no cell recorded any."""
    import dataclasses

    import numpy as np

    from jaxnat.reproduce import grid
    from jaxnat.reproduce.report import CellResult, data_section

    cell = grid.Cell("c", "mujoco", "mujoco", "X/Y-v0", {}, "ppo", None, grid.Budget(10), {}, {})
    empty = np.zeros((0,))
    base = CellResult(cell, True, 1, empty, np.zeros((0, 1)), empty, np.zeros((0, 1)), np.zeros((0, 1)), None, 0.0)
    clip = {"name": "tree.avi", "sha256": "ab" * 32, "frames": 50}
    data = {"train": [[clip]], "test": [[{"name": "cup.mp4", "sha256": "cd" * 32, "frames": 30}]]}
    other = dataclasses.replace(base, cell=dataclasses.replace(cell, name="d"), data={"train": [[clip]], "test": []})
    lines = data_section([dataclasses.replace(base, data=data), other, base])
    assert lines[0] == "## Natural data the cells saw"
    assert "| test | cup.mp4 | `cdcdcdcdcdcd` | 30 | 1 |" in lines
    assert "| train | tree.avi | `abababababab` | 50 | 2 |" in lines
    assert data_section([base]) == []


def test_versions_line_names_each_device_with_its_cells():
    """Cells from two sittings on two device kinds: the report names both, with their counts;
    a field every cell agrees on once; a field a cell lacks as not recorded."""
    line = report.versions_line([{"jax": "0.11.2", "device": "H100"}, {"jax": "0.11.2", "device": "H200"},
                                 {"jax": "0.11.2", "device": "H100", "flax": "0.12"}])
    assert line == "jax 0.11.2, device H100 (2 cells) / H200 (1 cell), flax not recorded (2 cells) / 0.12 (1 cell)"
    assert report.versions_line([{"jax": "0.11.2"}]) == "jax 0.11.2"


def test_interval_note_only_where_cells_ran_on_a_gpu():
    """GPU cells: the report says the intervals cover seeds, not the GPU kernels' run-to-run
    variation, and counts those cells; CPU-only reports (deterministic under a key) say nothing."""
    (line,) = report.interval_note([{"device": "NVIDIA H200"}, {"device": "cpu"}, {"device": "NVIDIA H100"}])
    assert line.startswith("- Intervals are 95% bootstrap intervals over seeds. 2 of the 3 cells ran on GPUs")
    assert "xla_gpu_deterministic_ops=true" in line
    assert report.interval_note([{"device": "cpu"}]) == [] == report.interval_note([{}])
