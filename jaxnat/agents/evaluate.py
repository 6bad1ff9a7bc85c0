"""Score a policy on held-out episodes (the test split), greedy and sampled.

    evaluate = make_evaluate(learner.network, test_env, test_params, num_episodes=1000)
    scores = jax.jit(jax.vmap(evaluate))(runner.train_state.params, keys)   # per seed

Each of `num_episodes` envs plays its first episode to the end (at most `max_steps` steps);
the result holds the mean return, the fraction of episodes that terminated (for
classification: were classified correctly) and the mean length, for the greedy policy (most
likely action per factor) and for actions sampled from the policy.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxnat.agents import distributions
from jaxnat.agents.networks import Memory, initial_memory
from jaxnat.agents.on_policy import act


def make_evaluate(network, env, env_params, num_episodes: int = 1000, max_steps: int | None = None):
    """`evaluate(network_params, key) -> dict of scalars`; pure and jittable."""
    if max_steps is None:
        max_steps = int(env_params.max_steps_in_episode)
    scalar_action = not hasattr(env.action_space(env_params), "nvec")  # Discrete (jaxnat's or gymnax's)
    reset = jax.vmap(env.reset, in_axes=(0, None))
    step = jax.vmap(env.step, in_axes=(0, 0, 0, None))

    def play(network_params, key, greedy: bool):
        key_reset, key_steps = jax.random.split(key)
        obs, state = reset(jax.random.split(key_reset, num_episodes), env_params)
        zeros = jnp.zeros(num_episodes)
        running = jnp.ones(num_episodes, bool)

        def body(carry, key):
            obs, state, running, total, length, terminated_any, memory = carry
            key_act, key_env = jax.random.split(key)
            logits, _, hidden = act(network, network_params, obs, memory)
            action = distributions.mode(logits) if greedy else distributions.sample(key_act, logits)
            action = action[..., 0] if scalar_action else action
            obs, state, reward, terminated, truncated, _ = step(
                jax.random.split(key_env, num_episodes), state, action, env_params
            )
            total = total + jnp.where(running, reward, 0.0)
            length = length + running
            terminated_any = terminated_any | (running & terminated)
            running = running & ~(terminated | truncated)
            if memory is not None:  # the first episode is all that counts: no reset to mark
                memory = Memory(hidden, action[..., None] if scalar_action else action, reward.astype(jnp.float32),
                                jnp.zeros_like(running))
            return (obs, state, running, total, length, terminated_any, memory), None

        memory = initial_memory(network, num_episodes) if getattr(network, "memory", 0) else None
        carry = (obs, state, running, zeros, zeros, jnp.zeros(num_episodes, bool), memory)
        (_, _, running, total, length, terminated, _), _ = jax.lax.scan(
            body, carry, jax.random.split(key_steps, max_steps)
        )
        return {"return": total.mean(), "terminated_fraction": terminated.mean(),
                "length": length.mean(), "unfinished": running.mean()}

    def evaluate(network_params, key):
        key_greedy, key_sampled = jax.random.split(key)
        greedy = play(network_params, key_greedy, greedy=True)
        sampled = play(network_params, key_sampled, greedy=False)
        return {**{f"greedy_{k}": v for k, v in greedy.items()},
                **{f"sampled_{k}": v for k, v in sampled.items()}}

    return evaluate
