"""The report of `jaxnat reproduce`: `<out>/report.md` and one PNG per paper figure, built only
from the cells' own run directories (`config.json`, `metrics.jsonl`, `eval.jsonl`,
`summary.json`, read through `jaxnat.training.read_run`) and `timings.jsonl`.

Per cell: the training curve (each seed's episode return, binned over env steps; the mean over
seeds with a 95% bootstrap band), the final training return (each seed's mean over the last 10%
of its updates in which an episode ended: the paper's figures plot training returns), and the
final test-split returns of the greedy and the sampled policy (the last evaluation), each with a
95% bootstrap interval over seeds, and the untrained policy's sampled test return (the evaluation
at update 0: the learning gate of every verdict). Findings: `findings.py`, judged by the rules of
`verdicts.py`; each findings row gives the share of the paper's env-step budget
(`grid.PAPER_BUDGETS`) its cells trained, and a report whose cells trained less opens with a
banner saying its verdicts are not evidence about the paper.

Beside them: the departures from the paper that concern the report's cells (`departures.py`),
aggregate scores over cells and seeds computed with rliable (`aggregates.py`), and every number
per seed in `<out>/results.json` (`results_json.py`). A cell on a stand-in dataset is printed
as "Digits (for MNIST)" wherever its dataset is named (`labels.py`).
"""

from __future__ import annotations

import collections
import dataclasses
import datetime
import json
import platform
import textwrap
from pathlib import Path

import numpy as np

from jaxnat.reproduce.aggregates import aggregate, aggregates_section
from jaxnat.reproduce.calibration import (calibration_panels, calibration_results, calibration_section,
                                         calibration_status)
from jaxnat.reproduce.departures import departures_data, departures_section
from jaxnat.reproduce.findings import FINDINGS, Verdict, noise_control_pairs
from jaxnat.reproduce.grid import PAPER_BUDGETS, ROBOTS, Cell
from jaxnat.reproduce.labels import dataset_label
from jaxnat.reproduce.results_json import results_document, write_results, write_text_atomic
from jaxnat.reproduce.stats import Interval, binned_curve, bootstrap_band, bootstrap_ci

__all__ = ["CellResult", "load_result", "write_report", "FIGURES"]

FINAL_FRACTION = 0.1  # the final training return averages the last 10% of a seed's updates with episodes
GREEDY_NOTE = ("Test greedy takes the most likely action at every step: a feed-forward classifier whose window "
               "stops moving (against an edge) then sees one observation over and over and repeats one wrong label "
               "to the episode's end, so its greedy return can sit far below its sampled one. A continuous "
               "policy's greedy action is its Gaussian's mean, free of the exploration noise the training and "
               "sampled returns carry: for a PixelMuJoCo policy that sees a constant observation, one fixed gait, "
               "whose greedy return can sit far above its sampled one.")

# figure file stem -> (title, cells' figure tag, panel label key, curve label key)
FIGURES = {
    "classify-cnn": ("Image classification, 3-layer CNN", "classify-cnn", "dataset", "algo"),
    "classify-resnet18": ("Image classification, ResNet-18", "classify-resnet18", "dataset", "algo"),
    "sweep": ("The difficulty sweep with PPO: window w at M=20, steps M at w=5", "sweep", "sweep", "value"),
    "localize": ("Object localisation: 3-layer CNN and ResNet-18", None, "panel", "algo"),
    "atari": ("Natural Atari: background none / noise / video", "atari", "game", "background"),
    "mujoco": ("PixelMuJoCo: checker floor / video floor / pure noise", "mujoco", "robot", "observation"),
    "noise-control": ("The noise control on the vision tasks (not in the paper)", "noise-control", "dataset", "observation"),
}


@dataclasses.dataclass
class CellResult:
    """What the report reads from one finished (or partial) cell."""

    cell: Cell
    complete: bool
    seeds: int
    steps: np.ndarray  # env steps per seed at each update
    train: np.ndarray  # [updates, seeds] mean return of the episodes that ended in the update
    eval_steps: np.ndarray  # env steps per seed at each evaluation
    greedy: np.ndarray  # [evaluations, seeds] test-split return of the greedy policy
    sampled: np.ndarray  # [evaluations, seeds]
    chance: float | None  # the uniform random policy's test return
    wall_time_s: float
    seed_values: tuple = ()  # the seeds, in the order of the columns (empty: not recorded)
    # The natural videos and photos the run saw, per split (`config.json`'s `data`: each bank's
    # `FrameBank.manifest()`); empty for a run with none, or written before runs recorded them.
    data: dict = dataclasses.field(default_factory=dict)
    # Where the untrained policy's evaluation was computed after the run, not by it (its rows'
    # `computed_after`, e.g. "cpu": a record lost with a machine, recomputed from the config).
    untrained_after: str | None = None

    @property
    def final_train(self) -> Interval:
        return self.train_at(None)

    def train_per_seed(self, steps: float | None = None) -> np.ndarray:
        """Each seed's final training return of the run up to `steps` env steps per seed (None: all
        of it): its mean over the last 10% of those updates in which an episode ended (NaN: none)."""
        finals = []
        for column in self.train[self.steps <= steps].T if steps is not None else self.train.T:
            ended = column[np.isfinite(column)]
            count = max(1, int(round(len(ended) * FINAL_FRACTION)))
            finals.append(ended[-count:].mean() if len(ended) else np.nan)
        return np.array(finals, np.float64)

    def train_at(self, steps: float | None) -> Interval:
        """The mean over seeds of `train_per_seed(steps)` and its 95% bootstrap interval."""
        return bootstrap_ci(self.train_per_seed(steps))

    @property
    def untrained_per_seed(self) -> np.ndarray | None:
        """Each seed's untrained sampled test return (the evaluation at update 0), or None when the
        run has none (host runs evaluate once, at the end)."""
        first = np.flatnonzero(self.eval_steps == 0)
        return self.sampled[first[0]] if first.size else None

    @property
    def untrained(self) -> Interval | None:
        """The untrained policy's sampled test return over seeds, or None (`untrained_per_seed`)."""
        values = self.untrained_per_seed
        return None if values is None else bootstrap_ci(values)

    @property
    def budget_share(self) -> float:
        """The env steps per seed trained, as a share of the paper's (`grid.PAPER_BUDGETS`; a
        calibration cell: of its group's experiment). A finished run of the paper's budget counts
        as 100%: it stops at its last whole update (10M steps in updates of 16,384 end at
        9,994,240), as the authors' code and every RL library count updates."""
        paper = PAPER_BUDGETS[self.cell.labels.get("group", self.cell.experiment)]
        share = (float(self.steps.max()) if self.steps.size else 0.0) / paper
        return max(share, 1.0) if self.complete and self.cell.budget.total_timesteps >= paper else share

    @property
    def final_eval(self) -> int | None:
        """The index of the test evaluation of the trained policy: the latest one after update 0
        (the untrained policy's is never a final score), or None when there is none (a run whose
        last evaluation was lost has its untrained one only)."""
        trained = np.flatnonzero(self.eval_steps > 0)
        return int(trained[-1]) if trained.size else None

    @property
    def final_greedy(self) -> Interval:
        return bootstrap_ci([] if self.final_eval is None else self.greedy[self.final_eval])

    @property
    def final_sampled(self) -> Interval:
        return bootstrap_ci([] if self.final_eval is None else self.sampled[self.final_eval])


def load_result(cell: Cell, run_dir: Path) -> CellResult:
    from jaxnat.training import read_run

    record = read_run(run_dir)
    seed_values = record.config["spec"]["seed_values"]
    index = {seed: i for i, seed in enumerate(seed_values)}

    def table(rows, key):
        points = sorted({r["env_steps"] for r in rows})
        where = {s: i for i, s in enumerate(points)}
        values = np.full((len(points), len(seed_values)), np.nan)
        for r in rows:
            value = r.get(key)
            if value is not None:
                values[where[r["env_steps"]], index[r["seed"]]] = value
        return np.array(points, np.float64), values

    steps, train = table(record.metrics, "episode_return")
    eval_steps, greedy = table(record.evals, "greedy_return")
    _, sampled = table(record.evals, "sampled_return")
    summary = record.summary or {}
    chance = (summary.get("chance") or {}).get("return")
    after = next((r["computed_after"] for r in record.evals if r["update"] == 0 and r.get("computed_after")), None)
    return CellResult(cell, bool(summary.get("complete")), len(seed_values), steps, train, eval_steps, greedy, sampled,
                      chance, float(summary.get("wall_time_s") or 0.0), tuple(seed_values),
                      record.config.get("data") or {}, after)


def data_section(results: list[CellResult]) -> list[str]:
    """The natural videos and photos the cells saw (their runs' data manifests): per split and
    file, its SHA-256 (first 12 hex digits here; whole in each cell's `config.json`), the frames
    used and how many cells saw it. Empty when no cell recorded any."""
    seen: dict[tuple, dict] = {}
    for r in results:
        for split, banks in r.data.items():
            for entry in (e for bank in banks for e in bank):
                key = (split, entry["name"], entry["sha256"], entry["frames"])
                seen.setdefault(key, set()).add(r.cell.name)
    if not seen:
        return []
    lines = ["## Natural data the cells saw", "",
             "Every video and photo of the natural backgrounds and floors, as the runs recorded them "
             "(`config.json`'s `data`, `jaxnat.natural.FrameBank.manifest`); the splits never share a file.", "",
             "| split | file | SHA-256 | frames used | cells |", "|---|---|---|---|---|"]
    for (split, name, digest, frames), cells in sorted(seen.items()):
        lines.append(f"| {split} | {name} | `{digest[:12] or 'unknown'}` | {frames} | {len(cells)} |")
    return lines + [""]


def _dataset_title(cell: Cell) -> str:
    """The dataset as panels and tables print it: "Digits (for MNIST)" for a stand-in."""
    return dataset_label(cell)


def _panels(figure: str, results: list[CellResult]) -> dict[str, list[tuple[str, CellResult]]]:
    """panel title -> [(curve label, result)] for one figure."""
    _, tag, panel_key, curve_key = FIGURES[figure]
    panels: dict[str, list[tuple[str, CellResult]]] = {}
    for r in results:
        cell = r.cell
        if figure == "localize":
            if cell.experiment != "localize" or cell.figure == "noise-control":
                continue
            title = f"{_dataset_title(cell)}, {cell.labels['trunk']}"
            panels.setdefault(title, []).append((cell.algo.upper(), r))
            continue
        if cell.figure != tag:
            continue
        if figure == "sweep":
            w, m = cell.labels["w"], cell.labels["M"]
            if m == 20:
                panels.setdefault(f"{_dataset_title(cell)}: window w (M=20)", []).append((f"w={w}", r))
            if w == 5:
                panels.setdefault(f"{_dataset_title(cell)}: steps M (w=5)", []).append((f"M={m}", r))
            continue
        if figure == "noise-control":
            title = f"{cell.experiment}: {_dataset_title(cell)}, PPO"
            real = [a for a, b in noise_control_pairs(results) if b is r]
            panels.setdefault(title, []).extend([("real observation", o) for o in real] + [("pure noise", r)])
            continue
        title = _dataset_title(cell) if panel_key == "dataset" else cell.labels.get(panel_key)
        label = cell.algo.upper() if curve_key == "algo" else f"{cell.labels[curve_key]} · {cell.algo.upper()}"
        panels.setdefault(str(title), []).append((label, r))
    if figure == "mujoco":
        panels = dict(sorted(panels.items(), key=lambda kv: ROBOTS.index(kv[0]) if kv[0] in ROBOTS else 99))
    return panels


def curve_colors(panels: dict) -> dict:
    """One colour per curve label over all of a figure's panels (in order of first appearance),
    so that a curve ("noise · PPO") has the same colour in every panel, whichever curves a
    panel has so far."""
    labels = dict.fromkeys(label for curves in panels.values() for label, _ in curves)
    return {label: f"C{i % 10}" for i, label in enumerate(labels)}


def plot_figure(path: Path, title: str, panels: dict) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from jaxnat.training.records import line_with_band

    n = len(panels)
    columns = min(n, 4)
    rows = -(-n // columns)
    fig = Figure(figsize=(4.2 * columns, 3.4 * rows + 0.6), constrained_layout=True)
    FigureCanvasAgg(fig)
    axes = np.atleast_1d(fig.subplots(rows, columns, squeeze=False)).ravel()
    colors = curve_colors(panels)
    for ax, (panel, curves) in zip(axes, panels.items()):
        for label, r in curves:
            color = colors[label]
            x, per_seed = binned_curve(r.steps, r.train)
            if len(x):
                line_with_band(ax, x, *bootstrap_band(per_seed), f"{label} (train)", color=color)
            if len(r.eval_steps):
                mean, low, high = bootstrap_band(r.sampled)
                ax.errorbar(r.eval_steps, mean, yerr=[mean - low, high - mean], color=color, linestyle="--",
                            marker="o", markersize=3, linewidth=1, capsize=2, label=f"{label} (test, sampled)")
        chance = [r.chance for _, r in curves if r.chance is not None]
        if chance:
            ax.axhline(float(np.mean(chance)), color="0.4", linestyle=":", linewidth=1, label="random policy (test)")
        ax.set_title(panel, fontsize="medium")
        ax.ticklabel_format(axis="x", style="sci", scilimits=(0, 0))
        ax.set_xlabel("env steps per seed")
        ax.set_ylabel("episode return")
        ax.grid(alpha=0.3)
        ax.legend(fontsize="x-small", loc="best")
    for ax in axes[n:]:
        ax.set_visible(False)
    fig.suptitle(textwrap.fill(f"{title} (mean over seeds, 95% bootstrap band)", 40 * columns), fontsize="large")
    fig.savefig(path, dpi=100)


def _versions() -> dict:
    import jax

    import jaxnat

    return {"jaxnat": jaxnat.__version__, "jax": jax.__version__, "python": platform.python_version(),
            "device": str(jax.devices()[0].device_kind), "backend": jax.default_backend()}


def _run_versions(run_dir: Path) -> dict:
    from jaxnat.training import read_run

    return read_run(run_dir).config.get("versions") or _versions()


def interval_note(per_cell: list[dict]) -> list[str]:
    """What the intervals cover, where cells ran on a GPU: seeds, not the run-to-run variation
    of XLA's default GPU kernels (a CPU run under a key is the same run every time)."""
    gpus = sum(str(v.get("device", "cpu")).lower() != "cpu" for v in per_cell)
    if not gpus:
        return []
    return [f"- Intervals are 95% bootstrap intervals over seeds. {gpus} of the {len(per_cell)} cells ran on GPUs "
            "with XLA's default kernels, which are not bit for bit reproducible across processes: a rerun of a "
            "cell is another draw for the same seeds, a variation the intervals do not include "
            "(`bench/results/determinism.md`; `XLA_FLAGS=--xla_gpu_deterministic_ops=true` removes it, at a "
            "cost in speed)."]


def versions_line(per_cell: list[dict]) -> str:
    """The versions and devices the cells ran with, each field once where every cell agrees,
    else each value with its number of cells (cells of one report may come from several
    sittings: one device kind, then another)."""
    fields = []
    for name in dict.fromkeys(k for versions in per_cell for k in versions):
        counts = collections.Counter(str(versions.get(name, "not recorded")) for versions in per_cell)
        if len(counts) == 1:
            fields.append(f"{name} {next(iter(counts))}")
        else:
            fields.append(f"{name} " + " / ".join(f"{value} ({n} cell{'s' * (n > 1)})" for value, n in counts.most_common()))
    return ", ".join(fields)


def _timings(out: Path) -> list[dict]:
    path = out / "timings.jsonl"
    if not path.is_file():
        return []
    rows = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    # Per cell, the sessions since its last fresh start (a cell deleted and rerun starts over).
    kept: dict[str, list[dict]] = {}
    for row in rows:
        kept[row["cell"]] = [row] if not row.get("resumed") else [*kept.get(row["cell"], []), row]
    return [row for cell_rows in kept.values() for row in cell_rows]


def _elapsed(timings: list[dict]) -> float:
    """The seconds during which at least one cell ran: the union of the sessions' intervals
    (`start`, `start + seconds`), so cells run side by side count once (rows written before
    `start` was recorded count in full)."""
    spans = sorted((t["start"], t["start"] + t["seconds"]) for t in timings if "start" in t)
    elapsed, end = sum(t["seconds"] for t in timings if "start" not in t), float("-inf")
    for lo, hi in spans:
        elapsed += max(0.0, hi - max(lo, end))
        end = max(end, hi)
    return elapsed


def write_report(plan, outcomes: dict[str, str]) -> Path:
    """Write `<out>/report.md` and its figures for the cells of `plan`; returns the report's path."""
    from jaxnat.training import TrainError, run_status

    out: Path = plan.out
    timings = _timings(out)
    failures = {t["cell"]: t.get("message", "failed") for t in timings if t.get("outcome") == "failed"}
    outcomes = {**failures, **outcomes}
    results: list[CellResult] = []
    missing: dict[str, str] = {}
    for cell in plan.cells:
        if cell.skip:
            missing[cell.name] = f"not run: {cell.skip}"
            continue
        status = run_status(out / cell.name)
        if status == "new":
            missing[cell.name] = outcomes.get(cell.name, "not run yet").replace("failed:", "not run (failed):")
            continue
        try:
            result = load_result(cell, out / cell.name)
        except TrainError as err:
            missing[cell.name] = f"not run: {err}"
            continue
        if not result.complete:
            failed = outcomes.get(cell.name, "")
            missing[cell.name] = (f"incomplete ({failed})" if failed.startswith("failed") else
                                  "incomplete (interrupted; rerun the command to finish it)")
        results.append(result)
    finished = [r for r in results if r.complete]

    written = datetime.datetime.now().isoformat(timespec="seconds")
    verdicts = verdict_rows(finished, plan.only)
    # The calibration trains to matched steps below the budget by design: not a finding's cell.
    findings_cells = [r for r in finished if r not in calibration_results(finished)]
    aggregates = aggregate(findings_cells)
    lines = [f"# Reproduction of Zhang, Wu and Pineau (2018): profile `{plan.profile.name}`", ""]
    lines += budget_banner(findings_cells)
    lines += calibration_status(results, plan.cells)
    saved = [r.cell.name for r in results]
    per_cell = [_run_versions(out / name) for name in saved] if saved else [_versions()]
    versions = versions_line(per_cell)
    lines += [f"- Written {written} by `jaxnat reproduce --profile "
              f"{plan.profile.name} --only {','.join(plan.only)} --seeds {plan.seeds}`.",
              f"- Profile: {plan.profile.description}.",
              f"- Versions and devices of the runs: {versions}.",
              f"- Cells: {len(plan.cells)} in the grid, {len(finished)} finished, {len(missing)} not finished or not run.",
              *interval_note(per_cell),
              "- Per seed and per checkpoint, every number of this report (and the verdicts, aggregates and "
              "departures): `results.json`.", ""]
    if timings:
        by_experiment: dict[str, float] = {}
        for t in timings:
            by_experiment[t["experiment"]] = by_experiment.get(t["experiment"], 0.0) + t["seconds"]
        total = sum(by_experiment.values())
        lines += ["## Wall time", "", "| experiment | seconds (training sessions, resumed ones included) |", "|---|---|"]
        lines += [f"| {k} | {v:.0f} |" for k, v in by_experiment.items()] + [f"| total | {total:.0f} |"]
        if any(t.get("overlapped") for t in timings):
            lines += [f"| elapsed (streams of cells side by side: overlapping times counted once) | "
                      f"{_elapsed(timings):.0f} |"]
        lines += ["", "Seconds of each cell's whole process (compiling, training, evaluating, test play) from the "
                  "out folder's `timings.jsonl`; `results.json`'s `wall_time_s` is the training run's own time, "
                  "without what comes before and after it.", ""]

    lines += departures_section(plan.profile, plan.cells)
    lines += data_section(results)
    if plan.profile.name != "smoke":  # (a smoke report is the tests' and the CPU's: no rendering)
        from jaxnat.reproduce.strips import strips_section

        lines += strips_section(plan.cells, plan.only, out)
    lines += _findings_lines(verdicts)
    lines += aggregates_section(aggregates, finished)

    lines += ["## Figures", ""]
    for stem, (title, *_rest) in FIGURES.items():
        panels = _panels(stem, results)
        if not panels:
            continue
        plot_figure(out / f"{stem}.png", title, panels)
        lines += [f"### {title}", "", f"![{title}]({stem}.png)", ""]

    calibration = calibration_panels(results)
    if calibration:
        plot_figure(out / "calibration.png", "Calibration: the batch against the authors'", calibration)
    lines += calibration_section(results, "calibration.png" if calibration else None)

    lines += ["## Final returns (mean [95% bootstrap CI] over seeds)", "",
              "| cell | env | seeds | env steps/seed | train (last 10%) | test greedy | test sampled | random policy (test) "
              "| untrained policy (test, sampled) |", "|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        chance = "—" if r.chance is None else f"{r.chance:.3g}"
        steps = int(r.steps.max()) if r.steps.size else 0
        mark = "" if r.complete else " (incomplete)"
        untrained = "not recorded" if r.untrained is None else str(r.untrained)
        if r.untrained is not None and r.untrained_after:
            untrained += f" (computed after the run, on {r.untrained_after})"
        lines.append(f"| `{r.cell.name}`{mark} | {r.cell.env_id} {_kwargs(r.cell.env_kwargs)} | {r.seeds} | {steps:,} | "
                     f"{r.final_train} | {r.final_greedy} | {r.final_sampled} | {chance} | {untrained} |")
    if results:
        lines += ["", GREEDY_NOTE]
    lines += [""]
    if missing:
        lines += ["## Cells not finished or not run", "", "| cell | why |", "|---|---|"]
        lines += [f"| `{name}` | {why} |" for name, why in missing.items()] + [""]
    path = out / "report.md"
    write_text_atomic(path, "\n".join(lines))
    write_results(out / "results.json", results_document(plan, results, missing, verdicts, aggregates,
                                                         departures_data(plan.profile, plan.cells), written))
    return path


def _percent(share: float) -> str:
    return f"{share:.0%}" if share >= 0.1 else f"{100 * share:.2g}%"


def _share(verdict: Verdict) -> str:
    """The least and the most of the paper's budget the verdict's cells trained, as percentages."""
    if verdict.share is None:
        return "—"
    low, high = verdict.share
    return _percent(low) if _percent(low) == _percent(high) else f"{_percent(low)}–{_percent(high)}"


def budget_banner(finished: list[CellResult]) -> list[str]:
    """The report's opening lines when a finished cell trained less than the paper's budget."""
    shares = [r.budget_share for r in finished]
    if not shares or min(shares) >= 1.0:
        return []
    span = _share(Verdict("", "", tuple(finished)))
    return [f"> **These verdicts are not evidence about the paper.** Its cells trained {span} of the paper's "
            "env-step budget per seed (10M agent steps per cell; Natural Atari's 10M agent steps are 40M frames: "
            "`jaxnat.reproduce.grid.PAPER_BUDGETS`). What a claim says at the paper's budget can come out "
            "otherwise at a smaller one: the verdicts say what this code does at these budgets.", ""]


def verdict_rows(finished: list[CellResult], only: tuple[str, ...]) -> list[tuple]:
    """`(finding, verdict)` for each of `findings.FINDINGS` (`verdicts.py`'s rules); "not run" for a
    claim whose experiments `only` leaves out."""
    return [(finding, Verdict("not run", f"--only leaves out {' and '.join(finding.experiments)}")
             if not set(finding.experiments) & set(only) else finding.judge(finished)) for finding in FINDINGS]


def findings_section(finished: list[CellResult], only: tuple[str, ...]) -> list[str]:
    """The findings table: each claim's verdict (`verdicts.py`'s rules), the share of the paper's
    budget its cells trained, and its comparisons."""
    return _findings_lines(verdict_rows(finished, only))


def _findings_lines(rows: list[tuple]) -> list[str]:
    lines = ["## Findings", "", "The quantity compared is each cell's training return (each seed's mean over the last "
             "10% of its updates, as the paper's figures plot training curves; the test scores are in the final "
             "table), its mean over seeds with a 95% bootstrap interval over seeds. "
             "Verdicts: reproduced (95% intervals apart, in the paper's order), contradicted "
             "(apart, the reverse order), inconclusive (intervals overlap), not shown (the cell the comparison "
             "needs did not beat its untrained policy), not run. A claim against a number (\"close to 1\") is "
             "reproduced when the interval is at or above it; \"as good a policy\" is reproduced when the other "
             "policy's mean is at or above the lower bound of the reference's interval. A claim is "
             "contradicted when any of its comparisons is, reproduced when every one shown is, else "
             "inconclusive (not shown when a part of it has none shown); the comparisons column gives each "
             "one. Rules in `jaxnat/reproduce/verdicts.py`.", "",
             "| the paper's claim | verdict | share of the paper's budget | comparisons |", "|---|---|---|---|"]
    for finding, verdict in rows:
        lines.append(f"| {finding.claim} | **{verdict.verdict}** | {_share(verdict)} | {verdict.numbers} |")
    return lines + [""]


def _kwargs(kwargs: dict) -> str:
    return " ".join(f"{k}={v}" for k, v in kwargs.items())
