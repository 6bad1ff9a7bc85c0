"""Adapters that expose jaxnat envs through other libraries' APIs (need `pip install 'jaxnat[gym]'`).

- `GymnasiumEnv` / `make_gymnasium`: one env behind `gymnasium.Env`, for single-env code and
  Gymnasium's wrappers (`check_env`, `RecordEpisodeStatistics`, `RecordVideo`).
- `GymnasiumVectorEnv` / `make_gymnasium_vec`: a batch behind `gymnasium.vector.VectorEnv`,
  numpy in and out, for PyTorch code (Stable-Baselines3, CleanRL).
- Importing this package registers the pure-JAX ids with Gymnasium as
  `jaxnat/<Family>-<Name>-vN` (`gymnasium_id`), so
  `gymnasium.make("jaxnat.compat:jaxnat/Classify-Digits-v0")` works from Gymnasium alone.
"""

from jaxnat.compat.gymnasium import (
    GymnasiumEnv,
    GymnasiumVectorEnv,
    gymnasium_id,
    make_gymnasium,
    make_gymnasium_vec,
    register_gymnasium_envs,
)

__all__ = [
    "GymnasiumEnv",
    "GymnasiumVectorEnv",
    "gymnasium_id",
    "make_gymnasium",
    "make_gymnasium_vec",
    "register_gymnasium_envs",
]
