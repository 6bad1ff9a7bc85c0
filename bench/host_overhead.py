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
  batched step, for one seed and for `--seeds` side by side (`--num-envs` envs each);
- the policy's round trip with Natural Atari's frames (uint8 84x84x4) and the paper's trunk
  ("atari", float32, 4 actions), as the loop makes it (key split, frames to the device, the
  jitted call, actions back), for each seed count three ways over the same envs: the seeds
  vmapped (the learner's `over_seeds`: XLA batches the convolutions over the seeds' weights),
  one seed's weights on all the envs (the same arithmetic with no vmap), and the seeds one
  after another in one jitted call; and the learner's way with the frames already on the
  device (what the transfer costs), and the learner's way with each `--convs` implementation
  of the convolutions (`jaxnat.agents.conv`: the same function). Where the vmapped round
  trip exceeds the other two, the batched convolutions, not the host, hold Natural Atari's
  policy call.

    python bench/host_overhead.py                      # 8 envs, 5 seeds
    python bench/host_overhead.py --num-envs 8 --seeds 5 10 --no-record
    python bench/host_overhead.py --no-trunk          # the null env's pieces and loop only
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
from jaxnat.agents.conv import IMPLEMENTATIONS  # noqa: E402
from jaxnat.agents.networks import make_actor_critic  # noqa: E402
from jaxnat.agents.rollout import on_policy_host_learner, stack_seeds  # noqa: E402
from jaxnat.agents.rollout.stacked import over_seeds, split_keys  # noqa: E402

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


def trunk_round_trips(num_envs: int, seed_counts: list[int], reps: int, convs=()) -> list[dict]:
    """Microseconds per policy round trip with the Atari trunk, for each seed count and way of
    computing it (see the module doc): `num_envs` envs per seed; `convs`: conv implementations
    (`jaxnat.agents.conv.IMPLEMENTATIONS`) also timed the learner's way beside "auto"."""
    frame_space = spaces.Box(0, 255, (84, 84, 4), np.uint8)

    def actor(conv):
        network = make_actor_critic(frame_space, spaces.Discrete(4), "atari", conv=conv)

        def act(params, obs, key):
            logits, value = network.apply(params, obs)
            action = distributions.sample(key, logits)
            return action, (distributions.log_prob(logits, action), value)
        return network, act

    network, act = actor("auto")

    rows = []
    for seeds in seed_counts:
        keys = jax.random.split(jax.random.key(0), seeds)
        params = jax.vmap(lambda k: network.init(k, jnp.zeros((1, 84, 84, 4), jnp.uint8)))(keys)
        one = jax.tree.map(lambda x: x[0], params)
        frames = np.random.default_rng(0).integers(0, 256, (seeds * num_envs, 84, 84, 4), np.uint8)

        def in_turn(params, obs, keys):
            outs = [act(jax.tree.map(lambda x, s=s: x[s], params), obs[s * num_envs:(s + 1) * num_envs], keys[s])
                    for s in range(seeds)]
            return jax.tree.map(lambda *xs: jnp.concatenate(xs), *outs)

        ways = [("seeds vmapped (the learner's)", jax.jit(over_seeds(act, seeds)), params, keys),
                ("one seed's weights on all envs", jax.jit(act), one, keys[0]),
                ("seeds in turn in one call", jax.jit(in_turn), params, keys)]
        state = {"key": keys}
        on_device = jax.device_put(frames)

        def round_trip(call, weights, key, resident=False):
            def fn():
                state["key"], _ = split_keys(state["key"])
                obs = on_device if resident else jax.device_put(frames)
                np.asarray(call(weights, obs, key)[0])
            return fn

        cases = [(name, round_trip(call, w, k)) for name, call, w, k in ways]
        cases.append(("seeds vmapped, frames already on the device", round_trip(*ways[0][1:], resident=True)))
        for conv in convs:  # the same weights, each conv implementation (one function: conv.py)
            cases.append((f"seeds vmapped, conv={conv}",
                          round_trip(jax.jit(over_seeds(actor(conv)[1], seeds)), params, keys)))
        for name, fn in cases:
            rows.append(dict(seeds=seeds, envs=seeds * num_envs, way=name, us=per_call_us(fn, reps)))
    return rows


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
    parser.add_argument("--trunk-reps", type=int, default=300, help="calls per round trip with the Atari trunk")
    parser.add_argument("--convs", nargs="*", default=["im2col", "native", "s2d", "unrolled", "grouped"], choices=IMPLEMENTATIONS,
                        help="conv implementations also timed the learner's way (none: only the default)")
    parser.add_argument("--trunk", action=argparse.BooleanOptionalAction, default=True,
                        help="also the round trips with the Atari trunk")
    parser.add_argument("--no-record", action="store_true")
    args = parser.parse_args(argv)
    info = common.machine()
    started = time.perf_counter()
    piece_rows = pieces(args.num_envs, args.reps)
    loop_rows = [loop(args.num_envs, seeds, args.num_steps, args.updates) for seeds in (None, *args.seeds)]
    trunk_rows = (trunk_round_trips(args.num_envs, [1, *args.seeds], args.trunk_reps, args.convs)
                  if args.trunk else [])
    base, jitted = piece_rows[0]["us"], piece_rows[1]["us"]
    table = (common.markdown_table(piece_rows, [("piece", "piece of a host step", "s"), ("us", "us per call", ".1f")])
             + "\n\n" + common.markdown_table(loop_rows, [
                 ("seeds", "seeds", "d"), ("envs", "envs (all seeds)", "d"), ("policy_ms", "policy ms", ".3f"),
                 ("env_ms", "env step ms", ".3f"), ("observe_ms", "observe ms", ".3f"),
                 ("step_ms", "whole step ms", ".3f")])
             + ("\n\n" + common.markdown_table(trunk_rows, [
                 ("seeds", "seeds", "d"), ("envs", "envs (all seeds)", "d"), ("way", "policy with the Atari trunk", "s"),
                 ("us", "us per round trip", ".1f")]) if trunk_rows else ""))
    summary = {
        "env": "a null host env (numpy zeros, no emulation), uint8[4] observations, mlp policy: dispatch, not compute",
        "loop": f"PPO host learner, {args.num_envs} envs per seed x {args.num_steps} steps, 1 warm-up + "
                f"{args.updates} timed updates; ms per batched step of all envs",
        "split_keys / unjitted split": f"{jitted / base:.2f}",
        "bench seconds": f"{time.perf_counter() - started:.0f}",
    }
    if trunk_rows:
        summary["trunk"] = (f"the paper's Atari trunk (float32) on uint8[84, 84, 4] frames, 4 actions, {args.num_envs} envs "
                            f"per seed; a round trip: key split, frames to the device, the call, actions to the host")
    common.record("host_overhead", info, table, summary, [*piece_rows, *loop_rows, *trunk_rows],
                  save=not args.no_record)


if __name__ == "__main__":
    main()
