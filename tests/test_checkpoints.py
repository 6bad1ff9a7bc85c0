"""Checkpoints restore by each array's path in the state: a field that holds no arrays need not
be on disk, and a checkpoint of another layout is refused with the arrays that differ named."""

import collections

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import struct

from jaxnat.training.args import TrainError
from jaxnat.training.checkpoints import Checkpoints

Runner = collections.namedtuple("Runner", ["env_state", "key", "update"])


@struct.dataclass
class Before:  # an env state as an older jaxnat wrote it
    label: jax.Array
    revealed: jax.Array


@struct.dataclass
class After:  # the same state with a new field that is None unless a dial is on
    label: jax.Array
    revealed: jax.Array
    background_index: jax.Array | None = None


def _save(directory, runner):
    checkpoints = Checkpoints(directory)
    checkpoints.save(runner, {"update": 3})
    return checkpoints


def _runner(state):
    return Runner(env_state=state, key=jax.random.split(jax.random.key(0), 2), update=jnp.array([3, 3]))


def test_a_field_without_arrays_need_not_be_on_disk(tmp_path):
    old = _runner(Before(label=jnp.array([1, 7]), revealed=jnp.arange(6, dtype=jnp.uint32).reshape(2, 3)))
    _save(tmp_path / "c", old).close()
    target = _runner(After(label=jnp.zeros(2, jnp.int32), revealed=jnp.zeros((2, 3), jnp.uint32)))
    checkpoints = Checkpoints(tmp_path / "c")
    (restored, meta) = checkpoints.restore(target)
    checkpoints.close()
    assert meta == {"update": 3} and restored.env_state.background_index is None
    np.testing.assert_array_equal(restored.env_state.label, [1, 7])
    np.testing.assert_array_equal(restored.env_state.revealed, np.arange(6).reshape(2, 3))
    np.testing.assert_array_equal(jax.random.key_data(restored.key), jax.random.key_data(old.key))


def test_a_checkpoint_of_another_layout_names_the_arrays(tmp_path):
    old = _runner(Before(label=jnp.array([1, 7]), revealed=jnp.zeros((2, 3), jnp.uint32)))
    _save(tmp_path / "c", old).close()
    checkpoints = Checkpoints(tmp_path / "c")
    needs_more = _runner(After(label=old.env_state.label, revealed=old.env_state.revealed,
                               background_index=jnp.zeros(2, jnp.int32)))
    with pytest.raises(TrainError, match=r"checkpoint 3 .*this run's state has env_state\.background_index, "
                                         r"the checkpoint does not"):
        checkpoints.restore(needs_more)
    wider = _runner(Before(label=jnp.zeros(4, jnp.int32), revealed=old.env_state.revealed))
    with pytest.raises(TrainError, match=r"shapes differ: env_state\.label \(2,\) \(this run: \(4,\)\)"):
        checkpoints.restore(wider)
    checkpoints.close()
    _save(tmp_path / "d", needs_more).close()
    checkpoints = Checkpoints(tmp_path / "d")
    with pytest.raises(TrainError, match=r"the checkpoint has env_state\.background_index, this run's state does not"):
        checkpoints.restore(old)
    checkpoints.close()
