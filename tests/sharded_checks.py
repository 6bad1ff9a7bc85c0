"""Checks of sharded envs and training on several (simulated) CPU devices, run by
`tests/test_sharding.py` in a fresh process: XLA reads the device count
(`XLA_FLAGS=--xla_force_host_platform_device_count=4`) once, when JAX starts, so the rest of
the suite keeps its one device.

    XLA_FLAGS=--xla_force_host_platform_device_count=4 python tests/sharded_checks.py DIR
    python tests/sharded_checks.py distributed DIR   # one process of a jax.distributed run
    XLA_FLAGS=--xla_force_host_platform_device_count=4 python tests/sharded_checks.py atari DIR
    python tests/sharded_checks.py atari-distributed DIR   # one process of a jax.distributed run
    XLA_FLAGS=--xla_force_host_platform_device_count=2 python tests/sharded_checks.py gspmd DIR

The first runs every check on 4 devices and saves PPO's parameters after training on one
device to `DIR/reference.npz`; each process of the second trains the same PPO over both
processes' devices and process 0 saves `DIR/distributed.npz`. The training checks use a probe
env (vector observations, an MLP: quick to compile) registered here as `Probe/Factored-v0`.
The last two do the same for Natural Atari's data-parallel host learner (ale-py): one process
steps the whole ALE batch (`DIR/atari_reference.npz`), then each of two processes steps its
half and saves `DIR/atari_process_<i>.npz`. The last trains data-parallel PPO with the
partitioner jaxnat uses on GPUs (GSPMD). Each check prints `ok <name>` or raises.
"""

from __future__ import annotations

import dataclasses
import io
import json
import sys
import tempfile
from contextlib import redirect_stderr
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's jaxnat

import jaxnat.sharding  # noqa: E402

DISTRIBUTED = ("distributed", "atari-distributed")  # the modes that run as one of several processes
if __name__ == "__main__" and sys.argv[1] in DISTRIBUTED:
    jaxnat.sharding.initialize_from_env()  # before anything touches a device

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import jaxnat  # noqa: E402
from jaxnat.agents import A2CConfig, DQNConfig, PPOConfig  # noqa: E402
from jaxnat.agents.probes import make_probe  # noqa: E402
from jaxnat.training import main, parse_args, train  # noqa: E402
from jaxnat.training.placement import make_sharded_train  # noqa: E402

FAST = {"xla_backend_optimization_level": 0}
# `TINY`'s config as `jaxnat train` resolves it (vector observations: normalised).
PPO = PPOConfig(total_timesteps=256, num_envs=8, num_steps=8, num_minibatches=2, update_epochs=2, trunk="mlp",
                normalize_observations=True, normalize_rewards=True)
TINY = ["--env-id", "Probe/Factored-v0", "--algo", "ppo", "--seeds", "2", "--num-envs", "8", "--num-steps", "8",
        "--num-minibatches", "2", "--update-epochs", "2", "--total-timesteps", "256", "--eval-every", "2",
        "--eval-episodes", "8"]
# Natural Atari's data-parallel host learner: 4 envs of Breakout, 3 updates. Tiny 10-step games
# end inside the rollouts (episode metrics summed over processes); no background, so every
# env's frames depend on its seed and actions only, however the batch is split.
ATARI_ENV = ("NaturalAtari/Breakout-v0", {"obs_size": 36, "num_threads": 1, "max_episode_steps": 10,
                                          "background": "none"})
ATARI_PPO = PPOConfig(total_timesteps=96, num_envs=4, num_steps=8, num_minibatches=2, update_epochs=2,
                      trunk="atari", lr=1e-2)
COLLECTIVES = ("all-reduce", "all-gather", "all-to-all", "collective-permute", "reduce-scatter")

jaxnat.register("Probe/Factored-v0", "jaxnat.agents.probes:FactoredProbe")


def _keys(n: int):
    return jax.vmap(jax.random.key)(jnp.arange(n, dtype=jnp.uint32))


def _close(a, b, atol=1e-5) -> float:
    """The largest difference between two pytrees of arrays (asserted below `atol`)."""
    diff = max(float(np.max(np.abs(np.asarray(x, np.float64) - np.asarray(y, np.float64))))
               for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True))
    assert diff <= atol, diff
    return diff


def check_env() -> None:
    """A sharded batch steps exactly as the unsharded one, with no cross-device traffic."""
    from jaxnat.datasets import DatasetNotFoundError

    try:
        plain = jaxnat.make_vec("Classify/Digits-v0", 8, w=5)
    except DatasetNotFoundError:
        print("skip env (Classify/Digits-v0 data not installed)")
        return
    split = jaxnat.make_vec("Classify/Digits-v0", 8, w=5, devices=4)
    space = plain.action_space(plain.default_params)
    key = jax.random.key(3)
    results = []
    for vec in (plain, split):
        obs, state = jax.jit(vec.reset)(key)
        trajectory = [obs]
        step = jax.jit(vec.step)
        for t in range(3):
            k = jax.random.fold_in(key, t)
            actions = jax.vmap(space.sample)(jax.random.split(k, 8))
            obs, state, reward, terminated, truncated, _ = step(k, state, actions)
            trajectory += [obs, reward, terminated, truncated, state]
        results.append(trajectory)
    for a, b in zip(jax.tree.leaves(results[0]), jax.tree.leaves(results[1]), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert results[1][0].sharding == split.sharding and len(results[1][0].sharding.device_set) == 4
    hlo = jax.jit(split.step).lower(key, state, actions).compile().as_text()
    assert not [c for c in COLLECTIVES if c in hlo], "the sharded step moves data between devices"
    print("ok env")


def check_ppo():
    """Data-parallel PPO trains the same parameters on 1, 2 and 4 devices (same global batch);
    seeds placed on 2 devices train what one device does. Returns the 1-device runner."""
    env, params = make_probe("factored")
    trained = {d: make_sharded_train("ppo", PPO, env, params, seeds=2, devices=d)(_keys(2)) for d in (1, 2, 4)}
    for d in (2, 4):
        _close(trained[d][0].train_state.params, trained[1][0].train_state.params)
        _close(trained[d][0].normalizer, trained[1][0].normalizer)
        _close(trained[d][1], trained[1][1])
    assert np.asarray(trained[4][0].obs).shape == (2, 8, 5)
    plain = make_sharded_train("ppo", PPO, env, params, seeds=2)(_keys(2))
    seeds = make_sharded_train("ppo", PPO, env, params, seeds=2, devices=2, shard="seeds")(_keys(2))
    _close(seeds[0].train_state.params, plain[0].train_state.params)
    # Gaussian actions, observation and reward normalisation: their statistics are the whole batch's.
    env, params = make_probe("target")
    a2c = A2CConfig(total_timesteps=3 * 8 * 5, num_envs=8, trunk="mlp", normalize_observations=True,
                    normalize_rewards=True)
    one, four = (make_sharded_train("a2c", a2c, env, params, seeds=1, devices=d)(_keys(1)) for d in (1, 4))
    _close(four[0].train_state.params, one[0].train_state.params)
    _close(four[0].normalizer, one[0].normalizer)
    print("ok ppo")
    return trained[1][0]


def _run(argv, **options) -> int:
    return main(argv, compiler_options=FAST, **options)


def check_resume(reference) -> None:
    """A `jaxnat train` run on 4 devices, stopped and resumed on 2, ends where the same PPO
    trained on 1 device in one go does (`reference`: its runner)."""
    with tempfile.TemporaryDirectory() as tmp:
        assert _run([*TINY, "--devices", "4", "--run-dir", tmp], stop_after_chunks=1) == 0
        spec = json.loads(Path(tmp, "config.json").read_text())["spec"]
        assert (spec["devices"], spec["shard"]) == (4, "envs") and spec["config"] == dataclasses.asdict(PPO)
        resumed = train(parse_args(["--resume", tmp, "--devices", "2"]), compiler_options=FAST)
        assert resumed.complete
    _close(resumed.runner.train_state.params, reference.train_state.params)
    print("ok resume")


def check_errors() -> None:
    """Requests the devices cannot take: one line saying what is wrong and how to fix it."""
    # Refused before the run directory is made: it stays absent.
    never = Path(tempfile.gettempdir(), "jaxnat-sharded-checks-never")
    tiny = ["--env-id", "Probe/Factored-v0", "--seeds", "2", "--num-envs", "8", "--run-dir", str(never)]
    cases = {
        ("--num-envs", "10", "--devices", "4"):
            "num_envs=10 does not split evenly over 4 devices: use --num-envs 8 or 12",
        ("--devices", "5"): "--devices 5: there are only 4 cpu devices here; use at most 4 (or all)",
        ("--devices", "two"): "--devices two: give a device count (e.g. 2) or all",
        ("--devices", "4", "--shard", "seeds"): "seeds=2 does not split evenly over 4 devices: use --seeds 4",
        ("--shard", "seeds"): "--shard seeds places work on devices: give --devices N (or all) too",
        ("--devices", "2", "--shard", "batch"): "--shard batch: choose envs",
        ("--devices", "2", "--algo", "dqn"): "--shard envs trains ppo and a2c data parallel; dqn needs the whole batch",
        ("--devices", "2", "--memory", "8"): "--shard envs trains feed-forward policies",
    }
    for extra, expected in cases.items():
        stderr = io.StringIO()
        with redirect_stderr(stderr):
            assert _run([*tiny, *extra]) == 2, extra
        message = stderr.getvalue()
        assert message.count("\n") == 1 and message.startswith("jaxnat train: error: ") and expected in message, message
    assert not never.exists()
    print("ok errors")


def check_distributed(out: Path) -> None:
    """One process of a `jax.distributed` run (`initialize_from_env`, one CPU device each):
    data-parallel PPO over every process's devices; process 0 saves the parameters."""
    assert jax.process_count() == 2 and jax.device_count() == 2, (jax.process_count(), jax.devices())
    env, params = make_probe("factored")
    runner, _ = make_sharded_train("ppo", PPO, env, params, seeds=2, devices="all")(_keys(2))
    leaves = [np.asarray(x) for x in jax.tree.leaves(runner.train_state.params)]
    if jax.process_index() == 0:
        np.savez(out / "distributed.npz", *leaves)
    print("ok distributed")


def _train_atari(devices):
    """The data-parallel host PPO on this process's share of `ATARI_ENV`: `(params, history,
    the initial params)`."""
    from jaxnat.training.host_backend import make_learner, make_train_env

    env = make_train_env(ATARI_ENV[0], ATARI_PPO.num_envs, ATARI_ENV[1], devices=devices)
    try:
        learner = make_learner("ppo", ATARI_PPO, env, FAST, devices=devices)
        state, history = learner.train(jax.random.key(7))
        return learner.params(state), history, learner.params(learner.init(jax.random.key(7)))
    finally:
        env.close()


def _atari_results(params, history, _) -> dict:
    """What the Natural Atari checks compare: parameters, every update's metrics."""
    return {**{f"param_{i}": np.asarray(x) for i, x in enumerate(jax.tree.leaves(params))},
            **{f"metric_{name}": np.asarray([row[name] for row in history]) for name in sorted(history[0])}}


def _one_line_error(error, expected: str, call, *args, **kwargs) -> None:
    try:
        call(*args, **kwargs)
    except error as err:
        assert str(err).count("\n") == 0 and expected in str(err), str(err)
    else:
        raise AssertionError(f"no {error.__name__}: {expected}")


def check_atari(out: Path) -> None:
    """Natural Atari's data-parallel host learner in one process: the whole batch on 1 and on
    4 devices trains the same parameters (`DIR/atari_reference.npz`: 1 device); bad input is
    refused in one line."""
    from jaxnat.training.host_backend import make_learner, make_train_env

    _one_line_error(ValueError, "num_envs=6 does not split evenly over 4 devices: use num_envs=4 or 8",
                    make_train_env, ATARI_ENV[0], 6, ATARI_ENV[1], devices=4)
    env = make_train_env(ATARI_ENV[0], 4, ATARI_ENV[1])
    try:
        _one_line_error(ValueError, "config.num_envs=8 is split over the devices: this process steps envs 0..7 (8) "
                        "but the env has 4", make_learner, "ppo", ATARI_PPO.replace(num_envs=8), env, devices=4)
        _one_line_error(ValueError, "dqn's host learner needs the whole batch on one device: leave devices out",
                        make_learner, "dqn", DQNConfig(num_envs=4, trunk="atari"), env, devices=2)
    finally:
        env.close()
    one, four = _train_atari(1), _train_atari(4)
    reference = _atari_results(*one)
    for name, value in _atari_results(*four).items():  # (metrics NaN where no episode ended, alike)
        np.testing.assert_allclose(value, reference[name], atol=1e-5, err_msg=name)
    moved = _close(one[0], one[2], atol=np.inf)
    assert moved > 1e-3, moved  # training moves the parameters far beyond the tolerance
    np.savez(out / "atari_reference.npz", **reference)
    check_atari_train()
    print("ok atari")


ATARI_RUN = ["--env-id", ATARI_ENV[0], "--algo", "ppo", "--seeds", "1", "--num-envs", "4", "--num-steps", "8",
             "--num-minibatches", "2", "--update-epochs", "2", "--total-timesteps", "64", "--eval-every", "1",
             "--eval-episodes", "1", "--env-kwargs", *(f"{k}={v}" for k, v in ATARI_ENV[1].items())]


def check_atari_train() -> None:
    """`jaxnat train --devices N` on Natural Atari: the update data parallel over N devices, so
    2 devices train the parameters 1 does (`--devices 1`, the same learner's draws); the run
    resumes on 1 device to more steps, and `load_policy` reads it; the requests it cannot take
    are one line each, before the run directory is made."""
    from jaxnat.trained import load_policy

    with tempfile.TemporaryDirectory() as tmp:
        trained = {}
        for devices in ("1", "2"):
            run_dir = Path(tmp, f"devices-{devices}")
            assert _run([*ATARI_RUN, "--devices", devices, "--run-dir", str(run_dir)]) == 0
            spec = json.loads((run_dir / "config.json").read_text())["spec"]
            assert (spec["devices"], spec["shard"], spec["host_seeds"]) == (int(devices), "envs", "sequential")
            policy = load_policy(run_dir, compiler_options=FAST)
            policy.env.close()
            trained[devices] = policy.params
        _close(trained["2"], trained["1"])
        resumed = train(parse_args(["--resume", str(Path(tmp, "devices-2")), "--devices", "1",
                                    "--total-timesteps", "96"]), compiler_options=FAST)
        assert resumed.complete and resumed.summary["updates"] == 3, resumed.summary
    never = Path(tempfile.gettempdir(), "jaxnat-sharded-checks-never")
    cases = {
        ("--devices", "2", "--shard", "seeds"): "--shard seeds places whole seeds on devices; a host env's seeds",
        ("--devices", "2", "--host-seeds", "together"): "--host-seeds together trains every seed on one device",
        ("--devices", "3"): "num_envs=4 does not split evenly over 3 devices: use --num-envs 3 or 6",
    }
    for extra, expected in cases.items():
        stderr = io.StringIO()
        with redirect_stderr(stderr):
            assert _run([*ATARI_RUN, "--run-dir", str(never), *extra]) == 2, extra
        message = stderr.getvalue()
        assert message.count("\n") == 1 and expected in message, message
    dqn = ["--env-id", ATARI_ENV[0], "--algo", "dqn", "--num-envs", "4", "--devices", "2", "--run-dir", str(never)]
    stderr = io.StringIO()
    with redirect_stderr(stderr):
        assert _run(dqn) == 2
    assert "dqn's host learner needs the whole batch on one device" in stderr.getvalue(), stderr.getvalue()
    assert not never.exists()


def check_atari_distributed(out: Path) -> None:
    """One process of a `jax.distributed` run: its half of the Natural Atari batch (one ALE
    batch per process), the update data parallel over both processes' devices; each process
    saves its parameters and metrics. Bad splits are refused in one line."""
    assert jax.process_count() == 2 and jax.device_count() == 2, (jax.process_count(), jax.devices())
    index = jax.process_index()
    assert jaxnat.sharding.process_share(4, "all") == (2 * index, 2)
    _one_line_error(ValueError, "num_envs=9 does not split evenly over 2 devices of 2 processes: use num_envs=8 or 10",
                    jaxnat.sharding.process_share, 9, "all")
    if index == 1:  # the first device is process 0's
        _one_line_error(ValueError, "process 1 holds none of the 1 devices: give every process's devices",
                        jaxnat.sharding.process_share, 4, 1)
    np.savez(out / f"atari_process_{index}.npz", **_atari_results(*_train_atari("all")))
    print("ok atari-distributed")


def check_gspmd() -> None:
    """Data-parallel PPO and A2C under the GSPMD partitioner, the one `jaxnat.sharding` switches a
    mesh of GPUs to: they compile (XLA aborted the process compiling minibatch rows gathered inside
    the epoch's scan under `shard_map` with it) and train what one device does. Whole seeds on
    devices (`--shard seeds`) are not checked here: XLA:CPU's GSPMD aborts on that program
    whichever way the minibatches are taken, XLA:GPU's compiles it (bench/devices_matrix.py)."""
    jax.config.update("jax_use_shardy_partitioner", False)
    env, params = make_probe("factored")
    one, two = (make_sharded_train("ppo", PPO, env, params, seeds=2, devices=d)(_keys(2)) for d in (1, 2))
    _close(two[0].train_state.params, one[0].train_state.params)
    _close(two[1], one[1])
    env, params = make_probe("target")  # A2C, the other data-parallel learner: Gaussian actions, normalisers
    a2c = A2CConfig(total_timesteps=3 * 8 * 5, num_envs=8, trunk="mlp", normalize_observations=True,
                    normalize_rewards=True)
    one, two = (make_sharded_train("a2c", a2c, env, params, seeds=1, devices=d)(_keys(1)) for d in (1, 2))
    _close(two[0].train_state.params, one[0].train_state.params)
    print("ok gspmd")


if __name__ == "__main__":
    if sys.argv[1] == "gspmd":
        check_gspmd()
    elif sys.argv[1] == "distributed":
        check_distributed(Path(sys.argv[2]))
    elif sys.argv[1] == "atari":
        check_atari(Path(sys.argv[2]))
    elif sys.argv[1] == "atari-distributed":
        check_atari_distributed(Path(sys.argv[2]))
    else:
        check_env()
        check_errors()
        runner = check_ppo()
        leaves = [np.asarray(x) for x in jax.tree.leaves(runner.train_state.params)]
        np.savez(Path(sys.argv[1], "reference.npz"), *leaves)
        check_resume(runner)
