"""Agents in flax + optax, PureJaxRL-shaped (`make_train(config, env, params) -> train(key)`).

PPO and A2C are jitted end to end and vmap over seeds; `evaluate` scores a policy on a held-out
env (the test split). `ALGORITHMS` maps names to `(Config, make_learner)`.
"""

from jaxnat.agents.a2c import A2CConfig, make_a2c
from jaxnat.agents.ppo import PPOConfig, make_ppo

ALGORITHMS = {"ppo": (PPOConfig, make_ppo), "a2c": (A2CConfig, make_a2c)}

__all__ = ["ALGORITHMS", "PPOConfig", "A2CConfig", "make_ppo", "make_a2c"]
