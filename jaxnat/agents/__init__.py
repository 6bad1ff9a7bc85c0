"""Agents in flax + optax, PureJaxRL-shaped (`make_train(config, env, params) -> train(key)`).

PPO, A2C, ACKTR and DQN are jitted end to end and vmap over seeds; `evaluate` scores a policy
on a held-out env (the test split). `ALGORITHMS` maps names to `(Config, make_learner)`.
"""

from jaxnat.agents.a2c import A2CConfig, make_a2c
from jaxnat.agents.acktr import ACKTRConfig, make_acktr
from jaxnat.agents.dqn import DQNConfig, make_dqn
from jaxnat.agents.ppo import PPOConfig, make_ppo

ALGORITHMS = {
    "ppo": (PPOConfig, make_ppo),
    "a2c": (A2CConfig, make_a2c),
    "acktr": (ACKTRConfig, make_acktr),
    "dqn": (DQNConfig, make_dqn),
}

__all__ = ["ALGORITHMS", "PPOConfig", "A2CConfig", "ACKTRConfig", "DQNConfig", "make_ppo", "make_a2c",
           "make_acktr", "make_dqn"]
