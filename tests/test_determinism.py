"""`jaxnat.testing.check_determinism`: same key, same trajectory, bit for bit."""

import numpy as np
import pytest

from jaxnat.testing import DeterminismReport, _first_difference, check_determinism, has_dataset


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
