"""Sharded envs and training (`jaxnat.sharding`, `make_vec(devices=)`, `jaxnat train --devices`).

The checks on several devices run `tests/sharded_checks.py` in fresh processes: 4 simulated
CPU devices (`XLA_FLAGS`, read once when JAX starts, so this process keeps its one device),
then a two-process `jax.distributed` run over the loopback address; for the jitted learners
and for Natural Atari's host learner (one ALE batch per process). Here: what one device can
check (bad input, the distributed set-up's environment variables).
"""

import os
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import jaxnat
from jaxnat import sharding
from jaxnat.training import main

CHECKS = Path(__file__).with_name("sharded_checks.py")
# Backend optimisation off: these programs compile about 3x faster on a CPU (as tests/test_train.py).
FAST_XLA = "--xla_backend_optimization_level=0"


def _env(**extra) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_") and k != "XLA_FLAGS"}
    return {**env, "JAX_PLATFORMS": "cpu", **extra}


def test_uneven_splits_name_the_nearest_counts():
    with pytest.raises(ValueError, match=r"^num_envs=10 does not split evenly over 4 devices: use num_envs=8 or 12$"):
        sharding.check_split(10, 4)
    with pytest.raises(ValueError, match=r"use --seeds 4$"):
        sharding.check_split(3, 4, "seeds", "--seeds ")
    assert sharding.nearest_multiples(1030, 8) == [1024, 1032]


def test_more_devices_than_there_are():
    with pytest.raises(ValueError, match=r"^devices=2: there is only 1 cpu device here; use at most 1 \(or all\)$"):
        jaxnat.make_vec("Classify/Digits-v0", 8, devices=2)
    assert len(sharding.resolve_devices("all")) == 1 and sharding.device_mesh(1).axis_names == (sharding.AXIS,)


def test_host_batched_envs_refuse_devices():
    with pytest.raises(TypeError, match="emulated on the host, not on devices: leave devices= out"):
        jaxnat.make_vec("NaturalAtari/Breakout-v0", 8, devices=1)


def test_train_refuses_devices_it_lacks(capsys, tmp_path):
    assert main(["--devices", "3", "--run-dir", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    assert err == "jaxnat train: error: --devices 3: there is only 1 cpu device here; use at most 1 (or all)\n"
    # A host env takes --devices (its update data parallel), not whole seeds per device.
    assert main(["--env-id", "NaturalAtari/Breakout-v0", "--devices", "1", "--shard", "seeds",
                 "--run-dir", str(tmp_path / "run")]) == 2
    assert "--shard seeds places whole seeds on devices; a host env's seeds share" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()


def test_distributed_environment(monkeypatch):
    for name in sharding.ENV_VARS:
        monkeypatch.delenv(name, raising=False)
    assert sharding.initialize_from_env() is False  # a single process: nothing to start
    monkeypatch.setenv("JAX_NUM_PROCESSES", "2")
    with pytest.raises(ValueError, match="JAX_COORDINATOR_ADDRESS, JAX_PROCESS_ID are not: set all of"):
        sharding.initialize_from_env()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_on_several_devices_and_processes(tmp_path):
    """Sharded env steps equal unsharded ones; data-parallel PPO on 1, 2 and 4 devices, and a
    run resumed on another device count, train the same parameters; bad input is refused in
    one line (`sharded_checks.py`). Then two processes over loopback train what one does.
    The time limits only catch a hang: the checks take about a minute on a free 2-core CPU,
    many times that on one short of memory."""
    flags = f"--xla_force_host_platform_device_count=4 {FAST_XLA}"
    done = subprocess.run([sys.executable, str(CHECKS), str(tmp_path)], env=_env(XLA_FLAGS=flags),
                          capture_output=True, text=True, timeout=1800)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert all(f"ok {name}" in done.stdout for name in ("errors", "ppo", "resume")), done.stdout[-3000:]

    _two_processes("distributed", tmp_path)
    reference, distributed = np.load(tmp_path / "reference.npz"), np.load(tmp_path / "distributed.npz")
    assert reference.files == distributed.files
    for name in reference.files:
        np.testing.assert_allclose(distributed[name], reference[name], atol=1e-5)


def test_data_parallel_ppo_under_gspmd(tmp_path):
    """With the partitioner jaxnat switches a mesh of GPUs to (GSPMD), data-parallel PPO and A2C
    on 2 devices compile and train what 1 device does (`sharded_checks.py gspmd`). In a child
    process: where XLA fails that compile it aborts the process."""
    flags = f"--xla_force_host_platform_device_count=2 {FAST_XLA}"
    done = subprocess.run([sys.executable, str(CHECKS), "gspmd", str(tmp_path)], env=_env(XLA_FLAGS=flags),
                          capture_output=True, text=True, timeout=900)
    assert done.returncode == 0 and "ok gspmd" in done.stdout, f"exit {done.returncode}: {done.stderr[-2000:]}"


def _two_processes(mode: str, tmp_path) -> None:
    """`sharded_checks.py <mode> tmp_path` as both processes of a `jax.distributed` run."""
    address = f"127.0.0.1:{_free_port()}"
    processes = [subprocess.Popen([sys.executable, str(CHECKS), mode, str(tmp_path)],
                                  env=_env(XLA_FLAGS=FAST_XLA, JAX_COORDINATOR_ADDRESS=address, JAX_NUM_PROCESSES="2",
                                           JAX_PROCESS_ID=str(i)),
                                  stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True) for i in range(2)]
    outputs = [p.communicate(timeout=900)[0] for p in processes]
    assert [p.returncode for p in processes] == [0, 0], "\n".join(o[-2000:] for o in outputs)
    assert all(f"ok {mode}" in o for o in outputs), "\n".join(o[-2000:] for o in outputs)


def test_natural_atari_one_ale_batch_per_process(tmp_path):
    """Natural Atari's data-parallel host learner: the whole ALE batch in one process, on 1 and
    4 devices, then half of it in each of two processes (update data parallel over both) train
    the same parameters and metrics; the two processes hold identical ones; bad splits are
    refused in one line (`sharded_checks.py atari`, `atari-distributed`). About a minute on a
    free 2-core CPU; the time limits only catch a hang."""
    pytest.importorskip("ale_py")
    flags = f"--xla_force_host_platform_device_count=4 {FAST_XLA}"
    done = subprocess.run([sys.executable, str(CHECKS), "atari", str(tmp_path)], env=_env(XLA_FLAGS=flags),
                          capture_output=True, text=True, timeout=1200)
    assert done.returncode == 0 and "ok atari" in done.stdout, done.stdout[-3000:] + done.stderr[-3000:]
    _two_processes("atari-distributed", tmp_path)
    reference = np.load(tmp_path / "atari_reference.npz")
    first, second = (np.load(tmp_path / f"atari_process_{i}.npz") for i in range(2))
    assert reference.files == first.files == second.files
    for name in reference.files:
        np.testing.assert_array_equal(second[name], first[name], err_msg=name)  # the same update in both
        np.testing.assert_allclose(first[name], reference[name], atol=1e-5, err_msg=name)


def test_resuming_on_fewer_devices_names_the_flag():
    from jaxnat.training import TrainError
    from jaxnat.training.placement import resumed_devices

    assert resumed_devices(1) == 1 and resumed_devices(8, "all") == 1
    with pytest.raises(TrainError, match="^this run was on 8 devices and there is 1 here: continue on them with "
                                         "--devices 1 "):
        resumed_devices(8)


# The smallest program that crashed XLA's Shardy partitioner on 2 GPUs (a segmentation fault
# while compiling): MJX's kinematics, vmapped, under jax.shard_map over a mesh of 2 devices.
# Run in a child process, so a crash fails this test instead of ending the suite.
SHARDY_CRASH = """
import jax, jax.numpy as jnp
from mujoco import mjx
from jax.sharding import NamedSharding, PartitionSpec
from jaxnat import sharding
from jaxnat.mjx_pixel.models import load_model

mesh = sharding.device_mesh(2)
model = mjx.put_model(load_model("swimmer"), impl="jax")
data = mjx.make_data(model)
batch = jax.vmap(lambda q: data.replace(qpos=q))(jnp.tile(data.qpos, (4, 1)) + 0.01 * jnp.arange(4)[:, None])
spec = PartitionSpec(sharding.AXIS)
step = sharding.shard_program(jax.vmap(lambda d: mjx.kinematics(model, d)), mesh, (spec,), spec)
out = step(jax.device_put(batch, NamedSharding(mesh, spec)))
print("xpos", float(jnp.abs(out.xpos).sum()))
"""


def test_mjx_under_shard_map_compiles_on_two_devices():
    """On 2+ devices (skipped on one): the program that crashed Shardy compiles and runs
    (`sharding.avoid_shardy_crash` switches a mesh of GPUs to GSPMD)."""
    import jax

    pytest.importorskip("mujoco.mjx")
    if jax.device_count() < 2:
        pytest.skip("needs 2 devices")
    done = subprocess.run([sys.executable, "-c", SHARDY_CRASH], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, f"exit {done.returncode}: {done.stdout[-1000:]}{done.stderr[-2000:]}"
    assert any(line.startswith("xpos ") for line in done.stdout.splitlines()), done.stdout[-1000:]
