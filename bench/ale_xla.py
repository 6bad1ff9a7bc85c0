"""Can Natural Atari join the one jitted stack? ALE stepped inside a jitted program (ale-py's XLA
interface) against ALE and jaxnat's env stepped from Python, side by side in one run.

ale-py 0.12's `AtariVectorEnv.xla()` registers FFI targets for reset and step (CPU, and CUDA
where the wheel has them), so `jax.lax.scan` can step the emulators inside a compiled program:
no Python between steps, the actions drawn in the program. If that runs at >= 90% of today's
host path, Natural Atari could train through the same jitted driver as every other family (the
compositor, which needs ALE's full-resolution screens, then a host callback or a JAX function on
the device). For each `--num-envs`, at `--threads` ALE threads, the same settings as
`bench/natural_atari.py` (Breakout, sticky actions 0.25, up to 30 no-ops, frame skip 4 with
max-pool, no FIRE at reset, unclipped rewards), uniformly random actions:

- `ale python`: ale-py's vector env at 84x84 gray, stack 4 (ALE's own resize), stepped from a
  Python loop with numpy actions;
- `ale xla`: the same env's XLA step in a jitted `lax.scan` of `--steps` steps, the actions
  drawn with `jax.random` in the program (on the default device: the GPU where there is one);
- `ale xla screen`: the same, returning the max-pooled 210x160 gray screen (stack 1): what a
  compositor on the device would take, so the cost of moving full screens into the program;
- `jaxnat none` and `jaxnat video`: jaxnat's `NaturalAtari/Breakout-v0` (background none and
  video) stepped from Python, today's env alone; `jaxnat none` is the host path the decision
  rule compares with (the `/ jaxnat none` column).

Each is timed `--repeats` times after a warm-up (compiling), the median kept. The XLA interface
needs `chex` (ale-py's `xla` extra: `pip install "ale-py[xla]"`); without it those rows say so.

    python bench/ale_xla.py                              # 64 256 envs, one thread per core
    python bench/ale_xla.py --num-envs 16 --steps 50 --repeats 2 --no-record
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

# ALE's preprocessing as bench/natural_atari.py sets it for both sides.
ALE_SETTINGS = dict(repeat_action_probability=0.25, noop_max=30, frameskip=4, maxpool=True, use_fire_reset=False,
                    reward_clipping=False, episodic_life=False)


def parse(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--game", default="Breakout")
    parser.add_argument("--num-envs", type=int, nargs="+", default=[64, 256])
    parser.add_argument("--threads", type=int, default=os.cpu_count() or 1, help="ALE threads")
    parser.add_argument("--steps", type=int, default=200, help="batched steps per timing")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--no-record", action="store_true")
    args = parser.parse_args(argv)
    for name in ("threads", "steps", "repeats"):
        if getattr(args, name) < 1:
            parser.error(f"--{name} must be at least 1, got {getattr(args, name)}")
    if min(args.num_envs) < 1:
        parser.error(f"--num-envs must be at least 1, got {min(args.num_envs)}")
    return args


def ale_env(game: str, num_envs: int, threads: int, screen: bool):
    """ale-py's vector env: 84x84 gray stack 4, or (`screen`) the 210x160 gray screen alone."""
    from ale_py.vector_env import AtariVectorEnv

    size = dict(img_height=210, img_width=160, stack_num=1) if screen else dict(img_height=84, img_width=84,
                                                                                 stack_num=4)
    return AtariVectorEnv(game.lower(), num_envs=num_envs, num_threads=threads, grayscale=True, **size,
                          **ALE_SETTINGS)


def median_rate(run, num_envs: int, steps: int, repeats: int) -> float:
    """Env steps/s of `run()` (which steps `num_envs` envs `steps` times): the median of
    `repeats` timings after one warm-up call."""
    run()
    seconds = []
    for _ in range(repeats):
        start = time.perf_counter()
        run()
        seconds.append(time.perf_counter() - start)
    return num_envs * steps / statistics.median(seconds)


def python_loop(env, num_envs: int, steps: int, seed: int = 0):
    """Steps `env` (numpy in, numpy out) with uniformly random actions from a Python loop."""
    rng = np.random.default_rng(seed)
    actions = int(env.single_action_space.n)
    env.reset(seed=seed)

    def run():
        for _ in range(steps):
            env.step(rng.integers(0, actions, num_envs))

    return run


def xla_loop(env, num_envs: int, steps: int):
    """`steps` of `env`'s XLA step in one jitted `lax.scan`, the actions drawn in the program."""
    import jax
    import jax.numpy as jnp

    handle, reset, step = env.xla()
    handle, _ = reset(handle, seed=0)
    actions = int(env.single_action_space.n)

    @jax.jit
    def program(handle, key):
        def body(carry, _):
            handle, key = carry
            key, key_act = jax.random.split(key)
            handle, (obs, reward, *_) = step(handle, jax.random.randint(key_act, (num_envs,), 0, actions, jnp.int32))
            return (handle, key), reward.sum() + obs.reshape(num_envs, -1)[:, 0].astype(jnp.int32).sum()
        return jax.lax.scan(body, (handle, key), None, length=steps)

    state = {"handle": handle, "key": jax.random.key(0)}

    def run():
        (state["handle"], state["key"]), out = program(state["handle"], state["key"])
        jax.block_until_ready(out)

    return run


def rows_for(args, num_envs: int) -> list[dict]:
    import jaxnat

    rows = []

    def add(name: str, make, loop):
        env = None
        try:
            env = make()
            rate, note = median_rate(loop(env), num_envs, args.steps, args.repeats), ""
        except Exception as err:  # noqa: BLE001 (a missing extra or ROM: the row says which)
            rate, note = float("nan"), f"{type(err).__name__}: {(str(err).splitlines() or [''])[0][:120]}"
        finally:
            if env is not None:
                env.close()
        rows.append({"envs": num_envs, "contender": name, "rate": rate, "note": note})
        print(f"{num_envs} envs · {name}: {rate:,.0f} env steps/s {note}", flush=True)

    def steps_of(env):
        return python_loop(env, num_envs, args.steps)

    def xla_of(env):
        return xla_loop(env, num_envs, args.steps)

    add("ale python", lambda: ale_env(args.game, num_envs, args.threads, False), steps_of)
    add("ale xla", lambda: ale_env(args.game, num_envs, args.threads, False), xla_of)
    add("ale xla screen", lambda: ale_env(args.game, num_envs, args.threads, True), xla_of)
    for background in ("none", "video"):
        add(f"jaxnat {background}", lambda b=background: jaxnat.make_vec(
            f"NaturalAtari/{args.game}-v0", num_envs, num_threads=args.threads, background=b), steps_of)
    ale = next(r["rate"] for r in rows if r["contender"] == "ale python")
    host = next(r["rate"] for r in rows if r["contender"] == "jaxnat none")  # today's host path
    for row in rows:
        row["ratio"], row["over_host"] = row["rate"] / ale, row["rate"] / host
    return rows


def main(argv=None) -> int:
    args = parse(argv)
    import common

    info = common.machine()
    rows = [row for n in args.num_envs for row in rows_for(args, n)]
    table = common.markdown_table(rows, [("envs", "envs", ","), ("contender", "contender", ""),
                                         ("rate", "env steps/s", ",.0f"), ("ratio", "/ ale python", ".2f"),
                                         ("over_host", "/ jaxnat none", ".2f"), ("note", "note", "")])
    xla = {row["envs"]: row["over_host"] for row in rows
           if row["contender"] == "ale xla" and np.isfinite(row["over_host"])}
    summary = {"game": args.game, "ALE threads": args.threads, "steps per timing": args.steps,
               "repeats": f"{args.repeats} (median), after one warm-up",
               "ale xla / jaxnat none": ", ".join(f"{n} envs {r:.2f}" for n, r in xla.items()) or "not run",
               "decision rule": "the XLA path joins the jitted stack only at >= 0.90 of today's host path"}
    common.record("ale_xla", info, table, summary, rows, save=not args.no_record)
    return 0


if __name__ == "__main__":
    sys.exit(main())
