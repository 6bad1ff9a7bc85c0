"""`AutoResetWrapper`: start a new episode inside `step` when the current one ends."""

from __future__ import annotations

import jax

from jaxnat.wrappers.base import Wrapper


class AutoResetWrapper(Wrapper):
    """On `terminated | truncated`, return the first observation of a fresh episode.

    The step's reward, `terminated` and `truncated` describe the transition that ended the
    episode; its last observation is in `info["final_observation"]` (so a learner can bootstrap
    from it on truncation). The reset sits behind `lax.cond`: unbatched, it runs only when the
    episode ended; under `vmap` the cond becomes a select, the cheapest batched form.
    Every reset draws a new initial state from the key (no cached first state).
    """

    def step(self, key, state, action, params=None):
        if params is None:
            params = self.default_params
        key_step, key_reset = jax.random.split(key)
        obs, state, reward, terminated, truncated, info = self._env.step(
            key_step, state, action, params
        )
        done = terminated | truncated

        def reset(_):
            return self._env.reset(key_reset, params)

        def keep(_):
            return obs, state

        next_obs, next_state = jax.lax.cond(done, reset, keep, None)
        info = {**info, "final_observation": obs}
        return next_obs, next_state, reward, terminated, truncated, info
