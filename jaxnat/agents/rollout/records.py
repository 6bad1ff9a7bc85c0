"""What a rollout records and the return maths on it: the transition, one vector step as the
drivers hand it on, GAE with correct time limits, and the episode metrics.

**Time limits.** A target bootstraps from the final observation of a truncated episode and not
from a terminated one: `next_value_t = (1 - terminated_t) * V(final_obs_t)` (`bootstrap`); the
GAE trace is cut at every episode end. Envs with the five-value step API of gymnax 0.x /
PureJaxRL (`done` only) work too; `done` then counts as termination.
"""

from __future__ import annotations

import functools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

__all__ = ["EPISODE_KEYS", "Transition", "EnvStep", "GAE_UNROLL", "gae", "bootstrap", "step_info",
           "episode_metrics", "count_updates"]

# What a host-batched env's `info` carries about episodes that ended (PureJaxRL's keys).
EPISODE_KEYS = ("returned_episode", "returned_episode_returns", "returned_episode_lengths")


class Transition(NamedTuple):
    obs: Any
    action: jax.Array  # [F] int32, one entry per action factor
    log_prob: jax.Array
    value: jax.Array
    reward: jax.Array
    done: jax.Array  # the episode ended (terminated or truncated): cuts the GAE trace
    next_value: jax.Array  # (1 - terminated) * V(final observation)
    info: dict
    # Recurrent policies: the `Memory` each step read; its `hidden` is only the state before the
    # rollout's first step, `[1, N, H]` (replay derives the rest).
    memory: Any = None


class EnvStep(NamedTuple):
    """One step of a batch of envs, as both drivers hand it to `observe`."""

    obs: Any  # the observation the action was chosen on
    action: Any  # the agent's action [B, F]
    next_obs: Any  # the next observation (the reset one where an episode ended)
    reward: Any
    terminated: Any
    done: Any  # terminated or truncated
    final_obs: Any  # the episode's last observation where it ended, else next_obs
    info: dict

    @classmethod
    def after(cls, obs, action, next_obs, reward, terminated, truncated, info: dict) -> EnvStep:
        """The step an env's outcome describes: `done` is either flag; `final_obs` the env's
        `info["final_observation"]` where it reports one, else `next_obs`."""
        return cls(obs, action, next_obs, reward, terminated, terminated | truncated,
                   info.get("final_observation", next_obs), info)


# Steps of the GAE recursion per loop iteration (`gae`): bench/results/agents_vs_references.md
# ("unrolling GAE") measures what it saves.
GAE_UNROLL = 32


def gae(transitions: Transition, gamma, gae_lambda) -> tuple[jax.Array, jax.Array]:
    """Advantages and value targets over a `[T, ...]` rollout (time-major)."""

    def backward(carry, t):
        reward, next_value, value, done = t
        delta = reward + gamma * next_value - value
        advantage = delta + gamma * gae_lambda * (1.0 - done) * carry
        return advantage, advantage

    steps = (transitions.reward, transitions.next_value, transitions.value, transitions.done)
    # Unrolled: each step is a few elementwise operations, so a rolled loop's per-iteration cost
    # (on a GPU, a launch and the loop's predicate read back) would outweigh its body.
    _, advantages = jax.lax.scan(backward, jnp.zeros_like(transitions.value[0]), steps, reverse=True,
                                 unroll=min(GAE_UNROLL, transitions.value.shape[0]))
    return advantages, advantages + transitions.value


def bootstrap(final_value, terminated):
    """The value a step's target bootstraps from: `V(final observation)`, 0 if it terminated."""
    return jnp.where(terminated, 0.0, final_value)


def step_info(info: dict, terminated) -> dict:
    """What `episode_metrics` needs from one vector step."""
    return {**{name: info[name] for name in EPISODE_KEYS}, "terminated": terminated}


def episode_metrics(info: dict, axis_name=None) -> dict:
    """Means over the episodes that ended in this rollout (NaN when none did); with
    `axis_name`, over every device's envs."""
    ended = info["returned_episode"]
    total = (lambda x: x) if axis_name is None else functools.partial(jax.lax.psum, axis_name=axis_name)
    count = total(jnp.sum(ended))

    def mean(x):
        return jnp.where(count > 0, total(jnp.sum(jnp.where(ended, x, 0.0))) / jnp.maximum(count, 1), jnp.nan)

    # A terminated episode ended by the env's own rule (classification: the right label).
    return {
        "episode_return": mean(info["returned_episode_returns"]),
        "episode_length": mean(info["returned_episode_lengths"].astype(jnp.float32)),
        "terminated_fraction": mean(info["terminated"].astype(jnp.float32)),
        "episodes": count,
    }


def count_updates(config) -> int:
    """Updates in a run: `total_timesteps // (num_envs * num_steps)`, at least one."""
    total_updates = config.total_timesteps // (config.num_envs * config.num_steps)
    if total_updates < 1:
        raise ValueError(
            f"total_timesteps={config.total_timesteps} is less than one rollout "
            f"(num_envs * num_steps = {config.num_envs * config.num_steps})"
        )
    return total_updates
