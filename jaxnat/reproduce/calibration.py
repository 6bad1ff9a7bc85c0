"""The calibration section of a report: does the paper profile's larger batch change the science?

A GPU wants hundreds of envs per seed where the authors had 8-32, and a larger batch takes
fewer optimizer steps per env step. `jaxnat reproduce --only calibration` trains the same cell
at the authors' batch, at 512 envs per seed and at batches and settings between
(`grid.CALIBRATION_VARIANTS`), every one to `grid.CALIBRATION_STEPS` env steps per seed, and
this section compares them at those matched steps. The paper profile (`grid.PAPER_SCALE`)
trains at the variant the calibration cleared (`grid.profile_variant`), named in the section.

**The quantity** is the verdicts' (`verdicts.py`): each seed's training return over the last 10%
of its updates with episodes, the mean over seeds with a 95% bootstrap interval. **The authors'
band** is that interval for the group's "authors" cell of the same algorithm. Each other cell is
*inside* the band when the two intervals overlap, *above* or *below* when they are apart; a cell
that did not beat its own untrained policy (`verdicts.learned`) is marked *did not learn* and
compared with nothing. When a large batch falls below the band, the fix is to restore optimizer
steps per env step first (PPO's minibatches: the "optimizer steps restored" variant), the
learning rate second; the table shows which variant closes the gap.

PixelMuJoCo's group compares reward treatments at the profile's batch (no authors' cell: see
`grid.CALIBRATION_VARIANTS`), each against its untrained policy only.
"""

from __future__ import annotations

from jaxnat.agents import ALGORITHMS
from jaxnat.reproduce.grid import CALIBRATION, CALIBRATION_STEPS, profile_variant
from jaxnat.reproduce.verdicts import learned

__all__ = ["calibration_results", "calibration_panels", "calibration_section", "calibration_status",
           "optimizer_steps", "band_position"]

AUTHORS = "authors"


def calibration_results(results: list) -> list:
    """The calibration cells among `results` (`report.CellResult`s)."""
    return [r for r in results if r.cell.experiment == CALIBRATION]


def _setting(cell, name: str):
    return cell.overrides.get(name, getattr(ALGORITHMS[cell.algo].config(), name, None))


def optimizer_steps(cell) -> tuple[int, int, float]:
    """`(envs, steps per env per update, optimizer steps per 1,000 env steps)` of a cell as it is
    configured (PPO: epochs x minibatches per update; A2C and ACKTR: one step per update)."""
    envs, steps = _setting(cell, "num_envs"), _setting(cell, "num_steps")
    per_update = _setting(cell, "update_epochs") * _setting(cell, "num_minibatches") if cell.algo == "ppo" else 1
    return envs, steps, 1000.0 * per_update / (envs * steps)


def band_position(result, authors) -> str:
    """Where `result`'s final training return sits against the `authors` cell's interval:
    "did not learn", "inside", "above" or "below" (`authors` None: "learned")."""
    if learned(result) is not None:
        return "did not learn"
    if authors is None:
        return "learned"
    got, band = result.final_train, authors.final_train
    if got.low > band.high:
        return "above"
    if got.high < band.low:
        return "below"
    return "inside"


def _groups(results: list) -> dict[tuple[str, str], list]:
    groups: dict[tuple[str, str], list] = {}
    for r in calibration_results(results):
        groups.setdefault((r.cell.labels["group"], r.cell.algo), []).append(r)
    return groups


def calibration_status(results: list, cells: tuple = ()) -> list[str]:
    """The report's opening lines on the calibration, when it ran: per group and algorithm, where
    the profile's cell sits against the authors' band, or what is missing to say. A verdict
    about an algorithm whose profile cell is not inside the band depends on the batch. `cells`:
    the grid's; a group and algorithm of its calibration with no cell run yet is named too."""
    lines = []
    groups = _groups(results)
    for (group, algo), rows in groups.items():
        by = {r.cell.labels["variant"]: r for r in rows if r.complete}
        chosen = profile_variant(group, algo)
        profile, authors = by.get(chosen), by.get(AUTHORS)
        name = "the profile's cell" if chosen in (None, "profile") else f"the profile's batch ({chosen})"
        if chosen == AUTHORS:
            said = ("the profile trains at the authors' batch" +
                    (f": {authors.final_train}" if authors is not None else ", whose cell has not run"))
        elif profile is None:
            said = f"{name} has not run"
        elif authors is None:
            said = (f"{name} {profile.final_train}; the authors' cell has not run"
                    if group != "mujoco" else f"{name} {profile.final_train} ({band_position(profile, None)})")
        else:
            said = f"{name} {profile.final_train} is {band_position(profile, authors)} the authors' {authors.final_train}"
        said_already = {chosen, AUTHORS} if profile is not None and authors is not None else {chosen}
        others = "; ".join(f"{variant} {r.final_train}" for variant, r in by.items() if variant not in said_already)
        lines.append(f"- {group} {algo.upper()}: {said}" + (f" (other cells: {others})" if others else "") + ".")
    if lines:
        pending = dict.fromkeys((c.labels["group"], c.algo) for c in cells if c.experiment == CALIBRATION)
        lines += [f"- {group} {algo.upper()}: not calibrated yet (none of its calibration cells has run): its "
                  "verdicts depend on the batch." for group, algo in pending if (group, algo) not in groups]
    if not lines:
        return []
    return ["> **Calibration of the batch** (the same cell at matched env steps, `--only calibration`; the paper "
            "profile trains at the batch it cleared; a verdict about an algorithm whose profile batch is not inside "
            "the authors' band depends on the batch):", ">",
            *[f"> {line}" for line in lines], ""]


def calibration_panels(results: list) -> dict[str, list[tuple[str, object]]]:
    """The calibration figure's panels for `report.plot_figure`: one per group and algorithm, a
    curve per variant."""
    return {f"{group}: {algo.upper()}": [(r.cell.labels["variant"], r) for r in rows]
            for (group, algo), rows in _groups(results).items()}


def calibration_section(results: list, figure: str | None = None) -> list[str]:
    """The report's calibration section (empty without calibration cells); `figure`: the file
    name of the calibration figure, shown when given."""
    groups = _groups(results)
    if not groups:
        return []
    lines = ["## Calibration: the batch against the authors'", "",
             f"Each cell trained to the same env steps per seed ({CALIBRATION_STEPS:,}: {CALIBRATION_STEPS / 1e7:.0%} of the "
             "paper's budget, so these rows judge the batch, never a claim of the paper; a cell that did not beat its "
             "untrained policy says so in the last column); train return = each seed's mean over its last 10% "
             "of updates with episodes (mean [95% bootstrap CI] over seeds). Against the authors' band: the "
             "authors'-batch cell's interval (inside: the intervals overlap). The paper profile trains at the row marked "
             "\"(the profile's)\". Rules: `jaxnat/reproduce/calibration.py`.",
             "", "| group | algo | variant | envs x steps per update | optimizer steps per 1,000 env steps | env steps/seed "
             "| train return | untrained (test, sampled) | against the authors' band |", "|---|---|---|---|---|---|---|---|---|"]
    for (group, algo), rows in groups.items():
        authors = next((r for r in rows if r.cell.labels["variant"] == AUTHORS and r.complete), None)
        for r in rows:
            envs, steps, per_k = optimizer_steps(r.cell)
            trained = int(r.steps.max()) if r.steps.size else 0
            position = "—" if r is authors else ("incomplete" if not r.complete else band_position(r, authors))
            untrained = "not recorded" if r.untrained is None else str(r.untrained)
            variant = r.cell.labels["variant"]
            if variant == profile_variant(group, algo) and variant != "profile":
                variant += " (the profile's)"
            lines.append(f"| {group} | {algo.upper()} | {variant} | {envs} x {steps} | {per_k:.3g} | "
                         f"{trained:,} | {r.final_train} | {untrained} | {position} |")
    lines += [""]
    if figure:
        lines += [f"![Calibration]({figure})", ""]
    return lines
