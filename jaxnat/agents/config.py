"""What the algorithms' configs share: `static` fields, and the fields every on-policy
algorithm (PPO, A2C, ACKTR) has, with the paper's settings as defaults where they agree.

A config is a flax dataclass: static fields set shapes and loop lengths (`static`); the others
are traced, so a batch of configs can be vmapped (a learning-rate sweep in one program). Each
algorithm's config (`ppo.PPOConfig`, ...) holds the paper's settings; `resolve.config_for`
builds one for an env, with the env family's defaults (`defaults.py`) where they differ.
"""

from __future__ import annotations

from flax import struct

__all__ = ["static", "OnPolicyConfig"]


def static(default):
    """A config field that sets shapes or loop lengths: static under jit, not vmappable."""
    return struct.field(pytree_node=False, default=default)


@struct.dataclass
class OnPolicyConfig:
    """The fields PPO, A2C and ACKTR share; each algorithm's config sets its own defaults."""

    # Static: they set shapes and loop lengths.
    total_timesteps: int = static(1_000_000)  # env steps per seed
    num_envs: int = static(8)
    num_steps: int = static(128)  # env steps per env per update
    trunk: str | None = static(None)  # None: the paper's trunk for the observation size
    # VecNormalize's two switches (`normalize.py`); None: on for vector observations, off for images.
    normalize_observations: bool | None = static(None)
    normalize_rewards: bool | None = static(None)
    # Traced: may be vmapped.
    lr: float = 2.5e-4
    gamma: float = 0.99
    gae_lambda: float = 0.95
    vf_coef: float = 1.0
    ent_coef: float = 0.01
