"""The jitted driver: a vector of JAX envs stepped inside `lax.scan` (`scan_steps`), and the
jitted `Learner` that repeats an algorithm's update in one `lax.scan` (`scan_learner`).

The driver takes two callbacks, `policy(carry, obs, key, t) -> (action [B, F], aux)` and
`observe(carry, EnvStep, aux, t) -> (carry, record)`, and hands back the records stacked over
time: the algorithm decides what a step stores (PPO a `Transition`, DQN a replay-buffer write).
The host driver (`host.py`) takes the same callbacks.
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp

from jaxnat.agents.rollout.policy import env_action
from jaxnat.agents.rollout.records import EnvStep
from jaxnat.wrappers import LogWrapper

__all__ = ["Learner", "vector_env", "scan_steps", "pack_vectors", "unpack_vectors", "scan_learner"]


class Learner(NamedTuple):
    """`train(key, config=config) -> (runner, metrics)`; `init`/`run` split it for chunked runs.

    The runner is the algorithm's own pytree. Code outside the agents reads it only through
    the learner: `policy_of(runner) -> (params, normalizer)` (what a policy acts with: the
    network's parameters, and the observation normaliser, None where observations are raw),
    `per_env(runner)` (a prefix of the runner's tree: True where a part has an env axis
    first, False where it is shared, None where it is absent; what a data-parallel run splits
    over devices) and `updates_of(runner)` (the updates done). Each works on a runner vmapped
    over seeds too."""

    init: Callable
    run: Callable
    train: Callable
    network: Any
    num_updates: int
    policy_of: Callable
    per_env: Callable
    updates_of: Callable
    # On-policy learners: `(runner, config) -> (runner, Transition)`, one rollout as an update
    # collects it (what the update trains on; for inspection and tests).
    rollout: Callable | None = None


def vector_env(env) -> tuple[Callable, Callable]:
    """`(reset(keys, params), step(keys, states, actions, params))` over a batch of envs, with
    episode statistics (`LogWrapper`, which also turns the five-value API into six values)."""
    env = LogWrapper(env)
    return jax.vmap(env.reset, in_axes=(0, None)), jax.vmap(env.step, in_axes=(0, 0, 0, None))


def scan_steps(step: Callable, env_params, action_space, num_envs: int, num_steps: int,
               policy: Callable, observe: Callable, carry, env_state, obs, key, env_keys: Callable | None = None):
    """`num_steps` steps of `num_envs` JAX envs in one `lax.scan` (`step` from `vector_env`).
    `env_keys(key, shape) -> keys [*shape, n]` for this device's `n` envs (default:
    `jax.random.split(key, (*shape, num_envs))`). Returns `((carry, env_state, obs, key), records
    stacked over time)`.

    Every step's keys are split before the loop, in two draws for the whole rollout: on a GPU
    each draw is a loop of its own, and two per step (the policy's key, the envs' keys) cost
    more kernel launches than a small policy's forward pass."""
    if env_keys is None:
        env_keys = lambda key, shape: jax.random.split(key, (*shape, num_envs))  # noqa: E731
    layout = {}

    def body(state, xs):
        carry, env_state, obs = state
        t, key_act, keys_env = xs
        action, aux = policy(carry, obs, key_act, t)
        next_obs, env_state, reward, terminated, truncated, info = step(
            keys_env, env_state, env_action(action, action_space), env_params)
        carry, record = observe(carry, EnvStep.after(obs, action, next_obs, reward, terminated, truncated, info),
                                aux, t)
        return (carry, env_state, next_obs), pack_vectors(record, layout)

    key, key_act, key_env = jax.random.split(key, 3)
    xs = (jnp.arange(num_steps), jax.random.split(key_act, num_steps), env_keys(key_env, (num_steps,)))
    (carry, env_state, obs), packed = jax.lax.scan(body, (carry, env_state, obs), xs)
    return (carry, env_state, obs, key), unpack_vectors(packed, layout)


# The per-env scalars a step records (reward, value, done, episode statistics, ...), written into
# one `[N, k]` array per step rather than k arrays: each array a loop stacks is its own write per
# iteration (on a GPU, its own kernel). float32 and bool only, so the round trip is exact.
_PACKED_DTYPES = (jnp.float32, jnp.bool_)


def pack_vectors(record, layout: dict):
    """`(packed [N, k] float32, the other leaves)` from `record`'s 1-D float32/bool leaves (k >= 2;
    else `record` as it is); `layout` keeps what `unpack_vectors` needs."""
    leaves, treedef = jax.tree_util.tree_flatten(record)
    vectors = [i for i, x in enumerate(leaves) if x.ndim == 1 and x.dtype in _PACKED_DTYPES]
    if len(vectors) < 2 or len({leaves[i].shape for i in vectors}) > 1:
        layout.clear()
        return record
    layout.update(treedef=treedef, vectors=vectors, dtypes=[leaves[i].dtype for i in vectors])
    packed = jnp.stack([leaves[i].astype(jnp.float32) for i in vectors], axis=-1)
    return packed, [x for i, x in enumerate(leaves) if i not in vectors]


def unpack_vectors(stacked, layout: dict):
    """`pack_vectors`'s output stacked over steps, back to the record's structure `[T, ...]`."""
    if not layout:
        return stacked
    packed, others = stacked
    others = iter(others)
    columns = dict(zip(layout["vectors"], range(packed.shape[-1])))
    leaves = [packed[..., columns[i]].astype(layout["dtypes"][columns[i]]) if i in columns else next(others)
              for i in range(layout["treedef"].num_leaves)]
    return jax.tree_util.tree_unflatten(layout["treedef"], leaves)


def scan_learner(config, init: Callable, update: Callable, optimizer: Callable, network, num_updates: int,
                 policy_of: Callable, per_env: Callable, rollout: Callable | None = None) -> Learner:
    """The jitted `Learner` of `init(key, config) -> runner` and `update(runner, config) ->
    (runner, metrics)` (`runner` a NamedTuple with `train_state` and `update`; `policy_of` and
    `per_env` declare the rest of it, as `Learner` says): `run` repeats
    `update` in one `lax.scan`, calling `callback(update count, metrics)` on the host after
    each; `train` is `init`, then `run`.

    The optimizer (`optimizer(config)`) closes over traced hyperparameters, so it is rebuilt
    from each call's config: chunked runs (init and run jitted separately) use their own, live
    values. The runner handed back keeps the caller's optimizer object (a static pytree
    field), so its structure matches the input and a compiled `run` can be fed its own output.
    """

    def run(runner, config=config, num_updates: int = num_updates, callback=None):
        caller_tx = runner.train_state.tx
        runner = runner._replace(train_state=runner.train_state.replace(tx=optimizer(config)))

        def body(runner, _):
            runner, metrics = update(runner, config)
            if callback is not None:
                jax.debug.callback(callback, runner.update, metrics)
            return runner, metrics

        runner, metrics = jax.lax.scan(body, runner, None, num_updates)
        return runner._replace(train_state=runner.train_state.replace(tx=caller_tx)), metrics

    def train(key, config=config):
        return run(init(key, config), config)

    return Learner(init, run, train, network, num_updates, policy_of, per_env, lambda runner: runner.update, rollout)
