"""The envs and the compiled programs of a run spec (init, a chunk of updates, evaluation), cached per process."""

from __future__ import annotations

import collections
import contextlib
import copy
import dataclasses
import functools
import inspect
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

import jaxnat
from jaxnat.agents import ALGORITHMS
from jaxnat.agents.rollout import make_chance, make_evaluate
from jaxnat.datasets import DatasetFormatError, DatasetNotFoundError
from jaxnat.registration import MissingDependencyError, UnknownEnvError
from jaxnat.training.args import TrainError, check_split_kwargs, constructor_parameters
from jaxnat.training.placement import Placement
from jaxnat.training.spec import RunSpec

EVAL_STREAM = 0x6576616C  # fold_in constant: evaluation keys never collide with training keys


def split_argument(env_id: str, env_kwargs: dict) -> str | None:
    """The env's constructor argument that picks disjoint train and test data: `split` (vision
    envs), `video_split` (PixelMuJoCo with `floor="video"`: held-out videos), else None."""
    parameters = constructor_parameters(env_id)
    if "split" in parameters:
        return "split"
    if "video_split" in parameters and env_kwargs.get("floor") == "video":
        return "video_split"
    return None


def make_envs(spec: RunSpec):
    """(train env, params, test env, params): the test env is the test split where the env has one."""
    kwargs = dict(spec.env_kwargs)
    check_split_kwargs(kwargs)
    try:
        argument = split_argument(spec.env_id, kwargs)
        train, test = ({argument: "train"}, {argument: "test"}) if argument is not None else ({}, {})
        env, params = jaxnat.make(spec.env_id, **train, **kwargs)
        test_env, test_params = jaxnat.make(spec.env_id, autoreset=False, **test, **kwargs)
    except (UnknownEnvError, MissingDependencyError, DatasetNotFoundError, DatasetFormatError) as err:
        raise TrainError(str(err)) from None
    except (TypeError, ValueError) as err:  # bad kwarg names or values
        message = str(err)
        raise TrainError(message if spec.env_id in message else f"{spec.env_id}: {message}") from None
    return env, params, test_env, test_params


_SINK = None  # the running chunk's progress display, `sink(update, metrics)`; None: drop


def _update_callback(update, metrics) -> None:
    """The one host callback every compiled chunk calls (once per update per seed); it forwards
    to the current run's progress display, so compiled programs can be reused across runs."""
    sink = _SINK
    if sink is not None:
        sink(update, metrics)


_EVAL_SINK = None  # the running evaluation's display, `sink(pass_index, steps_done)`; None: drop


def _eval_callback(pass_index, steps_done) -> None:
    """The host callback of the evaluation and chance programs (`make_evaluate`'s `progress`),
    forwarded to the current evaluation's display (`progress.EvalProgress`), as `_update_callback`."""
    sink = _EVAL_SINK
    if sink is not None:
        sink(pass_index, steps_done)


class DeviceBackend:
    """`chunk_loop.Backend` for pure-JAX envs: the compiled functions of one run spec (init, a chunk
    of updates, evaluation), every seed at once in one vmapped program; the test split is
    scored after every chunk; checkpoints in `checkpoints/` hold the vmapped runner state.
    With `spec.shard`, the programs run on `spec.devices` devices (`placement.Placement`)."""

    evaluates_each_chunk = True
    checkpoints_per_seed = False  # one checkpoint of the vmapped runner

    def __init__(self, spec: RunSpec, compiler_options: dict | None, envs=None):
        self.spec = spec
        self.compiler_options = compiler_options
        self.placement = Placement.resolve(spec.algo, spec.config, spec.seeds, spec.devices, spec.shard)
        env, params, test_env, test_params = envs or make_envs(spec)
        make_learner = ALGORITHMS[spec.algo].make
        # The env params (datasets, window, time limit, ...) are arguments of every program, not
        # constants baked into it: runs that differ only in traced params (the w/M sweep) can run
        # the same compiled programs (`may_serve`, `reuse_for`).
        # Built once here for its network, its runner's layout and its errors; the programs
        # build it again inside their traces, on traced env params. What a placement cannot
        # shard, `Placement.resolve` refused already.
        try:
            self.learner = make_learner(spec.config, env, params)
        except ValueError as err:  # trunk/observation mismatch, run shorter than one rollout
            raise TrainError(str(err)) from None
        self.params, self.test_params = self._place_params(params, test_params)
        network, episodes = self.learner.network, spec.eval_episodes
        # A test episode's length bounds the evaluation's scan, whose length is static.
        max_steps = self.eval_steps = int(self.test_params.max_steps_in_episode)

        def evaluate(test_params, *args):
            return jax.vmap(make_evaluate(network, test_env, test_params, episodes, max_steps, _eval_callback))(*args)

        def chance(test_params, keys):
            return jax.vmap(make_chance(test_env, test_params, episodes, max_steps, _eval_callback))(keys)

        keys = jax.ShapeDtypeStruct((spec.seeds,), jax.random.key(0).dtype)
        place = self.placement
        init_program, self._chunk_program = place.learner_programs(spec.algo, spec.config, env, params, spec.seeds,
                                                                   _update_callback, self.learner)
        # The runner's shape is the init program's own trace, which lowering it reuses, so the
        # chunks take exactly the tree init returns.
        self.runner_shape = jax.eval_shape(init_program, self.params, keys)
        replicated, per_seed = place.specs("replicated"), place.specs("per_seed")
        # Evaluation reads the parameters and the normaliser's moments: per seed, or replicated.
        self._scored = scored = place.specs("per_seed" if place.shard == "seeds" else "replicated")
        self._lowered = {  # compiled on first use, or together by `prepare`
            "init": self._lower(init_program, self.params, keys),
            "evaluate": self._lower(place.program(evaluate, (replicated, scored, place.specs("keys"), scored),
                                                  per_seed),
                                    self.test_params, *_unplaced(_policy_and_keys(self.learner, self.runner_shape,
                                                                                  keys))),
            "chance": self._lower(place.program(chance, (replicated, place.specs("keys")), per_seed),
                                  self.test_params, keys)}
        self._compiled: dict[Any, Any] = {}
        self.groups = [spec.seed_values]

    @staticmethod
    def _lower(jitted, *args):
        try:
            return jitted.lower(*args)
        except ValueError as err:  # e.g. a batch that the minibatches do not divide
            raise TrainError(str(err)) from None

    def prepare(self, chunk_lengths=()) -> None:
        """Lower, then compile every program (init, evaluation, chance, a chunk of each length)
        not compiled yet (`lower`, `compile_pending`)."""
        self.lower(chunk_lengths)
        self.compile_pending()

    def lower(self, chunk_lengths=()) -> None:
        """Trace and lower the chunk programs of these lengths (the others are lowered when the
        backend is built). Tracing stays on the thread that uses the programs: JAX's tracing
        caches are not safe to share with a thread compiling at the same time."""
        for n in chunk_lengths:
            if ("chunk", n) not in self._lowered and ("chunk", n) not in self._compiled:
                self._lowered[("chunk", n)] = self._lower(self._chunk_program(n), self.params, self.runner_shape)

    def compile_pending(self) -> None:
        """Compile every lowered program not compiled yet: XLA only, no tracing, so it may run on
        another thread; concurrently on an accelerator (XLA compiles without holding the GIL, and
        a GPU compile spends much of its time autotuning, so separate programs overlap), one
        after another on a CPU (there the compiler's own threads already use the cores)."""
        pending = {name: lowered for name, lowered in self._lowered.items() if name not in self._compiled}
        workers = 1 if jax.default_backend() == "cpu" else max(1, len(pending))
        with ThreadPoolExecutor(max_workers=workers) as pool:
            futures = {name: pool.submit(lowered.compile, self.compiler_options) for name, lowered in pending.items()}
        for name, future in futures.items():
            self._compiled[name] = future.result()
            del self._lowered[name]

    def _program(self, name):
        if name not in self._compiled:
            if isinstance(name, tuple):
                self.lower([name[1]])
            self._compiled[name] = self._lowered.pop(name).compile(self.compiler_options)
        return self._compiled[name]

    def compiled_chunk(self, num_updates: int):
        """`runner -> (runner, metrics [seeds, num_updates])`, compiled once per length."""
        return functools.partial(self._program(("chunk", num_updates)), self.params)

    def _place_params(self, *params):
        """Env params on every device of the placement (as they are on one device)."""
        return self.placement.put(params, self.placement.specs("replicated"))

    def keys(self):
        keys = jax.vmap(jax.random.key)(jnp.asarray(self.spec.seed_values, jnp.uint32))
        return self.placement.put(keys, self.placement.specs("keys"))

    def eval_keys(self):
        keys = jax.vmap(lambda k: jax.random.fold_in(k, EVAL_STREAM))(self.keys())
        return self.placement.put(keys, self.placement.specs("keys"))

    def place(self, state):
        """A runner (e.g. restored from a checkpoint written on another device count) laid out as
        this backend's programs take it."""
        return self.placement.put(state, self.placement.runner_specs(self.learner.per_env(state)))

    # The trainer's interface (`chunk_loop.Backend`): one group of every seed.

    def checkpoint_dir(self, group) -> str:
        return "checkpoints"

    def init(self, group=None):
        return self._program("init")(self.params, self.keys())

    def update_of(self, state) -> int:
        return int(np.asarray(self.learner.updates_of(state))[0])

    def begin(self, group, state) -> None:
        pass

    def chunk(self, state, num_updates: int, progress):
        global _SINK
        _SINK = progress
        try:
            state, metrics = self.compiled_chunk(num_updates)(self.place(state))
            return state, jax.device_get(metrics)
        finally:
            _SINK = None

    def evaluate(self, group, state, progress=None) -> dict:
        params, normalizer = self.placement.put(self.learner.policy_of(state), self._scored)
        with _reporting_to(progress):
            return jax.device_get(self._program("evaluate")(self.test_params, params, self.eval_keys(), normalizer))

    def chance(self, progress=None) -> dict:
        """The uniform random policy's test scores, over the seeds' evaluation keys."""
        with _reporting_to(progress):
            scores = jax.device_get(self._program("chance")(self.test_params, self.eval_keys()))
        return {name: float(np.mean(value)) for name, value in scores.items()}

    def data_manifest(self) -> dict:
        """The videos and photos in the env params (`natural.bank_manifests`), per split."""
        from jaxnat.natural import bank_manifests

        return {"train": bank_manifests(self.params), "test": bank_manifests(self.test_params)}

    def close(self) -> None:
        pass

    def may_serve(self, spec: RunSpec, compiler_options: dict | None) -> bool:
        """Whether `spec` differs from this backend's only in env params (kwargs that are not
        constructor arguments, e.g. `window` and `max_steps_in_episode`): then `reuse_for` may
        serve it with these programs."""
        differing = {name for name, _ in self.spec.env_kwargs.items() ^ spec.env_kwargs.items()}
        same_but_kwargs = dataclasses.replace(spec, env_kwargs=self.spec.env_kwargs).program_key() == \
            self.spec.program_key()
        return same_but_kwargs and compiler_options == self.compiler_options and \
            not differing & _structural_kwargs(spec.env_id)

    def reuse_for(self, spec: RunSpec, envs) -> DeviceBackend | None:
        """This backend's programs serving `spec` (one `may_serve` accepts) with its own envs'
        params (`make_envs(spec)`), when they have the same shapes and test-episode bound; else
        None."""
        _, params, _, test_params = envs
        if (_signature(params), _signature(test_params), int(test_params.max_steps_in_episode)) != (
                _signature(self.params), _signature(self.test_params), int(self.test_params.max_steps_in_episode)):
            return None
        other = copy.copy(self)  # shares the lowered and compiled programs (dicts, not copies)
        other.spec = spec
        other.params, other.test_params = self._place_params(params, test_params)
        return other


@contextlib.contextmanager
def _reporting_to(progress):
    """Evaluation programs run inside report their steps to `progress` (None: nowhere)."""
    global _EVAL_SINK
    _EVAL_SINK = progress
    try:
        yield
    finally:
        _EVAL_SINK = None


def _structural_kwargs(env_id: str) -> set[str]:
    """The make kwargs that change an env's program, not only its params: the entry point's
    constructor arguments and `jaxnat.make`'s own (e.g. `observation_noise`, which wraps the env)."""
    own = {name for name, p in inspect.signature(jaxnat.make).parameters.items() if p.kind is p.KEYWORD_ONLY}
    return own | set(constructor_parameters(env_id))


def _policy_and_keys(learner, runner, keys) -> tuple:
    """The evaluation program's arguments after the env params: `(params, keys, normalizer)`."""
    params, normalizer = learner.policy_of(runner)
    return params, keys, normalizer


def _unplaced(tree):
    """Shapes and dtypes of `tree` without their shardings (a program placing them its own way)."""
    return jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype), tree)


def _signature(tree):
    """A pytree's structure and its leaves' shapes and dtypes: what a compiled program accepts."""
    return jax.tree.structure(tree), [jax.typeof(x) for x in jax.tree.leaves(tree)]


_PROGRAMS: collections.OrderedDict = collections.OrderedDict()
# Three: the run training now, the next one compiled ahead (`command.prepare_programs`) and the one
# before, whose programs the next may reuse.
_CACHED_PROGRAMS = 3


def compiled_program(spec: RunSpec, compiler_options: dict | None = None, envs=None) -> DeviceBackend:
    """Build (or reuse, within this process) the compiled programs for `spec`: a run that
    differs from a cached one only in traced env params (a w/M sweep) reuses its programs.
    `envs`: `make_envs(spec)` when the caller built them already."""
    key = (spec.program_key(), tuple(sorted((compiler_options or {}).items())))
    if key not in _PROGRAMS:
        backend = None
        for cached in reversed(_PROGRAMS.values()):
            if backend is None and cached.may_serve(spec, compiler_options):
                envs = envs or make_envs(spec)  # built once, whether reused or not
                backend = cached.reuse_for(spec, envs)
        _PROGRAMS[key] = backend or DeviceBackend(spec, compiler_options, envs)
        while len(_PROGRAMS) > _CACHED_PROGRAMS:
            _PROGRAMS.popitem(last=False)
    _PROGRAMS.move_to_end(key)
    return _PROGRAMS[key]
