"""`python -m jaxnat.reproduce.cellstream`: a stream of `jaxnat reproduce`, a child process that
trains a named list of the grid's cells into the same `--out` as its parent (the host cells
beside the device cells, or one GPU's share of the device cells: `cell_stream.cell_stream_main`
says what it does; `cell_stream.CellStream` starts it). Only the entry point is here: the logic
lives in `cell_stream`, which the parent imports, so that `python -m` does not run a module the
package has already imported."""

import sys

from jaxnat.reproduce.cell_stream import cell_stream_main

if __name__ == "__main__":
    sys.exit(cell_stream_main())
