"""Orbax checkpoints of the vmapped runner state (or, seeds side by side on the host, of each
seed's slice of their stacked state: `SeedCheckpoints`), and loading a run's checkpoint back."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import jax
import jax.numpy as jnp

from jaxnat.agents.rollout import seed_slice, stack_seeds
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


def _path(path) -> str:
    """A leaf's path as a dotted name (`train_state.opt_state.1.0.nu`), the same for the state's
    dataclasses and named tuples as for the dicts and lists orbax stores them as."""
    names = []
    for key in path:
        for attr in ("name", "key", "idx"):
            if hasattr(key, attr):
                names.append(str(getattr(key, attr)))
                break
        else:
            names.append(str(key))
    return ".".join(names)


def _check_layout(step: int, wanted: dict, stored: dict) -> None:
    """A `TrainError` naming the first arrays in which checkpoint `step` and this run's state
    differ (missing, extra, or of another shape), if any."""
    def first(names):
        names = sorted(names)
        return ", ".join(names[:3]) + (f" and {len(names) - 3} more" if len(names) > 3 else "")

    missing, extra = wanted.keys() - stored.keys(), stored.keys() - wanted.keys()
    shapes = [f"{name} {tuple(stored[name].shape)} (this run: {tuple(wanted[name].shape)})"
              for name in sorted(wanted.keys() & stored.keys())
              if tuple(stored[name].shape) != tuple(wanted[name].shape)]
    problems = ([f"this run's state has {first(missing)}, the checkpoint does not"] * bool(missing)
                + [f"the checkpoint has {first(extra)}, this run's state does not"] * bool(extra)
                + [f"shapes differ: {first(shapes)}"] * bool(shapes))
    if problems:
        raise TrainError(f"checkpoint {step} does not match this run's state: {'; '.join(problems)} "
                         "(written by another version of jaxnat, or for another config); start a new run")


def damaged(step: int, directory: Path, err: Exception) -> TrainError:
    """The one-line error of checkpoint `step` in `directory` that cannot be read."""
    return TrainError(f"cannot resume: checkpoint {step} in {directory} is damaged ({type(err).__name__}); "
                      f"delete {directory / str(step)} to resume from the checkpoint before it, or start a new run")


class Checkpoints:
    """Orbax checkpoints of the vmapped RunnerState under run_dir/checkpoints, step = update."""

    def __init__(self, directory: Path):
        import orbax.checkpoint as ocp

        self.ocp = ocp
        self.directory = Path(directory)
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
        fields, the network's apply_fn and the optimizer, come from this process). Arrays are
        matched by their path in the state (`env_state.env_state.label`), not by position, so a
        field that holds no arrays (None, or a dial that is off) does not have to be on disk; an
        array this run needs that the checkpoint lacks, or the other way round, or one of another
        shape, is a `TrainError` that names it."""
        ocp = self.ocp
        step = self.latest_step() if step is None else step
        fields = _stored_fields(target)
        target_leaves, treedef = jax.tree_util.tree_flatten_with_path(fields)
        wanted = {_path(path): to_saveable(ref) for path, ref in target_leaves if not _is_empty(ref)}
        item = self.manager.directory / str(step) / "state"  # an epath.Path, as orbax's handlers take
        on_disk = ocp.StandardCheckpointHandler().metadata(item).tree
        stored = {_path(path): meta for path, meta in jax.tree_util.tree_flatten_with_path(on_disk)[0]}
        _check_layout(step, wanted, stored)
        abstract = jax.tree_util.tree_map_with_path(
            lambda path, _: ocp.utils.to_shape_dtype_struct(wanted[_path(path)]), on_disk)
        restored = self.manager.restore(step, args=ocp.args.Composite(
            state=ocp.args.StandardRestore(abstract), meta=ocp.args.JsonRestore()))
        arrays = {_path(path): value for path, value in jax.tree_util.tree_flatten_with_path(restored.state)[0]}
        leaves = []
        for path, ref in target_leaves:
            if _is_empty(ref):
                leaves.append(jnp.zeros(ref.shape, ref.dtype))
                continue
            value = arrays[_path(path)]
            leaves.append(jax.random.wrap_key_data(value, impl=jax.random.key_impl(ref)) if _is_key(ref)
                          else jnp.asarray(value))
        state = jax.tree.unflatten(treedef, leaves)
        return (target._replace(**state) if hasattr(target, "_asdict") else state), dict(restored.meta)

    def steps(self) -> list[int]:
        return list(self.manager.all_steps())

    def delete(self, step: int) -> None:
        self.manager.delete(step)

    def close(self) -> None:
        self.manager.close()


class SeedCheckpoints:
    """`Checkpoints`' interface over a state stacked along a leading seed axis (seeds side by
    side: `rollout.stacked`), one folder per seed, each holding that seed's slice: what a
    one-seed run of it would save, so each folder reads as a one-seed run's.

    The seeds are saved one after another; a run stopped between two saves leaves some seeds one
    checkpoint ahead, so `latest_step` is the newest step every seed holds, `restore` stacks
    the seeds at it, and a save over a step a seed already holds (written ahead, then not
    resumed from) replaces it."""

    def __init__(self, directories: list[Path]):
        self.directory = Path(directories[0]).parent if directories else Path()
        self.seeds = []
        try:
            for directory in directories:
                self.seeds.append(Checkpoints(Path(directory)))
        except BaseException:
            self.close()
            raise

    def latest_step(self) -> int | None:
        common = set.intersection(*(set(c.steps()) for c in self.seeds))
        return max(common) if common else None

    def save(self, state, meta: dict) -> None:
        for i, checkpoints in enumerate(self.seeds):
            if int(meta["update"]) in checkpoints.steps():
                checkpoints.delete(int(meta["update"]))
            checkpoints.save(seed_slice(state, i), meta)

    def restore(self, target, step: int | None = None):
        """`(stacked state, meta)` of every seed at `step` (default: `latest_step`), each
        restored into its slice of `target` (`Checkpoints.restore`: a seed's damaged checkpoint
        is a `TrainError` naming its folder)."""
        step = self.latest_step() if step is None else step
        states, meta = [], None
        for i, checkpoints in enumerate(self.seeds):
            try:
                state, meta = checkpoints.restore(seed_slice(target, i), step)
            except TrainError:
                raise
            except Exception as err:  # noqa: BLE001 (orbax and tensorstore raise many kinds for bad bytes)
                raise damaged(step, checkpoints.directory, err) from None
            states.append(state)
        return stack_seeds(states), meta

    def close(self) -> None:
        for checkpoints in self.seeds:
            checkpoints.close()


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
