"""`Wrapper`: an `Environment` around another one, delegating what it does not override."""

from __future__ import annotations

from typing import Any

from jaxnat.core import Environment


class Wrapper(Environment):
    """Delegates `reset`/`step`, spaces and params to the wrapped env.

    Subclasses override `reset` and `step` (the public API: wrappers see the step counter and
    `truncated` already computed by the inner env). Wrappers that keep state of their own hold
    the inner state in an `env_state` field.
    """

    def __init__(self, env: Environment):
        self._env = env

    @property
    def unwrapped(self) -> Environment:
        env = self._env
        while isinstance(env, Wrapper):
            env = env._env
        return env

    @property
    def default_params(self):
        return self._env.default_params

    @property
    def name(self) -> str:
        return self._env.name

    def observation_space(self, params):
        return self._env.observation_space(params)

    def action_space(self, params):
        return self._env.action_space(params)

    def reset(self, key, params=None):
        return self._env.reset(key, params)

    def step(self, key, state, action, params=None):
        return self._env.step(key, state, action, params)

    def __getattr__(self, name: str) -> Any:
        # Only reached for attributes not found normally: forward to the inner env.
        if name == "_env":
            raise AttributeError(name)
        return getattr(self._env, name)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self._env!r})"
