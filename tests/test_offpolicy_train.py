"""`jaxnat train --algo acktr|dqn`: a run interrupted after its first chunk and resumed equals
the uninterrupted run bit for bit, K-FAC factors and replay buffer included (as test_train.py
checks for PPO). Tiny runs: Classify/Digits-v0, 2 seeds x 8 envs x 16 steps, 4 updates in 2
chunks, unoptimised XLA (compiles about 3x faster on CPU)."""

import json

import jax
import numpy as np
import pytest

from jaxnat import train
from jaxnat.agents.kfac import KFACState
from jaxnat.testing import has_dataset
from jaxnat.training import checkpoints

FAST = {"xla_backend_optimization_level": 0}
TINY = ["--env-id", "Classify/Digits-v0", "--seeds", "2", "--num-envs", "8", "--num-steps", "16",
        "--total-timesteps", "512", "--eval-every", "2", "--eval-episodes", "16", "--trunk", "mnist"]
EXTRA = {"acktr": [], "dqn": ["--learning-starts", "128", "--buffer-size", "256", "--gradient-steps", "2",
                             "--target-update-period", "3"]}


@pytest.mark.skipif(not has_dataset("digits"), reason="Classify/Digits-v0 data not installed")
@pytest.mark.parametrize("algo", ["acktr", "dqn"])
def test_run_and_exact_resume(algo, tmp_path):
    argv = [*TINY, "--algo", algo, *EXTRA[algo]]
    full, resumed = tmp_path / "full", tmp_path / "resumed"
    assert train.main([*argv, "--run-dir", str(full)], compiler_options=FAST) == 0
    assert train.main([*argv, "--run-dir", str(resumed)], compiler_options=FAST, stop_after_chunks=1) == 0
    assert json.loads((resumed / "summary.json").read_text())["complete"] is False
    assert train.main(["--resume", str(resumed)], compiler_options=FAST) == 0

    (expected, _), (actual, meta) = (train.load_checkpoint(d, compiler_options=FAST) for d in (full, resumed))
    assert meta["update"] == 4
    for a, b in zip(jax.tree.leaves(checkpoints.to_saveable(expected)),
                    jax.tree.leaves(checkpoints.to_saveable(actual)), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))  # params, optimizer, env, keys
    if algo == "acktr":  # the K-FAC factors are in the checkpoint, and have moved off identity
        kfac_state = actual.train_state.opt_state[0]
        assert isinstance(kfac_state, KFACState) and np.all(np.asarray(kfac_state.count) == 4)
        a, _ = kfac_state.factors["Dense_0"]
        assert not np.allclose(np.asarray(a)[0], np.eye(a.shape[-1]))
    else:  # the replay buffer is, with every env step of the run
        np.testing.assert_array_equal(np.asarray(actual.buffer.size), [256, 256])
        assert np.all(np.asarray(actual.train_state.step) > 0)
    assert (resumed / "metrics.jsonl").read_text() == (full / "metrics.jsonl").read_text()
    summary = json.loads((full / "summary.json").read_text())
    assert summary["algo"] == algo and summary["complete"]
    assert all(np.isfinite(v) for v in summary["metrics"]["test_greedy_return"]["per_seed"])
