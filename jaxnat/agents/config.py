"""What the algorithms' configs share: `static` fields, and the fields every on-policy
algorithm (PPO, A2C, ACKTR) has, with the paper's settings as defaults where they agree.

A config is a flax dataclass: static fields set shapes and loop lengths (`static`); the others
are traced, so a batch of configs can be vmapped (a learning-rate sweep in one program). Each
algorithm's config (`ppo.PPOConfig`, ...) holds the paper's settings; `resolve.config_for`
builds one for an env, with the env family's defaults (`defaults.py`) where they differ.
"""

from __future__ import annotations

import dataclasses
import numbers
from typing import Any

from flax import struct

__all__ = ["static", "OnPolicyConfig", "RANGES", "check_ranges"]


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
    # Train on sign(reward) (baselines' Atari `ClipRewardEnv`), before any reward scaling;
    # the episode returns reported stay the env's (`normalize.py`).
    clip_rewards: bool = static(False)
    # Traced: may be vmapped.
    lr: float = 2.5e-4
    gamma: float = 0.99
    gae_lambda: float = 0.95
    vf_coef: float = 1.0
    ent_coef: float = 0.01


_AT_LEAST_1 = (">= 1", lambda v: v >= 1)  # counts and sizes
_AT_LEAST_0 = (">= 0", lambda v: v >= 0)
_POSITIVE = ("> 0", lambda v: v > 0)
_FRACTION = ("in [0, 1]", lambda v: 0 <= v <= 1)
_DISCOUNT = ("in (0, 1]", lambda v: 0 < v <= 1)
# The valid values of the config fields (of any algorithm; a field its config lacks is passed
# over): (the range as printed, the test). Comparisons are written so that NaN fails them.
RANGES: dict[str, tuple[str, Any]] = {
    **dict.fromkeys(("total_timesteps", "num_envs", "num_steps", "update_epochs", "num_minibatches",
                     "gradient_steps", "batch_size", "buffer_size", "n_step", "target_update_period"), _AT_LEAST_1),
    **dict.fromkeys(("memory", "vf_coef", "ent_coef", "clip_eps", "weight_decay", "rms_eps", "adam_eps", "damping",
                     "vf_fisher_coef", "exploration_steps", "learning_starts"), _AT_LEAST_0),
    **dict.fromkeys(("lr", "max_grad_norm", "kl_clip"), _POSITIVE),
    **dict.fromkeys(("gae_lambda", "rms_alpha", "rms_decay", "stats_decay", "eps_start", "eps_end"), _FRACTION),
    "gamma": _DISCOUNT,  # (DQN's tau: dqn.check_config, with what its values mean)
    "momentum": ("in [0, 1)", lambda v: 0 <= v < 1),  # ACKTR's SGD steps scale by 1 - momentum
}


def check_ranges(config) -> None:
    """Raise a one-line `ValueError` for the first field of `config` whose value is a concrete
    number out of its range (`RANGES`); arrays and traced values (a sweep) pass unchecked."""
    for field in dataclasses.fields(config):
        value = getattr(config, field.name)
        if field.name not in RANGES or isinstance(value, bool) or not isinstance(value, numbers.Real):
            continue
        rule, valid = RANGES[field.name]
        if not valid(value):
            raise ValueError(f"{field.name}={value!r} is out of range: {field.name} must be {rule}")
