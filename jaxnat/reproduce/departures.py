"""Where a reproduction departs from the paper (Zhang, Wu and Pineau 2018) or from its authors'
code, as data: each `Departure` says what the paper (or the authors' code, where the paper is
silent) did and what jaxnat does, and which cells it touches. The report's "Departures from the
paper" section lists those that apply to the cells of the report (`applying`), so a reader
judging a verdict sees every way its cells differ from the paper's, and none that does not
concern them.

Some departures are fixed (the ALE preprocessing, the classification window's start, the
natural videos); others are read from the cells: a stand-in dataset (`labels.stand_in_for`),
the PixelMuJoCo physics setting and reward treatment (`env_kwargs`, `overrides`), the batch of
each algorithm (envs per seed x steps per update, from `Cell.overrides` or the configs'
defaults) against the authors' (PPO 8 x 128, A2C 16 x 5, ACKTR 32 x 20), and the env settings a
profile changes (`Profile.env_kwargs`). `docs/environments.md` has the full comparison with the
authors' code, departures that touch no cell of a reproduction included.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

from jaxnat.reproduce.grid import CALIBRATION, DATASET_NAMES, RUN_SETTINGS, Cell, Profile
from jaxnat.reproduce.labels import stand_in_for, stand_in_name

__all__ = ["Departure", "DEPARTURES", "AUTHORS_BATCH", "applying", "batch_rows", "departures_section",
           "departures_data"]


@dataclasses.dataclass(frozen=True)
class Departure:
    topic: str
    paper: str  # what the paper did (or the authors' code, where the paper says nothing)
    jaxnat: str  # what jaxnat does in the cells it applies to
    applies: Callable[[Cell], bool]  # whether it concerns a cell


def _experiment(*names: str) -> Callable[[Cell], bool]:
    return lambda cell: cell.experiment in names


def _stand_in(dataset: str, trunk: str | None = None) -> Callable[[Cell], bool]:
    return lambda cell: stand_in_for(cell) == dataset and (trunk is None or cell.labels.get("trunk") == trunk)


def _natural_video(cell: Cell) -> bool:
    return cell.env_kwargs.get("background") == "video" or cell.env_kwargs.get("floor") == "video"


def _physics(setting: str | None) -> Callable[[Cell], bool]:
    return lambda cell: cell.experiment == "mujoco" and cell.env_kwargs.get("physics") == setting


def _rewards(kind: str) -> Callable[[Cell], bool]:
    """PixelMuJoCo cells whose rewards the learner sees `kind`: "normalised", "clipped" or "raw"."""
    def applies(cell: Cell) -> bool:
        if cell.experiment != "mujoco":
            return False
        normalised, clipped = bool(cell.overrides.get("normalize_rewards")), bool(cell.overrides.get("clip_rewards"))
        return {"normalised": normalised, "clipped": clipped and not normalised,
                "raw": not (normalised or clipped)}[kind]
    return applies


DEPARTURES: tuple[Departure, ...] = (
    Departure(f"{stand_in_name('mnist')} stands in for MNIST",
              "70,000 handwritten digits at 28x28 (not found on this machine: `jaxnat.datasets.download('mnist')`)",
              "OpenCV's 5,000 handwritten digits (`opencv-doc`'s digits sheet), 20x20 padded to 28x28, a fixed "
              "stratified split; the cells keep the paper's panels and comparisons, labelled with the data they "
              "trained on",
              _stand_in("mnist")),
    Departure(f"{stand_in_name('cifar10')} stands in for CIFAR-10",
              "60,000 colour photos of 10 classes at 32x32 (not found on this machine: "
              "`jaxnat.datasets.download('cifar10')`)",
              "70,000 grey 28x28 photos of 10 kinds of clothing; the difficulty sweep runs on them too",
              _stand_in("cifar10")),
    Departure(f"3-layer CNN on {stand_in_name('cifar10')} (for CIFAR-10)",
              "the appendix's geometry for 32x32x3 photos: conv 6@5x5/2, 16@5x5, 6@5x5",
              "the trunk follows the image size: Fashion-MNIST's 28x28x1 takes the appendix's 28x28 geometry, "
              "conv 10@5x5/2, 20@5x5, 10@5x5 (`agents.networks.default_trunk`)",
              _stand_in("cifar10", "cnn")),
    Departure("localisation data", "Cityscapes street scenes (a registration to download)",
              "Clutter: OpenCV's handwritten digits and Fashion-MNIST items pasted on `opencv-doc`'s natural "
              "photos, 20 classes (`jaxnat.natural.clutter`), run whether Cityscapes is found or not",
              lambda cell: cell.experiment == "localize" and cell.labels.get("dataset") == "clutter"),
    Departure("start of the classification window",
              "a random position (the authors' code: top-left (16 - w, 16 - w) on 32x32)",
              "a uniformly random top-left in [0, H - w] x [0, W - w] (`start=\"random\"`), as the paper's text",
              lambda cell: cell.experiment == "classify" and cell.env_kwargs.get("start", "random") == "random"),
    Departure("classification moves",
              "four moves (the authors' code: UP and LEFT did nothing, a bug they fixed later)",
              "all four moves shift the window by w pixels, clamped inside the image",
              lambda cell: cell.experiment == "classify"),
    Departure("classification observation",
              "the image where revealed, -1 elsewhere (the authors' code), which collides with black pixels",
              "the image where revealed and 0 elsewhere, plus a revealed-mask channel and a window channel",
              lambda cell: cell.experiment == "classify"),
    Departure("natural videos",
              "840 Kinetics \"driving car\" clips, one set for training and testing (the authors' PixelMuJoCo "
              "advanced 4 video frames per agent step)",
              "the natural clips of Debian's `opencv-doc` found on the machine that trained (its 4.6 package "
              "ships vtest, tree and Megamind; later ones add box and cup; \"Natural data the cells saw\" lists "
              "each file used), split by whole file: test play sees clips never trained on; one video frame per "
              "agent step, a random clip and start frame at each reset",
              _natural_video),
    Departure("ALE: sticky actions",
              "\"frame skipping and sticky actions\" (no probability given)",
              "repeat_action_probability 0.25 at every emulated frame, frame skip 4 with a max-pool over the last "
              "two frames, 0 to 29 no-ops at each reset",
              _experiment("atari")),
    Departure("ALE: FIRE at reset and life loss",
              "not stated (the authors' code evaluated per life)",
              "no FIRE at reset (the policy must learn to serve) and whole games as episodes, with no life-loss "
              "signal in training or in test play",
              _experiment("atari")),
    Departure("ALE: rewards",
              "not stated (the authors' code clipped rewards to [-1, 1])",
              "training on rewards clipped to [-1, 1] (`ClipRewardWrapper`), as the authors' code; every return "
              "reported (training and test) is the unclipped game score (`jaxnat/training/host_backend.py`)",
              _experiment("atari")),
    Departure("PixelMuJoCo physics", "MuJoCo",
              "MuJoCo MJX with the robot's `physics=\"fast\"` settings (fewer solver iterations: its distance from "
              "Gymnasium's dynamics is in `bench/results/mjx_fidelity.md`)",
              _physics("fast")),
    Departure("PixelMuJoCo physics", "MuJoCo",
              "MuJoCo MJX with the model's own solver settings (Gymnasium v5's MJCF files)",
              _physics(None)),
    Departure("PixelMuJoCo rendering",
              "MuJoCo's OpenGL renderer at 128x128, resized to 84x84 grey, the floor keyed on its black checker "
              "pixels (the authors' code)",
              "a pure-JAX ray caster at 84x84 grey through the tracking camera; the floor found by geometry",
              _experiment("mujoco")),
    Departure("PixelMuJoCo rewards", "sign-clipped, also at evaluation (the authors' code)",
              "the learner sees the summed physics rewards scaled by a running estimate of the return's standard "
              "deviation and clipped to +-10 (`normalize_rewards`); returns are reported unscaled",
              _rewards("normalised")),
    Departure("PixelMuJoCo rewards", "sign-clipped, also at evaluation (the authors' code)",
              "the learner sees sign-clipped rewards (`clip_rewards`), as the authors; returns are reported unclipped",
              _rewards("clipped")),
    Departure("PixelMuJoCo rewards", "sign-clipped, also at evaluation (the authors' code)",
              "the learner sees the summed physics rewards, unclipped and unscaled; returns are reported the same",
              _rewards("raw")),
)

# The authors' batch per algorithm: (envs per seed, steps per env per update) (docs/environments.md
# section 5; the configs' defaults). DQN's is not stated.
AUTHORS_BATCH = {"ppo": (8, 128), "a2c": (16, 5), "acktr": (32, 20)}
_BATCH = ("num_envs", "num_steps")


def applying(cells: list[Cell]) -> list[tuple[Departure, list[str]]]:
    """The departures that concern any of `cells`, each with the names of the cells it concerns."""
    found = [(d, [c.name for c in cells if d.applies(c)]) for d in DEPARTURES]
    return [(d, names) for d, names in found if names]


def _config_default(algo: str, name: str):
    from jaxnat.agents import ALGORITHMS

    return {f.name: f.default for f in dataclasses.fields(ALGORITHMS[algo].config)}.get(name)


def batch_rows(cells: list[Cell]) -> list[dict]:
    """Per experiment, algorithm and settings: this report's envs per seed x steps per update, the
    authors', the other learning settings the cells override (`Cell.overrides` less
    `RUN_SETTINGS`) and, where cells of one experiment and algorithm differ (PixelMuJoCo's pixel
    cells and its state and constant references), the observations each row is for; only the
    rows that differ from the authors'."""
    rows: dict[tuple, dict] = {}
    for cell in cells:
        if cell.experiment == CALIBRATION:  # several batches by design: the calibration section's table
            continue
        envs, steps = (cell.overrides.get(k, _config_default(cell.algo, k)) for k in _BATCH)
        others = {k: v for k, v in cell.overrides.items() if k not in _BATCH and k not in RUN_SETTINGS}
        authors = AUTHORS_BATCH.get(cell.algo)
        if authors == (envs, steps) and not others:
            continue
        key = (cell.experiment, cell.algo, envs, steps, tuple(sorted((k, repr(v)) for k, v in others.items())))
        row = rows.setdefault(key, {"experiment": cell.experiment, "algo": cell.algo, "batch": (envs, steps),
                                    "authors": authors, "others": others, "observations": []})
        observation = cell.labels.get("observation")
        if observation and observation not in row["observations"]:
            row["observations"].append(observation)
    split = {(r["experiment"], r["algo"]) for r in rows.values()
             if sum((o["experiment"], o["algo"]) == (r["experiment"], r["algo"]) for o in rows.values()) > 1}
    for row in rows.values():
        if (row["experiment"], row["algo"]) not in split:
            row["observations"] = []
    return list(rows.values())


def _batch_text(batch) -> str:
    return "not stated" if batch is None else f"{batch[0]} x {batch[1]} = {batch[0] * batch[1]:,}"


def _env_settings(profile: Profile, cells: list[Cell]) -> list[str]:
    """The env settings the profile sets for an experiment with cells (`physics` has its own entry)."""
    experiments = {c.experiment for c in cells}
    return [f"- **{experiment} env settings**: the paper: each env's defaults. jaxnat (profile `{profile.name}`): "
            + ", ".join(f"`{k}={v}`" for k, v in kwargs.items() if k != "physics") + "."
            for experiment, kwargs in profile.env_kwargs.items()
            if experiment in experiments and any(k != "physics" for k in kwargs)]


def _names(names: list[str], cells: list[Cell]) -> str:
    if len(names) == len(cells):
        return "every cell"
    shown = ", ".join(f"`{n}`" for n in names[:6])
    return shown + (f" and {len(names) - 6} more" if len(names) > 6 else "")


def departures_section(profile: Profile, cells: list[Cell]) -> list[str]:
    """The report's "Departures from the paper" lines for the grid's `cells` (the runnable ones'
    departures; the datasets of the cells that cannot run)."""
    skipped = sorted({DATASET_NAMES.get(c.labels.get("dataset"), "") for c in cells if c.skip} - {""})
    cells = [c for c in cells if not c.skip]
    found = applying(cells)
    batches = batch_rows(cells)
    settings = _env_settings(profile, cells)
    if not (found or batches or settings or skipped or any(c.note and stand_in_for(c) is None for c in cells)):
        return []
    lines = ["## Departures from the paper", "",
             "Each departure says what the paper did (or the authors' code, where the paper is silent) and what "
             "jaxnat does, for the cells of this report (`jaxnat/reproduce/departures.py`; the full comparison: "
             "`docs/environments.md`).", ""]
    for departure, names in found:
        lines.append(f"- **{departure.topic}** ({_names(names, cells)}): the paper: {departure.paper}. "
                     f"jaxnat: {departure.jaxnat}.")
    lines += settings
    lines += [f"- `{c.name}`: {c.note}." for c in cells if c.note and stand_in_for(c) is None]
    if batches:
        lines += ["", "Batch per update, per seed (envs x steps per env), against the authors' (PPO 8 x 128, A2C "
                  "16 x 5, ACKTR 32 x 20):", "",
                  "| experiment | algorithm | this report | the authors' | other settings changed |",
                  "|---|---|---|---|---|"]
        lines += [f"| {r['experiment']}{' (' + ', '.join(r['observations']) + ')' if r['observations'] else ''} "
                  f"| {r['algo'].upper()} | {_batch_text(r['batch'])} "
                  f"| {_batch_text(r['authors'])} "
                  f"| {', '.join(f'`{k}={v}`' for k, v in r['others'].items()) or '—'} |" for r in batches]
    if skipped:
        lines += ["", f"Not run (no data, no stand-in): {', '.join(skipped)}; the table of cells not run says why."]
    return lines + [""]


def departures_data(profile: Profile, cells: list[Cell]) -> list[dict]:
    """The same departures as JSON-ready rows (for `results.json`)."""
    cells = [c for c in cells if not c.skip]
    rows = [{"topic": d.topic, "paper": d.paper, "jaxnat": d.jaxnat, "cells": names} for d, names in applying(cells)]
    rows += [{"topic": f"batch: {r['experiment']} {r['algo']}", "paper": _batch_text(r["authors"]),
              "jaxnat": _batch_text(r["batch"]), "other_settings": r["others"],
              **({"observations": r["observations"]} if r["observations"] else {})} for r in batch_rows(cells)]
    rows += [{"topic": f"note: {c.name}", "paper": "", "jaxnat": c.note, "cells": [c.name]}
             for c in cells if c.note and stand_in_for(c) is None]
    rows += [{"topic": f"{e} env settings", "paper": "the env's defaults",
              "jaxnat": {k: v for k, v in kw.items() if k != "physics"}}
             for e, kw in profile.env_kwargs.items() if e in {c.experiment for c in cells}
             and any(k != "physics" for k in kw)]
    return rows
