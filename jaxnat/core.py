"""The environment contract: `Environment`, `EnvState`, `EnvParams`.

jaxnat follows gymnax 1.0's functional API::

    obs, state = env.reset(key, params)
    obs, state, reward, terminated, truncated, info = env.step(key, state, action, params)

Implementers write `reset_env`, `step_env`, `default_params`, `observation_space(params)` and
`action_space(params)`. The public `reset`/`step` own the step counter: `step` increments
`state.time` after `step_env` and sets `truncated = time >= params.max_steps_in_episode` unless
the step terminated, so a time limit is never reported as termination. States and params are
`flax.struct.dataclass`es; params are traced (vmappable), shapes are constructor arguments.

Envs whose observation is a function of the state alone also implement
`get_obs(state, params)`. `AutoResetWrapper` then selects between the stepped and the fresh state
first and renders one observation, instead of computing two and selecting: for a rendered env
under `vmap` that halves the work of every step.

`step` checks the action's shape and dtype against `action_space(params)` while tracing, so a
wrong action fails once, at trace time, with a readable message.

Host-batched envs (`NaturalAtari/*`: the emulator runs in C++ on the host) cannot be pure JAX
functions; they follow `HostBatchedEnv`, the batched numpy API of Gymnasium's vector envs with
same-step autoreset, and are registered with `batched=True`. `jaxnat.make_vec` returns one env
object for both kinds: a `VmapWrapper` (this contract, batched) or a `HostBatchedEnv`.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable, Generic, Protocol, TypeVar, runtime_checkable

import jax
import jax.numpy as jnp
from flax import struct

from jaxnat import spaces

__all__ = ["Environment", "EnvState", "EnvParams", "HostBatchedEnv", "is_concrete", "sweep_distraction"]


def is_concrete(value) -> bool:
    """Whether `value` is known now (a number or an array), not a tracer inside jit or vmap."""
    return not isinstance(value, jax.core.Tracer)


def sweep_distraction(params, values: dict, check: Callable[[dict], None]):
    """`(params, in_axes)` for `jax.vmap` over a strength axis: `params` (with a `distraction`
    group, a dataclass of traced strengths) with the named fields of that group replaced by
    arrays of one leading length, and the `in_axes` prefix that is 0 on those fields and None
    everywhere else (the data stays shared, not copied per strength). `check(arrays)` refuses
    concrete values out of range. Unknown names, none, or arrays of other lengths are one-line
    `ValueError`s. The envs' `params.sweep(**values)`."""
    group = type(params.distraction)
    names = [f.name for f in dataclasses.fields(group)]
    unknown = sorted(set(values) - set(names))
    if unknown or not values:
        raise ValueError(f"sweep takes Distraction fields {names}, got {sorted(values)}")
    arrays = {k: jnp.asarray(v) for k, v in values.items()}
    lengths = {k: (a.shape[0] if a.ndim else None) for k, a in arrays.items()}
    if None in lengths.values() or len(set(lengths.values())) != 1:
        raise ValueError(f"sweep needs arrays of one leading length, got lengths {lengths}")
    check(arrays)
    axes = jax.tree.map(lambda _: None, params)
    axes = axes.replace(distraction=group(**{k: (0 if k in values else None) for k in names}))
    return params.replace(distraction=params.distraction.replace(**arrays)), axes


@struct.dataclass
class EnvState:
    """Base of every env state: `time` counts steps taken in the episode (int32)."""

    time: jax.Array


@struct.dataclass
class EnvParams:
    """Base of every env's params: the time limit after which `truncated` is set."""

    max_steps_in_episode: int = 1000


TState = TypeVar("TState", bound=EnvState)
TParams = TypeVar("TParams", bound=EnvParams)


class Environment(Generic[TState, TParams]):
    """A pure, jittable environment. Nothing on `self` changes after construction."""

    @property
    def default_params(self) -> TParams:
        raise NotImplementedError

    @property
    def name(self) -> str:
        return type(self).__name__

    @property
    def unwrapped(self) -> "Environment":
        """The innermost env (itself here; wrappers return what they wrap, all the way in)."""
        return self

    def reset_env(self, key: jax.Array, params: TParams) -> tuple[Any, TState]:
        """Return `(obs, state)` with `state.time == 0`."""
        raise NotImplementedError

    def step_env(
        self, key: jax.Array, state: TState, action: Any, params: TParams
    ) -> tuple[Any, TState, jax.Array, jax.Array, dict]:
        """Return `(obs, state, reward, terminated, info)`; `time` is advanced by `step`."""
        raise NotImplementedError

    def get_obs(self, state: TState, params: TParams) -> Any:
        """The observation of `state`. Optional: implement it when the observation depends on
        the state (and params) alone; `has_state_observation` then reports True."""
        raise NotImplementedError

    def observe(self, state: TState, params: TParams) -> tuple[Any, TState]:
        """`(get_obs(state, params), state)` by default. An env whose observation must also be
        written into the state (a frame stack holding the newest rendered frame) overrides it
        to return the state with that written; `AutoResetWrapper` calls it once, after its
        select, so the select carries no observation and a batched step renders one."""
        return self.get_obs(state, params), state

    # `AutoResetWrapper` computes this env's reset, and the final observation of an ended
    # episode, for the envs of the (vmapped) batch that ended alone, behind one `lax.switch`
    # (`jaxnat.gating`): for an env whose reset and observation are costly (a render) and whose
    # episodes rarely end in the same step as others; otherwise every env of a batch computes
    # them every step.
    gated_autoreset: bool = False

    @property
    def has_state_observation(self) -> bool:
        """True when `get_obs(state, params)` is implemented (observation = f(state))."""
        return type(self).get_obs is not Environment.get_obs

    def check_params(self, params: TParams) -> None:
        """Raise `ValueError` for params out of range; `jaxnat.make` calls it on the params it
        builds (under jit a traced value cannot be checked). Envs with more params extend it."""
        limit = params.max_steps_in_episode
        if is_concrete(limit) and int(limit) < 1:
            raise ValueError(f"max_steps_in_episode (M) must be at least 1, got {limit}")

    def observation_space(self, params: TParams) -> spaces.Space:
        raise NotImplementedError

    def action_space(self, params: TParams) -> spaces.Space:
        raise NotImplementedError

    def reset(self, key: jax.Array, params: TParams | None = None) -> tuple[Any, TState]:
        if params is None:
            params = self.default_params
        return self.reset_env(key, params)

    def step(
        self, key: jax.Array, state: TState, action: Any, params: TParams | None = None
    ) -> tuple[Any, TState, jax.Array, jax.Array, jax.Array, dict]:
        if params is None:
            params = self.default_params
        self.action_space(params).check(action, "action")
        obs, state, reward, terminated, info = self.step_env(key, state, action, params)
        time = state.time + 1
        state = state.replace(time=time)
        terminated = jnp.asarray(terminated, dtype=jnp.bool_)
        truncated = (time >= params.max_steps_in_episode) & ~terminated
        return obs, state, jnp.asarray(reward, jnp.float32), terminated, truncated, info

    def __repr__(self) -> str:
        return f"<{self.name}>"


@runtime_checkable
class HostBatchedEnv(Protocol):
    """The contract of a host-batched env: `num_envs` envs stepped together on the host.

        obs, info = env.reset(seed=0)                       # numpy, leading axis num_envs
        obs, reward, terminated, truncated, info = env.step(actions)

    Same-step autoreset: the step that ends an env's episode returns the next episode's first
    observation, with the episode's last one in `info["final_observation"]` (the agents
    bootstrap a truncated episode from it). `info` also carries PureJaxRL's episode keys
    (`returned_episode`, `returned_episode_returns`, `returned_episode_lengths`), per env.
    Spaces are those of one env (`single_observation_space`, `single_action_space`, jaxnat
    spaces). `close()` frees the host resources (emulators, decoder threads). To train seeds
    side by side on one batch (`jaxnat train --host-seeds together`) an env also takes
    `reset(seeds=[...])`: the batch as equal groups, each reset as a batch of its own
    (`NaturalAtariVecEnv` does).
    """

    num_envs: int
    single_observation_space: spaces.Space
    single_action_space: spaces.Space

    def reset(self, *, seed: int | None = None) -> tuple[Any, dict]: ...

    def step(self, actions) -> tuple[Any, Any, Any, Any, dict]: ...

    def close(self) -> None: ...
