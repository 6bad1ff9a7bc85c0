"""How rollouts run, for every algorithm: the transition record, GAE with correct time limits,
episode metrics, two drivers, the on-policy learners built on them, and evaluation. An
algorithm file (`ppo.py`, `a2c.py`, `acktr.py`, `dqn.py`) holds its config, loss and update.

- **Drivers.** `scan_steps` steps a vector of JAX envs inside `lax.scan`; `host_steps` steps a
  host-batched env (`jaxnat.core.HostBatchedEnv`: Natural Atari) from a Python loop around
  jitted calls. Both take the same callbacks, `policy(carry, obs, key, t) -> (action [B, F],
  aux)` and `observe(carry, EnvStep, aux, t) -> (carry, record)` (the host driver's also get
  the part of a pipelined batch last), and hand back the records, stacked over time or as a
  list: the algorithm decides what a step stores (PPO a `Transition`, DQN a replay-buffer
  write). `scan_learner` and `host_updates` repeat an algorithm's update on the device or from
  Python.
- **Time limits.** A target bootstraps from the final observation of a truncated episode and
  not from a terminated one: `next_value_t = (1 - terminated_t) * V(final_obs_t)`
  (`bootstrap`); the GAE trace is cut at every episode end. Envs with the five-value step API
  of gymnax 0.x / PureJaxRL (`done` only) work too; `done` then counts as termination.
- **Recurrent policies** (`memory > 0`, jitted envs only): each env's `Memory` rides in the
  runner; the update replays whole env rollouts from their first stored state (`replay`), so
  it sees the outputs the rollout saw (to float tolerance: the trunk runs on a bigger batch).
  The final observation of a truncated step is valued with the memory after that step.
- **Data parallel** (`axis_name`, PPO and A2C on jitted envs): inside a `jax.shard_map` over
  a mesh axis, each device steps its share of the envs (`shard_slice`) and the optimizer
  applies the devices' mean gradient (`pmean_gradients`). Every random draw is per env (env `i`
  of all `num_envs` gets the same keys on any device count) and every statistic over the batch
  (normalisation moments, metrics, PPO's advantage normalisation and minibatches: an equal
  share of every env's steps) is the whole batch's, so 1, 2, 4 ... devices train the same
  parameters to float tolerance. It is not the default learner's stream of random draws.
  The host learner does the same across processes (`on_policy_host_learner(devices=)`): each
  process steps its share of a host-batched env (one ALE batch per host).
- **Evaluation.** `make_evaluate` (jitted: each env plays its first episode) and
  `evaluate_host` (whole games of a host env), greedy or sampled.
"""

from __future__ import annotations

import functools
import itertools
import time
from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import struct
from flax.training.train_state import TrainState
from jax.sharding import PartitionSpec

from jaxnat.agents import distributions, normalize
from jaxnat.agents.networks import Memory, init_params, initial_memory, is_box, make_actor_critic, one_step_sequence
from jaxnat.sharding import AXIS, device_mesh, local_copy, process_share, put_global, replicated, shard_program, sharded
from jaxnat.wrappers import LogWrapper

__all__ = [
    "static", "Transition", "EnvStep", "RunnerState", "UpdateRule", "Learner", "HostState", "HostLearner",
    "gae", "GAE_UNROLL", "bootstrap", "step_info", "episode_metrics", "count_updates", "is_box",
    "is_scalar_action", "env_action", "act", "replay", "choose", "vector_env", "scan_steps", "pack_vectors",
    "unpack_vectors", "scan_learner", "host_steps", "host_steps_pipelined", "host_updates", "TIMING_KEYS",
    "on_policy_learner", "on_policy_host_learner", "shard_slice", "pmean_gradients", "check_host_batch",
    "make_evaluate", "make_chance", "evaluate_host",
    "clip_by_global_norm", "dtype_and_memory", "EPISODE_KEYS",
]

# What a host-batched env's `info` carries about episodes that ended (PureJaxRL's keys).
EPISODE_KEYS = ("returned_episode", "returned_episode_returns", "returned_episode_lengths")


def static(default):
    """A config field that sets shapes or loop lengths: static under jit, not vmappable."""
    return struct.field(pytree_node=False, default=default)


# ---------------------------------------------------------------------------------------------
# Records


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


class RunnerState(NamedTuple):
    train_state: TrainState
    env_state: Any
    obs: Any
    key: jax.Array
    update: jax.Array  # updates done so far (int32)
    memory: Any = None  # recurrent policies: each env's `Memory` before its next step
    normalizer: Any = None  # `normalize.Normalizer` when observations or rewards are normalised


class UpdateRule(NamedTuple):
    """An on-policy algorithm's parts that do not depend on how rollouts are collected."""

    make_optimizer: Callable  # (config, num_updates) -> optax.GradientTransformation
    update_step: Callable  # (config, network, train_state, transitions, advantages, targets, key)
    # `update_step` takes `axis_name=` and trains data parallel inside a shard_map (its
    # gradient is a mean over the batch, made whole by `pmean_gradients`).
    data_parallel: bool = False
    # config -> keyword arguments of `networks.make_actor_critic` beyond the trunk
    # (`dtype_and_memory` for configs that have those fields)
    network_options: Callable = lambda config: {}

    def train_state(self, config, network, observation_space, num_updates: int, key) -> TrainState:
        """Fresh parameters and optimizer state for a run of `num_updates` updates."""
        return TrainState.create(apply_fn=network.apply, params=init_params(network, observation_space, key),
                                 tx=self.make_optimizer(config, num_updates))

    def averaged(self, axis_name) -> UpdateRule:
        """This rule trained data parallel over `axis_name`: its optimizer applies the devices'
        mean gradient (`pmean_gradients`); a `ValueError` for a rule that cannot."""
        if not self.data_parallel:
            raise ValueError("this algorithm does not train data parallel (its update needs the whole batch "
                             "on one device): place whole seeds on devices, or leave devices out")
        make_optimizer = self.make_optimizer
        return self._replace(make_optimizer=lambda config, num_updates: pmean_gradients(
            make_optimizer(config, num_updates), axis_name))

    def learn(self, config, network, train_state: TrainState, transitions: Transition, key, axis_name=None):
        """One update on a rollout, as both drivers make it: GAE, then `update_step`. Returns
        `(train_state, metrics)`: the episode metrics and the losses. With `axis_name` (inside
        a shard_map) the rollout is this device's envs and the metrics are the whole batch's."""
        advantages, targets = gae(transitions, config.gamma, config.gae_lambda)
        if axis_name is None:
            train_state, losses = self.update_step(config, network, train_state, transitions, advantages, targets,
                                                   key)
        else:
            local = config.replace(num_envs=transitions.reward.shape[1])
            train_state, losses = self.update_step(local, network, train_state, transitions, advantages, targets,
                                                   key, axis_name=axis_name)
            losses = jax.lax.pmean(losses, axis_name)
        return train_state, {**episode_metrics(transitions.info, axis_name), **losses}


class Learner(NamedTuple):
    """`train(key, config=config) -> (runner, metrics)`; `init`/`run` split it for chunked runs."""

    init: Callable
    run: Callable
    train: Callable
    network: Any
    num_updates: int
    # On-policy learners: `(runner, config) -> (runner, Transition)`, one rollout as an update
    # collects it (what the update trains on; for inspection and tests).
    rollout: Callable | None = None


def dtype_and_memory(config) -> dict:
    """`UpdateRule.network_options` of a config with `dtype` and `memory` fields (PPO's, A2C's)."""
    return {"dtype": config.dtype, "memory": config.memory}


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


def clip_by_global_norm(max_norm) -> optax.GradientTransformation:
    """`optax.clip_by_global_norm` (the same rule and the same, empty, state) with the norm
    taken in one reduction over every gradient at once: optax reduces each parameter array on
    its own, one kernel per array on a GPU, which a small network's update (bound by kernel
    launches, not arithmetic) pays on every minibatch."""

    def update(updates, state, params=None):
        del params
        leaves = jax.tree_util.tree_leaves(updates)
        norm = jnp.sqrt(jnp.sum(jnp.concatenate([jnp.ravel(g).astype(jnp.float32) for g in leaves]) ** 2))
        keep = norm < max_norm
        return jax.tree_util.tree_map(
            lambda g: jnp.where(keep, g, (g / norm.astype(g.dtype)) * max_norm).astype(g.dtype), updates), state

    return optax.GradientTransformation(lambda params: optax.EmptyState(), update)


def pmean_gradients(tx: optax.GradientTransformation, axis_name) -> optax.GradientTransformation:
    """`tx` applied to the mean of the devices' gradients over `axis_name` (before clipping),
    with `tx`'s own state: a data-parallel run's checkpoints hold what a single device's do."""

    def update(updates, state, params=None, **extra):
        return tx.update(jax.lax.pmean(updates, axis_name), state, params, **extra)

    return optax.GradientTransformation(tx.init, update)


def shard_slice(x, axis_name, axis: int = 0):
    """This device's share of `x` along `axis`, inside a shard_map over `axis_name` (e.g. its
    envs' keys out of `jax.random.split(key, num_envs)`)."""
    size = x.shape[axis] // jax.lax.axis_size(axis_name)
    return jax.lax.dynamic_slice_in_dim(x, jax.lax.axis_index(axis_name) * size, size, axis)


def _stack_batches(a, b):
    """Two batches of observations (pytrees alike) as one: `a`'s rows, then `b`'s."""
    return jax.tree_util.tree_map(lambda x, y: jnp.concatenate([x, y]), a, b)


def _sample_each(keys, logits):
    """One action per env, each drawn with its own key."""
    if isinstance(logits, distributions.Gaussian):  # a shared log-std, given to every env
        logits = logits._replace(log_std=jnp.broadcast_to(logits.log_std, jnp.shape(logits.mean)))
    return jax.vmap(distributions.sample)(keys, logits)


# ---------------------------------------------------------------------------------------------
# Policy calls


def act(network, params, obs, memory: Memory | None):
    """One step of the policy over a batch of envs: `(logits, value, hidden after the step)`;
    `memory` is None for a feed-forward network (hidden is then None too)."""
    if memory is None:
        return (*network.apply(params, obs), None)
    logits, value, hidden = network.apply(params, jax.tree_util.tree_map(lambda x: x[None], obs),
                                          one_step_sequence(memory))
    return jax.tree_util.tree_map(lambda x: x[0], logits), value[0], hidden


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


# ---------------------------------------------------------------------------------------------
# The scan driver: JAX envs


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
                 rollout: Callable | None = None) -> Learner:
    """The jitted `Learner` of `init(key, config) -> runner` and `update(runner, config) ->
    (runner, metrics)` (`runner` a NamedTuple with `train_state` and `update`): `run` repeats
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

    return Learner(init, run, train, network, num_updates, rollout)


def on_policy_learner(config, env, env_params, rule: UpdateRule, axis_name=None) -> Learner:
    """The jitted on-policy learner: a `lax.scan` of updates, each a `lax.scan` rollout of
    `config.num_steps` steps of `config.num_envs` envs, GAE, then `rule.update_step`.

    Args:
        config: the algorithm's config (static fields: num_envs, num_steps, total_timesteps,
            trunk, ...; traced: learning rate, gamma, ...).
        env, env_params: any env with the jaxnat/gymnax API; it should reset itself when an
            episode ends (`jaxnat.make` envs do).
        rule: the algorithm's optimizer, update and network options.
        axis_name: train data parallel over this mesh axis (the functions then run inside a
            `jax.shard_map` over it, the runner's per-env fields split along their env axis,
            the rest replicated; `config.num_envs` counts every device's envs). See the
            module docstring; None: one device, the default learner.
    """
    total_updates = count_updates(config)
    observation_space = env.observation_space(env_params)
    action_space = env.action_space(env_params)
    network = make_actor_critic(observation_space, action_space, config.trunk, **rule.network_options(config))
    normalizing = normalize.switches(config, observation_space)
    reset, step = vector_env(env)
    if axis_name is not None:
        rule = rule.averaged(axis_name)
        if network.memory:
            raise ValueError(f"memory={network.memory}: a recurrent policy's minibatches are whole env rollouts, "
                             "which do not split evenly over devices: place whole seeds on devices instead")

    def env_keys(key, config, shape=()):
        """The keys of this device's envs `[*shape, n]` (every env's without `axis_name`)."""
        keys = jax.random.split(key, (*shape, config.num_envs))
        return keys if axis_name is None else shard_slice(keys, axis_name, axis=len(shape))

    def init(key, config=config) -> RunnerState:
        key, key_net, key_env = jax.random.split(key, 3)
        train_state = rule.train_state(config, network, observation_space, total_updates, key_net)
        keys = env_keys(key_env, config)
        obs, env_state = reset(keys, env_params)
        memory = initial_memory(network, config.num_envs) if network.memory else None
        normalizer = normalize.init_normalizer(*normalizing, observation_space, len(keys))
        return RunnerState(train_state, env_state, obs, key, jnp.zeros((), jnp.int32), memory, normalizer)

    def policy(carry, obs, key, t):
        params, memory, normalizer, pending = carry
        normalizer = normalize.observe(normalizer, obs, axis_name)
        obs = normalize.normalize(normalizer, obs)
        if pending is None:  # recurrent: the final observation is valued in `observe`
            logits, value, hidden = act(network, params, obs, memory)
            pending_value = None
        else:  # this step's observations and the previous step's final ones, in one batch
            logits, values, hidden = act(network, params, _stack_batches(obs, pending), None)
            # (Every leaf of the head's output has a row per observation: a Gaussian's log-std
            # is broadcast to the mean's shape.)
            value, pending_value = jnp.split(values, 2)
            logits = jax.tree_util.tree_map(lambda x: x[:len(value)], logits)
        if axis_name is None:
            action = distributions.sample(key, logits)
        else:
            action = _sample_each(env_keys(key, config), logits)
        return action, (obs, distributions.log_prob(logits, action), value, hidden, normalizer, pending_value)

    def rollout(runner: RunnerState, config):
        """`config.num_steps` steps of every env: `(runner after them, Transition [T, N, ...])`
        (parameters and update count unchanged).

        The value of a step's final observation, as if the episode went on (it bootstraps a
        truncated step), is read in the same network call as the next step's observations (a
        feed-forward policy; the last step's after the loop): a call of its own on every step
        would cost a small network's rollout as many kernel launches again. A recurrent policy
        reads it in `observe`, after this step's memory."""
        params = runner.train_state.params

        def observe(carry, s: EnvStep, aux, t):
            params, memory, _, _ = carry
            obs, log_prob, value, hidden, normalizer, pending_value = aux
            final_obs = normalize.normalize(normalizer, s.final_obs)
            following = None if memory is None else Memory(hidden, s.action, s.reward.astype(jnp.float32),
                                                           jnp.zeros_like(s.done))
            if memory is None:  # V(the previous step's final observation); moved to its step below
                final_value, pending = pending_value, final_obs
            else:
                (_, final_value, _), pending = act(network, params, final_obs, following), None
            normalizer, reward = normalize.scale_rewards(normalizer, s.reward, s.done, config.gamma, axis_name)
            transition = Transition(obs, s.action, log_prob, value, reward, s.done.astype(jnp.float32),
                                    final_value, step_info(s.info, s.terminated),
                                    None if memory is None else memory._replace(hidden=None))
            next_memory = None if memory is None else following._replace(start=s.done)
            return (params, next_memory, normalizer, pending), transition

        pending = None if runner.memory is not None else jax.tree_util.tree_map(
            jnp.zeros_like, normalize.normalize(runner.normalizer, runner.obs))
        ((_, memory, normalizer, pending), env_state, obs, key), transitions = scan_steps(
            step, env_params, action_space, config.num_envs, config.num_steps, policy, observe,
            (params, runner.memory, runner.normalizer, pending), runner.env_state, runner.obs, runner.key,
            None if axis_name is None else lambda key, shape: env_keys(key, config, shape))
        final_values = transitions.next_value  # V(final observation), before `bootstrap`
        if runner.memory is not None:  # the state before the rollout's first step (`replay`)
            transitions = transitions._replace(memory=transitions.memory._replace(hidden=runner.memory.hidden[None]))
        else:  # step t's final value was read at step t + 1; the last step's now
            _, last, _ = act(network, params, pending, None)
            final_values = jnp.concatenate([final_values[1:], last[None]])
        transitions = transitions._replace(next_value=bootstrap(final_values, transitions.info["terminated"]))
        return runner._replace(env_state=env_state, obs=obs, key=key, memory=memory, normalizer=normalizer), transitions

    def update(runner: RunnerState, config):
        runner, transitions = rollout(runner, config)
        key, key_update = jax.random.split(runner.key)
        train_state, metrics = rule.learn(config, network, runner.train_state, transitions, key_update,
                                              axis_name)
        return runner._replace(train_state=train_state, key=key, update=runner.update + 1), metrics

    return scan_learner(config, init, update, lambda config: rule.make_optimizer(config, total_updates), network,
                        total_updates, rollout)


# ---------------------------------------------------------------------------------------------
# The host driver: host-batched envs (the emulator steps in C++ on the host)


class HostState(NamedTuple):
    """A host run's state apart from the env: a pytree (what a checkpoint holds). An emulator's
    state cannot be saved, so `run(state)` starts new games, seeded from `key`."""

    learner: Any  # TrainState (PPO, A2C) or dqn.DQNState
    key: jax.Array
    update: jax.Array  # updates done (int32)


class HostLearner(NamedTuple):
    """`train(key) -> (state, history)`, `run(state) -> (state, history)` and their parts."""

    init: Callable  # key -> HostState at update 0
    run: Callable  # (state, num_updates=None) -> (state, history)
    train: Callable  # (key, num_updates=None) -> (state, history)
    updates: Callable  # state -> iterator of (state, metrics, seconds), one per update, from fresh games
    params: Callable  # state -> the network's params
    greedy: Callable  # jitted (params, obs, key) -> the most likely action [B, F]
    sample: Callable  # jitted (params, obs, key) -> an action sampled from the policy [B, F]
    network: Any
    num_updates: int
    # Where the time of `updates` went, added up over the learner's life (`TIMING_KEYS`); the
    # caller may clear it. On-policy learners time their steps too; DQN's only its updates.
    timings: dict | None = None


def check_host_batch(config, env, memory: int = 0, share: tuple[int, int] | None = None) -> int:
    """The run's update count; `config.num_envs` must equal `env.num_envs` (a host-batched env
    is built with its batch size), or with `share` (`(first, size)`, a data-parallel run's
    `jaxnat.sharding.process_share`) `size`; the policy must be feed-forward (`memory` 0)."""
    if share is not None and share[1] != env.num_envs:
        first, size = share
        raise ValueError(f"config.num_envs={config.num_envs} is split over the devices: this process steps envs "
                         f"{first}..{first + size - 1} ({size}) but the env has {env.num_envs} (build it with "
                         "jaxnat.sharding.process_share)")
    if share is None and config.num_envs != env.num_envs:
        raise ValueError(f"config.num_envs={config.num_envs} but the env has {env.num_envs} envs")
    if memory:
        raise ValueError(f"memory={memory}: recurrent policies train on jitted envs only; a host-batched env "
                         "(Natural Atari) takes a feed-forward policy (memory=0) and frame stacking")
    return count_updates(config)


def host_steps(env, num_steps: int, policy: Callable, observe: Callable, carry, obs, key,
               timings: dict | None = None):
    """`num_steps` steps of a host-batched env from Python: per step one jitted `policy` call
    (observations to the device, actions back to the host) and `observe` with the outcome.
    The callbacks are the scan driver's with the part of the batch last, always 0 here:
    `policy(carry, obs, key, t, part)`, `observe(carry, EnvStep, aux, t, part) -> (carry,
    record)`. Returns `((carry, obs, key), records)`, the records a list, one per step.
    `timings`, when given, adds up where the time went (`TIMING_KEYS`)."""
    (carry, obs_parts, key), records = _step_parts([env], num_steps, policy, observe, carry, [obs], key, timings)
    return (carry, obs_parts[0], key), records


def host_steps_pipelined(env, num_steps: int, policy: Callable, observe: Callable, carry, obs, key,
                         timings: dict | None = None):
    """`host_steps` over the parts of a `jaxnat.atari.wrappers.PipelinedVecEnv` (two or more) in
    turn, so that the device's policy call for one part runs while ALE emulates another:

        send part p's actions; finish part p-1's step (outcome, `observe`), dispatch its next
        policy call; then fetch part p+1's actions (computed meanwhile) and send them ...

    Every action is the current policy's on its env's latest observation, as in `host_steps`;
    only the sampling keys differ (one split of `key` per part and step, in that order). The
    callbacks see one part's envs. Parts with `step_async`/`step_wait` emulate while the driver
    finishes the previous part (its host pass, `observe`, the next policy call); others step in
    `send`. Returns `((carry, obs of the whole batch, key), records)`, the records a list in
    the order the steps ran: step `t` of part `p` at `t * len(env.parts) + p`."""
    if len(env.parts) < 2:
        raise ValueError("host_steps_pipelined needs an env of two or more parts")
    (carry, obs_parts, key), records = _step_parts(env.parts, num_steps, policy, observe, carry, env.split(obs),
                                                   key, timings)
    return (carry, np.concatenate(obs_parts), key), records


def _step_parts(parts: list, num_steps: int, policy: Callable, observe: Callable, carry, obs_parts: list, key,
                timings: dict | None):
    """The host driver over `parts` stepped in turn (events `e = t * len(parts) + part`):
    `((carry, each part's last observations, key), records in event order)`. With one part a
    step's outcome is needed before the next action; with more, part p's outcome is awaited
    after part p+1's actions are sent, so its emulation overlaps the driver's work."""
    count = len(parts)
    overlap = count > 1
    clock = _Clock(timings)
    obs_parts = list(obs_parts)
    total = num_steps * count
    queued, in_flight, records = {}, {}, []

    def dispatch(e, part_obs):
        nonlocal key
        key, key_act = jax.random.split(key)
        obs_device = jax.device_put(part_obs)
        queued[e] = obs_device, policy(carry, obs_device, key_act, e // count, e % count)

    def send(e):
        obs_device, (action, aux) = queued.pop(e)
        action = np.asarray(action)
        clock.lap("policy_s")
        part = parts[e % count]
        env_actions = env_action(action, part.single_action_space)
        if overlap and hasattr(part, "step_async"):
            part.step_async(env_actions)
            outcome = None
        else:
            outcome = part.step(env_actions)
        in_flight[e] = obs_device, action, aux, outcome
        clock.lap("env_s")

    def finish(e):
        nonlocal carry
        obs_device, action, aux, outcome = in_flight.pop(e)
        part = e % count
        if outcome is None:
            outcome = parts[part].step_wait()
        clock.lap("env_s")
        next_obs, reward, terminated, truncated, info = outcome
        carry, record = observe(carry, EnvStep.after(obs_device, action, next_obs, reward, terminated, truncated,
                                                     info), aux, e // count, part)
        records.append(record)
        obs_parts[part] = next_obs
        clock.lap("observe_s")
        if e + count < total:
            dispatch(e + count, next_obs)
            clock.lap("policy_s")

    for e in range(count):
        dispatch(e, obs_parts[e])
    clock.lap("policy_s")
    lag = 1 if overlap else 0  # how many steps are sent ahead of the one finished
    for e in range(total):
        send(e)
        if e >= lag:
            finish(e - lag)
    if lag:
        finish(total - 1)
    clock.done(num_steps)
    return (carry, obs_parts, key), records


# What `host_steps` and `host_updates` add up in a learner's `timings` (seconds and counts):
# per batched step the policy's round trip (key split, observations to the device, the jitted
# call, actions back), the env's step and `observe`; per update the rollout and the whole
# update (rollout, then stacking, GAE and the jitted update until its metrics are on the host).
TIMING_KEYS = ("steps", "policy_s", "env_s", "observe_s", "rollout_s", "updates", "update_s")


class _Clock:
    """Adds the seconds since the previous lap to `timings[name]`; a no-op without `timings`."""

    def __init__(self, timings: dict | None):
        self.timings = timings
        self.start = self.last = time.perf_counter()

    def lap(self, name: str) -> None:
        if self.timings is not None:
            now = time.perf_counter()
            self.timings[name] = self.timings.get(name, 0.0) + now - self.last
            self.last = now

    def done(self, steps: int) -> None:
        if self.timings is not None:
            self.timings["steps"] = self.timings.get("steps", 0) + steps
            self.timings["rollout_s"] = self.timings.get("rollout_s", 0.0) + time.perf_counter() - self.start


def host_updates(env, network, num_updates: int, init_learner: Callable, update: Callable,
                 params: Callable, jit: Callable, timings: dict | None = None, first_env: int = 0) -> HostLearner:
    """The Python loop of updates on a host-batched env. `update(learner, obs, key, update_index)
    -> (learner, obs, key, metrics)` does one update's env steps and learning; `timings` (the
    one `update` hands its `host_steps`, if any) also gets each update's seconds. `first_env`:
    the index of the env's first env in a batch split over processes (its games are seeded
    as that batch's)."""
    timings = {} if timings is None else timings

    greedy, sample = (jit(lambda params, obs, key, g=g: choose(network.apply(params, obs)[0], key, g))
                      for g in (True, False))

    def init(key) -> HostState:
        key, key_init = jax.random.split(key)
        return HostState(init_learner(key_init), key, jnp.zeros((), jnp.int32))

    def updates(state: HostState):
        """Updates `state.update + 1, ...` (up to `num_updates`) on freshly reset envs, one
        `(state, metrics, seconds)` per update; a consumer may stop anywhere (a chunk)."""
        key, key_env = jax.random.split(state.key)
        obs, _ = env.reset(seed=int(jax.random.randint(key_env, (), 0, 2**31 - 1)) + first_env)
        learner = state.learner
        for index in range(int(state.update), num_updates):
            start = time.perf_counter()
            learner, obs, key, metrics = update(learner, obs, key, index)
            metrics = {k: float(v) for k, v in jax.device_get(metrics).items()}
            seconds = time.perf_counter() - start
            timings["updates"] = timings.get("updates", 0) + 1
            timings["update_s"] = timings.get("update_s", 0.0) + seconds
            yield HostState(learner, key, jnp.asarray(index + 1, jnp.int32)), metrics, seconds

    def run(state: HostState, num_updates: int = num_updates):
        """Updates `state.update + 1 .. num_updates` on freshly reset envs: `(state, history)`."""
        history = []
        for state, metrics, _ in itertools.islice(updates(state), max(0, num_updates - int(state.update))):
            history.append(metrics)
        return state, history

    def train(key, num_updates: int = num_updates):
        """Train from scratch."""
        return run(init(key), num_updates)

    return HostLearner(init, run, train, updates, params, greedy, sample, network, num_updates, timings)


def on_policy_host_learner(config, env, rule: UpdateRule, compiler_options: dict | None = None,
                           devices=None) -> HostLearner:
    """The host-loop on-policy learner for `config` (a `PPOConfig` or `A2CConfig`) on a batched
    host env: per env step one jitted policy call, and one value call on final observations
    when an episode ended; per update the rollout goes to the device once and one jitted
    update runs (`rule.update_step`, as the jitted learner's).

    On a `jaxnat.atari.wrappers.PipelinedVecEnv` of two or more parts the steps run through
    `host_steps_pipelined`: each part's policy call overlaps the other parts' emulation. Same
    policy, same update; the action samples use other keys, so the run is not the one-batch
    run bit for bit (with one batch, it is the run it always was).

    `devices` (a count, "all", devices or a mesh: `jaxnat.sharding.device_mesh`): train data
    parallel over them, and over every process of a `jax.distributed` run (one ALE batch per
    host). `env` then holds this process's share of the `config.num_envs` envs
    (`jaxnat.sharding.process_share`), whose games are seeded as that share of one batch; env
    `i` of the whole batch samples its actions with key `i` of each step's `num_envs` keys; the
    update runs under `jax.shard_map` over the mesh on every process's rollouts (`rule.learn`
    with `axis_name`: the gradients averaged by `pmean_gradients`, batch statistics whole), so
    every process holds the same parameters and any process or device count trains the same
    ones to float tolerance (with env parts: given the same parts per process, whose turns
    the step keys follow). Its random draws are not the default learner's (`devices=None`,
    unchanged)."""
    options = rule.network_options(config)
    mesh = None if devices is None else device_mesh(devices)
    if mesh is not None:
        rule = rule.averaged(AXIS)
    share = None if mesh is None else process_share(config.num_envs, mesh)
    num_updates = check_host_batch(config, env, options.get("memory", 0), share)
    observation_space = env.single_observation_space
    if config.normalize_observations or config.normalize_rewards:  # (None, the default, is off here)
        raise ValueError("normalize_observations and normalize_rewards apply to jitted envs; a host-batched "
                         "env (Natural Atari) trains on raw frames and clipped rewards: leave them off")
    network = make_actor_critic(observation_space, env.single_action_space, config.trunk, **options)
    jit = functools.partial(jax.jit, compiler_options=compiler_options)  # XLA options for every program

    @functools.partial(jit, static_argnames="first")
    def policy(params, obs, key, first=None):
        logits, value = network.apply(params, obs)
        if first is None:
            action = distributions.sample(key, logits)
        else:  # data parallel: env i of the whole batch draws with key i (`first`: this call's first env)
            action = _sample_each(jax.random.split(key, config.num_envs)[first:first + len(obs)], logits)
        return action, (distributions.log_prob(logits, action), value)

    @jit
    def value_of(params, obs):
        return network.apply(params, obs)[1]

    init, learn, local_params = _host_programs(config, network, rule, observation_space, num_updates, jit, mesh)
    parts = getattr(env, "parts", None)
    pipelined = parts is not None and len(parts) > 1
    offsets = env.offsets[:-1] if pipelined else [0]
    # Each part's first env in the whole batch (data parallel), or None: the default sampling.
    starts = [None if share is None else share[0] + int(offset) for offset in offsets]
    timings = {}

    def update(train_state, obs, key, index):
        del index  # on-policy updates do not depend on the update count (schedules are in the optimizer)
        params = local_params(train_state)

        def observe(carry, s: EnvStep, aux, t, part):
            log_prob, value = aux
            # V(final observation) where an episode ended; elsewhere the next step's value serves.
            final_value = (value_of(params, jax.device_put(s.final_obs)) if s.done.any()
                           else np.zeros(len(s.done), np.float32))
            return carry, {"obs": s.obs, "action": s.action, "log_prob": log_prob, "value": value, "reward": s.reward,
                           "done": s.done, "terminated": s.terminated, "final_value": final_value,
                           **{k: s.info[k] for k in EPISODE_KEYS}}

        steps = host_steps_pipelined if pipelined else host_steps
        (_, obs, key), records = steps(env, config.num_steps,
                                       lambda carry, o, k, t, part: policy(params, o, k, first=starts[part]),
                                       observe, None, obs, key, timings)
        last_value = [value_of(params, jax.device_put(o)) for o in (env.split(obs) if pipelined else [obs])]
        # name -> one entry per part of the batch: its steps. Host arrays (actions, rewards,
        # flags, episode statistics) stacked here go to the device as one transfer per name and
        # part, not one per step.
        count = len(parts) if pipelined else 1
        rollout = {name: [[r[name] for r in records[p::count]] for p in range(count)] for name in records[0]}
        rollout = {name: [np.stack(steps) if all(isinstance(x, np.ndarray) for x in steps) else steps
                          for steps in part_steps] for name, part_steps in rollout.items()}
        transitions = _host_transitions(rollout, last_value)
        key, key_update = jax.random.split(key)
        train_state, metrics = learn(train_state, transitions, key_update)
        return train_state, obs, key, metrics

    return host_updates(env, network, num_updates, init, update, lambda s: local_params(s.learner), jit, timings,
                        0 if share is None else share[0])


def _host_programs(config, network, rule: UpdateRule, observation_space, num_updates: int, jit: Callable, mesh):
    """`(init, learn, local_params)` of an on-policy host learner: `init(key) -> TrainState`,
    `learn(train_state, transitions, key) -> (train_state, metrics)` on this process's rollout,
    and `local_params(train_state)`, the parameters its policy calls read. Without `mesh`,
    programs of one device. With it, data parallel (`rule` is then `UpdateRule.averaged`): the
    train state replicated over the mesh, and `learn` runs `rule.learn`
    with `AXIS` under `jax.shard_map` on every process's rollouts side by side (each process
    gives its own: `jax.make_array_from_process_local_data`) with the same key in every
    process; the policy reads this process's copy of the parameters."""
    # One compiled program, not hundreds of small eager ones.
    make_state = jit(lambda key: rule.train_state(config, network, observation_space, num_updates, key))
    if mesh is None:
        learn = jit(lambda train_state, transitions, key: rule.learn(config, network, train_state, transitions, key))
        return make_state, learn, lambda train_state: train_state.params
    whole, per_env = PartitionSpec(), PartitionSpec(None, AXIS)  # replicated; split along the env axis
    program = shard_program(lambda train_state, transitions, key: rule.learn(
        config, network, train_state, transitions, key, AXIS), mesh, (whole, per_env, whole), (whole, whole), jit)

    def init(key):
        return put_global(make_state(key), replicated(mesh))

    def learn(train_state, transitions, key):
        transitions = jax.make_array_from_process_local_data(sharded(mesh, 1), transitions)
        return program(train_state, transitions, put_global(key, replicated(mesh)))

    return init, learn, lambda train_state: local_copy(train_state.params)


@jax.jit
def _host_transitions(rollout: dict, last_value: list) -> Transition:
    """Stack the per-step lists (host and device arrays, or arrays stacked already; one per part
    of the batch, the parts side by side) into a time-major `Transition` on the device; the value after a step
    is the next step's (the last one's: `last_value`, one array per part), or V(final
    observation) where the episode ended."""
    stacked = {name: jnp.concatenate([jnp.stack(steps) if isinstance(steps, list) else steps for steps in parts],
                                     axis=1)
               for name, parts in rollout.items()}
    value, done, terminated = stacked["value"], stacked["done"], stacked["terminated"]
    following = jnp.concatenate([value[1:], jnp.concatenate(last_value)[None]])
    info = {name: stacked[name] for name in EPISODE_KEYS}
    return Transition(
        obs=stacked["obs"],
        action=stacked["action"],
        log_prob=stacked["log_prob"],
        value=value,
        reward=stacked["reward"].astype(jnp.float32),
        done=done.astype(jnp.float32),
        next_value=bootstrap(jnp.where(done, stacked["final_value"], following), terminated),
        info=step_info(info, terminated),
    )


# ---------------------------------------------------------------------------------------------
# Evaluation


def _first_episodes(env, env_params, num_episodes: int, max_steps: int | None):
    """`play(policy, memory, key) -> scores`: each of `num_episodes` envs plays its first episode
    to the end (at most `max_steps` steps); `policy(obs, key, memory) -> (action [B, F], hidden)`."""
    if max_steps is None:
        max_steps = int(env_params.max_steps_in_episode)
    action_space = env.action_space(env_params)
    reset = jax.vmap(env.reset, in_axes=(0, None))
    step = jax.vmap(env.step, in_axes=(0, 0, 0, None))

    def play(policy: Callable, memory, key):
        key_reset, key_steps = jax.random.split(key)
        obs, state = reset(jax.random.split(key_reset, num_episodes), env_params)
        zeros = jnp.zeros(num_episodes)
        running = jnp.ones(num_episodes, bool)

        def body(carry, key):
            obs, state, running, total, length, terminated_any, memory = carry
            key_act, key_env = jax.random.split(key)
            action, hidden = policy(obs, key_act, memory)
            obs, state, reward, terminated, truncated, _ = step(
                jax.random.split(key_env, num_episodes), state, env_action(action, action_space), env_params
            )
            total = total + jnp.where(running, reward, 0.0)
            length = length + running
            terminated_any = terminated_any | (running & terminated)
            running = running & ~(terminated | truncated)
            if memory is not None:  # the first episode is all that counts: no reset to mark
                memory = Memory(hidden, action, reward.astype(jnp.float32), jnp.zeros_like(running))
            return (obs, state, running, total, length, terminated_any, memory), None

        carry = (obs, state, running, zeros, zeros, jnp.zeros(num_episodes, bool), memory)
        (_, _, running, total, length, terminated, _), _ = jax.lax.scan(
            body, carry, jax.random.split(key_steps, max_steps)
        )
        return {"return": total.mean(), "terminated_fraction": terminated.mean(),
                "length": length.mean(), "unfinished": running.mean()}

    return play


def make_evaluate(network, env, env_params, num_episodes: int = 1000, max_steps: int | None = None):
    """`evaluate(network_params, key, normalizer=None) -> dict of scalars`; pure and jittable.

        evaluate = make_evaluate(learner.network, test_env, test_params, num_episodes=1000)
        scores = jax.jit(jax.vmap(evaluate))(runner.train_state.params, keys, runner.normalizer)

    Each of `num_episodes` envs (built with `autoreset=False`) plays its first episode to the
    end (at most `max_steps` steps, default the env's time limit); the result holds the mean
    return, the fraction of episodes that terminated (for classification: were classified
    correctly), the mean length and the fraction unfinished, for the greedy policy (most likely
    action per factor, or a Gaussian's mean) and for actions sampled from the policy. A learner
    that normalises observations passes its `normalizer` (`RunnerState.normalizer`), which is
    read, never updated: the policy sees what it was trained on.
    """
    play = _first_episodes(env, env_params, num_episodes, max_steps)

    def evaluate(network_params, key, normalizer: normalize.Normalizer | None = None):
        def policy(obs, key, memory, greedy: bool):
            logits, _, hidden = act(network, network_params, normalize.normalize(normalizer, obs), memory)
            return choose(logits, key, greedy), hidden

        memory = initial_memory(network, num_episodes) if network.memory else None
        key_greedy, key_sampled = jax.random.split(key)
        greedy = play(functools.partial(policy, greedy=True), memory, key_greedy)
        sampled = play(functools.partial(policy, greedy=False), memory, key_sampled)
        return {**{f"greedy_{k}": v for k, v in greedy.items()},
                **{f"sampled_{k}": v for k, v in sampled.items()}}

    return evaluate


def make_chance(env, env_params, num_episodes: int = 1000, max_steps: int | None = None):
    """`chance(key) -> dict of scalars`: `make_evaluate`'s scores for the uniform random policy
    (every action factor drawn uniformly), the baseline a trained policy must beat."""
    play = _first_episodes(env, env_params, num_episodes, max_steps)
    space = env.action_space(env_params)

    def uniform(obs, key, memory):
        action = jax.vmap(space.sample)(jax.random.split(key, num_episodes))
        return (action[:, None] if is_scalar_action(space) else action), None

    return lambda key: play(uniform, None, key)


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
