"""Natural Atari behind Gymnasium's APIs, for PyTorch users: `AtariGymnasiumVectorEnv` (a batch)
and `AtariGymnasiumEnv` (one game, for single-env code and its wrappers).

    vec = jaxnat.compat.make_gymnasium_vec("NaturalAtari/Breakout-v0", 8, background="video")
    obs, info = vec.reset(seed=0)
    obs, rewards, terminations, truncations, info = vec.step(vec.action_space.sample())

    env = jaxnat.compat.make_gymnasium("NaturalAtari/Breakout-v0", render_mode="rgb_array")
    obs, info = env.reset(seed=0)
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
"""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from jaxnat.atari.env import NaturalAtariVecEnv

__all__ = ["AtariGymnasiumVectorEnv", "AtariGymnasiumEnv"]


class AtariGymnasiumVectorEnv(VectorEnv):
    """A `NaturalAtariVecEnv` in Gymnasium's `AutoresetMode.NEXT_STEP` (as `SyncVectorEnv`).

    The step that ends an episode returns its final observation with the ending flags; the
    next step ignores that env's action, resets it (new game, new background video) and returns
    its first observation with reward 0 and both flags False. ale-py does this itself, in its
    next-step mode. Rewards are float64 (unclipped, but `sign(r)` with
    `preprocessing="deepmind"`, whose lost lives end episodes too), flags bool, observations
    `uint8[num_envs, 84, 84, 4]`. `info` holds the env's per-env arrays in Gymnasium's vector
    layout (`info[k]` with mask `info["_k"]`: True for every env, except that the episode
    statistics are masked to the envs whose episode ended at this step).

    Args: `NaturalAtariVecEnv`'s (`game`, `num_envs`, `background`, `split`, ...), except
    `autoreset_mode`.
    """

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": []}
    _EPISODE_KEYS = ("returned_episode_returns", "returned_episode_lengths")

    def __init__(self, game: str = "Breakout", num_envs: int = 8, **kwargs: Any):
        if "autoreset_mode" in kwargs:
            raise ValueError("AtariGymnasiumVectorEnv always uses Gymnasium's next-step autoreset")
        self.env = NaturalAtariVecEnv(game, num_envs, autoreset_mode="next_step", **kwargs)
        self.num_envs = self.env.num_envs
        self.single_observation_space = self.env.single_observation_space.to_gymnasium()
        self.single_action_space = self.env.single_action_space.to_gymnasium()
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Reset every env; `seed` seeds env `i` with `seed + i`."""
        if options:
            raise ValueError(f"NaturalAtari takes no reset options, got {sorted(options)}")
        super().reset(seed=seed)
        obs, info = self.env.reset(seed=seed)
        return obs, self._vector_info(info, None)

    def step(self, actions):
        obs, reward, terminated, truncated, info = self.env.step(np.asarray(actions))
        ended = info.pop("returned_episode")
        return obs, reward.astype(np.float64), terminated, truncated, self._vector_info(info, ended)

    def close_extras(self, **kwargs: Any) -> None:
        self.env.close()

    def __repr__(self) -> str:
        return f"AtariGymnasiumVectorEnv({self.env!r})"

    def _vector_info(self, info: dict, ended) -> dict:
        out = {}
        for key, value in info.items():
            out[key] = value
            mask = ended if key in self._EPISODE_KEYS else np.ones(self.num_envs, bool)
            out[f"_{key}"] = mask.copy()
        return out


class AtariGymnasiumEnv(gymnasium.Env):
    """One Natural Atari game as a `gymnasium.Env` (a `NaturalAtariVecEnv` of one env), numpy in
    and out: observations `uint8[84, 84, 4]` (the frame stack), rewards as Python floats
    (unclipped, but `sign(r)` with `preprocessing="deepmind"`), flags as Python bools, `info`
    with the env's per-env values as Python scalars. `reset(seed=s)` seeds the emulator and the
    background draws with `s` and Gymnasium's `np_random`; a later `reset()` without a seed
    starts a new game and new background. After an episode ends, call `reset` (a step then
    would start the next game itself and return its first observation).

    `render_mode="rgb_array"`: `render()` returns the newest frame of the current observation
    as uint8 `[h, w, 3]` grey, what the agent sees (`jaxnat play` draws the same);
    `render_fps` 15 (an agent step is 4 emulator frames at 60 per second).

    Args: `render_mode`, and `NaturalAtariVecEnv`'s (`game`, `background`, `split`, ...) except
    `num_envs` and `autoreset_mode`.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 15}

    def __init__(self, game: str = "Breakout", render_mode: str | None = None, **kwargs: Any):
        for name in ("num_envs", "autoreset_mode"):
            if name in kwargs:
                raise ValueError(f"AtariGymnasiumEnv is one game: it takes no {name} (make_gymnasium_vec "
                                 "gives a batch)")
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.env = NaturalAtariVecEnv(game, 1, autoreset_mode="next_step", **kwargs)
        self.observation_space = self.env.single_observation_space.to_gymnasium()
        self.action_space = self.env.single_action_space.to_gymnasium()
        self.render_mode = render_mode
        self._obs = None

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        if options:
            raise ValueError(f"NaturalAtari takes no reset options, got {sorted(options)}")
        super().reset(seed=seed)
        obs, info = self.env.reset(seed=seed)
        self._obs = obs[0]
        return obs[0].copy(), {k: np.asarray(v)[0].item() for k, v in info.items()}

    def step(self, action):
        if not self.action_space.contains(action):
            raise ValueError(f"action {action!r} is not in {self.action_space}")
        obs, reward, terminated, truncated, info = self.env.step(np.asarray([action]))
        self._obs = obs[0]
        return (obs[0].copy(), float(reward[0]), bool(terminated[0]), bool(truncated[0]),
                {k: np.asarray(v)[0].item() for k, v in info.items()})

    def render(self):
        if self.render_mode is None or self._obs is None:
            return None
        return np.repeat(self._obs[..., -1:], 3, axis=-1)

    def close(self) -> None:
        self.env.close()

    def __repr__(self) -> str:
        return f"AtariGymnasiumEnv({self.env!r})"
