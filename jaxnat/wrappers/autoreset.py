"""`AutoResetWrapper`: start a new episode inside `step` when the current one ends."""

from __future__ import annotations

import jax

from jaxnat.wrappers.base import Wrapper


class AutoResetWrapper(Wrapper):
    """On `terminated | truncated`, return the first observation of a fresh episode.

    The step's reward, `terminated` and `truncated` describe the transition that ended the
    episode; its last observation is in `info["final_observation"]` (so a learner can bootstrap
    from it on truncation). Every reset draws a new initial state from the key (no cached
    first state).

    The reset sits behind `lax.cond`: unbatched, it runs only when the episode ended; under
    `vmap` the cond becomes a select. When the inner env renders its observation from the state
    alone (`has_state_observation`), the select is over states and one observation is rendered
    from the result (`observe`, which may also write it into the state), so a batched step
    renders once, not twice; `final_observation` is then computed only if the caller uses it
    (XLA drops it otherwise).
    """

    def step(self, key, state, action, params=None):
        if params is None:
            params = self.default_params
        key_step, key_reset = jax.random.split(key)
        obs, stepped, reward, terminated, truncated, info = self._env.step(
            key_step, state, action, params
        )
        done = terminated | truncated
        info = {**info, "final_observation": obs}

        if self._env.has_state_observation:
            next_state = jax.lax.cond(
                done, lambda: self._env.reset(key_reset, params)[1], lambda: stepped
            )
            next_obs, next_state = self._env.observe(next_state, params)
        else:
            next_obs, next_state = jax.lax.cond(
                done, lambda: self._env.reset(key_reset, params), lambda: (obs, stepped)
            )
        return next_obs, next_state, reward, terminated, truncated, info
