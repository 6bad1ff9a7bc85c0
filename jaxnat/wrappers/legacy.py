"""`LegacyStepAPIWrapper`: the five-value step of gymnax 0.x, PureJaxRL and rejax."""

from __future__ import annotations

from jaxnat.wrappers.base import Wrapper


class LegacyStepAPIWrapper(Wrapper):
    """`step -> (obs, state, reward, done, info)` with `done = terminated | truncated`.

    `info["terminated"]` and `info["truncated"]` keep the distinction for code that wants to
    bootstrap correctly at time limits.
    """

    def step(self, key, state, action, params=None):
        obs, state, reward, terminated, truncated, info = self._env.step(
            key, state, action, params
        )
        info = {**info, "terminated": terminated, "truncated": truncated}
        return obs, state, reward, terminated | truncated, info
