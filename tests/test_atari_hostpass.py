"""jaxnat.atari.hostpass: the parallel host pass equals the serial pieces, and numba's idle
threads sleep instead of spinning on the cores ALE needs."""

import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

pytest.importorskip("numba")

from jaxnat.atari.area import area_plan, composite_resize
from jaxnat.atari.hostpass import composite_resize_stack

PLAN = area_plan((210, 160), (84, 84))


def _inputs(rng, b, depth):
    screens = rng.integers(0, 256, (b, 210, 160), dtype=np.uint8)
    screens[:, 40:150] = 0  # a black background to composite over
    backgrounds = rng.integers(0, 256, (b, 210, 160), dtype=np.uint8)
    ring = rng.integers(0, 256, (depth, b, 84, 84), dtype=np.uint8)
    slots = [int(s) for s in rng.permutation(depth)]
    return screens, backgrounds, ring, slots


@pytest.mark.parametrize("depth", [1, 2, 3, 4])
def test_pass_equals_the_kernel_then_the_stack(depth):
    rng = np.random.default_rng(depth)
    screens, backgrounds, ring, slots = _inputs(rng, 7, depth)
    expected_ring = ring.copy()
    composite_resize(screens, backgrounds, expected_ring[slots[-1]], PLAN)
    expected = np.stack([expected_ring[s] for s in slots], axis=-1)
    for threads in (1, 2, 64):  # numba's threads are capped at NUMBA_NUM_THREADS (see below)
        out_ring = ring.copy()
        obs = np.full((7, 84, 84, depth), 3, np.uint8)
        assert composite_resize_stack(screens, backgrounds, out_ring, slots, obs, PLAN,
                                      threads) is obs
        np.testing.assert_array_equal(out_ring, expected_ring)  # only the newest slot changed
        np.testing.assert_array_equal(obs, expected)


_ANY_THREAD_COUNT = textwrap.dedent("""
    import numba, numpy as np
    from jaxnat.atari.area import area_plan, composite_resize
    from jaxnat.atari.hostpass import composite_resize_stack
    assert numba.config.NUMBA_NUM_THREADS == 8
    plan, rng = area_plan((210, 160), (84, 84)), np.random.default_rng(0)
    screens = rng.integers(0, 256, (7, 210, 160), dtype=np.uint8) // 2
    backgrounds = rng.integers(0, 256, (7, 210, 160), dtype=np.uint8)
    ring = rng.integers(0, 256, (4, 7, 84, 84), dtype=np.uint8)
    expected_ring = ring.copy()
    composite_resize(screens, backgrounds, expected_ring[1], plan)
    expected = np.stack([expected_ring[s] for s in (2, 3, 0, 1)], axis=-1)
    for threads in (1, 3, 6, 7, 8):  # uneven chunks, one env a chunk, more threads than envs
        out_ring, obs = ring.copy(), np.zeros((7, 84, 84, 4), np.uint8)
        composite_resize_stack(screens, backgrounds, out_ring, [2, 3, 0, 1], obs, plan, threads)
        assert (out_ring == expected_ring).all() and (obs == expected).all(), threads
    print("ok")
""")


def _run_python(code, **env_vars):
    env = {k: v for k, v in os.environ.items() if k not in ("OMP_WAIT_POLICY", "NUMBA_NUM_THREADS")}
    env.update(env_vars)
    return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                          check=True).stdout.split()


def test_any_thread_count_gives_the_same_output():
    assert _run_python(_ANY_THREAD_COUNT, NUMBA_NUM_THREADS="8") == ["ok"]


_FORK = textwrap.dedent("""
    import os, numba
    from jaxnat.atari import hostpass
    print(hostpass.usable(), numba.threading_layer())
    pid = os.fork()
    if pid == 0:  # numba would terminate this child at a parallel call on GNU OpenMP
        print(hostpass.usable(), flush=True)
        os._exit(0)
    os.waitpid(pid, 0)
    print(hostpass.usable())
""")


def test_a_process_forked_after_openmp_started_does_not_use_the_pass():
    parent, layer, child, parent_again = _run_python(_FORK)
    if layer != "omp":
        pytest.skip(f"numba's threading layer is {layer!r}, not OpenMP")
    assert (parent, child, parent_again) == ("True", "False", "True")


def test_the_workqueue_layer_is_not_used():  # it aborts on concurrent calls (module docstring)
    code = "from jaxnat.atari import hostpass; print(hostpass.usable())"
    assert _run_python(code, NUMBA_THREADING_LAYER="workqueue") == ["False"]


def test_screens_as_their_own_backgrounds_composite_nothing():
    rng = np.random.default_rng(0)
    screens, _, ring, slots = _inputs(rng, 3, 4)
    obs = np.empty((3, 84, 84, 4), np.uint8)
    composite_resize_stack(screens, screens, ring, slots, obs, PLAN, 2)
    expected = np.empty((3, 84, 84), np.uint8)
    composite_resize(screens, screens, expected, PLAN)
    np.testing.assert_array_equal(obs[..., -1], expected)


def test_bad_shapes_are_clear_errors():
    rng = np.random.default_rng(0)
    screens, backgrounds, ring, slots = _inputs(rng, 2, 4)
    obs = np.empty((2, 84, 84, 4), np.uint8)
    with pytest.raises(ValueError, match="screens and backgrounds"):
        composite_resize_stack(screens[:, :100], backgrounds, ring, slots, obs, PLAN, 2)
    with pytest.raises(ValueError, match="screens and backgrounds"):
        composite_resize_stack(screens, backgrounds.astype(np.int16), ring, slots, obs, PLAN, 2)
    with pytest.raises(ValueError, match="C-contiguous uint8 ring"):
        composite_resize_stack(screens, backgrounds, ring, slots, obs[..., :3], PLAN, 2)
    with pytest.raises(ValueError, match="permutation"):
        composite_resize_stack(screens, backgrounds, ring, [0, 0, 1, 2], obs, PLAN, 2)
    with pytest.raises(ValueError, match="C-contiguous uint8 ring"):
        composite_resize_stack(screens, backgrounds, ring[:, :, ::-1], slots, obs, PLAN, 2)


_IDLE_CPU = textwrap.dedent("""
    import resource, sys, time
    import numba, numpy as np
    from jaxnat.atari.area import area_plan
    from jaxnat.atari.hostpass import composite_resize_stack
    plan = area_plan((210, 160), (84, 84))
    screens = np.zeros((8, 210, 160), np.uint8)
    ring = np.zeros((4, 8, 84, 84), np.uint8)
    obs = np.empty((8, 84, 84, 4), np.uint8)
    def cpu():
        usage = resource.getrusage(resource.RUSAGE_SELF)
        return usage.ru_utime + usage.ru_stime
    idle = 0.0
    for _ in range(6):
        composite_resize_stack(screens, screens, ring, [0, 1, 2, 3], obs, plan, 2)
        before = cpu()
        time.sleep(0.03)
        idle += cpu() - before
    print(numba.threading_layer(), idle)
""")


def _idle_cpu_seconds(policy=None):
    out = _run_python(_IDLE_CPU, NUMBA_NUM_THREADS="2",
                      **({} if policy is None else {"OMP_WAIT_POLICY": policy}))
    return out[0], float(out[1])


def test_idle_threads_sleep_instead_of_spinning():
    layer, idle = _idle_cpu_seconds()
    if layer != "omp":
        pytest.skip(f"numba's threading layer is {layer!r}, not OpenMP")
    # 6 x 30 ms asleep: a spinning thread burns up to that much CPU (see the control below)
    assert idle < 0.02, f"numba's threads used {idle:.3f} s of CPU while the caller slept"
    if len(os.sched_getaffinity(0)) < 2:  # libgomp barely spins with more threads than CPUs
        return
    _, spinning = _idle_cpu_seconds("ACTIVE")  # the user's own setting wins, and it spins
    assert spinning > max(0.03, 5 * idle), (idle, spinning)
