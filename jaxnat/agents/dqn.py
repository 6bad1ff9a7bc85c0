"""DQN (Mnih et al. 2015, "Nature DQN"), fully jitted: envs, replay buffer and learner on the
device, vmappable over seeds like `ppo.py`.

    learner = make_dqn(DQNConfig(total_timesteps=1_000_000), env, params)
    runner, metrics = jax.jit(jax.vmap(learner.train))(jax.random.split(jax.random.key(0), 5))

One update: `num_steps` epsilon-greedy steps of `num_envs` envs go into the replay buffer,
then `gradient_steps` TD-loss steps (`loss`: squared error, or Nature DQN's Huber) on
minibatches of `batch_size` sampled uniformly from it (none before `learning_starts` env
steps); every `target_update_period` gradient steps the target network copies the online one
(`tau=1`), or moves a fraction `tau` of the way to it (Polyak averaging, as rejax's and SB3's
`tau < 1`).
`double_dqn` picks the next action with the online network and values it with the target one
(van Hasselt et al. 2016). `n_step` > 1 stores n-step returns (Sutton 1988; as Rainbow): the
transition from `s_t` carries `r_t + gamma r_{t+1} + ... + gamma^{m-1} r_{t+m-1}` and
bootstraps from `s_{t+m}` with `gamma^m`, where m = n, or fewer when the episode ends first
(then no bootstrap if it terminated, a bootstrap from its final observation if it was
truncated). One-step Q-learning cannot solve a task whose reward comes after an observation
that hides the earlier action (`probes.TwoStepProbe`); two-step returns can.

Settings: Nature DQN's (RMSprop lr 2.5e-4, decay 0.95, centered, batch 32, gamma 0.99, epsilon
1.0 -> 0.1, one gradient step per 4 env steps) but for the loss, the squared error (Huber's is
`loss="huber"`, which `jaxnat train` keeps for Atari; see `DQNConfig`), and with the replay
memory, exploration period, learning start and target period 10x shorter (100k, 100k, 10k env
steps; 1k gradient steps) since the paper's tasks train for 1-10M steps rather than Atari's
50M. RMSprop's epsilon is 1e-5 (Dopamine's, for a loss averaged over the batch), not
DeepMind's 0.01 (`docs/design.md`, "Factored actions in DQN", says why).
`optimizer="adam"` uses Adam (eps 1.5e-4, as Dopamine's DQN).
Time limits: the target bootstraps from the final observation of a truncated episode and not
from a terminated one (`rollout.bootstrap`'s rule).

Factored actions (classification's `(move, label)`): one Q head per factor over the shared
trunk ("action branching", Tavakoli et al. 2018; `docs/design.md`, "Factored actions in DQN",
says why not one head over the product space). Every head learns towards the same target,
`r + gamma * mean_f max_a Q_f(s', a)`, so each `Q_f(s, a_f)` estimates the return of taking
`a_f` while the other factors follow the behaviour policy. The greedy action is the argmax of
each head. The network is jaxnat's actor-critic whose "logits" are the Q values (its value
head is unused), so evaluation's greedy policy is `argmax Q` per factor (its "sampled" policy
is a Boltzmann one over Q); with `q_network=True`, its `mlp` trunk is CleanRL's and
PureJaxRL's Q-network, one ReLU MLP of 120 and 84 units, rather than the actor-critic's two
tanh MLPs of 64 (see `DQNConfig`).

The pieces (`DQNParts`: init, act, store, learn) serve both drivers of `jaxnat.agents.rollout`:
`make_dqn` here (jitted, JAX envs) and `dqn_host.make_host_dqn` (host-batched envs such as
Natural Atari, where the env steps in Python).
"""

from __future__ import annotations

import functools
from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import optax
from flax import struct
from flax.training.train_state import TrainState

from jaxnat.agents import distributions, normalize
from jaxnat.agents.config import check_ranges, static
from jaxnat.agents.networks import init_params, make_actor_critic
from jaxnat.agents.rollout import (EnvStep, Learner, count_updates, episode_metrics, scan_learner, scan_steps, step_info,
                                   vector_env)
from jaxnat.agents.replay import ReplayBuffer, replay_add, replay_init, replay_sample

__all__ = ["DQNConfig", "DQNRunner", "DQNState", "DQNParts", "epsilon", "learning_on", "step_callbacks", "make_dqn",
           "make_dqn_parts", "make_train", "nstep_transition", "td_error_loss", "td_loss"]

OPTIMIZERS = {  # name -> (config -> the optax optimizer)
    "rmsprop": lambda c: optax.rmsprop(c.lr, decay=c.rms_decay, eps=c.rms_eps, centered=True),
    "adam": lambda c: optax.adam(c.lr, eps=c.adam_eps),
}
LOSSES = {"mse": jnp.square, "huber": lambda errors: optax.huber_loss(errors, delta=1.0)}  # of each TD error


def _pick(table: dict, name: str, what: str):
    if name not in table:
        raise ValueError(f"DQN {what} {name!r} is not one of {tuple(table)}")
    return table[name]


@struct.dataclass
class DQNConfig:
    """DQN's settings (defaults: the module docstring).

    `loss` is the loss of the TD error: `"mse"` (the default) its square, as in PureJaxRL's and
    CleanRL's DQN, or `"huber"`, Huber's with delta 1, Nature DQN's. NaturalAtari uses
    `"huber"` (`jaxnat train` sets it unless `--loss` is given; its rewards are clipped to
    [-1, 1]), every other family `"mse"`. With the `mlp` trunk (vector observations) the
    Q-network is one ReLU MLP of 120 and 84 units (`networks.Q_MLP`, CleanRL's and
    PureJaxRL's). Why both: `docs/design.md`, "Agents against the reference implementations".
    """

    total_timesteps: int = static(1_000_000)
    num_envs: int = static(8)
    num_steps: int = static(4)  # env steps per env per update
    gradient_steps: int = static(8)  # per update: one per 4 env steps with the defaults
    batch_size: int = static(32)
    buffer_size: int = static(100_000)
    n_step: int = static(1)  # returns over this many steps (1: Nature DQN's one-step target)
    optimizer: str = static("rmsprop")
    loss: str = static("mse")  # of the TD error: "mse" (squared) or "huber" (Nature DQN's, delta 1)
    double_dqn: bool = static(False)
    trunk: str | None = static(None)
    # Store sign(reward) (baselines' Atari `ClipRewardEnv`); episode returns reported stay the env's.
    clip_rewards: bool = static(False)
    lr: float = 2.5e-4
    rms_decay: float = 0.95
    rms_eps: float = 1e-5
    adam_eps: float = 1.5e-4
    gamma: float = 0.99
    eps_start: float = 1.0
    eps_end: float = 0.1
    exploration_steps: int = 100_000  # env steps (per seed) of the linear epsilon decay
    learning_starts: int = 10_000  # env steps (per seed) before the first gradient step
    target_update_period: int = 1_000  # gradient steps
    tau: float = 1.0  # target <- tau * online + (1 - tau) * target at each target update (1: a copy)


class DQNState(NamedTuple):
    """What DQN learns with, apart from the envs: a pytree (checkpointed as a whole)."""

    train_state: TrainState  # online network; `step` counts gradient steps taken
    target_params: Any
    buffer: ReplayBuffer  # n-step transitions: obs, action, reward, next_obs, discount
    recent: dict  # the last `n_step` one-step transitions of every env, [n_step, num_envs, ...]


class DQNRunner(NamedTuple):
    """The jitted loop's carry: `DQNState`'s fields, flat, and the envs'."""

    train_state: TrainState
    target_params: Any
    buffer: ReplayBuffer
    recent: dict
    env_state: Any
    obs: Any
    key: jax.Array
    update: jax.Array  # updates done so far (int32)

    @property
    def learner(self) -> DQNState:
        return DQNState(**{name: getattr(self, name) for name in DQNState._fields})

    def with_learner(self, learner: DQNState, **changes) -> DQNRunner:
        """This runner with `learner`'s fields, and `changes` to the others, by name."""
        return self._replace(**learner._asdict(), **changes)


class DQNParts(NamedTuple):
    """DQN's pieces, pure and jittable, shared by the jitted loop here and the host loop.

    - `init(key, obs, config) -> DQNState` (`obs`: a batch of `num_envs` observations)
    - `act(params, obs, key, rate) -> action [B, F]`: epsilon-greedy with exploration `rate`
    - `store(state, step, steps_taken, config) -> state`: one env step of every env
      (`step`: obs, action, reward, next_obs = the final observation where an episode ended,
      terminated, done) joins `recent`; once `steps_taken` (before this one) reaches
      `n_step - 1`, the n-step transition from the oldest goes into the buffer
    - `learn(state, key, learning, config) -> (state, losses)`: `gradient_steps` TD steps
      (no-ops unless `learning`), with the target-network copies
    """

    network: Any
    init: Callable
    act: Callable
    store: Callable
    learn: Callable


def epsilon(config: DQNConfig, env_steps):
    """Exploration rate after `env_steps` env steps (per seed): linear from `eps_start` to
    `eps_end` over `exploration_steps`, then constant."""
    done = jnp.clip(env_steps / jnp.maximum(config.exploration_steps, 1), 0.0, 1.0)
    return config.eps_start + (config.eps_end - config.eps_start) * done


def _optimizer(config: DQNConfig):
    return _pick(OPTIMIZERS, config.optimizer, "optimizer")(config)


def learning_on(config: DQNConfig, update):
    """Whether update number `update` (from 0) takes its gradient steps: by its end, the seed's
    envs have made `learning_starts` steps."""
    return (update + 1) * config.num_steps * config.num_envs >= config.learning_starts


def nstep_transition(recent: dict, gamma) -> dict:
    """The n-step transition from the oldest of `recent`'s one-step transitions (`[n, B, ...]`,
    oldest first): `reward = sum_k gamma^k r_k` over the first m steps (m = n, or up to and
    including the first step that ended its episode), `next_obs` = that step's next (final)
    observation, `discount = gamma^m`, or 0 if it terminated."""
    done = recent["done"].astype(jnp.float32)
    n = done.shape[0]
    # alive[k]: steps 0..k-1 all continued the episode, so step k belongs to the return.
    alive = jnp.cumprod(jnp.concatenate([jnp.ones_like(done[:1]), 1.0 - done[:-1]]), axis=0)
    powers = gamma ** jnp.arange(n, dtype=jnp.float32).reshape((n,) + (1,) * (done.ndim - 1))
    reward = jnp.sum(alive * powers * recent["reward"], axis=0)
    steps = jnp.sum(alive, axis=0)
    last = steps.astype(jnp.int32) - 1  # the step the return ends with
    pick = lambda x: jnp.take_along_axis(  # noqa: E731
        x, last.reshape((1, -1) + (1,) * (x.ndim - 2)), axis=0)[0]
    discount = gamma ** steps * (1.0 - pick(recent["terminated"].astype(jnp.float32)))
    return {"obs": jax.tree.map(lambda x: x[0], recent["obs"]),
            "action": recent["action"][0], "reward": reward,
            "next_obs": jax.tree.map(pick, recent["next_obs"]), "discount": discount}


def td_error_loss(errors, loss: str):
    """Per-element loss of TD errors: `"mse"` their square, `"huber"` Huber's with delta 1
    (`e^2 / 2` for `|e| <= 1`, `|e| - 1/2` beyond)."""
    return _pick(LOSSES, loss, "loss")(errors)


def _chosen(q, actions) -> jax.Array:
    """The Q value of each factor's action in `actions` `[B, F]`, as `[F, B]`."""
    return jnp.stack([jnp.take_along_axis(qf, actions[:, f : f + 1], -1)[:, 0] for f, qf in enumerate(q)])


def td_loss(config: DQNConfig, network, params, target_params, batch) -> tuple[jax.Array, dict]:
    """Mean TD loss (`config.loss`) over the batch and the action factors; the target is
    `reward + discount * mean_f next value_f` (`discount` = gamma^m, 0 at termination)."""
    q, _ = network.apply(params, batch["obs"])
    q_next, _ = network.apply(target_params, batch["next_obs"])
    if config.double_dqn:
        online_next, _ = network.apply(params, batch["next_obs"])
        next_values = _chosen(q_next, distributions.mode(online_next))
    else:
        next_values = jnp.stack([qf.max(-1) for qf in q_next])
    target = jax.lax.stop_gradient(batch["reward"] + batch["discount"] * jnp.mean(next_values, axis=0))
    taken = _chosen(q, batch["action"])
    loss = td_error_loss(taken - target, config.loss).mean()
    return loss, {"loss": loss, "q_mean": taken.mean()}


def check_config(config: DQNConfig) -> None:
    _pick(OPTIMIZERS, config.optimizer, "optimizer")
    _pick(LOSSES, config.loss, "loss")
    if config.buffer_size < config.num_envs:
        raise ValueError(f"buffer_size={config.buffer_size} is smaller than one env step of "
                         f"num_envs={config.num_envs} envs")
    if isinstance(config.tau, (int, float)) and not 0 < config.tau <= 1:  # (a traced tau is not checked)
        raise ValueError(f"tau={config.tau} must be in (0, 1]: 1 copies the online network, less moves the "
                         "target that fraction of the way")
    check_ranges(config)


def _stored(s: EnvStep, clip: bool = False) -> dict:
    """What `DQNParts.store` takes from an env step: its final observation as `next_obs`, its
    rewards sign-clipped if `clip` (`normalize.sign_clip`, the on-policy learners' clipping)."""
    reward = normalize.sign_clip(s.reward, True) if clip else s.reward
    return {"obs": s.obs, "action": s.action, "reward": reward, "next_obs": s.final_obs,
            "terminated": s.terminated, "done": s.done}


def step_callbacks(config: DQNConfig, first_step, act: Callable, store: Callable, rate_of: Callable):
    """Both drivers' `(policy, observe)` for one update whose first step (per env) is
    `first_step`: epsilon-greedy actions at each step's rate (`rate_of(env steps)`), every step
    `store`d; a step's record is `(episode info, rate)`."""

    def policy(state: DQNState, obs, key, t, part=0):
        rate = rate_of((first_step + t) * config.num_envs)
        return act(state.train_state.params, obs, key, rate), rate

    def observe(state: DQNState, s: EnvStep, rate, t, part=0):
        return store(state, _stored(s, config.clip_rewards), first_step + t), (step_info(s.info, s.terminated), rate)

    return policy, observe


def make_dqn_parts(config: DQNConfig, observation_space, action_space) -> DQNParts:
    """DQN's network and pure functions for these spaces (see `DQNParts`)."""
    check_config(config)
    network = make_actor_critic(observation_space, action_space, config.trunk, q_network=True)
    dims = network.action_dims

    def init(key, obs, config=config) -> DQNState:
        params = init_params(network, observation_space, key)
        train_state = TrainState.create(apply_fn=network.apply, params=params, tx=_optimizer(config))
        num_envs = jax.tree.leaves(obs)[0].shape[0]
        step = {"obs": obs, "action": jnp.zeros((num_envs, len(dims)), jnp.int32),
                "reward": jnp.zeros(num_envs, jnp.float32), "next_obs": obs,
                "terminated": jnp.zeros(num_envs, bool), "done": jnp.zeros(num_envs, bool)}
        recent = jax.tree.map(lambda x: jnp.zeros((config.n_step, *x.shape), x.dtype), step)
        item = jax.tree.map(lambda x: x[0], nstep_transition(recent, config.gamma))
        return DQNState(train_state, params, replay_init(item, config.buffer_size), recent)

    def act(params, obs, key, rate):
        q, _ = network.apply(params, obs)
        greedy = distributions.mode(q)
        # One uniform draw per env for the coin and every factor's random action (a split and
        # a `randint` per factor would each be a loop of their own on a GPU, on every step).
        u = jax.random.uniform(key, (greedy.shape[0], 1 + len(dims)))
        sizes = jnp.asarray(dims, jnp.int32)
        random = jnp.minimum((u[:, 1:] * sizes).astype(jnp.int32), sizes - 1)
        explore = u[:, 0] < rate
        return jnp.where(explore[:, None], random, greedy).astype(jnp.int32)

    def store(state: DQNState, step: dict, steps_taken, config=config) -> DQNState:
        recent = jax.tree.map(lambda old, new: jnp.concatenate([old[1:], new[None].astype(old.dtype)]),
                              state.recent, step)
        buffer = jax.lax.cond(
            steps_taken >= config.n_step - 1,
            lambda b: replay_add(b, nstep_transition(recent, config.gamma)),
            lambda b: b, state.buffer)
        return state._replace(buffer=buffer, recent=recent)

    def gradient_step(carry, key, config, learning):
        train_state, target_params, buffer = carry
        batch = replay_sample(buffer, key, config.batch_size)
        grads, losses = jax.grad(
            lambda p: td_loss(config, network, p, target_params, batch), has_aux=True
        )(train_state.params)
        stepped = train_state.apply_gradients(grads=grads)
        train_state = jax.tree.map(lambda new, old: jnp.where(learning, new, old), stepped, train_state)
        copy = learning & (train_state.step % config.target_update_period == 0)
        # tau = 1 selects the online parameters themselves: a hard copy, bit for bit.
        moved = jax.tree.map(lambda p, t: jnp.where(config.tau == 1.0, p, optax.incremental_update(p, t, config.tau)),
                             train_state.params, target_params)
        target_params = jax.tree.map(lambda m, t: jnp.where(copy, m, t), moved, target_params)
        return (train_state, target_params, buffer), losses

    def learn(state: DQNState, key, learning, config=config) -> tuple[DQNState, dict]:
        (train_state, target_params, _), losses = jax.lax.scan(
            lambda c, k: gradient_step(c, k, config, learning),
            (state.train_state, state.target_params, state.buffer),
            jax.random.split(key, config.gradient_steps),
        )
        state = state._replace(train_state=train_state, target_params=target_params)
        return state, jax.tree.map(jnp.mean, losses)

    return DQNParts(network, init, act, store, learn)


def make_dqn(config: DQNConfig, env, env_params) -> Learner:
    """The DQN learner (`init`, `run`, `train`, `network`, `num_updates`)."""
    total_updates = count_updates(config)
    action_space = env.action_space(env_params)
    parts = make_dqn_parts(config, env.observation_space(env_params), action_space)
    reset, step = vector_env(env)

    def init(key, config=config) -> DQNRunner:
        key, key_net, key_env = jax.random.split(key, 3)
        obs, env_state = reset(jax.random.split(key_env, config.num_envs), env_params)
        state = parts.init(key_net, obs, config)
        return DQNRunner(**state._asdict(), env_state=env_state, obs=obs, key=key,
                         update=jnp.zeros((), jnp.int32))

    def update(runner: DQNRunner, config):
        first_step = runner.update * config.num_steps  # per env, before this update
        policy, observe = step_callbacks(config, first_step, parts.act, functools.partial(parts.store, config=config),
                                          functools.partial(epsilon, config))
        (state, env_state, obs, key), (infos, rates) = scan_steps(
            step, env_params, action_space, config.num_envs, config.num_steps, policy, observe,
            runner.learner, runner.env_state, runner.obs, runner.key)
        key, key_learn = jax.random.split(key)
        state, losses = parts.learn(state, key_learn, learning_on(config, runner.update), config)
        runner = runner.with_learner(state, env_state=env_state, obs=obs, key=key, update=runner.update + 1)
        return runner, {**episode_metrics(infos), **losses, "epsilon": rates[-1]}

    return scan_learner(config, init, update, _optimizer, parts.network, total_updates, _policy_of, _per_env)


def _policy_of(runner: DQNRunner):
    """What the greedy policy acts with (`Learner.policy_of`): the online network's parameters;
    DQN reads raw observations."""
    return runner.train_state.params, None


def _per_env(runner: DQNRunner) -> DQNRunner:
    """The runner's parts with an env axis (`Learner.per_env`): the envs', and the recent
    one-step transitions (`[n_step, num_envs, ...]`: not first, so DQN does not split them;
    it trains on whole seeds)."""
    return DQNRunner(train_state=False, target_params=False, buffer=False, recent=False, env_state=True, obs=True,
                     key=False, update=False)


def make_train(config: DQNConfig, env, env_params):
    """`train(key, config=config) -> (runner, metrics)`, pure and jittable."""
    return make_dqn(config, env, env_params).train
