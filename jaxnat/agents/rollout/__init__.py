"""How rollouts run, for every algorithm, one concern per module. An algorithm file
(`ppo.py`, `a2c.py`, `acktr.py`, `dqn.py`) holds its config, loss and update.

| module | holds |
|---|---|
| `records` | the transition, one vector step (`EnvStep`), GAE with correct time limits, episode metrics |
| `policy` | acting, replaying a rollout, V(final observation), the env's form of an action |
| `optim` | optimizer pieces the algorithms share |
| `parallel` | data parallel over a mesh axis: each device's share, the mean gradient |
| `scan` | the jitted driver (JAX envs in `lax.scan`) and the jitted `Learner` |
| `on_policy` | the jitted on-policy learner (PPO, A2C, ACKTR) over `UpdateRule`s |
| `host` | the host driver (host-batched envs: Natural Atari) and its `HostLearner` loop |
| `on_policy_host` | the on-policy learner on a host-batched env (one seed, or several side by side) |
| `stacked` | seeds side by side: stacked states, their slices, per-seed keys |
| `evaluate` | evaluation: jitted first episodes, the uniform random policy, whole host games |

The jitted side (`scan`, `on_policy`) and the host side (`host`, `on_policy_host`) share the
records, the policy calls and the update rules; nothing else crosses between them.
"""

from jaxnat.agents.rollout.evaluate import evaluate_host, make_chance, make_evaluate
from jaxnat.agents.rollout.host import (TIMING_KEYS, HostLearner, HostState, check_host_batch, host_steps,
                                        host_steps_pipelined, host_updates)
from jaxnat.agents.rollout.on_policy import RunnerState, UpdateRule, dtype_and_memory, on_policy_learner
from jaxnat.agents.rollout.on_policy_host import on_policy_host_learner
from jaxnat.agents.rollout.optim import clip_by_global_norm
from jaxnat.agents.rollout.parallel import pmean_gradients, shard_slice
from jaxnat.agents.rollout.policy import act, choose, env_action, final_value, is_scalar_action, replay, sample_each
from jaxnat.agents.rollout.records import (EPISODE_KEYS, GAE_UNROLL, EnvStep, Transition, bootstrap, count_updates,
                                           episode_metrics, gae, step_info)
from jaxnat.agents.rollout.scan import Learner, pack_vectors, scan_learner, scan_steps, unpack_vectors, vector_env
from jaxnat.agents.rollout.stacked import over_seeds, seed_slice, split_keys, stack_seeds

__all__ = [
    "EPISODE_KEYS", "Transition", "EnvStep", "GAE_UNROLL", "gae", "bootstrap", "step_info", "episode_metrics",
    "count_updates", "is_scalar_action", "env_action", "sample_each", "act", "final_value", "replay", "choose",
    "clip_by_global_norm", "pmean_gradients", "shard_slice", "Learner", "vector_env", "scan_steps", "pack_vectors",
    "unpack_vectors", "scan_learner", "RunnerState", "UpdateRule", "dtype_and_memory", "on_policy_learner",
    "HostState", "HostLearner", "check_host_batch", "host_steps", "host_steps_pipelined", "TIMING_KEYS",
    "host_updates", "on_policy_host_learner", "make_evaluate", "make_chance", "evaluate_host", "seed_slice",
    "stack_seeds", "split_keys", "over_seeds",
]
