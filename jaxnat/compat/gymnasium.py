"""jaxnat envs behind Gymnasium's APIs: one env (`GymnasiumEnv`) or a batch (`GymnasiumVectorEnv`).

    env = jaxnat.compat.make_gymnasium("Classify/Digits-v0", render_mode="rgb_array")
    obs, info = env.reset(seed=0)
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())

    vec = jaxnat.compat.make_gymnasium_vec("Classify/Digits-v0", num_envs=8, seed=0)
    obs, info = vec.reset()
    obs, rewards, terminations, truncations, info = vec.step(vec.action_space.sample())

Importing this module registers every pure-JAX id with Gymnasium as `jaxnat/<Family>-<Name>-vN`
(`register_gymnasium_envs`), so `gymnasium.make("jaxnat.compat:jaxnat/Classify-Digits-v0")`
works without importing jaxnat first.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

try:
    import gymnasium
    from gymnasium.vector import AutoresetMode, VectorEnv
    from gymnasium.vector.utils import batch_space
except ImportError as err:  # pragma: no cover - exercised only without the extra
    raise ImportError(
        "jaxnat.compat needs gymnasium>=1.1: pip install 'jaxnat[gym]'"
    ) from err

from jaxnat import spaces
from jaxnat.compat.frames import Frames
from jaxnat.core import Environment
from jaxnat.registration import make, registered_envs, spec
from jaxnat.wrappers import AutoResetWrapper, VmapWrapper, Wrapper

__all__ = [
    "GymnasiumEnv",
    "GymnasiumVectorEnv",
    "gymnasium_id",
    "make_gymnasium",
    "make_gymnasium_vec",
    "register_gymnasium_envs",
]

NAMESPACE = "jaxnat"  # Gymnasium ids: jaxnat/<Family>-<Name>-vN


class GymnasiumEnv(gymnasium.Env):
    """One jaxnat env as a `gymnasium.Env`, numpy in and out, for single-env Gymnasium code
    and its wrappers (`check_env`, `RecordEpisodeStatistics`, `RecordVideo`, ...).

    Keys (so a run can be replayed with jaxnat's own `env.reset`/`env.step`): `reset(seed=s)`
    sets the key to `jax.random.key(s)` and seeds `np_random` (as every Gymnasium env does);
    the first `reset()` without a seed draws the key's seed from `np_random`, which Gymnasium
    seeds from the OS. Each `reset` and `step` then splits the key, `key, sub =
    jax.random.split(key)`, and passes `sub` to the env's `reset` or `step`; a later `reset()`
    without a seed continues the same chain, so episodes differ.

    `step` returns the observation as writable numpy arrays (a dict of them for `Dict` spaces),
    the reward as a Python float, `terminated`/`truncated` as Python bools (the env's own time
    limit truncates: no `TimeLimit` wrapper is needed) and `info` with 0-d values as Python
    scalars and the rest as numpy arrays. Actions are checked against the action space
    (integers in range for discrete spaces; the jitted env would clip them). After an episode
    ends, call `reset`: stepping on is not defined (the env keeps counting).

    `render_mode="rgb_array"`: `render()` returns a uint8 `[H, W, 3]` frame of the current
    state (`jaxnat.compat.frames`: image observations as the agent sees them, the window or
    footprint tinted red; MuJoCo robots through the tracking camera); `render_fps` is the
    env's steps per second of simulated time (MuJoCo), else 30.

    `reset` and `step` are each one call of a function jitted once, at construction.

    Args:
        env: an env id (built with `jaxnat.make(env, autoreset=False, **kwargs)`) or a raw
            jaxnat env (an outermost `AutoResetWrapper` is stripped: episodes end here and
            Gymnasium's caller resets).
        params: env params (default: those `make` built, or `env.default_params`).
        render_mode: None or "rgb_array".
        **kwargs: `jaxnat.make`'s keyword arguments, with an id only.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 30}

    def __init__(self, env: str | Environment, params=None, *, render_mode: str | None = None,
                 **kwargs: Any):
        if isinstance(env, str):
            if spec(env).batched:
                raise ValueError(f"{env} is emulated on the host, not a JAX env: use "
                                 f"jaxnat.compat.make_gymnasium({env!r}) for one game or "
                                 f"make_gymnasium_vec({env!r}, num_envs) for a batch")
            env, made = make(env, autoreset=False, **kwargs)
            params = made if params is None else params
        elif kwargs:
            raise TypeError(f"keyword arguments {sorted(kwargs)} are for an env id, not a built env")
        env = _raw_env(env, "GymnasiumEnv")
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.jax_env = env
        self.params = jax.device_put(env.default_params if params is None else params)
        self._action_space = env.action_space(self.params)
        self.observation_space = env.observation_space(self.params).to_gymnasium()
        self.action_space = self._action_space.to_gymnasium()
        self.render_mode = render_mode
        self._frames = None
        if render_mode is not None:
            self._frames = Frames(env, self.params)
            self.metadata = {**type(self).metadata, "render_fps": self._frames.fps}
        self._key = self._obs = self._state = None  # set by reset()
        self._reset_fn = jax.jit(self._reset)
        self._step_fn = jax.jit(self._step)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Start an episode; `seed` re-seeds the key and `np_random`. Returns `(obs, {})`."""
        if options:
            raise ValueError(f"jaxnat envs take no reset options, got {sorted(options)}")
        super().reset(seed=seed)
        if seed is not None:
            self._key = jax.random.key(seed)
        elif self._key is None:
            self._key = jax.random.key(int(self.np_random.integers(2**63)))
        self._key, self._obs, self._state = self._reset_fn(self._key, self.params)
        return self._observation(), {}

    def step(self, action):
        """One env step; numpy (or Python numbers) in, numpy and Python scalars out."""
        if self._state is None:
            raise RuntimeError("Call reset() before step().")
        action = _cast_actions(action, self._action_space, None, "action")
        self._key, self._obs, self._state, reward, terminated, truncated, info = self._step_fn(
            self._key, self._state, action, self.params)
        return self._observation(), float(reward), bool(terminated), bool(truncated), _scalars(info)

    def render(self):
        """The current frame, uint8 `[H, W, 3]` (`render_mode="rgb_array"`), else None."""
        if self.render_mode is None:
            return None
        if self._state is None:
            raise RuntimeError("Call reset() before render().")
        return self._frames(_to_numpy(self._obs), self._state)

    def __repr__(self) -> str:
        return f"GymnasiumEnv({self.jax_env.name})"

    def _observation(self):
        """The current observation in numpy; a `Discrete` one (Localize's goal) as `np.int64`,
        the type Gymnasium's `Discrete` samples and its checker expects."""
        def host(obs, space):
            if isinstance(space, gymnasium.spaces.Dict):
                return {k: host(obs[k], s) for k, s in space.spaces.items()}
            return np.int64(obs) if isinstance(space, gymnasium.spaces.Discrete) else np.array(obs)

        return host(self._obs, self.observation_space)

    def _reset(self, key, params):
        key, sub = jax.random.split(key)
        obs, state = self.jax_env.reset(sub, params)
        return key, obs, state

    def _step(self, key, state, action, params):
        key, sub = jax.random.split(key)
        return (key, *self.jax_env.step(sub, state, action, params))


def make_gymnasium(env_id: str, *, render_mode: str | None = None, **kwargs: Any) -> gymnasium.Env:
    """`GymnasiumEnv` of `jaxnat.make(env_id, autoreset=False, **kwargs)`: one env for
    single-env Gymnasium code (without the checker and order wrappers `gymnasium.make` adds);
    a host-batched id (`NaturalAtari/*`) gives `jaxnat.atari.gymnasium.AtariGymnasiumEnv`, one
    game."""
    if spec(env_id).batched:
        from jaxnat.atari.gymnasium import AtariGymnasiumEnv

        return AtariGymnasiumEnv(render_mode=render_mode, **{**spec(env_id).kwargs, **kwargs})
    return GymnasiumEnv(env_id, render_mode=render_mode, **kwargs)


def gymnasium_id(env_id: str) -> str:
    """The Gymnasium id of a jaxnat id: `Classify/Digits-v0` -> `jaxnat/Classify-Digits-v0`
    (Gymnasium allows one `/`, before the name)."""
    family, _, name = env_id.partition("/")
    return f"{NAMESPACE}/{family}-{name}"


def register_gymnasium_envs() -> tuple[str, ...]:
    """Register every pure-JAX jaxnat id with Gymnasium (`gymnasium_id`), entry point
    `GymnasiumEnv`; ids already there are left alone. Host-batched ids (`NaturalAtari/*`) are
    not registered: `make_gymnasium` (one game) and `make_gymnasium_vec` build them. Returns
    the ids.

    `gymnasium.make(id, **kwargs)` passes `kwargs` (and `render_mode`) to `jaxnat.make`; its
    `PassiveEnvChecker` and `OrderEnforcing` wrappers come with it, and no `TimeLimit`: the env
    truncates at its own limit (`M=`/`max_steps_in_episode`)."""
    ids = []
    for env_id in registered_envs():
        if spec(env_id).batched:
            continue
        gym_id = gymnasium_id(env_id)
        if gym_id not in gymnasium.registry:
            gymnasium.register(gym_id, entry_point=f"{__name__}:GymnasiumEnv", kwargs={"env": env_id})
        ids.append(gym_id)
    return tuple(ids)


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
        render_mode: None or "rgb_array": `render()` returns each env's frame
            (`jaxnat.compat.frames`, as `GymnasiumEnv.render`).
    """

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": ["rgb_array"],
                "render_fps": 30}

    def __init__(self, env: Environment, params=None, num_envs: int = 8, seed: int = 0, *,
                 render_mode: str | None = None):
        env = _raw_env(env, "GymnasiumVectorEnv")
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
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
        self.render_mode = render_mode
        self._frames = None
        if render_mode is not None:
            self._frames = Frames(env, self.params, batched=True)
            self.metadata = {**type(self).metadata, "render_fps": self._frames.fps}
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

    def render(self):
        """Every env's current frame, a tuple of `num_envs` uint8 `[H, W, 3]` arrays (as
        `SyncVectorEnv`; `render_mode="rgb_array"`), else None. An env that just ended shows
        its final observation until the next `step` resets it."""
        if self.render_mode is None:
            return None
        if self._state is None:
            raise RuntimeError("Call reset() before render().")
        return tuple(self._frames(_to_numpy(self._obs), self._state))

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


def make_gymnasium_vec(env_id: str, num_envs: int, seed: int = 0, *, render_mode: str | None = None,
                       **kwargs: Any):
    """`GymnasiumVectorEnv` of `jaxnat.make(env_id, autoreset=False, **kwargs)`; host-batched
    envs (`NaturalAtari/*`) get their own adapter (`jaxnat.atari.gymnasium`, no rendering)."""
    if spec(env_id).batched:
        from jaxnat.atari.gymnasium import AtariGymnasiumVectorEnv

        if render_mode is not None:
            raise ValueError(f"{env_id}'s Gymnasium adapter does not render; its observations "
                             "are the frames")
        return AtariGymnasiumVectorEnv(num_envs=num_envs, seed=seed, **{**spec(env_id).kwargs, **kwargs})
    env, params = make(env_id, autoreset=False, **kwargs)
    return GymnasiumVectorEnv(env, params, num_envs=num_envs, seed=seed, render_mode=render_mode)


def _raw_env(env: Environment, who: str) -> Environment:
    """`env` without an outermost `AutoResetWrapper` (Gymnasium's caller resets); an
    `AutoResetWrapper` or `VmapWrapper` further in is an error."""
    if isinstance(env, AutoResetWrapper):
        env = env._env
    inner = env
    while isinstance(inner, Wrapper):
        if isinstance(inner, (AutoResetWrapper, VmapWrapper)):
            raise ValueError(
                f"{who} batches and autoresets envs itself; pass {env!r} "
                f"without its {type(inner).__name__} (e.g. jaxnat.make(id, autoreset=False))."
            )
        inner = inner._env
    return env


def _to_numpy(tree):
    """Device arrays -> writable numpy arrays (same tree)."""
    return jax.tree.map(np.array, tree)


def _cast_actions(actions, space: spaces.Space, num_envs: int | None, what: str):
    """Numpy actions -> arrays of `space`'s dtype, checking the batched shape (one action's
    shape when `num_envs` is None)."""
    if isinstance(space, spaces.Dict):
        return {k: _cast_actions(actions[k], s, num_envs, f"{what}[{k!r}]")
                for k, s in space.spaces.items()}
    actions = np.asarray(actions)
    expected = space.shape if num_envs is None else (num_envs, *space.shape)
    if actions.shape != expected:
        raise ValueError(f"{what} has shape {actions.shape}, expected shape {expected}")
    if isinstance(space, (spaces.Discrete, spaces.MultiDiscrete)):
        # As Gymnasium's own envs: an action outside the space is an error, never rounded or
        # wrapped (a jitted env cannot raise, so this is the place to catch it).
        if not np.issubdtype(actions.dtype, np.integer):
            raise TypeError(f"{what} must be integers for {space}, got dtype {actions.dtype}")
        size = space.nvec if isinstance(space, spaces.MultiDiscrete) else space.n
        outside = (actions < 0) | (actions >= size)
        if outside.any() and num_envs is None:
            raise ValueError(f"{what} {actions.tolist()} is outside {space}")
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


def _scalars(info: dict) -> dict:
    """One env's step info on the host: 0-d values as Python scalars, others numpy arrays."""
    return {k: _scalars(v) if isinstance(v, dict) else (np.asarray(v).item() if np.ndim(v) == 0 else np.array(v))
            for k, v in info.items()}


register_gymnasium_envs()
