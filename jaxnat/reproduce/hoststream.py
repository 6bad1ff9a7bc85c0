"""`python -m jaxnat.reproduce.hoststream`: the host stream of `jaxnat reproduce`, a child process
that trains the grid's host cells (Natural Atari) into the same `--out` while its parent trains
the device cells (`command.host_stream_main` says what it does; `run_cells` starts it)."""

import sys

from jaxnat.reproduce.command import host_stream_main

if __name__ == "__main__":
    sys.exit(host_stream_main())
