"""Registry of environment ids (`Namespace/Name-vN`) -> lazy entry points.

Entry points are `"module:attr"` strings, imported only when `make` is called, so optional
dependencies (mujoco, ale-py) load only for the envs that need them. Keyword arguments passed to
`make` go to the env's constructor when it names them, and otherwise replace fields of its
default params; anything else is an error that names the argument and lists the valid ones.
"""

from __future__ import annotations

import dataclasses
import difflib
import importlib
import inspect
from typing import Any, Callable

__all__ = [
    "EnvSpec",
    "UnknownEnvError",
    "MissingDependencyError",
    "register",
    "registered_envs",
    "spec",
    "close_matches",
    "constructor_parameters",
    "make",
    "make_vec",
]


class UnknownEnvError(KeyError):
    """An id that is not registered. The message lists the closest registered ids."""

    def __str__(self) -> str:  # KeyError would repr() the message
        return str(self.args[0])


class MissingDependencyError(ImportError):
    """An env needs an optional dependency that is not installed."""


@dataclasses.dataclass(frozen=True)
class EnvSpec:
    """What `make` needs to build an env.

    Attributes:
        id: `Namespace/Name-vN`.
        entry_point: `"module:attr"` (imported lazily) or a callable returning an `Environment`.
        kwargs: defaults passed to the entry point and/or params, overridable in `make`.
        extra: the pip extra that provides this env's optional dependencies, if any.
        batched: the entry point builds a whole batch itself (`num_envs=` argument; host
            emulators such as Atari): only `make_vec` builds it.
    """

    id: str
    entry_point: str | Callable[..., Any]
    kwargs: dict = dataclasses.field(default_factory=dict)
    extra: str | None = None
    batched: bool = False


_REGISTRY: dict[str, EnvSpec] = {}


def register(
    id: str,
    entry_point: str | Callable[..., Any],
    *,
    extra: str | None = None,
    batched: bool = False,
    **kwargs: Any,
) -> None:
    """Register `id`. Re-registering an id replaces it (useful in notebooks)."""
    namespace, _, rest = id.partition("/")
    if not namespace or not rest or "-v" not in rest:
        raise ValueError(f"Env ids look like 'Namespace/Name-v0', got {id!r}")
    _REGISTRY[id] = EnvSpec(
        id=id, entry_point=entry_point, kwargs=dict(kwargs), extra=extra, batched=batched
    )


def registered_envs() -> tuple[str, ...]:
    """All registered ids, sorted."""
    return tuple(sorted(_REGISTRY))


def close_matches(name: str, names) -> list[str]:
    """Up to ten of `names` closest to a mistyped `name`, as spelled and then ignoring case,
    without repeats (for "Did you mean" hints)."""
    names = list(names)
    folded = {n.lower(): n for n in names}
    close = difflib.get_close_matches(name, names, n=5, cutoff=0.5)
    close += [folded[m] for m in difflib.get_close_matches(name.lower(), folded, n=5, cutoff=0.5)]
    return list(dict.fromkeys(close))


def spec(id: str) -> EnvSpec:
    """The `EnvSpec` of `id`; unknown ids raise `UnknownEnvError` with the closest matches."""
    try:
        return _REGISTRY[id]
    except KeyError:
        pass
    ids = registered_envs()
    close = close_matches(id, ids)
    hint = f" Did you mean: {', '.join(close)}?" if close else ""
    raise UnknownEnvError(
        f"No env registered as {id!r}.{hint} See jaxnat.registered_envs() for all "
        f"{len(ids)} ids."
    )


def _load_entry_point(env_spec: EnvSpec) -> Callable[..., Any]:
    entry = env_spec.entry_point
    if callable(entry):
        return entry
    module_name, _, attr = entry.partition(":")
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as err:
        if err.name and err.name.partition(".")[0] != "jaxnat":  # else: a bug, not a missing extra
            fix = (
                f"pip install 'jaxnat[{env_spec.extra}]'"
                if env_spec.extra
                else f"pip install {err.name}"
            )
            raise MissingDependencyError(
                f"{env_spec.id} needs the package {err.name!r}, which is not installed. "
                f"Fix: {fix}"
            ) from err
        raise
    return getattr(module, attr)


def _entry_parameters(entry: Callable[..., Any]) -> dict[str, inspect.Parameter]:
    target = entry.__init__ if inspect.isclass(entry) else entry
    return {name: p for name, p in inspect.signature(target).parameters.items()
            if name not in ("self", "args", "kwargs")}


def constructor_parameters(id: str) -> dict[str, inspect.Parameter]:
    """The parameters of `id`'s entry point (a class's `__init__`) by name, without `self`,
    `*args` and `**kwargs`: the keyword arguments `make` passes to the constructor rather than
    to the params. Imports the entry point: an unknown id raises `UnknownEnvError`, a missing
    optional dependency `MissingDependencyError`."""
    return _entry_parameters(_load_entry_point(spec(id)))


def _split_kwargs(entry: Callable[..., Any], kwargs: dict, env_id: str) -> tuple[dict, dict]:
    """Split kwargs into constructor kwargs and params overrides, rejecting unknown names."""
    ctor_names = set(_entry_parameters(entry))
    params_type = getattr(entry, "params_type", None)
    param_names = {f.name for f in dataclasses.fields(params_type)} if params_type else set()
    ctor = {k: v for k, v in kwargs.items() if k in ctor_names}
    params = {k: v for k, v in kwargs.items() if k not in ctor_names and k in param_names}
    unknown = sorted(set(kwargs) - set(ctor) - set(params))
    if unknown:
        valid = sorted(ctor_names | param_names)
        raise TypeError(
            f"{env_id} got unknown keyword argument(s) {unknown}. Valid: {valid}."
        )
    return ctor, params


def _check_param_types(env_id: str, params, values: dict) -> None:
    """Params given to `make` are numbers (or numeric arrays) of their field's kind: an int
    field takes a whole number, not a string or 5.5 (JAX would fail later, far from the cause)."""
    import jax
    import numpy as np

    for name, value in values.items():
        default = getattr(params, name)
        kind = np.asarray(value).dtype if isinstance(value, (np.ndarray, np.generic, jax.Array)) else type(value)
        numeric = (isinstance(value, (bool, int, float, np.generic, np.ndarray, jax.Array))
                   and np.issubdtype(kind, np.number) | np.issubdtype(kind, np.bool_))
        if not numeric:
            raise TypeError(f"{env_id}: {name}={value!r} must be a number (a traced param), got {type(value).__name__}")
        wants_int = isinstance(default, (int, np.integer)) and not isinstance(default, bool)
        if wants_int and not float(np.asarray(value)).is_integer():
            raise TypeError(f"{env_id}: {name}={value!r} must be a whole number")


def make(id: str, *, autoreset: bool = True, observation_noise: bool | str = False, **kwargs: Any):
    """Build a registered env: `env, params = jaxnat.make("Classify/MNIST-v0", w=5)`.

    Args:
        id: a registered id (see `registered_envs()`).
        autoreset: wrap in `AutoResetWrapper` (a fresh reset inside `step` when an episode
            ends, the final observation in `info["final_observation"]`), as gymnax users
            expect. `False` returns the raw env.
        observation_noise: the paper's noise control: every observation (the final one in
            `info` too) replaced by Gaussian noise of the same shape and dtype
            (`NoiseObservationWrapper`, composed inside the autoreset so no real frame leaks).
            True: the default pixel-noise law (`jaxnat.natural.DEFAULT_NOISE`, the authors');
            a name in `jaxnat.natural.NOISE_LAWS` (`"authors"`, `"centred"`): that law.
        **kwargs: constructor arguments (static: dataset, split, shapes) or params fields
            (traced: window size, time limit, rewards), by name.

    Returns:
        `(env, params)`.
    """
    env_spec = spec(id)
    if env_spec.batched:
        raise TypeError(
            f"{id} is emulated in batches on the host: build it with "
            f"jaxnat.make_vec({id!r}, num_envs, ...)."
        )
    entry = _load_entry_point(env_spec)
    ctor_kwargs, param_kwargs = _split_kwargs(entry, {**env_spec.kwargs, **kwargs}, id)
    env = entry(**ctor_kwargs)
    params = env.default_params
    if param_kwargs:
        _check_param_types(id, params, param_kwargs)
        params = params.replace(**param_kwargs)
    try:
        env.check_params(params)
    except ValueError as err:
        raise ValueError(f"{id}: {err}") from None
    if observation_noise:
        from jaxnat.wrappers import NoiseObservationWrapper

        env = (NoiseObservationWrapper(env, noise=observation_noise)
               if isinstance(observation_noise, str) else NoiseObservationWrapper(env))
    if autoreset:
        from jaxnat.wrappers import AutoResetWrapper

        env = AutoResetWrapper(env)
    return env, params


def make_vec(id: str, num_envs: int, *, autoreset: bool = True, devices=None, **kwargs: Any):
    """Build `num_envs` copies of an env behind one batched interface: one env object.

    Pure-JAX envs come back as a `VmapWrapper` (one key in, `num_envs` envs out) whose
    `default_params` are the params `make` built with these kwargs, so `vec.reset(key)` and
    `vec.step(key, state, actions)` need no params (pass others to override them). Envs
    registered with `batched=True` (host emulators: `NaturalAtari/*`) come back as their entry
    point built with `num_envs`: a `jaxnat.core.HostBatchedEnv`, with numpy
    `reset(seed=)`/`step(actions)` that autoreset themselves (`autoreset` does not apply).

    `devices` (pure-JAX envs): a count, "all" or a list of devices; the batch is split over a
    1-D mesh of them (`VmapWrapper`: each device steps its share, the same envs as unsharded).
    `num_envs` must divide evenly. Host-batched envs refuse it: they run on the host's cores,
    one batch per process (with several hosts, each process builds its own).
    """
    from jaxnat.wrappers import VmapWrapper

    env_spec = spec(id)
    if env_spec.batched:
        if devices is not None:
            raise TypeError(f"{id} is emulated on the host, not on devices: leave devices= out (with several "
                            "hosts, each process builds its own batch)")
        if kwargs.get("observation_noise"):
            raise TypeError(f"observation_noise is the noise control of pure-JAX envs; {id}'s is "
                            "background='noise' (the game's pixels over Gaussian noise)")
        entry = _load_entry_point(env_spec)
        ctor_kwargs, _ = _split_kwargs(entry, {**env_spec.kwargs, **kwargs}, id)
        return entry(num_envs=num_envs, **ctor_kwargs)

    env, params = make(id, autoreset=autoreset, **kwargs)  # (observation_noise too)
    return VmapWrapper(env, num_envs, params, devices=devices)
