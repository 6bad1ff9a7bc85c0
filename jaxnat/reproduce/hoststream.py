"""`python -m jaxnat.reproduce.hoststream`: the host stream of `jaxnat reproduce`, a child process
that trains the grid's host cells (Natural Atari) into the same `--out` while its parent trains
the device cells (`host_stream.host_stream_main` says what it does; `host_stream.HostStream`
starts it). Only the entry point is here: the logic lives in `host_stream`, which the parent
imports, so that `python -m` does not run a module the package has already imported."""

import sys

from jaxnat.reproduce.host_stream import host_stream_main

if __name__ == "__main__":
    sys.exit(host_stream_main())
