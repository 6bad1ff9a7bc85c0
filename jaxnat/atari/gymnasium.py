"""`AtariGymnasiumVectorEnv`: Natural Atari behind Gymnasium's vector API, for PyTorch users.

    vec = jaxnat.compat.make_gymnasium_vec("NaturalAtari/Breakout-v0", 8, background="video")
    obs, info = vec.reset(seed=0)
    obs, rewards, terminations, truncations, info = vec.step(vec.action_space.sample())
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from jaxnat.atari.env import NaturalAtariVecEnv

__all__ = ["AtariGymnasiumVectorEnv"]


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
