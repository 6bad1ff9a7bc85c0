"""The algorithms by name: `ALGORITHMS` maps each to `Algorithm(config, make, make_host)`."""

from __future__ import annotations

from typing import Callable, NamedTuple

from jaxnat.agents.a2c import A2CConfig, make_a2c, make_host_a2c
from jaxnat.agents.acktr import ACKTRConfig, make_acktr, make_host_acktr
from jaxnat.agents.dqn import DQNConfig, make_dqn
from jaxnat.agents.dqn_host import make_host_dqn
from jaxnat.agents.ppo import PPOConfig, make_host_ppo, make_ppo

__all__ = ["Algorithm", "ALGORITHMS"]


class Algorithm(NamedTuple):
    config: type  # the config dataclass
    make: Callable  # (config, env, env_params) -> rollout.Learner (jitted, JAX envs)
    # (config, env, compiler_options=None) -> rollout.HostLearner (host-batched envs: Natural
    # Atari), or None; data-parallel ones also take devices=, and those that train seeds side
    # by side seeds= (`rollout.on_policy_host_learner`)
    make_host: Callable | None


ALGORITHMS = {
    "ppo": Algorithm(PPOConfig, make_ppo, make_host_ppo),
    "a2c": Algorithm(A2CConfig, make_a2c, make_host_a2c),
    "acktr": Algorithm(ACKTRConfig, make_acktr, make_host_acktr),
    "dqn": Algorithm(DQNConfig, make_dqn, make_host_dqn),
}
