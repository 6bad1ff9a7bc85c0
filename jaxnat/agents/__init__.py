"""Agents in flax + optax, PureJaxRL-shaped (`make_train(config, env, params) -> train(key)`).

PPO, A2C, ACKTR and DQN are jitted end to end and vmap over seeds; PPO, A2C and DQN also train
host-batched envs (Natural Atari) from a Python loop. Each algorithm's file holds its config,
loss and update; `rollout` runs the envs for all of them and evaluates policies.
`ALGORITHMS` maps names to `Algorithm(config, make, make_host)`.
"""

from typing import Callable, NamedTuple

from jaxnat.agents.a2c import A2CConfig, make_a2c, make_host_a2c
from jaxnat.agents.acktr import ACKTRConfig, make_acktr
from jaxnat.agents.dqn import DQNConfig, make_dqn, make_host_dqn
from jaxnat.agents.ppo import PPOConfig, make_host_ppo, make_ppo


class Algorithm(NamedTuple):
    config: type  # the config dataclass
    make: Callable  # (config, env, env_params) -> rollout.Learner (jitted, JAX envs)
    # (config, env, compiler_options=None) -> rollout.HostLearner; data-parallel ones also take
    # devices= (`rollout.on_policy_host_learner`)
    make_host: Callable | None


ALGORITHMS = {
    "ppo": Algorithm(PPOConfig, make_ppo, make_host_ppo),
    "a2c": Algorithm(A2CConfig, make_a2c, make_host_a2c),
    "acktr": Algorithm(ACKTRConfig, make_acktr, None),
    "dqn": Algorithm(DQNConfig, make_dqn, make_host_dqn),
}

__all__ = ["ALGORITHMS", "Algorithm", "PPOConfig", "A2CConfig", "ACKTRConfig", "DQNConfig", "make_ppo", "make_a2c",
           "make_acktr", "make_dqn", "make_host_ppo", "make_host_a2c", "make_host_dqn"]
