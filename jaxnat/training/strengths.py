"""Training at every strength of a distraction grid in one program: seeds x strengths.

    env, params = jaxnat.make("Classify/Digits-v0", noise_sigma=0.0)
    train = make_strength_train("ppo", PPOConfig(num_envs=512), env, params, noise_sigma=[0.0, 32.0, 64.0])
    runner, metrics = train(jax.vmap(jax.random.key)(jnp.arange(5)))    # leading axes [3 strengths, 5 seeds]

An env's dial (`env_params.distraction`: PixelMuJoCo's `video_alpha`, `noise_sigma`, ...,
Classify's and Localize's `noise_sigma`) is a group of traced params, so the learner, which
takes the env's params as an argument of its programs, can be vmapped over a strength axis as
over seeds: one compile, one launch, the GPU filled by strengths x seeds x envs. Every strength
trains its seeds from the same keys (common random numbers: a difference between strengths is
the dial's, not the draws'). Slice `s` of the result is what training at strength `s` alone
gives (`placement.make_sharded_train` with those params), to float rounding.
"""

from __future__ import annotations

import jax

from jaxnat.agents import ALGORITHMS
from jaxnat.agents.rollout import count_updates
from jaxnat.training.args import TrainError
from jaxnat.training.placement import Placement

__all__ = ["make_strength_train"]


def make_strength_train(algo: str, config, env, env_params, **values):
    """`train(keys) -> (runner, metrics)`, jitted: `algo` trained with `config` on `env` for the
    seeds of `keys` (`[seeds]`) at every strength of `values` (dial fields -> arrays of one
    length S, as `env_params.sweep` takes them: checked there, one line for a value out of
    range), all in one program; the runner and metrics have leading axes `[S, seeds]`.
    Raises `TrainError` for an env without a dial or an unknown algorithm."""
    if algo not in ALGORITHMS:
        raise TrainError(f"unknown algorithm {algo!r}; algorithms: {', '.join(ALGORITHMS)}")
    if not hasattr(env_params, "sweep"):
        raise TrainError(f"{type(env).__name__}'s params have no distraction dial to train over "
                         "(PixelMuJoCo, Classify and Localize have one)")
    if not values:
        raise TrainError("name at least one dial field and its strengths, e.g. noise_sigma=[0.0, 32.0]")
    swept, axes = env_params.sweep(**values)

    def train(keys):
        # One device's programs (`make_sharded_train`'s), vmapped over the strength axis.
        placement = Placement.resolve(algo, config, keys.shape[0], 1, None)
        init, chunk = placement.learner_programs(algo, config, env, env_params, keys.shape[0])
        run = chunk(count_updates(config))
        return jax.vmap(lambda params: run(params, init(params, keys)), in_axes=(axes,))(swept)

    return jax.jit(train)
