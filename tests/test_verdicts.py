"""The findings' verdicts (`jaxnat.reproduce.verdicts`, `findings`) on hand-made results, no
training: the five outcomes, the learning gate, the MNIST claim on the 3-layer CNN only, speed
claims at fixed env-step checkpoints, and the report's budget-share column and banner, written
from hand-made run directories."""

import json

import numpy as np
import pytest

from jaxnat.reproduce import findings, grid, verdicts
from jaxnat.reproduce.report import CellResult, write_report

PAPER = grid.PAPER_BUDGETS["classify"]
SPREAD = np.array([-0.05, 0.0, 0.05])  # three seeds around a mean: an interval of about +-0.05


def _result(experiment, figure, algo, mean, *, untrained=0.0, steps=None, **labels):
    """A finished cell: seeds at `mean` (+ SPREAD) at every update, or `mean(steps)` for a curve;
    its untrained policy's test return `untrained` (None: not recorded, as in a host run). By
    default 10 updates up to the paper's 10M env steps."""
    steps = np.linspace(PAPER / 10, PAPER, 10) if steps is None else np.asarray(steps, np.float64)
    curve = mean(steps) if callable(mean) else np.full(steps.size, mean)
    train = curve[:, None] + SPREAD
    if untrained is None:
        eval_steps, sampled = steps[-1:], train[-1:]
    else:
        eval_steps, sampled = np.array([0.0, steps[-1]]), np.stack([untrained + SPREAD, train[-1]])
    cell = grid.Cell(f"{experiment}-{figure}-{algo}-{labels}", experiment, figure, "X/Y-v0", {}, algo, None,
                     grid.Budget(int(steps[-1])), {}, labels)
    return CellResult(cell, True, 3, steps, train, eval_steps, sampled, sampled, None, 1.0)


def _judge(rule, results) -> verdicts.Verdict:
    return next(f for f in findings.FINDINGS if f.rule.__name__ == rule).judge(results)


def _localize(trunk, mean, **kwargs):
    return _result("localize", f"localize-{trunk}", "ppo", mean, dataset="clutter", trunk=trunk, **kwargs)


def test_verdict_five_outcomes_of_an_ordering():
    cnn = _localize("cnn", 0.85)
    for resnet, outcome in ((0.25, "reproduced"), (1.25, "contradicted"), (0.8, "inconclusive")):
        assert _judge("_resnet_worse_localize", [cnn, _localize("resnet18", resnet)]).verdict == outcome
    # The CNN, which the paper puts above, no better than its untrained policy: not shown.
    untrained = _localize("cnn", 0.85, untrained=0.85)
    assert _judge("_resnet_worse_localize", [untrained, _localize("resnet18", 0.25)]).verdict == "not shown"
    assert _judge("_resnet_worse_localize", [cnn]).verdict == "not run"
    assert _judge("_resnet_worse_localize", []).numbers == "no finished cells for localisation with both trunks"


def test_verdict_learning_gate():
    resnet = _localize("resnet18", 0.25)
    # Intervals apart in the paper's order, but the higher cell did not beat its untrained policy.
    verdict = _judge("_resnet_worse_localize", [_localize("cnn", 0.85, untrained=0.9), resnet])
    assert verdict.verdict == "not shown" and "did not learn" in verdict.numbers
    # The lower cell need not learn (a policy that fails completely is part of some claims).
    assert _judge("_resnet_worse_localize", [_localize("cnn", 0.85), _localize("resnet18", 0.25, untrained=0.5)]
                  ).verdict == "reproduced"
    # No record of the untrained policy (a host run): not shown.
    verdict = _judge("_resnet_worse_localize", [_localize("cnn", 0.85, untrained=None), resnet])
    assert verdict.verdict == "not shown" and "records no untrained policy" in verdict.numbers
    assert verdicts.learned(_localize("cnn", 0.85, untrained=0.7)) is None
    # The gate of the vision noise control is the real observation's cell, never the noise one.
    real = _result("classify", "classify-cnn", "ppo", 0.5, dataset="mnist", trunk="cnn")
    noise = _result("classify", "noise-control", "ppo", 0.1, untrained=0.1, dataset="mnist", trunk="cnn",
                    observation="noise")
    assert _judge("_noise_control", [real, noise]).verdict == "reproduced"
    stuck = _result("classify", "classify-cnn", "ppo", 0.5, untrained=0.6, dataset="mnist", trunk="cnn")
    assert _judge("_noise_control", [stuck, noise]).verdict == "not shown"


def _classify(algo, mean, dataset="mnist", trunk="cnn", **kwargs):
    return _result("classify", f"classify-{trunk}", algo, mean, dataset=dataset, trunk=trunk, **kwargs)


def test_verdict_aggregates_comparisons():
    ppo, a2c = _classify("ppo", 0.85), _classify("a2c", 0.25)
    for acktr, outcome in ((0.85, "reproduced"), (0.3, "inconclusive"), (0.05, "contradicted")):
        verdict = _judge("_a2c_worst", [ppo, a2c, _classify("acktr", acktr, untrained=-1.0)])
        assert verdict.verdict == outcome
    # A comparison not shown is listed and counted neither for nor against.
    verdict = _judge("_a2c_worst", [ppo, a2c, _classify("acktr", 0.85, untrained=0.9)])
    assert verdict.verdict == "reproduced"
    assert verdict.numbers.startswith("2 comparisons: 1 reproduced, 1 not shown.")
    stuck = [_classify("ppo", 0.85, untrained=0.9), a2c, _classify("acktr", 0.85, untrained=0.9)]
    assert _judge("_a2c_worst", stuck).verdict == "not shown"
    # A contradiction stands beside comparisons that were not shown.
    assert _judge("_a2c_worst", [stuck[0], a2c, _classify("acktr", 0.05, untrained=-1.0)]).verdict == "contradicted"


def test_verdict_close_to_one_on_mnist_judges_the_cnn_only():
    resnet = [_classify(algo, 0.3, trunk="resnet18") for algo in ("ppo", "acktr")]  # the paper: ResNet-18 fails
    for mean, outcome in ((0.96, "reproduced"), (0.5, "contradicted"), (0.9, "inconclusive")):
        cnn = [_classify(algo, mean) for algo in ("ppo", "acktr")]
        verdict = _judge("_close_to_one", cnn + resnet + [_classify("a2c", 0.1)])
        assert verdict.verdict == outcome and verdict.numbers.startswith("2 comparisons:")
    assert _judge("_close_to_one", resnet).verdict == "not run"


def _sweep(w, m, mean, **kwargs):
    return _result("classify", "sweep", "ppo", mean, dataset="cifar10", w=w, M=m, **kwargs)


def _early_late(early, late):
    """A curve at `early` up to 1M env steps and at `late` after."""
    return lambda steps: np.where(steps <= 1_000_000, early, late)


def test_verdict_speed_claims_at_fixed_checkpoints():
    steps = np.arange(1, 101) * 100_000  # every 100k env steps up to the paper's 10M
    # w=7 leads up to 1M, w=2 after it. Over the first 20% of the run (2M), w=2 would lead.
    w7, w2 = _sweep(7, 20, _early_late(0.5, 0.3), steps=steps), _sweep(2, 20, _early_late(0.1, 0.9), steps=steps)
    verdict = _judge("_small_window_later", [w7, w2])
    assert verdict.verdict == "reproduced"
    assert "initially at 1M env steps: w=7 0.5 [" in verdict.numbers
    assert "later at 10M env steps: w=2 0.9 [" in verdict.numbers
    swapped = [_sweep(7, 20, _early_late(-0.2, 0.3), steps=steps, untrained=-1.0), w2]
    assert _judge("_small_window_later", swapped).verdict == "contradicted"
    # Runs that stop at 500k: the first checkpoint at their last step, the later part not reached.
    short = [_sweep(w, 20, _early_late(e, 0.0), steps=steps[:5]) for w, e in ((7, 0.5), (2, 0.1))]
    verdict = _judge("_small_window_later", short)
    assert verdict.verdict == "not shown"
    assert "initially at 1M env steps (the runs end at 500,000): w=7" in verdict.numbers
    assert "w=2 vs w=7 at 10M env steps: not reached" in verdict.numbers
    # Fewer steps M: judged at 1M and at 10M; leading only at the end is not "faster".
    ms = [_sweep(5, m, _early_late(e, 1.0 - m / 50), steps=steps) for m, e in ((10, 0.2), (20, 0.5), (40, 0.8))]
    verdict = _judge("_smaller_m_easier", ms)
    assert verdict.verdict == "contradicted" and verdict.numbers.startswith("4 comparisons: 2 reproduced, 2 contra")
    ms = [_sweep(5, m, 1.0 - m / 50, steps=steps) for m in (10, 20, 40)]
    assert _judge("_smaller_m_easier", ms).verdict == "reproduced"
    assert verdicts.checkpoint_steps(ms[0]) == [(1_000_000, 1_000_000), (10_000_000, 10_000_000)]
    # M moves the return's floor and the untrained policy: the sweep compares normalised scores.
    # M=20's raw return is above M=10's, but both close 80% of the gap from untrained to 1.
    floors = [_sweep(5, 10, 0.8, steps=steps, untrained=0.0), _sweep(5, 20, 0.96, steps=steps, untrained=0.8)]
    verdict = _judge("_smaller_m_easier", floors)
    assert verdict.verdict == "inconclusive" and "M=10 0.8 [" in verdict.numbers and "normalised" in verdict.numbers
    unrecorded = [floors[0], _sweep(5, 20, 0.96, steps=steps, untrained=None)]
    assert "records no untrained policy" in _judge("_smaller_m_easier", unrecorded).numbers
    assert verdicts.checkpoint_steps(short[0]) == [(1_000_000, 500_000), (10_000_000, None)]


def _write_run(run_dir, steps, mean, untrained, seeds=(0, 1, 2)):
    """A finished run directory as `jaxnat train` writes it: training returns at `mean` at every
    update, its evaluation at update 0 at `untrained`."""
    run_dir.mkdir(parents=True)
    (run_dir / "config.json").write_text(json.dumps({"spec": {"seed_values": list(seeds)},
                                                     "versions": {"jaxnat": "test"}}))
    metrics = [{"update": i + 1, "env_steps": s, "seed": seed, "episode_return": mean + d}
               for i, s in enumerate(steps) for seed, d in zip(seeds, SPREAD)]
    evals = [{"update": u, "env_steps": s, "seed": seed, "greedy_return": v + d, "sampled_return": v + d}
             for u, s, v in ((0, 0, untrained), (len(steps), steps[-1], mean)) for seed, d in zip(seeds, SPREAD)]
    for name, rows in (("metrics.jsonl", metrics), ("eval.jsonl", evals)):
        (run_dir / name).write_text("".join(json.dumps(r) + "\n" for r in rows))
    (run_dir / "summary.json").write_text(json.dumps({"complete": True, "chance": {"return": 0.3},
                                                      "wall_time_s": 1.0}))


def _report(out, cnn_steps, resnet_steps):
    """The report of two hand-made localisation runs: (findings row, report text)."""
    profile = grid.Profile("hand", "hand-made runs", 3, {"localize": grid.Budget(cnn_steps)})
    cells = [grid.Cell(f"localize-clutter-{trunk}-ppo", "localize", f"localize-{trunk}", "Localize/Clutter-v0", {},
                       "ppo", None, grid.Budget(n), {}, {"dataset": "clutter", "trunk": trunk})
             for trunk, n in (("cnn", cnn_steps), ("resnet18", resnet_steps))]
    for cell, mean in zip(cells, (0.85, 0.25)):
        n = cell.budget.total_timesteps
        _write_run(out / cell.name, [n // 2, n], mean, untrained=0.1)
    text = write_report(grid.Plan(profile, ("localize",), 3, out, cells), {}).read_text()
    row = next(line for line in text.splitlines() if line.startswith("| a small drop in performance"))
    return row, text


def test_verdict_report_has_budget_share_column_and_banner(tmp_path):
    row, text = _report(tmp_path / "quick", 150_000, 150_000)
    assert row.split(" | ")[1:3] == ["**reproduced**", "1.5%"]
    title, blank, banner = text.splitlines()[:3]
    assert title.startswith("# Reproduction") and not blank
    assert banner.startswith("> **These verdicts are not evidence about the paper.** Its cells trained 1.5% of")
    # The untrained policy, read from eval.jsonl's update-0 rows, is in the table of final returns.
    table = next(line for line in text.splitlines() if line.startswith("| `localize-clutter-cnn-ppo` |"))
    assert table.rstrip(" |").endswith("| 0.1 [0.05, 0.15]")
    row, text = _report(tmp_path / "paper", PAPER, PAPER)
    assert row.split(" | ")[1:3] == ["**reproduced**", "100%"] and "not evidence" not in text
    row, text = _report(tmp_path / "mixed", PAPER // 2, PAPER)
    assert row.split(" | ")[2] == "50%–100%" and "Its cells trained 50%–100% of" in text


@pytest.mark.parametrize("share, text", [(1.0, "100%"), (0.26, "26%"), (0.015, "1.5%"), (3.2e-6, "0.00032%")])
def test_verdict_budget_share_as_percent(share, text):
    from jaxnat.reproduce.report import _percent

    assert _percent(share) == text


def test_verdict_noise_control_reads_localisation_alone(tmp_path):
    """The noise control is judged with `--only localize` (its cells are in both vision experiments)."""
    profile = grid.Profile("hand", "hand-made runs", 3, {"localize": grid.Budget(1000)})
    cells = [grid.Cell(name, "localize", figure, "Localize/Clutter-v0", {}, "ppo", None, grid.Budget(1000), {},
                       {"dataset": "clutter", "trunk": "cnn", **extra})
             for name, figure, extra in (("real", "localize-cnn", {}),
                                         ("noise", "noise-control", {"observation": "noise"}))]
    for cell, mean in zip(cells, (0.85, 0.25)):
        _write_run(tmp_path / cell.name, [500, 1000], mean, untrained=0.1)
    text = write_report(grid.Plan(profile, ("localize",), 3, tmp_path, cells), {}).read_text()
    row = next(line for line in text.splitlines() if line.startswith("| (not in the paper; jaxnat's control)"))
    assert row.split(" | ")[1:3] == ["**reproduced**", "0.01%"]


def test_constant_reference_is_gated_too():
    """jaxnat's sight finding puts each PixelMuJoCo policy above the constant-observation cell,
    the best state-independent policy: a constant cell that did not learn is not that reference."""
    def mujoco(observation, mean, untrained=0.0):
        return _result("mujoco", "mujoco", "a2c", mean, untrained=untrained, robot="Swimmer", observation=observation)

    noise = mujoco("noise", 14.0)
    assert _judge("_sight_helps", [noise, mujoco("constant", 4.0)]).verdict == "reproduced"
    verdict = _judge("_sight_helps", [noise, mujoco("constant", 4.0, untrained=4.0)])
    assert verdict.verdict == "not shown" and "constant" in verdict.numbers and "did not learn" in verdict.numbers
    # The policy above is still gated first.
    assert _judge("_sight_helps", [mujoco("noise", 14.0, untrained=14.0), mujoco("constant", 4.0)]
                  ).verdict == "not shown"
