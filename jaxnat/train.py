"""`jaxnat train` (also `python -m jaxnat.train`): train PPO or A2C on a jaxnat env over many seeds.

    jaxnat train                                   # PPO on Classify/Digits-v0, 5 seeds
    jaxnat train --env-id Classify/MNIST-v0 --algo a2c --lr 1e-3 --env-kwargs w=3 M=10
    jaxnat train --resume runs/Classify_Digits-v0-ppo-20250101-120000

All seeds train at once (`jit(vmap(...))` over their keys). Training runs in chunks of
`--eval-every` updates, each one compiled `lax.scan`; after every chunk all seeds are scored on
the test split (the same env id with `split="test"` when the env has splits), and the run
directory gets:

- `config.json`   env id and kwargs, algorithm, the full resolved config, seeds, versions
- `metrics.jsonl` one line per update per seed: update, env_steps, seed, training metrics
- `eval.jsonl`    one line per evaluation per seed: greedy/sampled test return, accuracy
                  (terminated fraction), length; chunk timing
- `curve.png`     mean +- std over seeds vs env steps: returns, and train/test accuracy
- `checkpoints/`  orbax checkpoints of the vmapped `RunnerState` (last 2 kept)
- `summary.json`  the final table: mean +- std over seeds

`--resume RUN_DIR` restores the latest checkpoint and finishes the run; because the runner
state carries the PRNG keys, the result is bit-for-bit that of an uninterrupted run.
"""

from __future__ import annotations

import collections
import dataclasses
import datetime
import functools
import importlib
import inspect
import json
import math
import platform
import sys
import threading
import time
import typing
from pathlib import Path
from typing import Annotated, Any, Optional

import jax
import jax.numpy as jnp
import numpy as np
import tyro

import jaxnat
from jaxnat.agents import ALGORITHMS
from jaxnat.agents.evaluate import make_evaluate
from jaxnat.agents.networks import TRUNKS, default_trunk
from jaxnat.datasets import DatasetFormatError, DatasetNotFoundError
from jaxnat.registration import MissingDependencyError, UnknownEnvError

__all__ = ["TrainArgs", "ConfigOverrides", "RunSpec", "TrainResult", "train", "load_checkpoint", "main"]

PROG = "jaxnat train"
# Fields of the algorithm configs that are top-level arguments rather than overrides.
_CORE_CONFIG_FIELDS = ("total_timesteps", "num_envs", "trunk")
_EVAL_STREAM = 0x6576616C  # fold_in constant: evaluation keys never collide with training keys
_TARGET_EVALUATIONS = 20  # --eval-every's default aims at about this many evaluations


class TrainError(Exception):
    """A user error: printed as one line `jaxnat train: error: <message>`, exit status 2."""


# ----------------------------------------------------------------------------- arguments


def _config_fields() -> dict[str, tuple[Any, dict[str, Any]]]:
    """Every algorithm config field except the core ones: name -> (type, {algo: default})."""
    fields: dict[str, tuple[Any, dict[str, Any]]] = {}
    for algo, (config_cls, _) in ALGORITHMS.items():
        hints = typing.get_type_hints(config_cls)
        for field in dataclasses.fields(config_cls):
            if field.name in _CORE_CONFIG_FIELDS:
                continue
            kind, defaults = fields.setdefault(field.name, (hints[field.name], {}))
            defaults[algo] = field.default
    return fields


def _metavar(kind) -> str:
    return {int: "INT", float: "FLOAT", bool: "{True,False}", str: "STR"}.get(kind, "VALUE")


def _make_overrides_class():
    fields = []
    for name, (kind, defaults) in _config_fields().items():
        hint = "(default: " + ", ".join(f"{algo} {value}" for algo, value in defaults.items()) + ")"
        only = "" if len(defaults) == len(ALGORITHMS) else f"{'/'.join(defaults)} only"
        fields.append((name, Annotated[Optional[kind], tyro.conf.arg(
            help=only, help_behavior_hint=hint, metavar=_metavar(kind))], None))
    cls = dataclasses.make_dataclass("ConfigOverrides", fields, frozen=True)
    cls.__module__ = __name__
    cls.__doc__ = ("Algorithm settings; unset ones take the algorithm's default. Every field of "
                   f"{', '.join(c.__name__ for c, _ in ALGORITHMS.values())} is here or above.")
    return cls


ConfigOverrides = _make_overrides_class()


@dataclasses.dataclass
class TrainArgs:
    """Train PPO, A2C, ACKTR or DQN on a jaxnat env over several seeds at once, evaluate on the test split,
    write metrics, a learning curve and checkpoints to a run directory."""

    env_id: str = "Classify/Digits-v0"
    """A registered env id (see jaxnat.registered_envs())."""
    env_kwargs: Annotated[tuple[str, ...], tyro.conf.arg(metavar="KEY=VALUE [KEY=VALUE ...]")] = ()
    """Keyword arguments of jaxnat.make, e.g. w=3 M=10 start=center; values are read as int, float, bool (true/false), none, else str. The trainer sets split (train, and test for evaluation)."""
    algo: Annotated[str, tyro.conf.arg(metavar="{" + ",".join(ALGORITHMS) + "}")] = "ppo"
    """The algorithm."""
    seeds: int = 5
    """Number of seeds, trained at once (vmapped)."""
    seed: int = 0
    """The first seed; the run uses seed, seed+1, ..., seed+seeds-1."""
    total_timesteps: Annotated[Optional[int], tyro.conf.arg(metavar="INT", help_behavior_hint="")] = None
    """Env steps per seed (unset: the algorithm's default, 1e6)."""
    num_envs: Annotated[Optional[int], tyro.conf.arg(metavar="INT", help_behavior_hint="")] = None
    """Parallel envs per seed (unset: the algorithm's default, ppo 8, a2c 16, acktr 32, dqn 8)."""
    trunk: Annotated[Optional[str], tyro.conf.arg(metavar="{" + ",".join(TRUNKS) + "}",
                                                  help_behavior_hint="")] = None
    """Network trunk (unset: the paper's trunk for the observation size)."""
    eval_every: Annotated[Optional[int], tyro.conf.arg(metavar="INT", help_behavior_hint="")] = None
    """Updates per chunk: evaluate, log and checkpoint after every this many updates (unset: about 20 evaluations over the run)."""
    eval_episodes: int = 1000
    """Test episodes per seed per evaluation."""
    run_dir: Annotated[Optional[Path], tyro.conf.arg(metavar="PATH", help_behavior_hint="")] = None
    """Where to write the run (unset: runs/<env>-<algo>-<timestamp>)."""
    resume: Annotated[Optional[Path], tyro.conf.arg(metavar="RUN_DIR", help_behavior_hint="")] = None
    """Continue the run in this directory from its latest checkpoint; other arguments must be left out or match its config.json."""
    config: Annotated[ConfigOverrides, tyro.conf.OmitArgPrefixes] = dataclasses.field(
        default_factory=ConfigOverrides)


def parse_env_kwargs(items) -> dict[str, Any]:
    """`["w=3", "start=center"]` (or a dict of strings) -> `{"w": 3, "start": "center"}`."""
    pairs = items.items() if isinstance(items, dict) else []
    if not isinstance(items, dict):
        for item in items:
            key, sep, value = item.partition("=")
            if not sep or not key:
                raise TrainError(f"--env-kwargs takes KEY=VALUE pairs, got {item!r}")
            pairs.append((key.strip(), value.strip()))
    return {key: _parse_value(value) for key, value in pairs}


def _parse_value(value: Any) -> Any:
    if not isinstance(value, str):
        return value
    for convert in (int, float):
        try:
            return convert(value)
        except ValueError:
            pass
    special = {"true": True, "false": False, "none": None, "null": None}
    return special.get(value.lower(), value)


# ----------------------------------------------------------------------------- the run spec


@dataclasses.dataclass(frozen=True)
class RunSpec:
    """Everything that determines a run's result; saved as config.json and read on --resume."""

    env_id: str
    env_kwargs: dict
    algo: str
    config: Any  # the algorithm's config dataclass, fully resolved (trunk included)
    seeds: int
    seed: int
    eval_every: int
    eval_episodes: int

    @property
    def num_updates(self) -> int:
        return self.config.total_timesteps // self.steps_per_update

    @property
    def steps_per_update(self) -> int:
        """Env steps per update per seed."""
        return self.config.num_envs * self.config.num_steps

    @property
    def seed_values(self) -> list[int]:
        return list(range(self.seed, self.seed + self.seeds))

    def program_key(self) -> tuple:
        """What the compiled programs depend on (not the seed values: keys are inputs)."""
        return (self.env_id, tuple(sorted(self.env_kwargs.items())), self.algo, self.config,
                self.seeds, self.eval_episodes)

    def to_json(self) -> dict:
        return {
            "env_id": self.env_id,
            "env_kwargs": self.env_kwargs,
            "algo": self.algo,
            "config": dataclasses.asdict(self.config),
            "static_fields": [f.name for f in dataclasses.fields(self.config)
                              if not f.metadata.get("pytree_node", True)],
            "seeds": self.seeds,
            "seed": self.seed,
            "seed_values": self.seed_values,
            "eval_every": self.eval_every,
            "eval_episodes": self.eval_episodes,
            "num_updates": self.num_updates,
            "steps_per_update": self.steps_per_update,
        }

    @classmethod
    def from_json(cls, data: dict) -> RunSpec:
        if data["algo"] not in ALGORITHMS:
            raise TrainError(f"config.json names algorithm {data['algo']!r}, which this jaxnat lacks")
        config_cls, _ = ALGORITHMS[data["algo"]]
        return cls(
            env_id=data["env_id"], env_kwargs=dict(data["env_kwargs"]), algo=data["algo"],
            config=config_cls(**data["config"]), seeds=int(data["seeds"]), seed=int(data["seed"]),
            eval_every=int(data["eval_every"]), eval_episodes=int(data["eval_episodes"]),
        )


def _check_algo(algo: str) -> None:
    if algo not in ALGORITHMS:
        import difflib

        close = difflib.get_close_matches(algo.lower(), ALGORITHMS, n=1, cutoff=0.5)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise TrainError(f"unknown algorithm {algo!r}{hint}; choose one of: {', '.join(ALGORITHMS)}")


def _resolve_config(args: TrainArgs, observation_space):
    """The algorithm's config with every override applied and the trunk resolved."""
    config_cls, _ = ALGORITHMS[args.algo]
    names = {f.name for f in dataclasses.fields(config_cls)}
    values = {}
    for field in dataclasses.fields(args.config):
        value = getattr(args.config, field.name)
        if value is None:
            continue
        if field.name not in names:
            flag = "--" + field.name.replace("_", "-")
            raise TrainError(f"{flag} is not a setting of {args.algo} (it belongs to "
                             f"{', '.join(a for a, (c, _) in ALGORITHMS.items() if field.name in {f.name for f in dataclasses.fields(c)})})")
        values[field.name] = value
    for name in _CORE_CONFIG_FIELDS:
        if getattr(args, name) is not None:
            values[name] = getattr(args, name)
    config = config_cls(**values)
    if config.trunk is None:
        config = config.replace(trunk=default_trunk(observation_space))
    return config


def _auto_eval_every(num_updates: int) -> int:
    """About `_TARGET_EVALUATIONS` chunks, preferring a chunk length that divides the run (so
    one program serves every chunk)."""
    target = num_updates / _TARGET_EVALUATIONS
    if target <= 1:
        return 1
    divisors = [d for d in range(max(1, int(target / 2)), int(target * 2) + 1) if num_updates % d == 0]
    if divisors:
        return min(divisors, key=lambda d: (abs(math.log(d / target)), d))
    return math.ceil(target)


# ----------------------------------------------------------------------------- programs


def _accepts(env_id: str, name: str) -> bool:
    """Whether the env's entry point takes the constructor argument `name` (e.g. "split")."""
    entry = jaxnat.spec(env_id).entry_point
    if isinstance(entry, str):
        module, _, attr = entry.partition(":")
        try:
            entry = getattr(importlib.import_module(module), attr)
        except ImportError:  # jaxnat.make says which dependency is missing
            return False
    target = entry.__init__ if inspect.isclass(entry) else entry
    try:
        return name in inspect.signature(target).parameters
    except (TypeError, ValueError):
        return False


def _make_envs(spec: RunSpec):
    """(train env, params, test env, params, whether the test env is the test split)."""
    kwargs = dict(spec.env_kwargs)
    if "split" in kwargs:
        raise TrainError("env kwarg 'split' is set by jaxnat train: split=train for training and "
                         "split=test for evaluation")
    try:
        has_split = _accepts(spec.env_id, "split")
        split = {"split": "train"} if has_split else {}
        env, params = jaxnat.make(spec.env_id, **split, **kwargs)
        test_split = {"split": "test"} if has_split else {}
        test_env, test_params = jaxnat.make(spec.env_id, autoreset=False, **test_split, **kwargs)
    except UnknownEnvError as err:
        raise TrainError(str(err)) from None
    except (MissingDependencyError, DatasetNotFoundError, DatasetFormatError) as err:
        raise TrainError(str(err)) from None
    except (TypeError, ValueError) as err:  # bad kwarg names or values
        message = str(err)
        raise TrainError(message if spec.env_id in message else f"{spec.env_id}: {message}") from None
    return env, params, test_env, test_params, has_split


def _update_callback(update, metrics) -> None:
    """The one host callback every compiled chunk calls (once per update per seed); it forwards
    to the current run's progress display, so compiled programs can be reused across runs."""
    sink = _SINK
    if sink is not None:
        sink(update, metrics)


_SINK = None


class _Program:
    """The compiled functions of one run spec: init, a chunk of updates, evaluation."""

    def __init__(self, spec: RunSpec, compiler_options: dict | None):
        self.spec = spec
        self.compiler_options = compiler_options
        env, params, test_env, test_params, self.test_split = _make_envs(spec)
        self.observation_space = env.observation_space(params)
        _, make_learner = ALGORITHMS[spec.algo]
        try:
            self.learner = make_learner(spec.config, env, params)
        except ValueError as err:  # trunk/observation mismatch, run shorter than one rollout
            raise TrainError(str(err)) from None
        evaluate = make_evaluate(self.learner.network, test_env, test_params, spec.eval_episodes)
        keys = jax.ShapeDtypeStruct((spec.seeds,), jax.random.key(0).dtype)
        # Seeds are initialised one after another (lax.map), not vmapped: jaxlib 0.10's CPU
        # LAPACK kernels split a batched QR (the orthogonal initialiser's) into tasks on XLA's
        # intra-op pool and block waiting for them, which deadlocks when several such calls
        # run at once on a small pool (seen on 2 cores). One matrix at a time runs inline.
        # The result is the same RunnerState, stacked over seeds.
        init = jax.jit(functools.partial(jax.lax.map, self.learner.init))
        self.runner_shape = jax.eval_shape(init, keys)
        self.init = self._compile(init, keys)
        self.evaluate = self._compile(jax.jit(jax.vmap(evaluate)),
                                      self.runner_shape.train_state.params, keys)
        self._chunks: dict[int, Any] = {}

    def _compile(self, jitted, *args):
        try:
            return jitted.lower(*args).compile(self.compiler_options)
        except ValueError as err:  # e.g. a batch that the minibatches do not divide
            raise TrainError(str(err)) from None

    def chunk(self, num_updates: int):
        """`runner -> (runner, metrics [seeds, num_updates])`, compiled once per length."""
        if num_updates not in self._chunks:
            run = functools.partial(self.learner.run, config=self.spec.config,
                                    num_updates=num_updates, callback=_update_callback)
            self._chunks[num_updates] = self._compile(jax.jit(jax.vmap(run)), self.runner_shape)
        return self._chunks[num_updates]

    def keys(self):
        return jax.vmap(jax.random.key)(jnp.asarray(self.spec.seed_values, jnp.uint32))

    def eval_keys(self):
        return jax.vmap(lambda k: jax.random.fold_in(k, _EVAL_STREAM))(self.keys())


_PROGRAMS: collections.OrderedDict = collections.OrderedDict()


def _program(spec: RunSpec, compiler_options: dict | None = None) -> _Program:
    """Build (or reuse, within this process) the compiled programs for `spec`."""
    key = (spec.program_key(), tuple(sorted((compiler_options or {}).items())))
    if key not in _PROGRAMS:
        _PROGRAMS[key] = _Program(spec, compiler_options)
        while len(_PROGRAMS) > 2:
            _PROGRAMS.popitem(last=False)
    _PROGRAMS.move_to_end(key)
    return _PROGRAMS[key]


# ----------------------------------------------------------------------------- checkpoints


def _is_key(x) -> bool:
    return isinstance(x, jax.Array) and jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key)


def _to_saveable(tree):
    return jax.tree.map(lambda x: jax.random.key_data(x) if _is_key(x) else x, tree)


class _Checkpoints:
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
            state=ocp.args.StandardSave(_to_saveable(runner)), meta=ocp.args.JsonSave(meta)))
        self.manager.wait_until_finished()

    def restore(self, target, step: int | None = None):
        """(runner, meta): arrays from the checkpoint in `target`'s structure (whose static
        fields, the network's apply_fn and the optimizer, come from this process)."""
        ocp = self.ocp
        step = self.latest_step() if step is None else step
        abstract = jax.tree.map(ocp.utils.to_shape_dtype_struct, _to_saveable(target))
        restored = self.manager.restore(step, args=ocp.args.Composite(
            state=ocp.args.StandardRestore(abstract), meta=ocp.args.JsonRestore()))
        target_leaves, treedef = jax.tree.flatten(target)
        leaves = jax.tree.leaves(restored.state)
        if len(leaves) != len(target_leaves):
            raise TrainError(f"checkpoint {step} does not match this run's state "
                             f"({len(leaves)} arrays, expected {len(target_leaves)})")
        leaves = [jax.random.wrap_key_data(leaf, impl=jax.random.key_impl(ref)) if _is_key(ref)
                  else jnp.asarray(leaf) for ref, leaf in zip(target_leaves, leaves)]
        return jax.tree.unflatten(treedef, leaves), dict(restored.meta)

    def close(self) -> None:
        self.manager.close()


def load_checkpoint(run_dir, step: int | None = None, *, compiler_options: dict | None = None):
    """`(runner, meta)` of a run directory's latest (or given) checkpoint: the vmapped
    `RunnerState` (params at `runner.train_state.params`, one slice per seed)."""
    run_dir = Path(run_dir)
    spec = RunSpec.from_json(json.loads((run_dir / "config.json").read_text())["spec"])
    program = _program(spec, compiler_options)
    checkpoints = _Checkpoints(run_dir / "checkpoints")
    try:
        if checkpoints.latest_step() is None:
            raise TrainError(f"{run_dir} has no checkpoint yet")
        return checkpoints.restore(program.init(program.keys()), step)
    finally:
        checkpoints.close()


# ----------------------------------------------------------------------------- records


def _json_value(x):
    x = np.asarray(x)
    if np.issubdtype(x.dtype, np.integer) or x.dtype == bool:
        return int(x)
    value = float(x)
    return value if math.isfinite(value) else None


def _read_jsonl(path: Path) -> list[dict]:
    if not path.exists():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def _write_jsonl(path: Path, rows, mode: str = "a") -> None:
    with path.open(mode) as f:
        for row in rows:
            f.write(json.dumps(row) + "\n")


class _History:
    """What the curve and the summary need, kept in memory (and re-read on --resume)."""

    def __init__(self, spec: RunSpec):
        self.spec = spec
        self.train: dict[str, list[np.ndarray]] = {"update": [], "episode_return": [],
                                                   "terminated_fraction": []}
        self.evals: list[dict] = []  # one per evaluation: update + arrays over seeds
        self.chunk_sps: list[float] = []

    def add_train(self, first_update: int, metrics: dict) -> None:
        n = np.asarray(metrics["episode_return"]).shape[1]
        self.train["update"].append(np.arange(first_update + 1, first_update + n + 1))
        for name in ("episode_return", "terminated_fraction"):
            self.train[name].append(np.asarray(metrics[name], np.float64).T)  # [n, seeds]

    def add_eval(self, update: int, scores: dict, sps: float | None) -> None:
        self.evals.append({"update": update, **{k: np.asarray(v, np.float64) for k, v in scores.items()}})
        if sps is not None:
            self.chunk_sps.append(sps)

    @classmethod
    def load(cls, spec: RunSpec, metrics_rows: list[dict], eval_rows: list[dict]) -> _History:
        history = cls(spec)
        index = {seed: i for i, seed in enumerate(spec.seed_values)}
        by_update: dict[int, np.ndarray] = {}
        for row in metrics_rows:
            arrays = by_update.setdefault(row["update"], np.full((2, spec.seeds), np.nan))
            for j, name in enumerate(("episode_return", "terminated_fraction")):
                value = row.get(name)
                arrays[j, index[row["seed"]]] = np.nan if value is None else value
        if by_update:
            updates = np.array(sorted(by_update))
            stacked = np.stack([by_update[u] for u in updates])  # [n, 2, seeds]
            history.train["update"].append(updates)
            history.train["episode_return"].append(stacked[:, 0])
            history.train["terminated_fraction"].append(stacked[:, 1])
        evals: dict[int, dict] = {}
        for row in eval_rows:
            entry = evals.setdefault(row["update"], {"update": row["update"], "sps": row.get("steps_per_second")})
            for k, v in row.items():
                if k.startswith(("greedy_", "sampled_")):
                    entry.setdefault(k, np.full(spec.seeds, np.nan))[index[row["seed"]]] = np.nan if v is None else v
        for update in sorted(evals):
            entry = evals[update]
            sps = entry.pop("sps")
            history.evals.append(entry)
            if sps is not None:
                history.chunk_sps.append(sps)
        return history

    def train_arrays(self):
        if not self.train["update"]:
            return np.zeros(0), np.zeros((0, self.spec.seeds)), np.zeros((0, self.spec.seeds))
        return tuple(np.concatenate(self.train[k]) for k in ("update", "episode_return", "terminated_fraction"))


def _mean_std(values) -> tuple[float, float]:
    values = np.asarray(values, np.float64)
    values = values[np.isfinite(values)]
    if values.size == 0:
        return float("nan"), float("nan")
    return float(values.mean()), float(values.std())


def _nanmean(x, axis):
    x = np.asarray(x, np.float64)
    count = np.isfinite(x).sum(axis)
    total = np.where(np.isfinite(x), x, 0.0).sum(axis)
    return np.where(count > 0, total / np.maximum(count, 1), np.nan)


def _plot(path: Path, spec: RunSpec, history: _History) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    updates, returns, accuracy = history.train_arrays()
    steps = updates * spec.steps_per_update
    eval_steps = np.array([e["update"] for e in history.evals]) * spec.steps_per_update
    fig = Figure(figsize=(11, 4.2), constrained_layout=True)
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, 2)

    def band(ax, x, per_seed, label, **style):
        if len(x) == 0:
            return
        mean = _nanmean(per_seed, 1)
        centred = np.where(np.isfinite(per_seed), per_seed - mean[:, None], np.nan)
        std = np.sqrt(_nanmean(centred**2, 1))
        line, = ax.plot(x, mean, label=label, **style)
        ax.fill_between(x, mean - std, mean + std, alpha=0.2, color=line.get_color(), linewidth=0)

    band(axes[0], steps, returns, "train (episodes ending in each rollout)", color="C0")
    band(axes[1], steps, accuracy, "train (episodes ending in each rollout)", color="C0")
    if history.evals:
        for ax, key in zip(axes, ("greedy_return", "greedy_terminated_fraction")):
            band(ax, eval_steps, np.stack([e[key] for e in history.evals]), "test split, greedy",
                 color="C1", marker="o", markersize=3)
    titles = ("Episode return", "Accuracy (fraction of episodes terminated)")
    for ax, title in zip(axes, titles):
        ax.set_title(title)
        ax.set_xlabel("env steps per seed")
        ax.grid(alpha=0.3)
        ax.legend(loc="best", fontsize="small")
    fig.suptitle(f"{spec.env_id}  {spec.algo}  (mean ± std over {spec.seeds} seeds)")
    fig.savefig(path, dpi=110)


def _summary(spec: RunSpec, history: _History, wall_time: float, complete: bool) -> dict:
    updates, returns, accuracy = history.train_arrays()
    window = max(1, min(spec.eval_every, len(updates)))  # the last chunk's updates
    per_seed = {
        "train_return": _nanmean(returns[-window:], 0) if len(updates) else np.full(spec.seeds, np.nan),
        "train_accuracy": _nanmean(accuracy[-window:], 0) if len(updates) else np.full(spec.seeds, np.nan),
    }
    last = history.evals[-1] if history.evals else {}
    for name, key in [("test_greedy_return", "greedy_return"),
                      ("test_greedy_accuracy", "greedy_terminated_fraction"),
                      ("test_sampled_return", "sampled_return"),
                      ("test_sampled_accuracy", "sampled_terminated_fraction")]:
        per_seed[name] = last.get(key, np.full(spec.seeds, np.nan))
    metrics = {}
    for name, values in per_seed.items():
        mean, std = _mean_std(values)
        metrics[name] = {"mean": _json_value(mean), "std": _json_value(std),
                         "per_seed": [_json_value(v) for v in values]}
    sps_mean, sps_std = _mean_std(history.chunk_sps)
    return {
        "env_id": spec.env_id, "algo": spec.algo, "seeds": spec.seed_values,
        "complete": complete,
        "updates": int(updates[-1]) if len(updates) else 0,
        "env_steps_per_seed": int(updates[-1]) * spec.steps_per_update if len(updates) else 0,
        "metrics": metrics,
        "steps_per_second": {"mean": _json_value(sps_mean), "std": _json_value(sps_std),
                             "note": "env steps/s over all seeds, mean ± std over chunks"},
        "wall_time_s": wall_time,
    }


def _print_summary(console, summary: dict) -> None:
    from rich.table import Table

    table = Table(title=f"{summary['env_id']} · {summary['algo']} · {len(summary['seeds'])} seeds · "
                        f"{summary['env_steps_per_seed']:,} env steps per seed")
    table.add_column("metric")
    table.add_column("mean", justify="right")
    table.add_column("± std", justify="right")
    labels = {"train_return": "train return (last chunk)", "train_accuracy": "train accuracy (last chunk)",
              "test_greedy_return": "test greedy return", "test_greedy_accuracy": "test greedy accuracy",
              "test_sampled_return": "test sampled return", "test_sampled_accuracy": "test sampled accuracy"}

    def fmt(x, pattern):
        return "—" if x is None else format(x, pattern)

    for name, label in labels.items():
        m = summary["metrics"][name]
        pattern = ".1%" if "accuracy" in name else "+.4f"
        table.add_row(label, fmt(m["mean"], pattern), fmt(m["std"], pattern.lstrip("+")))
    sps = summary["steps_per_second"]
    table.add_row("env steps/s (all seeds, over chunks)", fmt(sps["mean"], ",.0f"), fmt(sps["std"], ",.0f"))
    table.add_row("wall time", f"{summary['wall_time_s']:.1f} s", "")
    console.print(table)


# ----------------------------------------------------------------------------- progress


class _Progress:
    """A rich progress bar advanced from the per-update host callback (once per seed)."""

    def __init__(self, console, spec: RunSpec, start_update: int):
        from rich.progress import (BarColumn, MofNCompleteColumn, Progress, ProgressColumn,
                                   TextColumn, TimeElapsedColumn, TimeRemainingColumn)
        from rich.text import Text

        seeds = spec.seeds

        class SpeedColumn(ProgressColumn):
            def render(self, task):
                speed = task.finished_speed or task.speed
                return Text("— steps/s" if speed is None else f"{speed * seeds:,.0f} steps/s")

        self.spec = spec
        self.progress = Progress(
            TextColumn("[bold]{task.description}"), BarColumn(bar_width=24), MofNCompleteColumn(),
            TextColumn("steps/seed ·"), SpeedColumn(),
            TextColumn("· train {task.fields[train]} · test {task.fields[test]} ·"),
            TimeElapsedColumn(), TextColumn("eta"), TimeRemainingColumn(), console=console,
            speed_estimate_period=10, disable=not (console.is_terminal or console.is_jupyter),
        )
        self.task = self.progress.add_task(
            "training", total=spec.num_updates * spec.steps_per_update,
            completed=start_update * spec.steps_per_update, train="—", test="—")
        self._lock = threading.Lock()
        self._calls = 0
        self._start = start_update
        self._returns = collections.deque(maxlen=spec.seeds)

    def __call__(self, update, metrics) -> None:
        value = float(np.asarray(metrics["episode_return"]))
        with self._lock:
            self._calls += 1
            if math.isfinite(value):
                self._returns.append(value)
            if self._calls % self.spec.seeds == 0:
                done = self._start + self._calls // self.spec.seeds
                train = f"{np.mean(self._returns):+.3f}" if self._returns else "—"
                self.progress.update(self.task, completed=done * self.spec.steps_per_update, train=train)

    def sync(self, update: int, test: str | None = None) -> None:
        with self._lock:
            self._calls = (update - self._start) * self.spec.seeds
            fields = {} if test is None else {"test": test}
            self.progress.update(self.task, completed=update * self.spec.steps_per_update, **fields)


# ----------------------------------------------------------------------------- training


@dataclasses.dataclass
class TrainResult:
    run_dir: Path
    runner: Any  # the vmapped RunnerState
    summary: dict
    complete: bool


def _versions() -> dict:
    versions = {"jaxnat": jaxnat.__version__, "jax": jax.__version__, "python": platform.python_version()}
    for name in ("jaxlib", "flax", "optax", "orbax.checkpoint"):
        try:
            versions[name] = importlib.import_module(name).__version__
        except Exception:  # noqa: BLE001 (versions are informative only)
            pass
    versions["device"] = str(jax.devices()[0].device_kind)
    return versions


def _default_run_dir(env_id: str, algo: str) -> Path:
    stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
    return Path("runs") / f"{env_id.replace('/', '_')}-{algo}-{stamp}"


def _check_resume_args(args: TrainArgs, saved: dict) -> None:
    """Arguments given with --resume must match the run's; defaults count as left out."""
    defaults = TrainArgs()
    conflicts = []
    for field in dataclasses.fields(TrainArgs):
        if field.name in ("resume", "run_dir", "config"):
            continue
        value, default = getattr(args, field.name), getattr(defaults, field.name)
        if field.name == "env_kwargs":
            value, default = parse_env_kwargs(value), parse_env_kwargs(default)
        if value != default and value != saved.get(field.name, saved["config"].get(field.name)):
            conflicts.append(f"--{field.name.replace('_', '-')}")
    for field in dataclasses.fields(args.config):
        value = getattr(args.config, field.name)
        if value is not None and value != saved["config"].get(field.name):
            conflicts.append(f"--{field.name.replace('_', '-')}")
    if args.run_dir is not None and Path(args.run_dir).absolute() != Path(args.resume).absolute():
        conflicts.append("--run-dir")
    if conflicts:
        verb = "conflicts" if len(conflicts) == 1 else "conflict"
        raise TrainError(f"{', '.join(conflicts)} {verb} with the config of the run being resumed "
                         f"({Path(args.resume) / 'config.json'}); leave them out")


def _setup(args: TrainArgs):
    """(spec, run_dir, the saved config.json when resuming else None)."""
    if args.resume is not None:
        run_dir = Path(args.resume)
        config_path = run_dir / "config.json"
        if not config_path.is_file():
            raise TrainError(f"cannot resume {run_dir}: no config.json there")
        saved = json.loads(config_path.read_text())
        _check_resume_args(args, saved["spec"])
        return RunSpec.from_json(saved["spec"]), run_dir, saved

    _check_algo(args.algo)
    for name in ("seeds", "eval_episodes"):
        if getattr(args, name) < 1:
            raise TrainError(f"--{name.replace('_', '-')} must be at least 1")
    if args.eval_every is not None and args.eval_every < 1:
        raise TrainError("--eval-every must be at least 1")
    env_kwargs = parse_env_kwargs(args.env_kwargs)
    # Resolving the trunk needs the observation space: build the env once (cheap; cached data).
    probe = RunSpec(args.env_id, env_kwargs, args.algo, None, args.seeds, args.seed, 1, args.eval_episodes)
    env, params, *_ = _make_envs(probe)
    try:
        config = _resolve_config(args, env.observation_space(params))
    except TypeError as err:
        raise TrainError(str(err)) from None
    spec = dataclasses.replace(probe, config=config)
    if spec.num_updates < 1:
        raise TrainError(f"total_timesteps={config.total_timesteps} is less than one rollout "
                         f"(num_envs * num_steps = {spec.steps_per_update})")
    eval_every = args.eval_every or _auto_eval_every(spec.num_updates)
    spec = dataclasses.replace(spec, eval_every=min(eval_every, spec.num_updates))
    run_dir = Path(args.run_dir) if args.run_dir is not None else _default_run_dir(args.env_id, args.algo)
    if (run_dir / "config.json").exists():
        raise TrainError(f"{run_dir} already holds a run; continue it with --resume {run_dir} "
                         "or choose another --run-dir")
    return spec, run_dir, None


def _print_config(console, spec: RunSpec, run_dir: Path) -> None:
    from rich.table import Table

    table = Table(title=f"jaxnat train · {spec.algo} on {spec.env_id}", show_header=False, box=None)
    table.add_column(style="dim")
    table.add_column()
    table.add_row("env kwargs", json.dumps(spec.env_kwargs) if spec.env_kwargs else "—")
    table.add_row("evaluation", f"{spec.eval_episodes} episodes per seed on "
                  f"{'split=test' if _accepts(spec.env_id, 'split') else 'the training env (no test split)'}, "
                  f"every {spec.eval_every} updates")
    table.add_row("seeds", f"{spec.seed_values}")
    table.add_row("updates", f"{spec.num_updates} x {spec.steps_per_update} env steps per seed")
    static = {f.name for f in dataclasses.fields(spec.config) if not f.metadata.get("pytree_node", True)}
    for field in dataclasses.fields(spec.config):
        tag = " (static)" if field.name in static else ""
        table.add_row(f"{field.name}{tag}", repr(getattr(spec.config, field.name)))
    table.add_row("run dir", str(run_dir))
    console.print(table)


def train(args: TrainArgs, *, console=None, compiler_options: dict | None = None,
          stop_after_chunks: int | None = None) -> TrainResult:
    """Run (or resume) a training run; raises `TrainError` for user errors.

    Args:
        args: the parsed command line.
        console: a `rich.console.Console` for output (default: stdout).
        compiler_options: XLA options for every compiled program, e.g.
            `{"xla_backend_optimization_level": 0}` (compiles much faster on CPU).
        stop_after_chunks: stop after this many chunks (checkpointed; `--resume` continues).
    """
    global _SINK
    from rich.console import Console

    console = console or Console()
    session_start = time.perf_counter()
    spec, run_dir, saved = _setup(args)
    _print_config(console, spec, run_dir)
    with console.status("compiling init, training chunk and evaluation programs..."):
        compile_start = time.perf_counter()
        program = _program(spec, compiler_options)
        for length in {spec.eval_every, spec.num_updates % spec.eval_every} - {0}:
            program.chunk(length)
        compile_seconds = time.perf_counter() - compile_start
    console.print(f"[dim]programs ready in {compile_seconds:.1f} s[/dim]")

    run_dir.mkdir(parents=True, exist_ok=True)
    metrics_path, eval_path = run_dir / "metrics.jsonl", run_dir / "eval.jsonl"
    checkpoints = _Checkpoints(run_dir / "checkpoints")
    runner = program.init(program.keys())
    prior_wall = 0.0
    if saved is None:
        config_json = {"spec": spec.to_json(), "args": _args_json(args), "versions": _versions(),
                       "created": datetime.datetime.now().isoformat(timespec="seconds"),
                       "command": sys.argv}
        (run_dir / "config.json").write_text(json.dumps(config_json, indent=2) + "\n")
        metrics_path.write_text("")
        eval_path.write_text("")
    if checkpoints.latest_step() is not None:
        runner, meta = checkpoints.restore(runner)
        prior_wall = float(meta.get("wall_time_s", 0.0))
        console.print(f"resumed from checkpoint at update {meta['update']} (chunk {meta['chunk']})")
    update = int(np.asarray(runner.update)[0])
    # Drop records written after the checkpoint (a run stopped between writing and saving).
    metrics_rows = [r for r in _read_jsonl(metrics_path) if r["update"] <= update]
    eval_rows = [r for r in _read_jsonl(eval_path) if r["update"] <= update]
    _write_jsonl(metrics_path, metrics_rows, "w")
    _write_jsonl(eval_path, eval_rows, "w")
    history = _History.load(spec, metrics_rows, eval_rows)

    seeds = spec.seed_values
    eval_keys = program.eval_keys()

    def evaluate(update: int, chunk_seconds: float | None) -> dict:
        scores = jax.device_get(program.evaluate(runner.train_state.params, eval_keys))
        sps = None if chunk_seconds is None else \
            (update - previous_update) * spec.steps_per_update * spec.seeds / chunk_seconds
        rows = [{"chunk": -(-update // spec.eval_every), "update": update,
                 "env_steps": update * spec.steps_per_update, "seed": seed,
                 **{k: _json_value(v[i]) for k, v in scores.items()},
                 "chunk_seconds": chunk_seconds, "steps_per_second": sps}
                for i, seed in enumerate(seeds)]
        _write_jsonl(eval_path, rows)
        history.add_eval(update, scores, sps)
        return scores

    previous_update = update
    if not history.evals:  # the untrained policy: the curve's first point
        evaluate(update, None)

    progress = _Progress(console, spec, update)
    chunks_done = 0
    interrupted = False
    _SINK = progress
    try:
        with progress.progress:
            last = history.evals[-1]
            progress.sync(update, _test_field(last))
            while update < spec.num_updates:
                if stop_after_chunks is not None and chunks_done >= stop_after_chunks:
                    break
                n = min(spec.eval_every, spec.num_updates - update)
                chunk = program.chunk(n)
                start = time.perf_counter()
                runner, metrics = chunk(runner)
                metrics = jax.device_get(metrics)
                seconds = time.perf_counter() - start
                previous_update, update = update, update + n
                _write_jsonl(metrics_path, (
                    {"update": previous_update + j + 1,
                     "env_steps": (previous_update + j + 1) * spec.steps_per_update, "seed": seed,
                     **{k: _json_value(v[i, j]) for k, v in metrics.items()}}
                    for j in range(n) for i, seed in enumerate(seeds)))
                history.add_train(previous_update, metrics)
                scores = evaluate(update, seconds)
                chunk_index = -(-update // spec.eval_every)
                wall = prior_wall + time.perf_counter() - session_start
                checkpoints.save(runner, {"chunk": chunk_index, "update": update,
                                          "env_steps": update * spec.steps_per_update,
                                          "wall_time_s": wall})
                _plot(run_dir / "curve.png", spec, history)
                chunks_done += 1
                progress.sync(update, _test_field(history.evals[-1]))
                train_mean, train_std = _mean_std(_nanmean(metrics["episode_return"], 1))
                greedy, greedy_std = _mean_std(scores["greedy_return"])
                accuracy, _ = _mean_std(scores["greedy_terminated_fraction"])
                sampled, _ = _mean_std(scores["sampled_return"])
                console.print(
                    f"chunk {chunk_index}/{-(-spec.num_updates // spec.eval_every)} · update "
                    f"{update}/{spec.num_updates} · {update * spec.steps_per_update:,} env steps/seed · "
                    f"train return {train_mean:+.3f} ± {train_std:.3f} · test greedy {greedy:+.3f} ± "
                    f"{greedy_std:.3f} (accuracy {accuracy:.1%}) · sampled {sampled:+.3f} · "
                    f"{history.chunk_sps[-1]:,.0f} steps/s")
    except KeyboardInterrupt:
        interrupted = True
    finally:
        _SINK = None
        checkpoints.close()

    complete = update >= spec.num_updates
    if not history.train["update"] or not (run_dir / "curve.png").exists():
        _plot(run_dir / "curve.png", spec, history)
    summary = _summary(spec, history, prior_wall + time.perf_counter() - session_start, complete)
    (run_dir / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    _print_summary(console, summary)
    if not complete:
        why = "interrupted" if interrupted else "stopped"
        console.print(f"{why} at update {update}/{spec.num_updates}; continue with: "
                      f"jaxnat train --resume {run_dir}")
    else:
        console.print(f"run directory: {run_dir}")
    if interrupted:
        raise KeyboardInterrupt
    return TrainResult(run_dir, runner, summary, complete)


def _test_field(entry: dict) -> str:
    greedy, _ = _mean_std(entry["greedy_return"])
    accuracy, _ = _mean_std(entry["greedy_terminated_fraction"])
    return f"{greedy:+.3f} ({accuracy:.0%})"


def _args_json(args: TrainArgs) -> dict:
    data = dataclasses.asdict(args)
    return json.loads(json.dumps(data, default=str))


def parse_args(argv=None) -> TrainArgs:
    return tyro.cli(TrainArgs, args=argv, prog=PROG, description=inspect.cleandoc(TrainArgs.__doc__))


def main(argv=None, **train_options) -> int:
    """`jaxnat train` with `argv` (default: sys.argv[1:]); returns the exit status. Keyword
    arguments go to `train` (e.g. `compiler_options`, `stop_after_chunks`)."""
    args = parse_args(argv)
    try:
        train(args, **train_options)
    except TrainError as err:
        print(f"{PROG}: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
