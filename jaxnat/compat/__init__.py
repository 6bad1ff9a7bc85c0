"""Adapters that expose jaxnat envs through other libraries' APIs.

`GymnasiumVectorEnv` (needs `pip install 'jaxnat[gym]'`) runs a batch of envs behind
`gymnasium.vector.VectorEnv`, numpy in and out, for PyTorch code (Stable-Baselines3, CleanRL).
"""

from jaxnat.compat.gymnasium import GymnasiumVectorEnv, make_gymnasium_vec

__all__ = ["GymnasiumVectorEnv", "make_gymnasium_vec"]
