"""Copy the finished cells of a `jaxnat reproduce` folder as records small enough to commit.

    python scripts/thin_records.py /tmp/paper thin/                    # every finished cell
    python scripts/thin_records.py /tmp/paper thin/ --cells 'mujoco-*' --skip-existing

For each cell folder of OUT whose `summary.json` says the run is complete: its `config.json`,
`summary.json` and `eval.jsonl` as written, and `metrics.jsonl` thinned to the columns the
report reads and the policy's entropy (`COLUMNS`), into DEST/<cell>/. Checkpoints, logs and
curves stay behind: a pixel cell's checkpoints are tens of MB, its thinned records a few
hundred kB. OUT's `timings.jsonl` rows of the copied cells are appended to DEST/timings.jsonl. `jaxnat reproduce --out DEST
--report-only` then writes the report from DEST, and a later `jaxnat reproduce --out DEST`
skips those cells (docs/reproduction/paper/SITTINGS.md packs DEST as `records.tar.xz`).

A cell already in DEST is refused in one line (`--skip-existing` leaves it as it is), so a
sitting's records never silently replace another's. Prints one line per cell copied.
"""

from __future__ import annotations

import argparse
import fnmatch
import json
import shutil
import sys
from pathlib import Path

# The columns of `metrics.jsonl` that `jaxnat reproduce --report-only` reads, and the entropy: a
# cell that did not learn shows in it whether its policy widened or collapsed.
COLUMNS = ("update", "seed", "env_steps", "episode_return", "episodes", "entropy")
KEPT = ("config.json", "summary.json", "eval.jsonl")


def finished_cells(out: Path, patterns: list[str]) -> list[Path]:
    """The cell folders of `out` with a complete run (`summary.json`: `"complete": true`) whose
    names match one of `patterns` (all when empty), in name order."""
    cells = []
    for folder in sorted(p for p in out.iterdir() if p.is_dir()):
        if patterns and not any(fnmatch.fnmatch(folder.name, p) for p in patterns):
            continue
        summary = folder / "summary.json"
        if summary.is_file() and json.loads(summary.read_text()).get("complete") is True:
            cells.append(folder)
    return cells


def thin_cell(cell: Path, dest: Path) -> None:
    """`cell`'s records into `dest` (created): `KEPT` as they are, `metrics.jsonl`'s rows
    reduced to `COLUMNS` (rows without an update and a seed are not training rows: dropped)."""
    dest.mkdir(parents=True)
    for name in KEPT:
        if (cell / name).is_file():
            shutil.copyfile(cell / name, dest / name)
    with open(cell / "metrics.jsonl") as rows, open(dest / "metrics.jsonl", "w") as thinned:
        for line in rows:
            row = json.loads(line)
            if "update" in row and "seed" in row:
                thinned.write(json.dumps({k: row[k] for k in COLUMNS if k in row}) + "\n")


def append_timings(out: Path, dest: Path, cells: set[str]) -> int:
    """Append `out/timings.jsonl`'s rows of `cells` to `dest/timings.jsonl`, skipping rows
    already there; how many were appended."""
    source = out / "timings.jsonl"
    if not source.is_file() or not cells:
        return 0
    target = dest / "timings.jsonl"
    present = set(target.read_text().splitlines()) if target.is_file() else set()
    new = [line for line in source.read_text().splitlines()
           if line.strip() and line not in present and json.loads(line).get("cell") in cells]
    with open(target, "a") as f:
        f.writelines(line + "\n" for line in new)
    return len(new)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", type=Path, help="the `jaxnat reproduce --out` folder")
    parser.add_argument("dest", type=Path, help="where the thinned records go (created)")
    parser.add_argument("--cells", nargs="*", default=[], help="cell name patterns (default: every finished cell)")
    parser.add_argument("--skip-existing", action="store_true", help="leave cells already in DEST as they are")
    args = parser.parse_args(argv)
    if not args.out.is_dir():
        parser.exit(2, f"error: {args.out} is not a folder: give the --out folder of jaxnat reproduce\n")
    cells = finished_cells(args.out, args.cells)
    existing = [c.name for c in cells if (args.dest / c.name).exists()]
    if existing and not args.skip_existing:
        parser.exit(2, f"error: {args.dest} already holds {', '.join(existing)}: "
                       "pass --skip-existing to keep those, or choose another DEST\n")
    args.dest.mkdir(parents=True, exist_ok=True)
    copied = set()
    for cell in cells:
        if cell.name in existing:
            continue
        thin_cell(cell, args.dest / cell.name)
        copied.add(cell.name)
        print(f"{cell.name}: {sum(f.stat().st_size for f in (args.dest / cell.name).iterdir()):,} bytes")
    timings = append_timings(args.out, args.dest, copied)
    print(f"{len(copied)} cells into {args.dest} ({len(existing)} already there), {timings} timing rows")
    return 0


if __name__ == "__main__":
    sys.exit(main())
