"""Default settings per env family, in one place with their sources.

Each algorithm's config dataclass holds the paper's settings (`docs/environments.md` section 5):
the authors kept one set for the vision tasks, Atari and PixelMuJoCo ("hyperparameters were kept
constant for all MuJoCo and Atari tasks"). Continuous control from a state vector (`MuJoCo/*`,
`PixelMuJoCo/*` with `observation="state"`, or `"constant"`, a vector too) instead takes the
MuJoCo settings of the authors' code base, ikostrikov/pytorch-a2c-ppo-acktr-gail (its README's
MuJoCo commands), which CleanRL's `ppo_continuous_action.py` shares:

- **ppo**: 1 env x 2048 steps, 10 epochs x 32 minibatches, Adam lr 3e-4 annealed, clip 0.2,
  entropy 0, value coef 0.5, gamma 0.99, GAE lambda 0.95, max grad norm 0.5. Source: the README's
  `--algo ppo --use-gae --num-steps 2048 --num-processes 1 --lr 3e-4 --entropy-coef 0
  --value-loss-coef 0.5 --ppo-epoch 10 --num-mini-batch 32 --gamma 0.99 --gae-lambda 0.95
  --use-linear-lr-decay` (clip 0.2 and grad norm 0.5 are its defaults).
- **a2c**: the config's own defaults (16 envs x 5 steps, RMSprop lr 7e-4, entropy 0.01, ...).
  Source: the README's MuJoCo A2C command sets nothing but the env and the step count.
- **acktr**: the config's own defaults (32 envs x 20 steps, lr 0.25, KL clip 0.001, ...). The
  README gives no MuJoCo ACKTR command ("ACKTR requires some modifications to be made
  specifically for MuJoCo").

Both families normalise observations and scale rewards when observations are vectors (the
authors wrap such envs in `VecNormalize`; `normalize.py`). Images keep the raw pixels.

The authors' single env makes 1M steps a long sequential rollout; on a GPU many envs are cheaper
per step, and `num_envs` x `num_steps` can be re-split keeping the 2048-step batch (e.g.
`num_envs=32, num_steps=64`). The benchmarks state the split they use.
"""

from __future__ import annotations

from typing import Any

from jaxnat.agents.networks import is_box
from jaxnat.agents.normalize import wants_normalization

__all__ = ["CONTINUOUS_STATE", "NATURAL_ATARI", "family_defaults"]

# Overrides of each config's defaults for Box actions with vector observations.
CONTINUOUS_STATE: dict[str, dict[str, Any]] = {
    "ppo": dict(num_envs=1, num_steps=2048, update_epochs=10, num_minibatches=32, lr=3e-4, anneal_lr=True,
                clip_eps=0.2, ent_coef=0.0, vf_coef=0.5, gamma=0.99, gae_lambda=0.95, max_grad_norm=0.5),
    "a2c": {},
    "acktr": {},
}


# Overrides for Natural Atari (`family="NaturalAtari"`): Nature DQN's Huber loss, since its
# rewards are clipped to [-1, 1] there too and Huber bounds the gradient of the rare large TD
# errors (`dqn.DQNConfig` says why it is not the general default).
NATURAL_ATARI: dict[str, dict[str, Any]] = {"dqn": dict(loss="huber")}


def family_defaults(algo: str, observation_space, action_space=None, *, family: str | None = None) -> dict[str, Any]:
    """The overrides of `algo`'s config defaults for an env with these spaces, or of this
    `family` (an env id's prefix, e.g. "NaturalAtari"); {} for the paper's other families:
    vision, PixelMuJoCo from pixels or noise. `resolve.config_for` applies them.

        config = PPOConfig(**family_defaults("ppo", env.observation_space(p), env.action_space(p)))
    """
    if family == "NaturalAtari":
        return dict(NATURAL_ATARI.get(algo, {}))
    if action_space is not None and is_box(action_space) and wants_normalization(observation_space):
        return dict(CONTINUOUS_STATE.get(algo, {}))
    return {}
