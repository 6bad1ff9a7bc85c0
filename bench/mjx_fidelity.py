"""How close each MJX physics setting stays to Gymnasium v5 on MuJoCo C.

For each robot and each `physics=` setting ("default", "fast"): `--episodes` episodes under a
uniformly random policy and `--episodes` under a fixed open-loop policy, in MJX (jaxnat, one
vmapped batch) and in MuJoCo C through Gymnasium's `<Robot>-v5` (worker processes); episode
return and length, mean and 95% t-interval, for each side. "in C CI" says whether the MJX mean
lies inside MuJoCo C's interval; "z" is the difference of means over its standard error
(Welch), so |z| < 2 is no detectable difference. Alongside, the short-horizon qpos drift of
`bench/mjx_physics.py` (MJX vs MuJoCo C from the same state under the same actions; C vs C
moved by 1e-7: chaos).

Policies: random draws each action uniformly from the action box (a different stream per
episode; MJX and C draw from different generators, so only the distributions match). The
fixed policy is `a_j(t) = 0.5 sin(2 pi t / 25 + 2 pi j / nu)` for actuator `j` at env step `t`,
the same in every episode: episodes differ only by their reset noise.

    python bench/mjx_fidelity.py                                  # 256 episodes, 1,000 steps
    python bench/mjx_fidelity.py --episodes 4 --max-steps 50      # a quick CPU check
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import sys

import jax
import jax.numpy as jnp
import numpy as np

_BENCH = __import__("pathlib").Path(__file__).resolve().parent
sys.path[:0] = [str(_BENCH), str(_BENCH.parent)]  # bench/common.py; this checkout's jaxnat
import common  # noqa: E402
import mjx_physics  # noqa: E402

import jaxnat  # noqa: E402

ROBOTS = ("Ant", "HalfCheetah", "Hopper", "Swimmer")
SETTINGS = ("default", "fast")
POLICIES = ("random", "fixed")
PERIOD = 25  # env steps per cycle of the fixed policy


def fixed_action(t, nu: int):
    """The fixed policy's action at env step `t` (numpy or jax `t`)."""
    xp = jnp if isinstance(t, jax.Array) else np
    return 0.5 * xp.sin(2 * np.pi * t / PERIOD + 2 * np.pi * xp.arange(nu) / nu)


def mjx_episodes(env, params, policy: str, episodes: int, max_steps: int, seed: int = 0):
    """(returns, lengths) of `episodes` MJX episodes (one vmapped batch, raw env)."""
    space = env.action_space(params)
    low, high, nu = jnp.asarray(space.low), jnp.asarray(space.high), space.shape[0]

    def run(key):
        key_reset, key_run = jax.random.split(key)
        _, state = jax.vmap(env.reset, in_axes=(0, None))(jax.random.split(key_reset, episodes), params)

        def body(carry, x):
            state, ret, length, alive = carry
            t, key = x
            if policy == "random":
                action = jax.random.uniform(key, (episodes, nu), minval=low, maxval=high)
            else:
                action = jnp.broadcast_to(fixed_action(t, nu), (episodes, nu)).astype(jnp.float32)
            keys = jax.random.split(key, episodes)
            _, state, reward, terminated, _ = jax.vmap(env.step_env, in_axes=(0, 0, 0, None))(
                keys, state, action, params)
            ret = ret + jnp.where(alive, reward, 0.0)
            length = length + alive
            alive = alive & ~terminated
            return (state, ret, length, alive), None

        init = (state, jnp.zeros(episodes), jnp.zeros(episodes, jnp.int32), jnp.ones(episodes, bool))
        xs = (jnp.arange(max_steps), jax.random.split(key_run, max_steps))
        (_, ret, length, _), _ = jax.lax.scan(body, init, xs)
        return ret, length

    ret, length = jax.jit(run)(jax.random.key(seed))
    return np.asarray(ret, np.float64), np.asarray(length)


def _c_episode(job):
    """One Gymnasium v5 episode on MuJoCo C: (return, length)."""
    import gymnasium as gym

    name, policy, seed, max_steps = job
    env = gym.make(f"{name}-v5", max_episode_steps=max_steps)
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    low, high = env.action_space.low, env.action_space.high
    ret, t = 0.0, 0
    while True:
        action = rng.uniform(low, high) if policy == "random" else fixed_action(t, low.shape[0])
        _, reward, terminated, truncated, _ = env.step(action)
        ret, t = ret + reward, t + 1
        if terminated or truncated:
            return ret, t


def c_episodes(pool, name: str, policy: str, episodes: int, max_steps: int):
    jobs = [(name, policy, 10_000 + i, max_steps) for i in range(episodes)]
    out = np.asarray(pool.map(_c_episode, jobs, chunksize=max(1, episodes // 64)), np.float64)
    return out[:, 0], out[:, 1]


def welch_z(a, b) -> float:
    se = np.sqrt(a.var(ddof=1) / len(a) + b.var(ddof=1) / len(b)) if min(len(a), len(b)) > 1 else 0.0
    return float((a.mean() - b.mean()) / se) if se > 0 else (0.0 if a.mean() == b.mean() else float("inf"))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", nargs="+", default=list(ROBOTS), choices=ROBOTS)
    parser.add_argument("--settings", nargs="+", default=list(SETTINGS), choices=SETTINGS)
    parser.add_argument("--episodes", type=int, default=256)
    parser.add_argument("--max-steps", type=int, default=1000)
    parser.add_argument("--drift-steps", type=int, default=100, help="0: skip the qpos drift")
    parser.add_argument("--workers", type=int, default=os.cpu_count())
    parser.add_argument("--ls-iterations", type=int, default=10,
                        help="the default setting's line-search bound (jaxnat's 10)")
    parser.add_argument("--no-record", action="store_true")
    args = parser.parse_args(argv)
    info = common.machine()
    print(f"MJX fidelity on {info['device']}: {args.robots} x {args.settings}, {args.episodes} "
          f"episodes per policy, <= {args.max_steps} steps, {args.workers} C workers", flush=True)
    rows = []
    with multiprocessing.get_context("spawn").Pool(args.workers) as pool:
        for name in args.robots:
            reference = {p: c_episodes(pool, name, p, args.episodes, args.max_steps)
                         for p in POLICIES}
            for setting in args.settings:
                env, params = jaxnat.make(f"MuJoCo/{name}-v0", autoreset=False, physics=setting,
                                          ls_iterations=args.ls_iterations)
                params = params.replace(max_steps_in_episode=args.max_steps)
                drift = {}
                if args.drift_steps:
                    drift = mjx_physics.drift_from_mujoco_c(env, params, args.drift_steps,
                                                            {10, args.drift_steps})
                for policy in POLICIES:
                    ret, length = mjx_episodes(env, params, policy, args.episodes, args.max_steps)
                    c_ret, c_length = reference[policy]
                    (m, h), (cm, ch) = common.mean_ci(ret), common.mean_ci(c_ret)
                    (lm, lh), (clm, clh) = common.mean_ci(length), common.mean_ci(c_length)
                    label = setting if setting == "fast" or args.ls_iterations == 10 else (
                        f"default, ls_iterations={args.ls_iterations}")
                    row = {
                        "robot": name, "physics": label, "policy": policy,
                        "return": f"{m:.1f} ± {h:.1f}", "c_return": f"{cm:.1f} ± {ch:.1f}",
                        "return_in_ci": "yes" if abs(m - cm) <= ch else "no",
                        "return_z": welch_z(ret, c_ret),
                        "length": f"{lm:.1f} ± {lh:.1f}", "c_length": f"{clm:.1f} ± {clh:.1f}",
                        "length_in_ci": "yes" if abs(lm - clm) <= max(clh, 1e-9) else "no",
                        "length_z": welch_z(length.astype(float), c_length),
                        "return_mean": m, "return_ci": h, "c_return_mean": cm, "c_return_ci": ch,
                        "length_mean": lm, "c_length_mean": clm,
                        "drift_10": drift.get("mjx@10"),
                        "drift_n": drift.get(f"mjx@{args.drift_steps}"),
                        "c_drift_n": drift.get(f"c@{args.drift_steps}"),
                    }
                    rows.append(row)
                    print(f"  {name} {label} {policy}: return {row['return']} vs C "
                          f"{row['c_return']} (z {row['return_z']:.2f}), length {row['length']} "
                          f"vs {row['c_length']}", flush=True)
    columns = [
        ("robot", "robot", ""), ("physics", "physics", ""), ("policy", "policy", ""),
        ("return", "MJX return", ""), ("c_return", "C return", ""),
        ("return_in_ci", "in C CI", ""), ("return_z", "z", ".2f"),
        ("length", "MJX length", ""), ("c_length", "C length", ""),
        ("length_in_ci", "in C CI", ""), ("length_z", "z", ".2f"),
        ("drift_10", "MJX-C qpos @10", ".1e"), ("drift_n", f"MJX-C qpos @{args.drift_steps}", ".1e"),
        ("c_drift_n", f"C-C' qpos @{args.drift_steps}", ".1e"),
    ]
    summary = {
        "episodes": f"{args.episodes} per policy and side, at most {args.max_steps} env steps",
        "reference": "MuJoCo C through Gymnasium <Robot>-v5 (float64), worker processes",
        "policies": f"random: uniform on the action box; fixed: a_j(t) = 0.5 sin(2 pi t / "
                    f"{PERIOD} + 2 pi j / nu), differing only by reset noise",
        "z": "(MJX mean - C mean) / Welch standard error; 'in C CI': MJX mean inside C's 95% "
             "t-interval",
    }
    common.record("mjx_fidelity", info, common.markdown_table(rows, columns), summary, rows,
                  save=not args.no_record)


if __name__ == "__main__":
    main()
