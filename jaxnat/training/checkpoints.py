"""Orbax checkpoints of the vmapped runner state, and loading a run's checkpoint back."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import jax
import jax.numpy as jnp

from jaxnat.training.args import TrainError
from jaxnat.training.placement import resumed_devices
from jaxnat.training.device_backend import compiled_program
from jaxnat.training.spec import RunSpec


def _is_key(x) -> bool:
    return isinstance(x, jax.Array) and jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key)


def _is_empty(x) -> bool:
    return 0 in getattr(x, "shape", ())


def to_saveable(tree):
    """Keys as their data; zero-size arrays (an MJX state's unused fields, e.g. `act` of a model
    without activations), which orbax cannot save, as None (restored as zeros from the target)."""
    return jax.tree.map(lambda x: None if _is_empty(x) else jax.random.key_data(x) if _is_key(x) else x, tree)


def _stored_fields(runner):
    """The runner's fields that hold arrays, by name. Fields that are None (a feed-forward
    policy's `memory`) are left out, so checkpoints written before such a field existed still
    match the runner they restore into."""
    if not hasattr(runner, "_asdict"):
        return runner
    return {name: value for name, value in runner._asdict().items() if value is not None}


class Checkpoints:
    """Orbax checkpoints of the vmapped RunnerState under run_dir/checkpoints, step = update."""

    def __init__(self, directory: Path):
        import orbax.checkpoint as ocp

        self.ocp = ocp
        self.manager = ocp.CheckpointManager(
            directory.absolute(),
            options=ocp.CheckpointManagerOptions(max_to_keep=2, enable_async_checkpointing=False),
        )

    def latest_step(self) -> int | None:
        return self.manager.latest_step()

    def save(self, runner, meta: dict) -> None:
        ocp = self.ocp
        self.manager.save(int(meta["update"]), args=ocp.args.Composite(
            state=ocp.args.StandardSave(to_saveable(_stored_fields(runner))), meta=ocp.args.JsonSave(meta)))
        self.manager.wait_until_finished()

    def restore(self, target, step: int | None = None):
        """(runner, meta): arrays from the checkpoint in `target`'s structure (whose static
        fields, the network's apply_fn and the optimizer, come from this process)."""
        ocp = self.ocp
        step = self.latest_step() if step is None else step
        fields = _stored_fields(target)
        abstract = jax.tree.map(ocp.utils.to_shape_dtype_struct, to_saveable(fields))
        restored = self.manager.restore(step, args=ocp.args.Composite(
            state=ocp.args.StandardRestore(abstract), meta=ocp.args.JsonRestore()))
        target_leaves, treedef = jax.tree.flatten(fields)
        stored = jax.tree.leaves(restored.state)
        expected = sum(not _is_empty(ref) for ref in target_leaves)
        if len(stored) != expected:
            raise TrainError(f"checkpoint {step} does not match this run's state "
                             f"({len(stored)} arrays, expected {expected})")
        stored = iter(stored)
        leaves = [jnp.zeros(ref.shape, ref.dtype) if _is_empty(ref)
                  else jax.random.wrap_key_data(next(stored), impl=jax.random.key_impl(ref)) if _is_key(ref)
                  else jnp.asarray(next(stored)) for ref in target_leaves]
        state = jax.tree.unflatten(treedef, leaves)
        return (target._replace(**state) if hasattr(target, "_asdict") else state), dict(restored.meta)

    def close(self) -> None:
        self.manager.close()


def load_checkpoint(run_dir, step: int | None = None, *, compiler_options: dict | None = None, devices=None):
    """`(runner, meta)` of a run directory's latest (or given) checkpoint: the vmapped
    `RunnerState` (params at `runner.train_state.params`, one slice per seed). A run trained
    with `--devices` loads onto `devices` (a count or "all"; default: the run's count)."""
    run_dir = Path(run_dir)
    spec = RunSpec.from_json(json.loads((run_dir / "config.json").read_text())["spec"])
    if spec.shard is not None:
        spec = dataclasses.replace(spec, devices=resumed_devices(spec.devices, devices))
    program = compiled_program(spec, compiler_options)
    checkpoints = Checkpoints(run_dir / "checkpoints")
    try:
        if checkpoints.latest_step() is None:
            raise TrainError(f"{run_dir} has no checkpoint yet")
        return checkpoints.restore(program.init(), step)
    finally:
        checkpoints.close()
