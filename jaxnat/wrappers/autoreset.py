"""`AutoResetWrapper`: start a new episode inside `step` when the current one ends."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxnat.gating import compact_sizes, put_rows, switch_rows, take_rows
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

    An env with `gated_autoreset` (PixelMuJoCo) computes its resets for the rows of the batch
    that need them. Under `vmap` the step is one `lax.switch` on an unbatched branch
    (`jaxnat.gating`; nested `vmap`s decide per inner batch, the branch for all of them):

    - no env of the batch ended: nothing is reset; the step's observation is rendered once and
      is also `final_observation`;
    - at most `ceil(share * batch)` ended, for the smallest share of `reset_share` that holds
      them: only that many rows are reset (the ended ones gathered, reset, scattered back); the
      batch is rendered once from the result, and `final_observation` renders the stepped frame
      of those rows only;
    - more ended: every env computes the reset and the final frame, as a select.

    The outputs are the same in every branch (a test compares them bit for bit). `reset_share`
    (default the tiers 1/8 and 3/8) sets the compacted branches' sizes: a step computes the rows
    of its tier, padding included, and one past the largest falls to the select. An untrained
    Hopper ends about a quarter of a batch every step, a learning one far fewer, and a batch of
    robots that only truncate ends together, which the select serves. `reset_share=None` has
    no compacted branch (every env computes the reset in a step where any ended).
    """

    def __init__(self, env, reset_share: float | tuple[float, ...] | None = (0.125, 0.375)):
        super().__init__(env)
        compact_sizes(reset_share, 1)  # a one-line error for a share out of range
        self.reset_share = reset_share

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
        """`(next_obs, next_state, final_observation)` of one env, whose `vmap` rule computes
        the resets and final frames of the ended rows only (the class docstring). Each branch
        renders from the state it returns (the inner step's own frame is dead code to XLA)."""
        env, share = self._env, self.reset_share

        def one(done, stepped, key_reset, params):  # one env; under vmap, the select
            fresh = jax.lax.cond(done, lambda: env.reset(key_reset, params)[1], lambda: stepped)
            next_obs, next_state = env.observe(fresh, params)
            final = jax.lax.cond(done, lambda: env.observe(stepped, params)[0], lambda: next_obs)
            return next_obs, next_state, final

        gated = jax.custom_batching.custom_vmap(one)

        @gated.def_vmap
        def _rule(axis_size, in_batched, done, stepped, key_reset, params):
            done_b, stepped_b, key_b, params_b = in_batched
            done, stepped, key_reset = (
                jax.tree.map(lambda x, b: x if b else jnp.broadcast_to(x, (axis_size, *jnp.shape(x))), t, tb)
                for t, tb in ((done, done_b), (stepped, stepped_b), (key_reset, key_b)))
            p_axes = jax.tree.map(lambda b: 0 if b else None, params_b)
            observe = jax.vmap(env.observe, in_axes=(0, p_axes))
            sizes = compact_sizes(share, axis_size)

            def none_ended():
                next_obs, next_state = observe(stepped, params)
                return next_obs, next_state, next_obs

            def few_ended(rows):
                p_rows = jax.tree.map(lambda x, b: take_rows(x, rows) if b else x, params, params_b)
                _, fresh = jax.vmap(env.reset, in_axes=(0, p_axes))(take_rows(key_reset, rows), p_rows)
                next_obs, next_state = observe(put_rows(stepped, rows, fresh), params)
                final = observe(take_rows(stepped, rows), p_rows)[0]
                return next_obs, next_state, put_rows(next_obs, rows, final)

            def many_ended():
                return jax.vmap(one, in_axes=(0, 0, 0, p_axes))(done, stepped, key_reset, params)

            out = switch_rows(done, sizes, none_ended, few_ended, many_ended)
            return out, jax.tree.map(lambda _: True, out)

        return gated(done, stepped, key_reset, params)
