"""`GymnasiumVectorEnv`: a batch of jaxnat envs as a `gymnasium.vector.VectorEnv`.

    vec = jaxnat.compat.make_gymnasium_vec("Classify/Digits-v0", num_envs=8, seed=0)
    obs, info = vec.reset()
    obs, rewards, terminations, truncations, info = vec.step(vec.action_space.sample())
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

try:
    from gymnasium.vector import AutoresetMode, VectorEnv
    from gymnasium.vector.utils import batch_space
except ImportError as err:  # pragma: no cover - exercised only without the extra
    raise ImportError(
        "jaxnat.compat needs gymnasium>=1.1: pip install 'jaxnat[gym]'"
    ) from err

from jaxnat import spaces
from jaxnat.core import Environment
from jaxnat.registration import make, spec
from jaxnat.wrappers import AutoResetWrapper, VmapWrapper, Wrapper

__all__ = ["GymnasiumVectorEnv", "make_gymnasium_vec"]


class GymnasiumVectorEnv(VectorEnv):
    """`num_envs` copies of a jaxnat env behind Gymnasium's vector API (`AutoresetMode.NEXT_STEP`).

    Autoreset follows Gymnasium's `SyncVectorEnv` in next-step mode: when sub-env `i` ends
    (`terminated | truncated`) at one `step`, the next `step` ignores action `i`, resets env `i`
    and returns its first observation with reward 0 and both flags False. The final observation
    is the one returned with the ending flags; nothing is put in `info` for it. `reset()`
    restarts every env; `reset(options={"reset_mask": mask})` restarts only the envs where the
    bool `(num_envs,)` mask is True (Gymnasium's partial reset, as `SyncVectorEnv` does): their
    pending autoreset is cancelled, and the other envs keep their state and observation. That
    lets a same-step-autoreset consumer (e.g. a Stable-Baselines3 `VecEnv` shim) reset the envs
    that just ended without a wasted step.

    Dtypes: observations are writable numpy arrays (dicts of arrays for `Dict` spaces) in the
    env's own dtype, with a leading `num_envs` axis; rewards are float64, terminations and
    truncations bool, all of shape `(num_envs,)`. Actions are numpy arrays of shape
    `(num_envs, *single_action_space.shape)`, cast to the env's action dtype. `info` holds the
    env's step info in Gymnasium's vector layout (`info[k]`, mask `info["_k"]`, False for envs
    that reset this step); `{}` for envs without info.

    Each `step` is one call of one jitted function (the masked reset and the vmapped step),
    compiled once. Randomness comes from one JAX key, seeded by `seed` and by `reset(seed=...)`.

    Args:
        env: a raw jaxnat env (`jaxnat.make(id, autoreset=False)`). An outermost
            `AutoResetWrapper` is stripped, since this class autoresets itself; an
            `AutoResetWrapper` or `VmapWrapper` further in raises `ValueError`.
        params: env params (default: `env.default_params`), shared by all envs.
        num_envs: batch size.
        seed: seed of the initial key.
    """

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": []}

    def __init__(self, env: Environment, params=None, num_envs: int = 8, seed: int = 0):
        if isinstance(env, AutoResetWrapper):
            env = env._env
        inner = env
        while isinstance(inner, Wrapper):
            if isinstance(inner, (AutoResetWrapper, VmapWrapper)):
                raise ValueError(
                    f"GymnasiumVectorEnv batches and autoresets envs itself; pass {env!r} "
                    f"without its {type(inner).__name__} (e.g. jaxnat.make(id, autoreset=False))."
                )
            inner = inner._env
        if int(num_envs) < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        self.jax_env = env
        self.num_envs = int(num_envs)
        self.params = jax.device_put(env.default_params if params is None else params)
        self._action_space = env.action_space(self.params)
        self.single_observation_space = env.observation_space(self.params).to_gymnasium()
        self.single_action_space = self._action_space.to_gymnasium()
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._key = jax.random.key(seed)
        self._obs = self._state = self._autoreset = None  # set by reset()
        self._reset_fn = jax.jit(self._reset_all)
        self._reset_some_fn = jax.jit(self._reset_some)
        self._step_fn = jax.jit(self._step_all)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Reset every env, or those where `options["reset_mask"]` is True; `seed` re-seeds the
        key. Returns `(obs, {})`."""
        options = dict(options or {})
        mask = options.pop("reset_mask", None)
        if options:
            raise ValueError(f"jaxnat envs take no reset options but 'reset_mask', got {sorted(options)}")
        super().reset(seed=seed)
        if seed is not None:
            self._key = jax.random.key(seed)
        if mask is None:
            self._key, self._obs, self._state = self._reset_fn(self._key, self.params)
            self._autoreset = jnp.zeros(self.num_envs, jnp.bool_)
        else:
            mask = self._check_reset_mask(mask)
            self._key, self._obs, self._state = self._reset_some_fn(
                self._key, self._obs, self._state, mask, self.params
            )
            self._autoreset = self._autoreset & ~mask
        return _to_numpy(self._obs), {}

    def step(self, actions):
        """Step every env (resetting those that ended at the previous step); numpy in and out."""
        if self._state is None:
            raise RuntimeError("Call reset() before step().")
        actions = _cast_actions(actions, self._action_space, self.num_envs, "actions")
        reset = self._autoreset
        self._key, self._obs, self._state, reward, terminated, truncated, info, self._autoreset = (
            self._step_fn(self._key, self._state, actions, reset, self.params)
        )
        info = _vector_info(info, ~np.asarray(reset)) if info else {}
        return (
            _to_numpy(self._obs),
            np.asarray(reward, np.float64),
            np.array(terminated),
            np.array(truncated),
            info,
        )

    def __repr__(self) -> str:
        return f"GymnasiumVectorEnv({self.jax_env.name}, num_envs={self.num_envs})"

    def _reset_all(self, key, params):
        key, sub = jax.random.split(key)
        keys = jax.random.split(sub, self.num_envs)
        obs, state = jax.vmap(self.jax_env.reset, in_axes=(0, None))(keys, params)
        return key, obs, state

    def _check_reset_mask(self, mask) -> np.ndarray:
        if self._state is None:
            raise RuntimeError("Call reset() before a partial reset (options={'reset_mask': ...}).")
        if not isinstance(mask, np.ndarray) or mask.dtype != np.bool_ or mask.shape != (self.num_envs,):
            raise ValueError(
                f"options['reset_mask'] must be a bool numpy array of shape ({self.num_envs},), got "
                f"{type(mask).__name__} {getattr(mask, 'dtype', '')} {getattr(mask, 'shape', '')}"
            )
        return mask

    def _reset_some(self, key, obs, state, mask, params):
        key, fresh_obs, fresh = self._reset_all(key, params)

        def pick(new, old):
            return jax.vmap(lambda m, n, o: jax.tree.map(lambda a, b: jnp.where(m, a, b), n, o))(mask, new, old)

        return key, pick(fresh_obs, obs), pick(fresh, state)

    def _step_all(self, key, state, actions, autoreset, params):
        key, sub = jax.random.split(key)
        keys = jax.random.split(sub, self.num_envs)
        obs, state, reward, terminated, truncated, info = jax.vmap(
            self._step_one, in_axes=(0, 0, 0, 0, None)
        )(keys, state, actions, autoreset, params)
        return key, obs, state, reward, terminated, truncated, info, terminated | truncated

    def _step_one(self, key, state, action, reset, params):
        """Env `i`'s next-step transition: a fresh episode if `reset`, else `env.step`."""
        key_step, key_reset = jax.random.split(key)
        obs, stepped, reward, terminated, truncated, info = self.jax_env.step(
            key_step, state, action, params
        )
        fresh_obs, fresh = self.jax_env.reset(key_reset, params)

        def pick(new, old):
            return jax.tree.map(lambda a, b: jnp.where(reset, a, b), new, old)

        state = pick(fresh, stepped)
        # Observations that are a function of the state are rendered once, from the result
        # (`observe`, as AutoResetWrapper: it may also write the frame into the state).
        if self.jax_env.has_state_observation:
            obs, state = self.jax_env.observe(state, params)
        else:
            obs = pick(fresh_obs, obs)
        reward = jnp.where(reset, 0.0, reward)
        return obs, state, reward, terminated & ~reset, truncated & ~reset, info


def make_gymnasium_vec(env_id: str, num_envs: int, seed: int = 0, **kwargs: Any):
    """`GymnasiumVectorEnv` of `jaxnat.make(env_id, autoreset=False, **kwargs)`; host-batched
    envs (`NaturalAtari/*`) get their own adapter (`jaxnat.atari.gymnasium`)."""
    if spec(env_id).batched:
        from jaxnat.atari.gymnasium import AtariGymnasiumVectorEnv

        return AtariGymnasiumVectorEnv(num_envs=num_envs, seed=seed, **{**spec(env_id).kwargs, **kwargs})
    env, params = make(env_id, autoreset=False, **kwargs)
    return GymnasiumVectorEnv(env, params, num_envs=num_envs, seed=seed)


def _to_numpy(tree):
    """Device arrays -> writable numpy arrays (same tree)."""
    return jax.tree.map(np.array, tree)


def _cast_actions(actions, space: spaces.Space, num_envs: int, what: str):
    """Numpy actions -> arrays of `space`'s dtype, checking the batched shape."""
    if isinstance(space, spaces.Dict):
        return {k: _cast_actions(actions[k], s, num_envs, f"{what}[{k!r}]")
                for k, s in space.spaces.items()}
    actions = np.asarray(actions)
    expected = (num_envs, *space.shape)
    if actions.shape != expected:
        raise ValueError(f"{what} has shape {actions.shape}, expected shape {expected}")
    if isinstance(space, (spaces.Discrete, spaces.MultiDiscrete)):
        # As Gymnasium's own envs: an action outside the space is an error, never rounded or
        # wrapped (a jitted env cannot raise, so this is the place to catch it).
        if not np.issubdtype(actions.dtype, np.integer):
            raise TypeError(f"{what} must be integers for {space}, got dtype {actions.dtype}")
        size = space.nvec if isinstance(space, spaces.MultiDiscrete) else space.n
        outside = (actions < 0) | (actions >= size)
        if outside.any():
            env = int(np.argwhere(outside)[0][0])
            raise ValueError(f"{what} of env {env} is {actions[env].tolist()}, outside {space}")
    return actions.astype(space.dtype)


def _vector_info(info: dict, stepped: np.ndarray) -> dict:
    """Step info in Gymnasium's vector layout: `info[k]` and mask `info["_k"]`."""
    out = {}
    for k, v in info.items():
        out[k] = _vector_info(v, stepped) if isinstance(v, dict) else np.array(v)
        out[f"_{k}"] = stepped.copy()
    return out
