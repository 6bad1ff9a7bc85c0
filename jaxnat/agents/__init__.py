"""Agents in flax + optax, PureJaxRL-shaped (`make_train(config, env, params) -> train(key)`).

PPO, A2C, ACKTR and DQN are jitted end to end and vmap over seeds, and also train host-batched
envs (Natural Atari) from a Python loop. Each algorithm's file holds its config,
loss and update; `rollout/` runs the envs for all of them and evaluates policies; `resolve`
builds a config for an env (`config_for`), as `jaxnat train` does. `ALGORITHMS` maps names to
`Algorithm(config, make, make_host)`.
"""

from jaxnat.agents.a2c import A2CConfig, make_a2c, make_host_a2c
from jaxnat.agents.acktr import ACKTRConfig, make_acktr, make_host_acktr
from jaxnat.agents.algorithms import ALGORITHMS, Algorithm
from jaxnat.agents.config import OnPolicyConfig
from jaxnat.agents.dqn import DQNConfig, make_dqn
from jaxnat.agents.dqn_host import make_host_dqn
from jaxnat.agents.ppo import PPOConfig, make_host_ppo, make_ppo
from jaxnat.agents.resolve import Resolved, config_for, resolve_config

__all__ = ["ALGORITHMS", "Algorithm", "PPOConfig", "A2CConfig", "ACKTRConfig", "DQNConfig", "OnPolicyConfig",
           "make_ppo", "make_a2c", "make_acktr", "make_dqn", "make_host_ppo", "make_host_a2c", "make_host_acktr", "make_host_dqn",
           "config_for", "resolve_config", "Resolved"]
