"""The GPUs `jaxnat reproduce` can train on, found without starting JAX on them in this process.

JAX preallocates 75% of every GPU it sees when its backend starts in a process, so a parent that
is to hand one GPU to each of its child streams must never start JAX on them itself.
`find_devices` asks JAX in a short child process instead (`python -c PROBE`, preallocation off,
so it takes a GPU's memory for a moment only): JAX's own answer counts exactly the GPUs a stream
could use, honouring `JAX_PLATFORMS`, `CUDA_VISIBLE_DEVICES` and a jaxlib without GPU support,
which `nvidia-smi -L` would not. It costs one JAX start (seconds), once per command. When JAX is
told to use only the CPU, or has already started here (a library caller), no probe is needed."""

from __future__ import annotations

import dataclasses
import json
import os
import sys

PROBE = "import json, jax; print(json.dumps({'platform': jax.default_backend(), 'devices': jax.local_device_count()}))"
PROBE_SECONDS = 300  # a CUDA start on a busy machine can take a while


@dataclasses.dataclass(frozen=True)
class Devices:
    """What JAX would train on here: its `platform` ("cpu", "gpu", as `estimates.RATES`; "" when
    it could not be found, `problem` says why) and the GPUs' `CUDA_VISIBLE_DEVICES` ids, in
    JAX's order (none unless `platform` is "gpu"; a test may name some on the CPU to run that
    many device streams there)."""

    platform: str
    gpus: tuple[str, ...] = ()
    problem: str = ""


def gpu_ids(count: int, environ) -> tuple[str, ...]:
    """The `CUDA_VISIBLE_DEVICES` ids of the `count` GPUs JAX sees under `environ`: the
    variable's entries when it is set (JAX's GPU i is its i-th entry: CUDA numbers the visible
    GPUs in that order, and stops at the first invalid entry), else 0 to count - 1."""
    given = [entry.strip() for entry in environ.get("CUDA_VISIBLE_DEVICES", "").split(",")]
    if "CUDA_VISIBLE_DEVICES" in environ:
        return tuple(given[:count])
    return tuple(str(i) for i in range(count))


def parse_probe(stdout: str, environ) -> Devices:
    """The `Devices` of `PROBE`'s output (its last line: JSON), run under `environ`."""
    lines = stdout.strip().splitlines()
    try:
        found = json.loads(lines[-1])
        platform, count = str(found["platform"]), int(found["devices"])
    except (IndexError, ValueError, KeyError, TypeError):
        return Devices("", problem=f"JAX's probe printed {stdout.strip()[-200:]!r}")
    return Devices(platform, gpu_ids(count, environ) if platform == "gpu" else ())


def jax_started() -> bool:
    """Whether JAX has started a backend in this process (when JAX cannot tell: as if it had)."""
    try:
        from jax._src.xla_bridge import backends_are_initialized
    except ImportError:
        return True
    return backends_are_initialized()


def find_devices() -> Devices:
    """This machine's `Devices`, without starting JAX here (unless it has started already)."""
    import subprocess

    import jax

    if jax.config.jax_platforms == "cpu":
        return Devices("cpu")
    if jax_started():
        backend = jax.default_backend()
        return Devices(backend, gpu_ids(jax.local_device_count(), os.environ) if backend == "gpu" else ())
    env = {**os.environ, "XLA_PYTHON_CLIENT_PREALLOCATE": "false"}
    try:
        done = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True,
                              timeout=PROBE_SECONDS)
    except (OSError, subprocess.TimeoutExpired) as err:
        return Devices("", problem=f"JAX's probe failed: {err}")
    if done.returncode != 0:
        last = (done.stderr.strip().splitlines() or ["no output"])[-1]
        return Devices("", problem=f"JAX's probe exited with status {done.returncode}: {last}")
    return parse_probe(done.stdout, os.environ)


def keep_jax_off_gpus() -> None:
    """Set this process's JAX to the CPU if it has not started (with a stream per GPU the GPUs
    are the children's; a stray JAX call here would otherwise take 75% of each)."""
    import jax

    if not jax_started():
        jax.config.update("jax_platforms", "cpu")
