"""The host loop's own cost per env step: what Natural Atari's learner spends around the emulator.

The host learner (`jaxnat.agents.rollout.host_steps`) makes, per env step, a key split, one
transfer of the observations to the device, one jitted policy call and one transfer of the
actions back; the env step and `observe` follow. This bench times those pieces alone and the
whole loop on a null env (numpy, no emulation: its step is a few array copies) with a tiny
policy (mlp on 4 features), so that what it measures is dispatch and Python, not compute:

- pieces, each in a tight loop of `--reps`: the key split two ways side by side (unjitted
  `jax.random.split` and unpacking, as the loop did before, against `stacked.split_keys`, one
  jitted dispatch), `jax.device_put` of an observation batch (`--num-envs` x the given shape),
  and the policy call with the actions fetched;
- the loop: the PPO host learner's `timings` (policy round trip, env step, `observe`) per
  batched step, for one seed and for `--seeds` side by side (`--num-envs` envs each).

    python bench/host_overhead.py                      # 8 envs, 5 seeds
    python bench/host_overhead.py --num-envs 8 --seeds 5 10 --no-record
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import common  # noqa: E402

from jaxnat import spaces  # noqa: E402
from jaxnat.agents import distributions, ppo  # noqa: E402
from jaxnat.agents.networks import make_actor_critic  # noqa: E402
from jaxnat.agents.rollout import on_policy_host_learner, stack_seeds  # noqa: E402
from jaxnat.agents.rollout.stacked import split_keys  # noqa: E402

OBS = (4,)  # the null env's observation: a tiny policy, so the loop's cost is dispatch, not compute


class NullEnv:
    """A host-batched env that does nothing: uint8 zeros out, reward 0, every env's episode
    ending each 50th step (so `observe`'s final-value call runs as often as in short games)."""

    def __init__(self, num_envs: int):
        self.num_envs = num_envs
        self.single_observation_space = spaces.Box(0, 255, OBS, np.uint8)
        self.single_action_space = spaces.Discrete(4)
        self._obs = np.zeros((num_envs, *OBS), np.uint8)
        self._t = 0

    def reset(self, seed=None, seeds=None):
        return self._obs.copy(), {}

    def step(self, actions):
        self._t += 1
        done = np.full(self.num_envs, self._t % 50 == 0)
        zeros = np.zeros(self.num_envs, np.float32)
        info = {"returned_episode": done, "returned_episode_returns": zeros,
                "returned_episode_lengths": zeros.astype(np.int32), "final_observation": self._obs}
        return self._obs.copy(), zeros, done, np.zeros(self.num_envs, bool), info


def per_call_us(fn, reps: int) -> float:
    fn()
    start = time.perf_counter()
    for _ in range(reps):
        fn()
    return 1e6 * (time.perf_counter() - start) / reps


def pieces(num_envs: int, reps: int) -> list[dict]:
    """Microseconds per call of each piece of a host step."""
    network = make_actor_critic(spaces.Box(0, 255, OBS, np.uint8), spaces.Discrete(4), "mlp")
    params = network.init(jax.random.key(0), jnp.zeros((1, *OBS), jnp.uint8))

    @jax.jit
    def act(params, obs, key):
        logits, value = network.apply(params, obs)
        action = distributions.sample(key, logits)
        return action, (distributions.log_prob(logits, action), value)

    keys = {"key": jax.random.key(0)}

    def unjitted_split():
        keys["key"], _ = jax.random.split(keys["key"])

    def jitted_split():
        keys["key"], _ = split_keys(keys["key"])

    obs = np.zeros((num_envs, *OBS), np.uint8)
    frames = np.zeros((num_envs, 84, 84, 4), np.uint8)
    on_device, key = jax.device_put(obs), jax.random.key(1)
    rows = [("key split, unjitted (jax.random.split, unpacked)", unjitted_split),
            ("key split, split_keys (jitted)", jitted_split),
            (f"device_put uint8[{num_envs}, 4]", lambda: jax.device_put(obs).block_until_ready()),
            (f"device_put uint8[{num_envs}, 84, 84, 4]", lambda: jax.device_put(frames).block_until_ready()),
            ("policy call, actions to the host", lambda: np.asarray(act(params, on_device, key)[0]))]
    return [dict(piece=name, us=per_call_us(fn, reps)) for name, fn in rows]


def loop(num_envs: int, seeds: int | None, num_steps: int, updates: int) -> dict:
    """ms per batched step of the PPO host learner's loop on the null env (after one warm-up
    update, which compiles)."""
    config = ppo.PPOConfig(num_envs=num_envs, num_steps=num_steps, trunk="mlp",
                           total_timesteps=num_envs * num_steps * (updates + 1))
    learner = on_policy_host_learner(config, NullEnv(num_envs * (seeds or 1)), rule=ppo.RULE, seeds=seeds)
    state = learner.init(jax.random.key(0) if seeds is None else
                         stack_seeds([jax.random.key(i) for i in range(seeds)]))
    updates_it = learner.updates(state)
    next(updates_it)
    learner.timings.clear()
    for _ in range(updates):
        next(updates_it)
    updates_it.close()
    t = learner.timings
    n = t["steps"]
    return dict(seeds=seeds or 1, envs=num_envs * (seeds or 1), policy_ms=1e3 * t["policy_s"] / n,
                env_ms=1e3 * t["env_s"] / n, observe_ms=1e3 * t["observe_s"] / n,
                step_ms=1e3 * t["rollout_s"] / n)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--num-envs", type=int, default=8, help="envs per seed")
    parser.add_argument("--seeds", type=int, nargs="+", default=[5], help="seed counts side by side (beside one)")
    parser.add_argument("--num-steps", type=int, default=128)
    parser.add_argument("--updates", type=int, default=3, help="timed updates of the loop")
    parser.add_argument("--reps", type=int, default=2000, help="calls per piece")
    parser.add_argument("--no-record", action="store_true")
    args = parser.parse_args(argv)
    info = common.machine()
    started = time.perf_counter()
    piece_rows = pieces(args.num_envs, args.reps)
    loop_rows = [loop(args.num_envs, seeds, args.num_steps, args.updates) for seeds in (None, *args.seeds)]
    base, jitted = piece_rows[0]["us"], piece_rows[1]["us"]
    table = (common.markdown_table(piece_rows, [("piece", "piece of a host step", "s"), ("us", "us per call", ".1f")])
             + "\n\n" + common.markdown_table(loop_rows, [
                 ("seeds", "seeds", "d"), ("envs", "envs (all seeds)", "d"), ("policy_ms", "policy ms", ".3f"),
                 ("env_ms", "env step ms", ".3f"), ("observe_ms", "observe ms", ".3f"),
                 ("step_ms", "whole step ms", ".3f")]))
    summary = {
        "env": "a null host env (numpy zeros, no emulation), uint8[4] observations, mlp policy: dispatch, not compute",
        "loop": f"PPO host learner, {args.num_envs} envs per seed x {args.num_steps} steps, 1 warm-up + "
                f"{args.updates} timed updates; ms per batched step of all envs",
        "split_keys / unjitted split": f"{jitted / base:.2f}",
        "bench seconds": f"{time.perf_counter() - started:.0f}",
    }
    common.record("host_overhead", info, table, summary, [*piece_rows, *loop_rows],
                  save=not args.no_record)


if __name__ == "__main__":
    main()
