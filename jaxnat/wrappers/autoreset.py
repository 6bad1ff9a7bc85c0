"""`AutoResetWrapper`: start a new episode inside `step` when the current one ends."""

from __future__ import annotations

import jax
import jax.numpy as jnp

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

    An env with `gated_autoreset` (PixelMuJoCo) also gets one `lax.cond` on whether any env of
    the batch ended (`any_in_batch`: a predicate that stays one value under `vmap`, nested
    too): in a step where none did, no env computes the reset, and `final_observation` is the
    step's observation itself, rendered once; in a step where one did, every env computes both
    as above. The outputs are the same either way.
    """

    def step(self, key, state, action, params=None):
        if params is None:
            params = self.default_params
        key_step, key_reset = jax.random.split(key)
        obs, stepped, reward, terminated, truncated, info = self._env.step(
            key_step, state, action, params
        )
        done = terminated | truncated
        if self._env.has_state_observation and self._env.gated_autoreset:
            next_obs, next_state, final = self._gated(done, stepped, key_reset, params)
            return next_obs, next_state, reward, terminated, truncated, {**info, "final_observation": final}
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

    def _gated(self, done, stepped, key_reset, params):
        """`(next_obs, next_state, final_observation)` with the reset and the stepped frame
        behind `any_in_batch(done)`; each branch renders from the state it returns (the inner
        step's own frame is then dead code to XLA)."""
        env = self._env

        def some_ended():
            fresh = jax.lax.cond(done, lambda: env.reset(key_reset, params)[1], lambda: stepped)
            next_obs, next_state = env.observe(fresh, params)
            final = jax.lax.cond(done, lambda: env.observe(stepped, params)[0], lambda: next_obs)
            return next_obs, next_state, final

        def none_ended():
            next_obs, next_state = env.observe(stepped, params)
            return next_obs, next_state, next_obs

        return jax.lax.cond(any_in_batch(done), some_ended, none_ended)


@jax.custom_batching.custom_vmap
def any_in_batch(flag):
    """`flag` (a scalar bool) itself; under `vmap`, whether it is true for any env of the batch,
    as one unbatched value (nested `vmap`s reduce each axis), so a `lax.cond` on it stays a
    conditional instead of becoming a select that computes both branches for every env."""
    return flag


@any_in_batch.def_vmap
def _any_in_batch_rule(axis_size, in_batched, flag):
    (batched,) = in_batched
    return any_in_batch(jnp.any(flag) if batched else flag), False
