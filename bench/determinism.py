"""Same key, same trajectory: `jaxnat.testing.check_determinism` over every env family, and what
XLA's deterministic GPU ops cost.

For each env: a vmapped rollout of random actions, run three times under one key (twice from
one compiled program, once after compiling again), every output compared bit for bit; the
median wall time of the compiled rollout gives env steps/s. Run once as is and once with
`--deterministic-ops` (sets `XLA_FLAGS=--xla_gpu_deterministic_ops=true` before JAX starts):
the two records side by side give each family's determinism and the flag's throughput cost.

`--train-ids` adds PPO training runs (`jaxnat.testing.check_training_determinism`: a few
updates, trained parameters and every other output compared bit for bit). `--isolate ID` runs
MJX's forward stages one by one on a batch of that env's states, each twice from one compiled
program, and names the stages whose outputs differ (which operations are not reproducible).

    python bench/determinism.py [--deterministic-ops] [--num-envs 1024] [--steps 8] [--ids ...]
        [--train-ids ...] [--isolate MuJoCo/Ant-v0]
"""

from __future__ import annotations

import argparse
import sys
import time

DEFAULT_IDS = [  # cheapest first, so a run stopped early has the most rows
    "Classify/Digits-v0", "Localize/Clutter-v0",
    "MuJoCo/Swimmer-v0", "MuJoCo/Hopper-v0", "MuJoCo/HalfCheetah-v0", "MuJoCo/Ant-v0",
    "PixelMuJoCo/Hopper-v0", "PixelMuJoCo/Hopper-v0:floor=video", "PixelMuJoCo/Ant-v0",
    "PixelMuJoCo/Ant-v0:floor=video", "PixelMuJoCo/Ant-v0:floor=noise", "PixelMuJoCo/Ant-v0:observation=noise",
    "PixelMuJoCo/Swimmer-v0", "PixelMuJoCo/HalfCheetah-v0",
]
DEFAULT_TRAIN_IDS = ["Classify/Digits-v0", "Localize/Clutter-v0", "MuJoCo/Ant-v0", "PixelMuJoCo/Ant-v0",
                     "PixelMuJoCo/Hopper-v0:floor=video"]


def parse_id(item: str) -> tuple[str, dict]:
    """`PixelMuJoCo/Ant-v0:floor=video,observation=noise` -> (id, kwargs)."""
    env_id, _, rest = item.partition(":")
    kwargs = dict(pair.split("=", 1) for pair in rest.split(",") if pair)
    return env_id, kwargs


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ids", nargs="*", default=DEFAULT_IDS, help="env ids, optionally ID:key=value,...")
    parser.add_argument("--train-ids", nargs="*", default=[], help="env ids whose PPO training is checked")
    parser.add_argument("--train-envs", type=int, default=64)
    parser.add_argument("--train-updates", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=2, help="timed runs of each compiled program (median)")
    parser.add_argument("--isolate", default=None, help="an MJX env id: which forward stages differ")
    parser.add_argument("--num-envs", type=int, default=1024)
    parser.add_argument("--steps", type=int, default=8)
    parser.add_argument("--deterministic-ops", action="store_true",
                        help="run with XLA_FLAGS=--xla_gpu_deterministic_ops=true")
    parser.add_argument("--budget-seconds", type=float, default=None,
                        help="start no new env after this long; the rest are listed as not run")
    parser.add_argument("--no-record", action="store_true")
    args = parser.parse_args(argv)
    if args.deterministic_ops:  # before JAX starts: XLA reads its flags once
        from jaxnat.testing import enable_deterministic_ops  # noqa: PLC0415
        enable_deterministic_ops()

    sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parent))
    import common  # noqa: PLC0415

    from jaxnat.datasets import DatasetNotFoundError  # noqa: PLC0415
    from jaxnat.registration import MissingDependencyError  # noqa: PLC0415
    from jaxnat.testing import check_determinism, check_training_determinism  # noqa: PLC0415

    info = common.machine()
    mode = "xla_gpu_deterministic_ops" if args.deterministic_ops else "default"
    if args.isolate:
        isolate(args.isolate, args.num_envs, args.steps)
    checks = [(item, "rollout", lambda i, kw: check_determinism(i, args.num_envs, args.steps,
                                                                   repeats=args.repeats, **kw))
              for item in args.ids]
    checks += [(item, f"ppo, {args.train_updates} updates",
                lambda i, kw: check_training_determinism(i, "ppo", args.train_envs, 16, args.train_updates,
                                                            repeats=args.repeats, **kw))
               for item in args.train_ids]
    rows, not_run, start = [], [], time.perf_counter()
    for item, what, check in checks:
        if args.budget_seconds is not None and time.perf_counter() - start > args.budget_seconds:
            not_run.append(f"{item} ({what})")
            continue
        env_id, kwargs = parse_id(item)
        try:
            report = check(env_id, kwargs)
        except (DatasetNotFoundError, MissingDependencyError) as err:
            print(f"{item}: skipped ({err})", flush=True)
            continue
        row = {"env": item, "what": what, "mode": mode, "identical": report.identical,
               "first_difference": "" if report.identical else str(report).split(": ", 1)[1],
               "steps_per_second": report.steps_per_second}
        rows.append(row)
        print(row, flush=True)
    table = common.markdown_table(rows, [("env", "env", ""), ("what", "checked", ""), ("mode", "XLA mode", ""),
                                         ("identical", "bitwise identical", ""),
                                         ("first_difference", "first difference", ""),
                                         ("steps_per_second", "env steps/s", ",.0f")])
    summary = {"mode": mode, "num_envs": args.num_envs, "steps": args.steps,
               "identical": f"{sum(r['identical'] for r in rows)} of {len(rows)}",
               **({"not run (time budget)": ", ".join(not_run)} if not_run else {})}
    common.record("determinism", info, table, summary, rows, save=not args.no_record)


def isolate(item: str, num_envs: int, steps: int) -> None:
    """Print, for each of MJX's forward stages, whether two runs of one compiled program on the
    same batch of states (`item` stepped `steps` times under random actions) give the same bits,
    and the fields that differ."""
    import jax  # noqa: PLC0415
    import numpy as np  # noqa: PLC0415

    from jaxnat.mjx_pixel.models import import_mjx  # noqa: PLC0415
    from jaxnat.registration import make  # noqa: PLC0415

    mjx = import_mjx()
    env_id, kwargs = parse_id(item)
    env, params = make(env_id, autoreset=False, **kwargs)
    m = env.unwrapped.mjx_model
    keys = jax.random.split(jax.random.key(0), num_envs)
    space = env.action_space(params)

    @jax.jit
    def states(keys):
        _, state = jax.vmap(env.reset, in_axes=(0, None))(keys, params)
        def body(state, key):
            action = jax.vmap(space.sample)(jax.random.split(key, num_envs))
            return jax.vmap(env.step, in_axes=(0, 0, 0, None))(keys, state, action, params)[1], None
        return jax.lax.scan(body, state, jax.random.split(keys[0], steps))[0]

    data = jax.block_until_ready(states(keys)).data
    stages = [("kinematics", mjx.kinematics), ("com_pos", mjx.com_pos), ("camlight", mjx.camlight),
              ("fwd_position (collision, constraints)", mjx.fwd_position), ("fwd_velocity", mjx.fwd_velocity),
              ("fwd_actuation", mjx.fwd_actuation), ("fwd_acceleration", mjx.fwd_acceleration),
              ("solve", mjx.solve), ("forward", mjx.forward)]
    with jax.default_matmul_precision("float32"):
        for name, stage in stages:
            fn = jax.jit(jax.vmap(lambda d, stage=stage: stage(m, d)))
            a, b = jax.device_get(fn(data)), jax.device_get(fn(data))
            fields = [jax.tree_util.keystr(path) for (path, x), y in
                      zip(jax.tree_util.tree_flatten_with_path(a)[0], jax.tree.leaves(b))
                      if np.asarray(x).tobytes() != np.asarray(y).tobytes()]
            print(f"isolate {item}: {name}: {'identical' if not fields else 'DIFFERS in ' + ', '.join(fields[:8])}",
                  flush=True)


if __name__ == "__main__":
    main()
