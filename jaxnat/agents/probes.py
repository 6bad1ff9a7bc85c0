"""Probe environments for debugging RL agents (Andy Jones' probes, bsuite-style).

Each probe isolates one thing a learner must get right, in one or two steps, with float32 vector
observations (use `trunk="mlp"`). If an agent fails a probe, the broken piece is named:

| probe                 | episode | what is learned                          | fails when                   |
|-----------------------|---------|------------------------------------------|------------------------------|
| `ConstantRewardProbe` | 1 step  | `V(obs) = params.reward`                 | value loss / targets broken  |
| `SignProbe`           | 1 step  | `argmax pi([c]) = (c > 0)`, c = +-1      | policy gradient broken       |
| `TwoStepProbe`        | 2 steps | step-1 action from the step-2 reward     | credit through time broken   |
| `FactoredProbe`       | 1 step  | both factors of `MultiDiscrete([2, 3])`  | factored heads broken        |
| `EndlessProbe`        | never   | `V = 1 / (1 - gamma)` despite time limit | truncation treated as a stop |
| `CostlyStartProbe`    | never   | as above, first step differs             | bootstrap from the reset obs |
| `RecallProbe`         | 2 steps | step-2 action from the step-1 cue        | memory (needs `memory > 0`)  |
| `TargetProbe`         | 1 step  | `mean pi([t]) = t`, a Box action         | Gaussian policy broken       |
| `OpenLoopProbe`       | 1 step  | one action `0.5` whatever noise is seen  | open-loop control from noise |

All are jaxnat `Environment`s with `get_obs`; wrap them in `AutoResetWrapper` (or use
`make_probe`) before giving them to a learner. Optimal returns: 1.0 per episode for the
one- and two-step discrete probes; `EndlessProbe` earns 1.0 per step; the continuous ones
(`Box(-1, 1, (1,))` actions) pay `-(action - target)^2` after clipping to the bounds, 0 at best.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from jaxnat import spaces
from jaxnat.core import Environment, EnvParams, EnvState
from jaxnat.wrappers import AutoResetWrapper

__all__ = ["ProbeState", "ProbeParams", "ConstantRewardProbe", "SignProbe", "TwoStepProbe", "FactoredProbe",
           "EndlessProbe", "CostlyStartProbe", "RecallProbe", "TargetProbe", "OpenLoopProbe", "PROBES",
           "make_probe"]


@struct.dataclass
class ProbeState(EnvState):
    """`cue`: what the observation shows (int32 `[2]`; probes use what they need);
    `first_action`: the action taken at step 1 (`TwoStepProbe`)."""

    cue: jax.Array
    first_action: jax.Array


@struct.dataclass
class ProbeParams(EnvParams):
    """`reward`: the reward of `ConstantRewardProbe` (traced). The one- and two-step probes end
    by termination long before the default time limit; `EndlessProbe` sets a short one."""

    max_steps_in_episode: int = 100
    reward: float = 1.0


def _state(cue) -> ProbeState:
    """An episode's first state, showing `cue`."""
    zero = jnp.asarray(0, jnp.int32)
    return ProbeState(time=zero, cue=jnp.asarray(cue, jnp.int32), first_action=zero)


def _random_sign(key) -> ProbeState:
    """A cue `c = +-1` at random, held as `(c > 0)` in `cue[0]`."""
    return _state(jnp.stack([jax.random.bernoulli(key).astype(jnp.int32), 0]))


def _squared_miss(action, target):
    """`-(a - target)^2` for a `Box(-1, 1, (1,))` action `a` clipped to the bounds."""
    action = jnp.clip(jnp.reshape(action, (1,)), -1.0, 1.0)
    return -jnp.sum((action - target) ** 2).astype(jnp.float32)


class _Probe(Environment):
    """Defaults: observation `[1.0]` (`obs_size` floats in [-1, 1]), `Discrete(num_actions)`
    actions, or `Box(-1, 1, (1,))` ones when `continuous`; a time limit of `time_limit` steps."""

    obs_size = 1
    num_actions = 2
    continuous = False
    time_limit = 100

    @property
    def default_params(self) -> ProbeParams:
        return ProbeParams(max_steps_in_episode=self.time_limit)

    def observation_space(self, params) -> spaces.Box:
        return spaces.Box(-1.0, 1.0, (self.obs_size,), jnp.float32)

    def action_space(self, params) -> spaces.Space:
        return spaces.Box(-1.0, 1.0, (1,), jnp.float32) if self.continuous else spaces.Discrete(self.num_actions)

    def reset_env(self, key, params):
        state = self._initial_state(key)
        return self.get_obs(state, params), state

    def _initial_state(self, key) -> ProbeState:
        return _state(jnp.zeros(2, jnp.int32))

    def get_obs(self, state, params):
        return jnp.ones((1,), jnp.float32)


class ConstantRewardProbe(_Probe):
    """Constant observation `[1.0]`, one action, reward `params.reward`, one-step episodes.

    The critic must output `params.reward` (no bootstrapping: the step terminates)."""

    num_actions = 1

    def step_env(self, key, state, action, params):
        return self.get_obs(state, params), state, jnp.float32(params.reward), jnp.bool_(True), {}


class SignProbe(_Probe):
    """Observation `[c]`, `c = +1` or `-1` at random; `Discrete(2)`; reward 1 if
    `action == (c > 0)`, else 0; one-step episodes. The policy must read the observation."""

    _initial_state = staticmethod(_random_sign)

    def get_obs(self, state, params):
        return (2.0 * state.cue[:1] - 1.0).astype(jnp.float32)

    def step_env(self, key, state, action, params):
        reward = (action == state.cue[0]).astype(jnp.float32)
        return self.get_obs(state, params), state, reward, jnp.bool_(True), {}


class TwoStepProbe(_Probe):
    """Two-step episodes. Step 1 shows `[c, 0]`, `c = +-1` at random; step 2 shows `[0, 1]`
    whatever happened (so the step-2 value cannot tell good from bad first actions). Reward is 0
    at step 1 and, at step 2, 1 if the step-1 action was `(c > 0)`, else 0. The step-2 action
    does not matter. Only a return that carries the step-2 reward back to step 1 (GAE with
    lambda > 0 over the non-terminal step) teaches the step-1 policy."""

    obs_size = 2
    _initial_state = staticmethod(_random_sign)

    def get_obs(self, state, params):
        first = state.time == 0
        cue = 2.0 * state.cue[0] - 1.0
        return jnp.stack([jnp.where(first, cue, 0.0), jnp.where(first, 0.0, 1.0)]).astype(jnp.float32)

    def step_env(self, key, state, action, params):
        first = state.time == 0
        reward = jnp.where(first, 0.0, (state.first_action == state.cue[0]).astype(jnp.float32))
        next_state = state.replace(first_action=jnp.where(first, action, state.first_action))
        # `Environment.step` advances `time` after this; the observation is of the next step.
        obs = self.get_obs(next_state.replace(time=state.time + 1), params)
        return obs, next_state, reward, ~first, {}


class FactoredProbe(_Probe):
    """`MultiDiscrete([2, 3])` actions. The observation one-hot encodes a random target
    `(t0, t1)`, `t0 in {0, 1}`, `t1 in {0, 1, 2}` (5 floats); reward 1 only if the action equals
    the target in both factors, else 0; one-step episodes."""

    obs_size = 5

    def action_space(self, params) -> spaces.MultiDiscrete:
        return spaces.MultiDiscrete([2, 3])

    def _initial_state(self, key):
        k0, k1 = jax.random.split(key)
        cue = jnp.stack([jax.random.randint(k0, (), 0, 2), jax.random.randint(k1, (), 0, 3)])
        return _state(cue)

    def get_obs(self, state, params):
        return jnp.concatenate(
            [jax.nn.one_hot(state.cue[0], 2), jax.nn.one_hot(state.cue[1], 3)]
        ).astype(jnp.float32)

    def step_env(self, key, state, action, params):
        reward = jnp.all(action == state.cue).astype(jnp.float32)
        return self.get_obs(state, params), state, reward, jnp.bool_(True), {}


class EndlessProbe(_Probe):
    """Constant observation `[1.0]`, one action, reward 1 every step, never terminates; episodes
    are truncated after `params.max_steps_in_episode` (default 5) steps. With discount gamma the
    true value is `1 / (1 - gamma)`: the time limit is not part of the task (and the observation
    does not show the time), so a learner must bootstrap through truncation. Treating it as
    termination instead gives about the mean finite-horizon return, far lower."""

    num_actions = 1
    time_limit = 5

    def step_env(self, key, state, action, params):
        return self.get_obs(state, params), state, jnp.float32(1.0), jnp.bool_(False), {}


class CostlyStartProbe(_Probe):
    """Like `EndlessProbe`, but the first step of an episode is different: it shows `[1, 0]`
    and pays -10; every later step shows `[0, 1]` and pays 1. Never terminates; truncated after
    `params.max_steps_in_episode` (default 5) steps. With discount gamma the true values are
    `V([0, 1]) = 1 / (1 - gamma)` and `V([1, 0]) = -10 + gamma / (1 - gamma)` (10 and -1 at
    gamma 0.9). The last observation of an episode (`[0, 1]`) is worth far more than the first
    observation of the next one (`[1, 0]`), so bootstrapping a truncated step from the wrong one
    (the reset observation instead of `info["final_observation"]`) pulls `V([0, 1])` far down
    (to about -10 at gamma 0.9; treating truncation as termination gives about 3)."""

    obs_size = 2
    num_actions = 1
    time_limit = 5

    def get_obs(self, state, params):
        first = state.time == 0
        return jnp.stack([first, ~first]).astype(jnp.float32)

    def step_env(self, key, state, action, params):
        reward = jnp.where(state.time == 0, -10.0, 1.0)
        obs = self.get_obs(state.replace(time=state.time + 1), params)
        return obs, state, reward, jnp.bool_(False), {}


class RecallProbe(TwoStepProbe):
    """The observations of `TwoStepProbe` (step 1 shows `[c, 0]`, `c = +-1` at random; step 2
    shows `[0, 1]`), but the reward is for the step-2 action: 1 if it is `(c > 0)`, else 0.
    The cue is gone when it is needed: a feed-forward policy scores 0.5 at best, a recurrent one
    (`memory > 0`) that carries the cue over one step scores 1.0."""

    def step_env(self, key, state, action, params):
        first = state.time == 0
        reward = jnp.where(first, 0.0, (action == state.cue[0]).astype(jnp.float32))
        obs = self.get_obs(state.replace(time=state.time + 1), params)
        return obs, state, reward, ~first, {}


class TargetProbe(_Probe):
    """Observation `[t]`, a target drawn uniformly from [-0.8, 0.8]; `Box(-1, 1, (1,))`
    actions; reward `-(a - t)^2` with `a` the action clipped to the bounds; one-step episodes.
    The Gaussian policy's mean must follow the observation (`mean = t`); a policy that ignores
    it scores `-var(t) = -0.213` at best."""

    continuous = True

    def _initial_state(self, key):
        # The target in thousandths, held in the int32 cue.
        return _state(jnp.stack([jax.random.randint(key, (), -800, 801), 0]))

    def get_obs(self, state, params):
        return (state.cue[:1] / 1000.0).astype(jnp.float32)

    def step_env(self, key, state, action, params):
        reward = _squared_miss(action, state.cue[:1] / 1000.0)
        return self.get_obs(state, params), state, reward, jnp.bool_(True), {}


class OpenLoopProbe(_Probe):
    """The paper's noise control in miniature: the observation is 4 floats of fresh N(0, 1)
    noise (it says nothing); `Box(-1, 1, (1,))` actions; reward `-(a - 0.5)^2` with `a` the
    clipped action; one-step episodes. The optimum is open loop (always 0.5, return 0), and a
    learner must find it from noise: the policy has to learn to ignore its inputs."""

    obs_size = 4
    continuous = True

    def _initial_state(self, key):
        # The noise's key, as int32 bits in the cue (fresh each episode).
        return _state(jax.random.randint(key, (2,), jnp.iinfo(jnp.int32).min, jnp.iinfo(jnp.int32).max))

    def get_obs(self, state, params):
        key = jax.random.key(jax.lax.bitcast_convert_type(state.cue, jnp.uint32)[0])
        key = jax.random.fold_in(key, jax.lax.bitcast_convert_type(state.cue[1], jnp.uint32))
        return jax.random.normal(key, (self.obs_size,), jnp.float32)

    def step_env(self, key, state, action, params):
        reward = _squared_miss(action, 0.5)
        return self.get_obs(state, params), state, reward, jnp.bool_(True), {}


PROBES = {
    "constant_reward": ConstantRewardProbe,
    "sign": SignProbe,
    "two_step": TwoStepProbe,
    "factored": FactoredProbe,
    "endless": EndlessProbe,
    "costly_start": CostlyStartProbe,
    "recall": RecallProbe,
    "target": TargetProbe,
    "open_loop": OpenLoopProbe,
}


def make_probe(name: str, **params) -> tuple[AutoResetWrapper, ProbeParams]:
    """`(AutoResetWrapper(probe), params)`; keyword arguments replace fields of the params."""
    env = PROBES[name]()
    return AutoResetWrapper(env), env.default_params.replace(**params)
