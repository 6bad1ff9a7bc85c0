"""Evaluating a policy: `make_evaluate` (jitted: each env plays its first episode),
`make_chance` (the uniform random policy, the baseline to beat) and `evaluate_host` (whole
games of a host env), greedy or sampled."""

from __future__ import annotations

import functools
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

from jaxnat.agents import normalize
from jaxnat.agents.networks import Memory, initial_memory
from jaxnat.agents.rollout.host import HostLearner, host_steps
from jaxnat.agents.rollout.policy import act, choose, env_action, is_scalar_action
from jaxnat.agents.rollout.records import EnvStep

__all__ = ["make_evaluate", "make_chance", "evaluate_host"]


# A progress report is sent this many times per pass (and after its last step).
PROGRESS_REPORTS = 20


def _report_steps(progress: Callable | None, max_steps: int):
    """`report(t)`, called in the scan body after step `t` (0-based, a scan index, so unbatched
    under vmap): calls `progress(t + 1)` on the host every `max_steps / PROGRESS_REPORTS` steps
    and after the last; no-op without `progress`. The step index is the only argument, so a
    vmapped program calls it once per report, not once per seed; it returns nothing and draws
    no key, so the scores are those of the program without it."""
    if progress is None:
        return lambda t: None
    stride = max(1, max_steps // PROGRESS_REPORTS)

    def report(t):
        done = t + 1
        jax.lax.cond((done % stride == 0) | (done == max_steps),
                     lambda: jax.debug.callback(progress, done), lambda: None)

    return report


def _first_episodes(env, env_params, num_episodes: int, max_steps: int | None):
    """`play(policy, memory, key, progress=None) -> scores`: each of `num_episodes` envs plays its
    first episode to the end (at most `max_steps` steps); `policy(obs, key, memory) -> (action
    [B, F], hidden)`; `progress(steps_done)` on the host as the scan goes (`_report_steps`)."""
    if max_steps is None:
        max_steps = int(env_params.max_steps_in_episode)
    action_space = env.action_space(env_params)
    reset = jax.vmap(env.reset, in_axes=(0, None))
    step = jax.vmap(env.step, in_axes=(0, 0, 0, None))

    def play(policy: Callable, memory, key, progress: Callable | None = None):
        report = _report_steps(progress, max_steps)
        key_reset, key_steps = jax.random.split(key)
        obs, state = reset(jax.random.split(key_reset, num_episodes), env_params)
        zeros = jnp.zeros(num_episodes)
        running = jnp.ones(num_episodes, bool)

        def body(carry, xs):
            key, t = xs
            obs, state, running, total, length, terminated_any, first, memory = carry
            key_act, key_env = jax.random.split(key)
            action, hidden = policy(obs, key_act, memory)
            obs, state, reward, terminated, truncated, _ = step(
                jax.random.split(key_env, num_episodes), state, env_action(action, action_space), env_params
            )
            total = total + jnp.where(running, reward, 0.0)
            length = length + running
            terminated_any = terminated_any | (running & terminated)
            first = first | ((t == 0) & terminated)
            running = running & ~(terminated | truncated)
            if memory is not None:  # the first episode is all that counts: no reset to mark
                memory = Memory(hidden, action, reward.astype(jnp.float32), jnp.zeros_like(running))
            report(t)
            return (obs, state, running, total, length, terminated_any, first, memory), None

        nothing = jnp.zeros(num_episodes, bool)
        carry = (obs, state, running, zeros, zeros, nothing, nothing, memory)
        (_, _, running, total, length, terminated, first, _), _ = jax.lax.scan(
            body, carry, (jax.random.split(key_steps, max_steps), jnp.arange(max_steps))
        )
        return {"return": total.mean(), "terminated_fraction": terminated.mean(),
                "length": length.mean(), "unfinished": running.mean(),
                "first_step_terminated": first.mean()}

    return play


def make_evaluate(network, env, env_params, num_episodes: int = 1000, max_steps: int | None = None,
                  progress: Callable | None = None):
    """`evaluate(network_params, key, normalizer=None) -> dict of scalars`; pure and jittable.

        evaluate = make_evaluate(learner.network, test_env, test_params, num_episodes=1000)
        scores = jax.jit(jax.vmap(evaluate))(runner.train_state.params, keys, runner.normalizer)

    Each of `num_episodes` envs (built with `autoreset=False`) plays its first episode to the
    end (at most `max_steps` steps, default the env's time limit); the result holds the mean
    return, the fraction of episodes that terminated (for classification: were classified
    correctly), the mean length and the fraction unfinished, for the greedy policy (most likely
    action per factor, or a Gaussian's mean) and for actions sampled from the policy. A learner
    that normalises observations passes its `normalizer` (`RunnerState.normalizer`), which is
    read, never updated: the policy sees what it was trained on. `progress(pass_index,
    steps_done)` is called on the host as the two passes (0 greedy, 1 sampled) go, each a scan
    over `max_steps` steps, whatever the episodes do: what a progress bar needs, as a long
    evaluation (1,000-step MuJoCo episodes) would otherwise run in silence.
    """
    play = _first_episodes(env, env_params, num_episodes, max_steps)

    def evaluate(network_params, key, normalizer: normalize.Normalizer | None = None):
        def policy(obs, key, memory, greedy: bool):
            logits, _, hidden = act(network, network_params, normalize.normalize(normalizer, obs), memory)
            return choose(logits, key, greedy), hidden

        memory = initial_memory(network, num_episodes) if network.memory else None
        key_greedy, key_sampled = jax.random.split(key)
        greedy = play(functools.partial(policy, greedy=True), memory, key_greedy, _pass(progress, 0))
        sampled = play(functools.partial(policy, greedy=False), memory, key_sampled, _pass(progress, 1))
        return {**{f"greedy_{k}": v for k, v in greedy.items()},
                **{f"sampled_{k}": v for k, v in sampled.items()}}

    return evaluate


def _pass(progress: Callable | None, index: int) -> Callable | None:
    return None if progress is None else functools.partial(progress, index)


def make_chance(env, env_params, num_episodes: int = 1000, max_steps: int | None = None,
                progress: Callable | None = None):
    """`chance(key) -> dict of scalars`: `make_evaluate`'s scores for the uniform random policy
    (every action factor drawn uniformly), the baseline a trained policy must beat; one pass,
    reported as `progress(0, steps_done)` (`make_evaluate`)."""
    play = _first_episodes(env, env_params, num_episodes, max_steps)
    space = env.action_space(env_params)

    def uniform(obs, key, memory):
        action = jax.vmap(space.sample)(jax.random.split(key, num_episodes))
        return (action[:, None] if is_scalar_action(space) else action), None

    return lambda key: play(uniform, None, key, _pass(progress, 0))


def evaluate_host(learner: HostLearner, params, env, num_episodes: int, key,
                  greedy: bool = False) -> np.ndarray:
    """Whole-game returns (unclipped) of the first `num_episodes` games that end, with the
    learner's policy sampled (or greedy); every env of `env` plays until enough have ended. The
    learner's jitted functions are reused (nothing new to compile)."""
    policy = learner.greedy if greedy else learner.sample
    returns: list[float] = []

    def observe(carry, s: EnvStep, aux, t, part):
        return carry, s.info["returned_episode_returns"][s.info["returned_episode"]].tolist()

    obs, _ = env.reset()
    while len(returns) < num_episodes:
        (_, obs, key), ended = host_steps(env, 1, lambda carry, o, k, t, part: (policy(params, o, k), None),
                                          observe, None, obs, key)
        returns += ended[0]
    return np.asarray(returns[:num_episodes], np.float32)
