"""`jaxnat.testing.check_determinism`: same key, same trajectory, bit for bit."""

import numpy as np
import pytest

from jaxnat.testing import (DeterminismReport, _first_difference, _first_leaf_difference, check_determinism,
                            check_training_determinism, has_dataset)


@pytest.mark.skipif(not has_dataset("digits"), reason="Classify/Digits-v0 data not installed")
def test_classify_is_bitwise_reproducible_on_this_backend():
    report = check_determinism("Classify/Digits-v0", num_envs=16, steps=24, M=5)  # episodes end and reset
    assert report.identical and report.first_difference is None, str(report)
    assert "identical bit for bit" in str(report) and report.seconds > 0


def _rollout(steps=6, envs=8):
    obs = np.zeros((envs, 3), np.float32)
    outputs = {"obs": np.zeros((steps, envs, 3), np.float32), "reward": np.zeros((steps, envs), np.float32),
               "terminated": np.zeros((steps, envs), bool)}
    return obs, outputs


def test_the_first_difference_is_found_by_step_then_field_then_env():
    reference, other = _rollout(), _rollout()
    assert _first_difference(reference, other) is None
    other[1]["reward"][4, 6] = 1.0
    other[1]["obs"][3, 5, 0] = -0.0  # bitwise different from 0.0: found, and earlier
    assert _first_difference(reference, other) == {"step": 3, "field": "['obs']", "env": 5}
    other[1]["obs"][3, 5, 0] = 0.0
    assert _first_difference(reference, other) == {"step": 4, "field": "['reward']", "env": 6}
    other[0][2, 1] = np.nan  # at reset
    assert _first_difference(reference, other) == {"step": "reset", "field": "obs", "env": 2}
    nan = _rollout(), _rollout()
    nan[0][1]["obs"][:] = nan[1][1]["obs"][:] = np.nan
    assert _first_difference(*nan) is None  # the same bits: NaN equals NaN here
    report = DeterminismReport("X-v0", 8, 6, False, {"run": "recompiled", "step": 4, "field": "['reward']", "env": 6},
                               0.5)
    assert report.steps_per_second == 96.0
    assert str(report) == "X-v0: the recompiled run differs first at step 4 in ['reward'] (env 6)"


@pytest.mark.skipif(not has_dataset("digits"), reason="Classify/Digits-v0 data not installed")
def test_ppo_training_is_bitwise_reproducible_on_this_backend():
    report = check_training_determinism("Classify/Digits-v0", "ppo", num_envs=8, num_steps=8, updates=2)
    assert report.identical, str(report)
    assert str(report) == ("Classify/Digits-v0: ppo, 2 updates of 8 envs x 16 steps identical bit for bit "
                           "(repeat and recompiled)")


def test_a_training_difference_names_the_first_differing_leaf():
    reference = {"params": {"a": np.zeros(3, np.float32), "b": np.ones(2, np.float32)}, "update": np.int32(2)}
    other = {"params": {"a": np.zeros(3, np.float32), "b": np.ones(2, np.float32)}, "update": np.int32(2)}
    assert _first_leaf_difference(reference, other) is None
    other["params"]["b"][1] = np.nextafter(np.float32(1), np.float32(2))  # one ulp
    assert _first_leaf_difference(reference, other) == {"step": None, "field": "['params']['b']", "env": None}
    report = DeterminismReport("X-v0", 8, 16, False, {"run": "repeat", **_first_leaf_difference(reference, other)},
                               0.5, "ppo, 2 updates")
    assert str(report) == "X-v0: the repeat run differs first in ['params']['b']"


def test_enable_deterministic_ops_sets_the_flag_once_and_refuses_after_jax_started(monkeypatch):
    import subprocess
    import sys

    monkeypatch.delenv("XLA_FLAGS", raising=False)
    code = ("import os; from jaxnat.testing import enable_deterministic_ops as e; e(); e(); print(os.environ['XLA_FLAGS']);"
            "import jax; jax.numpy.zeros(1).block_until_ready(); os.environ['XLA_FLAGS'] = '';\n"
            "try: e()\nexcept RuntimeError as err: print('refused:', err)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         env={**__import__("os").environ, "JAX_PLATFORMS": "cpu"}).stdout.splitlines()
    assert out[0] == "--xla_gpu_deterministic_ops=true"
    assert out[1].startswith("refused: enable_deterministic_ops() came after JAX started its backends")
