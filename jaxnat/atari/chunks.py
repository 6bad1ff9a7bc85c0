"""Split a batch's host work into row chunks and run them on a pool of threads.

A chunk's work is a few whole-chunk numba/numpy/OpenCV calls that release the GIL, so chunks
run in parallel (many small per-env calls would serialise on the GIL instead), and a chunk of a
few envs is small enough that OpenCV keeps its own calls single-threaded. `docs/design.md`,
"Host threads", says where this pool is used and where jaxnat.atari.hostpass replaces it.
"""

from __future__ import annotations

import itertools
import os
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor, wait

import numpy as np

__all__ = ["ChunkRunner", "default_threads"]


def default_threads(num_envs: int) -> int:
    """ale-py's rule for `num_threads=0`: one thread per env, at most one per CPU."""
    return max(1, min(num_envs, os.cpu_count() or 1))


class ChunkRunner:
    """Runs `work(lo, hi)` over `min(threads, num_rows)` contiguous, near-equal row ranges of a
    batch of `num_rows`: the first range on the calling thread, the others on `threads - 1`
    pool threads; returns when all are done and re-raises the first error.

    `threads=1` runs the whole batch on the calling thread (no pool, no copies).
    """

    def __init__(self, num_rows: int, threads: int):
        if isinstance(threads, bool) or not isinstance(threads, (int, np.integer)) or threads < 1:
            raise ValueError(f"threads must be an integer >= 1, got {threads!r}")
        n = min(int(threads), int(num_rows))
        edges = np.linspace(0, num_rows, n + 1).round().astype(int).tolist()
        self.chunks = list(itertools.pairwise(edges))
        self._pool = (ThreadPoolExecutor(n - 1, thread_name_prefix="jaxnat-atari")
                      if n > 1 else None)

    @property
    def threads(self) -> int:
        return len(self.chunks)

    def run(self, work: Callable[[int, int], None],
            alongside: Callable[[], None] | None = None) -> None:
        """`work` over every chunk; then `alongside()`, if given, on the calling thread while the
        pool finishes. Not before the calling thread's own chunk: `alongside` is Python that holds
        the GIL, which the pool threads need to start their chunks; `work` releases it at once."""
        futures = [self._pool.submit(work, lo, hi) for lo, hi in self.chunks[1:]] if self._pool else []
        try:
            work(*self.chunks[0])
            if alongside is not None:
                alongside()
        finally:
            wait(futures)  # every chunk has finished before any error propagates
            for future in futures:
                future.result()

    def submit(self, work: Callable[[int, int], None]) -> list[Future]:
        """Start `work` on every chunk on the pool threads and return at once (the caller's
        thread goes on, e.g. into ALE); `[]` without a pool (the caller then does the work).
        The pool takes tasks in order, so a `run` started later never waits on these."""
        if self._pool is None:
            return []
        return [self._pool.submit(work, lo, hi) for lo, hi in self.chunks]

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None
