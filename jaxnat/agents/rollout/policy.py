"""Calls of the policy network: acting on a batch of envs, replaying a stored rollout, the
value of a final observation, and the agent's action in the env's form."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxnat.agents import distributions
from jaxnat.agents.networks import Memory, is_box, one_step_sequence

__all__ = ["is_scalar_action", "env_action", "sample_each", "act", "final_value", "replay", "choose"]


def is_scalar_action(action_space) -> bool:
    """Whether the env takes one integer per step (Discrete, jaxnat's or gymnax's) rather than a
    vector (MultiDiscrete, Box); the agents always hold actions as `[..., F]` (or `[..., D]`)."""
    return not hasattr(action_space, "nvec") and not is_box(action_space)


def env_action(action, action_space):
    """The agent's action in the env's form: a Discrete env's integer; a Box env's vector
    clipped to the bounds (NaN, from a diverged policy, becomes 0 first: it never reaches the
    env). numpy in, numpy out (the host driver); else jax."""
    if is_box(action_space):
        xp = np if isinstance(action, np.ndarray) else jnp
        return xp.clip(xp.nan_to_num(action, nan=0.0), action_space.low, action_space.high)
    return action[..., 0] if is_scalar_action(action_space) else action


def sample_each(keys, logits):
    """One action per env, each drawn with its own key."""
    if isinstance(logits, distributions.Gaussian):  # a shared log-std, given to every env
        logits = logits._replace(log_std=jnp.broadcast_to(logits.log_std, jnp.shape(logits.mean)))
    return jax.vmap(distributions.sample)(keys, logits)


def act(network, params, obs, memory: Memory | None):
    """One step of the policy over a batch of envs: `(logits, value, hidden after the step)`;
    `memory` is None for a feed-forward network (hidden is then None too)."""
    if memory is None:
        return (*network.apply(params, obs), None)
    logits, value, hidden = network.apply(params, jax.tree_util.tree_map(lambda x: x[None], obs),
                                          one_step_sequence(memory))
    return jax.tree_util.tree_map(lambda x: x[0], logits), value[0], hidden


def final_value(network, params, final_obs, memory: Memory | None = None):
    """V(final observation): what a truncated step's target bootstraps from, as if the episode
    went on (`records.bootstrap` zeroes it where the episode terminated); a recurrent policy
    values it with `memory`, its state after that step. Both drivers read it here: the host
    driver where an episode ended, the scan driver for recurrent policies and for a rollout's
    last step (a feed-forward policy's other final observations ride in the next step's `act`,
    one network call for both: `on_policy.on_policy_learner`)."""
    return act(network, params, final_obs, memory)[1]


def replay(network, params, obs, memory: Memory | None):
    """`(logits, value)` of a stored rollout: `obs` `[T, B, ...]` and its per-step memory
    (`Transition.memory`, whose `hidden[0]` is the state before the first step), replayed so
    the recurrent policy's outputs are those the rollout saw; a feed-forward network reads any
    batch shape."""
    if memory is None:
        return network.apply(params, obs)
    logits, value, _ = network.apply(params, obs, memory._replace(hidden=memory.hidden[0]))
    return logits, value


def choose(logits, key, greedy: bool):
    """The action of an evaluated policy: the most likely (greedy) or a sampled one."""
    return distributions.mode(logits) if greedy else distributions.sample(key, logits)
