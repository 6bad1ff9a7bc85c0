"""Natural Atari's host work after ALE, as one parallel numba call (`composite_resize_stack`):
composite each env's gray screen over its background, shrink it with jaxnat.atari.area's exact
INTER_AREA kernel into the frame stack's newest slot, and interleave the stack into the
channels-last observation (the numba code is `jaxnat.atari.area.parallel_pass`).

`threads` sets how many of numba's threads the call uses (`numba.set_num_threads`, which
affects only the calling thread; restored afterwards); envs are split into that many contiguous
chunks. The output does not depend on it.
The first pass starts numba's threads (OpenMP's libgomp, which reads `OMP_WAIT_POLICY` once,
when loaded) with `OMP_WAIT_POLICY=PASSIVE` set for that moment only, unless you set it
yourself; a libgomp loaded before keeps its policy, and `GOMP_SPINCOUNT`, if set, overrides it.

`usable()` says whether the pass may run here: not on numba's `workqueue` layer (no OpenMP or
TBB: it aborts the process when two threads call parallel code at once), and not in a process
forked after numba's OpenMP threads started (GNU OpenMP is not fork-safe); envs then use the
Python pool (`host_pass="pool"`, also kept for comparison). An env made before a fork cannot be
stepped in the child either way (ale-py's emulation threads do not survive a fork). Why one
numba call, and why idle threads must sleep: `docs/design.md`, "Host threads".
"""

from __future__ import annotations

import os
import threading

import numba
import numpy as np

from jaxnat.atari.area import AreaPlan, check_screens, kernel_arguments, parallel_pass

__all__ = ["composite_resize_stack", "usable"]

_start_lock = threading.Lock()
_started_in_pid: int | None = None  # the process that started numba's threads; None: not yet


def usable() -> bool:
    """Whether the pass may run in this process (see the module docstring): numba's threading
    layer is not `workqueue`, and this is not a process forked after GNU OpenMP's threads
    started. Starts numba's threads (with OpenMP's passive wait policy) if needed."""
    if _started_in_pid not in (None, os.getpid()) and numba.threading_layer() == "omp":
        return False
    _start_threads()
    return numba.threading_layer() != "workqueue"


def composite_resize_stack(screens: np.ndarray, backgrounds: np.ndarray, ring: np.ndarray,
                           slots: list[int], obs: np.ndarray, plan: AreaPlan,
                           threads: int) -> np.ndarray:
    """For every env `i`: `ring[slots[-1], i] = composite_resize(screens[i], backgrounds[i])`,
    then `obs[i, :, :, k] = ring[slots[k], i]` (`slots` oldest first, the newest last).

    `screens`, `backgrounds`: `uint8[B, H, W]` (`backgrounds=screens`: nothing composited);
    `ring`: a frame stack's ring buffer `uint8[depth, B, h, w]`; `obs`: C-contiguous
    `uint8[B, h, w, depth]`. Releases the GIL. Returns `obs`."""
    depth, b = ring.shape[:2]
    check_screens(screens, backgrounds, plan, b)
    if (ring.shape[2:] != plan.dst_shape or ring.dtype != np.uint8 or not ring.flags.c_contiguous
            or obs.shape != (b, *plan.dst_shape, depth) or obs.dtype != np.uint8
            or not obs.flags.c_contiguous or sorted(slots) != list(range(depth))):
        raise ValueError(f"need a C-contiguous uint8 ring [depth, {b}, *{plan.dst_shape}], obs "
                         f"[{b}, *{plan.dst_shape}, depth] and slots a permutation of the "
                         f"ring's; got {ring.dtype} {ring.shape}, {obs.dtype} {obs.shape}, {slots}")
    _start_threads()
    chunks = max(1, min(int(threads), numba.config.NUMBA_NUM_THREADS, b))
    previous = numba.get_num_threads()
    numba.set_num_threads(chunks)
    try:
        parallel_pass(screens, backgrounds, ring, np.asarray(slots, np.int64), obs, chunks,
                      *kernel_arguments(plan))
    finally:
        numba.set_num_threads(previous)
    return obs


def _start_threads() -> None:
    """Start numba's threads (once) with OpenMP's passive wait policy: see the module docstring."""
    global _started_in_pid
    with _start_lock:
        if _started_in_pid is not None:  # in this process, or inherited across a fork
            return
        ours = "OMP_WAIT_POLICY" not in os.environ
        if ours:
            os.environ["OMP_WAIT_POLICY"] = "PASSIVE"
        try:
            numba.get_num_threads()  # launches the threading layer, which loads libgomp
        finally:
            if ours:
                del os.environ["OMP_WAIT_POLICY"]
        _started_in_pid = os.getpid()
