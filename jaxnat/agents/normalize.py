"""Observation normalisation and return-based reward scaling, as OpenAI baselines' `VecNormalize`
(which the authors' code wraps around every env with vector observations), held in the
learner's state instead of an env wrapper: per seed under `vmap`, saved in checkpoints with the
runner, and frozen (read, never updated) when a policy is evaluated.

- **Observations**: running mean and variance over every observation the policy has been given
  (each vector step's batch updates them before it is normalised); the policy reads
  `clip((obs - mean) / sqrt(var + 1e-8), -10, 10)`.
- **Rewards**: each env keeps a discounted running return `R <- gamma * R + r` (reset to 0
  where an episode ends); the learner trains on `clip(r / sqrt(var(R) + 1e-8), -10, 10)`, with
  `var(R)` the running variance of those returns. Episode returns in the metrics stay raw.
- **Sign clipping** (`clip_rewards`, off by default; baselines' Atari `ClipRewardEnv`): the
  learner trains on `sign(r)` (-1, 0 or 1). With reward scaling on as well, the rewards are
  clipped first and the clipped ones scaled (`R` runs over `sign(r)`), as `VecNormalize` around
  a `ClipRewardEnv`. Episode returns in the metrics stay raw here too. `scale_rewards` does
  both, for the jitted and the host learners alike.

The running moments merge batches exactly (Chan et al.'s parallel update) and start from no
data, so after any stream they equal NumPy's `mean`/`var` of it (baselines starts at a count of
1e-4 with variance 1, a difference of order 1e-4 / steps).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

__all__ = ["Moments", "Normalizer", "CLIP", "EPSILON", "init_moments", "update_moments", "init_normalizer",
           "observe", "normalize", "sign_clip", "scale_rewards", "per_env", "wants_normalization", "switches"]

CLIP = 10.0  # baselines' clipob and cliprew
EPSILON = 1e-8


class Moments(NamedTuple):
    """Running mean and (population) variance of a stream of arrays shaped like `mean`."""

    mean: jax.Array
    var: jax.Array
    count: jax.Array  # float32: how many arrays have been merged


def init_moments(shape) -> Moments:
    """No data yet (`count` 0; the variance 1 makes an unused normaliser the identity)."""
    return Moments(jnp.zeros(shape, jnp.float32), jnp.ones(shape, jnp.float32), jnp.zeros((), jnp.float32))


def update_moments(moments: Moments, batch: jax.Array, axis_name=None) -> Moments:
    """Merge a batch `[N, *shape]` into the moments (Chan et al.'s update; exact for any split).
    `axis_name`: the batch is split over a mesh axis (data-parallel learners, equal shares);
    its moments are the whole batch's."""
    batch = batch.astype(jnp.float32)
    batch_count = jnp.asarray(batch.shape[0], jnp.float32)
    batch_mean = batch.mean(axis=0)
    batch_var = batch.var(axis=0)
    if axis_name is not None:
        local_mean, batch_mean = batch_mean, jax.lax.pmean(batch_mean, axis_name)
        batch_var = jax.lax.pmean(batch_var + (local_mean - batch_mean) ** 2, axis_name)
        batch_count = batch_count * jax.lax.axis_size(axis_name)
    total = moments.count + batch_count
    delta = batch_mean - moments.mean
    mean = moments.mean + delta * batch_count / total
    squares = moments.var * moments.count + batch_var * batch_count + delta**2 * moments.count * batch_count / total
    return Moments(mean, squares / total, total)


class Normalizer(NamedTuple):
    """The normalisation state of one learner (one seed): either part may be off (None)."""

    obs: Moments | None  # of the observations
    returns: Moments | None  # of the running discounted returns (scalars)
    running_return: jax.Array | None  # [num_envs]: each env's discounted return so far


def per_env(normalizer: Normalizer) -> Normalizer:
    """The parts with an env axis (True: the running returns), shared (False) or off (None):
    what a data-parallel learner splits over devices (`rollout.Learner.per_env`)."""
    return Normalizer(*(None if part is None else name == "running_return"
                        for name, part in zip(Normalizer._fields, normalizer)))


def wants_normalization(observation_space) -> bool:
    """The default of both switches: on for vector observations (a 1-D Box, as the authors'
    `len(obs_shape) == 1` test), off for images and dict observations."""
    return not hasattr(observation_space, "spaces") and len(getattr(observation_space, "shape", ())) == 1


def init_normalizer(observations: bool, rewards: bool, observation_space, num_envs: int) -> Normalizer | None:
    """A fresh normaliser, or None when both switches are off."""
    if not (observations or rewards):
        return None
    if observations and not wants_normalization(observation_space):
        raise ValueError(f"normalize_observations needs vector observations (a 1-D Box); these are "
                         f"{observation_space}: leave it off for images")
    return Normalizer(init_moments(observation_space.shape) if observations else None,
                      init_moments(()) if rewards else None,
                      jnp.zeros((num_envs,), jnp.float32) if rewards else None)


def normalize(normalizer: Normalizer | None, obs):
    """The observations as the policy reads them (unchanged without observation moments)."""
    if normalizer is None or normalizer.obs is None:
        return obs
    moments = normalizer.obs
    return jnp.clip((obs - moments.mean) / jnp.sqrt(moments.var + EPSILON), -CLIP, CLIP)


def observe(normalizer: Normalizer | None, obs, axis_name=None) -> Normalizer | None:
    """Merge a vector step's observations `[num_envs, D]` into the moments (`axis_name`:
    `update_moments`')."""
    if normalizer is None or normalizer.obs is None:
        return normalizer
    return normalizer._replace(obs=update_moments(normalizer.obs, obs, axis_name))


def sign_clip(reward, clip: bool) -> jax.Array:
    """float32 `sign(reward)` if `clip` (a static bool), else the float32 rewards unchanged."""
    reward = jnp.asarray(reward).astype(jnp.float32)
    return jnp.sign(reward) if clip else reward


def scale_rewards(normalizer: Normalizer | None, reward, done, gamma, axis_name=None, *,
                  clip: bool = False) -> tuple[Normalizer | None, jax.Array]:
    """One vector step's rewards `[num_envs]` as the learner trains on them, and the updated
    normaliser (`done`: where an episode ended, its running return restarts; `axis_name`:
    `update_moments`'; `clip`: sign-clip them first, a config's static `clip_rewards`)."""
    reward = sign_clip(reward, clip)
    if normalizer is None or normalizer.returns is None:
        return normalizer, reward
    running = normalizer.running_return * gamma + reward
    returns = update_moments(normalizer.returns, running, axis_name)
    scaled = jnp.clip(reward / jnp.sqrt(returns.var + EPSILON), -CLIP, CLIP)
    return normalizer._replace(returns=returns, running_return=jnp.where(done, 0.0, running)), scaled


def switches(config, observation_space) -> tuple[bool, bool]:
    """`(observations, rewards)`: an on-policy config's `normalize_observations` and
    `normalize_rewards`, where None (their default) means `wants_normalization`."""
    default = wants_normalization(observation_space)
    return tuple(default if value is None else bool(value)
                 for value in (config.normalize_observations, config.normalize_rewards))
