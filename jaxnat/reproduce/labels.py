"""How the report names a cell's dataset: the paper's name for the paper's data, and the data's
own name with the paper's in parentheses for a stand-in ("Digits (for MNIST)").

A cell trained on an embedded stand-in (`grid.STAND_INS`: Digits for MNIST, Fashion-MNIST for
CIFAR-10) keeps the paper's dataset in its labels, so that it fills the paper's panel and the
findings compare it where the paper compared that dataset. Everything printed about it (panel
titles, comparisons, tables, legends) must still say which data it trained on: a verdict on
Digits is evidence about Digits, not about MNIST.
"""

from __future__ import annotations

from jaxnat.reproduce.grid import DATASET_NAMES, STAND_INS, Cell

__all__ = ["stand_in_for", "stand_in_name", "dataset_label"]


def stand_in_for(cell: Cell) -> str | None:
    """The paper's dataset (a `DATASET_NAMES` key) the cell's data stands in for; None when the
    cell trains on the paper's own data (or has no dataset)."""
    dataset = cell.labels.get("dataset")
    if dataset not in STAND_INS:
        return None
    return dataset if cell.env_id == STAND_INS[dataset][1] or "stands in for" in cell.note else None


def stand_in_name(dataset: str) -> str:
    """The short name of the data standing in for the paper's `dataset` ("Digits", "Fashion-MNIST")."""
    return STAND_INS[dataset][2].split(" (")[0]


def dataset_label(cell: Cell) -> str:
    """The dataset as printed: "MNIST", or "Digits (for MNIST)" for a stand-in."""
    dataset = cell.labels.get("dataset")
    if dataset is None:
        return ""
    name = DATASET_NAMES.get(dataset, dataset)
    paper = stand_in_for(cell)
    return f"{stand_in_name(paper)} (for {name})" if paper else name
