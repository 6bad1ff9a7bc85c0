"""`jaxnat reproduce` (also `python -m jaxnat.reproduce`): the experiments of Zhang, Wu and
Pineau (2018) as a grid of training runs, and a findings report.

    jaxnat reproduce --profile smoke                  # every cell type, tiny budgets (CPU, minutes)
    jaxnat reproduce --profile quick --out runs/repro  # every finding, reduced budgets (one GPU)
    jaxnat reproduce --profile paper --only atari      # the paper's budgets, piecewise

Each cell is a `jaxnat train` run (seeds vmapped, or the host loop for Natural Atari) written to
`<out>/<cell>/` in the same run-directory format, its log in `<out>/logs/<cell>.log`, its wall
time in `<out>/timings.jsonl`. Rerunning the same command skips finished cells and resumes an
interrupted one from its checkpoint. On an accelerator the Natural Atari cells (ALE on the host's
cores) train in a second process alongside the others (`--sequential`: every cell in turn, as on
a CPU), and with two or more GPUs the other cells are shared among one process per GPU
(`--gpus`). The report, `<out>/report.md` with one PNG per paper figure, is built from the
cells' own files once every cell has ended.

Modules: `grid` (profiles, cells and their `jaxnat train` arguments, the plan), `command` (the
command line and the run over the cells), `estimates` (wall times, the streams), `cells`
(training cells in a process, compiling ahead, timing lines), `board` (the progress board),
`gpus` (the GPUs, counted without starting JAX on them), `cell_stream` (streams of cells in
child processes: the host cells, a GPU's share of the device cells; `cellstream` is its
`python -m` entry point), `report` (curves, tables, figures), `findings` (the paper's claims),
`verdicts` (how a claim is judged), `stats` (bootstrap intervals).
"""

from jaxnat.reproduce.command import ReproduceArgs, ReproduceError, main, make_plan, reproduce
from jaxnat.reproduce.grid import EXPERIMENTS, PROFILES, Cell, Profile, build_grid

__all__ = ["ReproduceArgs", "ReproduceError", "main", "make_plan", "reproduce", "EXPERIMENTS", "PROFILES", "Cell",
           "Profile", "build_grid"]
