"""Where an MJX robot's physics step spends its time, and what each solver setting costs.

For Ant, HalfCheetah, Hopper and Swimmer (Gymnasium v5 models, jaxnat's default settings):

- **sizes**: candidate collision pairs, contacts (MJX's static count: a capsule-plane pair makes
  two), constraint rows (`efc`), degrees of freedom;
- **solver work on a random-action rollout** (autoresetting, `--envs` envs, `--steps` steps):
  Newton iterations per forward pass per env (mean, max) and the batch's maximum per forward
  pass (under `vmap` the solver's `while_loop` runs until every env has converged, so the batch
  pays for its slowest env); contacts within margin and active constraint rows per env;
- **stage times** of one batched forward pass on states from that rollout: positions
  (kinematics, inertia, factorisation), collision, constraint build, velocity/actuation/smooth
  dynamics, the solve, next to a whole env step (`frame_skip` x RK4's four forward passes, or
  Euler's one, plus the env's own work);
- **settings** (`--variants`): env steps/s of the raw env with one setting changed at a time:
  line-search bound, Newton iteration cap, Euler instead of RK4, the `physics="fast"` contacts
  only, `physics="fast"` itself, and `physics="fast"` without its fused static bodies.

Iterations are counted by wrapping the solver's `while_loop` with a debug callback while the
rollout is traced (profiling only; the envs run MJX unchanged).

    python bench/mjx_profile.py                          # CPU default: 64 envs, 20 steps
    python bench/mjx_profile.py --robots Hopper --variants none
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import sys

import jax
import jax.numpy as jnp
import numpy as np

_BENCH = __import__("pathlib").Path(__file__).resolve().parent
sys.path[:0] = [str(_BENCH), str(_BENCH.parent)]  # bench/common.py; this checkout's jaxnat
import common  # noqa: E402

import jaxnat  # noqa: E402
from jaxnat.mjx_pixel import base  # noqa: E402

mjx = base.mjx
ROBOTS = ("Ant", "HalfCheetah", "Hopper", "Swimmer")
VARIANTS = {  # label -> PhysicsSettings fields changed from the default env (None: fast)
    "ls_iterations=4": {"ls_iterations": 4},
    "iterations<=4": {"iterations": 4},
    "iterations=1": {"iterations": 1},
    "euler": {"integrator": "euler"},
    "fast contacts only": "contacts",
    'physics="fast"': None,
    'physics="fast", static bodies not fused': "unfused",
}


@contextlib.contextmanager
def count_newton_iterations(sink: list):
    """While tracing inside this context, the Newton solver's `while_loop` reports each env's
    iteration count to `sink` (one value per env per forward pass)."""
    original = jax.lax.while_loop

    def while_loop(cond, body, init):
        out = original(cond, body, init)
        if hasattr(init, "solver_niter"):  # MJX's solver context; the line search is a scan
            jax.debug.callback(lambda n: sink.append(np.asarray(n)), out.solver_niter)
        return out

    jax.lax.while_loop = while_loop
    try:
        yield
    finally:
        jax.lax.while_loop = original


def variant_env(name: str, change):
    """The raw default env with `change` applied to its model (see VARIANTS)."""
    if change is None:
        return jaxnat.make(f"MuJoCo/{name}-v0", autoreset=False, physics="fast")[0]
    if change == "unfused":  # fast, jointless bodies kept (Ant: 14 bodies where fast has 10)
        cls = type(jaxnat.make(f"MuJoCo/{name}-v0", autoreset=False)[0])
        fast = dataclasses.replace(cls.fast_physics, fuse_static=False)
        return type(f"Unfused{cls.__name__}", (cls,), {"fast_physics": fast})(physics="fast")
    env, _ = jaxnat.make(f"MuJoCo/{name}-v0", autoreset=False)
    if change == "contacts":  # the fast setting's colliding geoms (and foot spheres) alone
        fast = env.fast_physics
        env.model = base.PhysicsSettings(ls_iterations=int(env.model.opt.ls_iterations),
                                         contact_geoms=fast.contact_geoms,
                                         foot_spheres=fast.foot_spheres).build(env.robot)
    else:
        base.PhysicsSettings(**change).apply(env.model)
    with jax.default_matmul_precision("float32"):  # as MJXEnv traces its physics
        env.mjx_model = mjx.put_model(env.model, impl="jax")
    return env


def rollout(env, params, num_envs: int, num_steps: int):
    """Jitted `run(key) -> stacked data`: autoresetting random-action rollout."""
    space = env.action_space(params)
    low, high = jnp.asarray(space.low), jnp.asarray(space.high)

    def run(key):
        _, state = jax.vmap(env.reset, in_axes=(0, None))(jax.random.split(key, num_envs), params)

        def body(state, key):
            action = jax.random.uniform(key, (num_envs, *space.shape), minval=low, maxval=high)
            keys = jax.random.split(key, num_envs)
            _, state, *_ = jax.vmap(env.step, in_axes=(0, 0, 0, None))(keys, state, action, params)
            return state, state.data

        return jax.lax.scan(body, state, jax.random.split(key, num_steps))[1]

    return jax.jit(run)


def timed(fn, *args) -> float:
    """Median seconds of a jitted `fn(*args)` after its compile."""
    jax.block_until_ready(fn(*args))
    return common.median_seconds(lambda: jax.block_until_ready(fn(*args)), 5)


def stage_times(env, data) -> dict[str, float]:
    """Seconds of each stage of one vmapped forward pass over the batch `data`."""
    m = env.mjx_model

    def positions(d):
        d = mjx.kinematics(m, d)
        d = mjx.com_pos(m, d)
        d = mjx.camlight(m, d)
        d = mjx.crb(m, d)
        d = mjx.factor_m(m, d)
        return mjx.transmission(m, d)

    def dynamics(d):
        d = mjx.fwd_velocity(m, d)
        d = mjx.fwd_actuation(m, d)
        return mjx.fwd_acceleration(m, d)

    stages = {"positions": positions, "collision": lambda d: mjx.collision(m, d),
              "constraints": lambda d: mjx.make_constraint(m, d), "dynamics": dynamics,
              "solve": lambda d: mjx.solve(m, d)}
    times = {}
    with jax.default_matmul_precision("float32"):  # as MJXEnv traces its physics
        d = jax.jit(jax.vmap(positions))(data)
        for label, fn in stages.items():
            fn = jax.jit(jax.vmap(fn))
            times[label] = timed(fn, d)
            d = fn(d)
    return times


def same_states(env, data):
    """`data`'s batch of states (qpos, qvel, warm start) as data of `env`'s model, whose
    contact arrays may differ in size."""
    fresh = jax.jit(jax.vmap(env._reset_data))(data.qpos, data.qvel)
    return fresh.replace(qacc_warmstart=data.qacc_warmstart)


def env_step_seconds(env, params, data, num_envs: int) -> float:
    """Seconds of one vmapped raw env step from `data` with random actions."""
    space = env.action_space(params)
    state = env.state_type(time=jnp.zeros(num_envs, jnp.int32), data=data)
    action = jax.random.uniform(jax.random.key(2), (num_envs, *space.shape),
                                minval=jnp.asarray(space.low), maxval=jnp.asarray(space.high))
    step = jax.jit(jax.vmap(env.step, in_axes=(0, 0, 0, None)))
    return timed(step, jax.random.split(jax.random.key(3), num_envs), state, action, params)


def physics_seconds(env, params, data, num_envs: int) -> float:
    """Seconds of the `frame_skip` physics steps alone (no reward, observation or
    `rne_postconstraint`) of one vmapped env step from `data`."""
    space = env.action_space(params)
    action = jax.random.uniform(jax.random.key(2), (num_envs, *space.shape),
                                minval=jnp.asarray(space.low), maxval=jnp.asarray(space.high))
    return timed(jax.jit(jax.vmap(env._step_data)), data, action)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", nargs="+", default=list(ROBOTS), choices=ROBOTS)
    parser.add_argument("--envs", type=int, default=64)
    parser.add_argument("--steps", type=int, default=20, help="rollout env steps")
    parser.add_argument("--variants", nargs="+", default=list(VARIANTS),
                        help=f"settings to time ({list(VARIANTS)}, or 'none')")
    parser.add_argument("--no-record", action="store_true")
    args = parser.parse_args(argv)
    variants = [v for v in args.variants if v != "none"]
    info = common.machine()
    n = args.envs
    print(f"MJX profile on {info['device']}: {args.robots}, {n} envs, {args.steps} steps",
          flush=True)
    rows = []
    for name in args.robots:
        auto, params = jaxnat.make(f"MuJoCo/{name}-v0")
        raw, _ = jaxnat.make(f"MuJoCo/{name}-v0", autoreset=False)
        from mujoco.mjx._src import collision_driver

        sink: list = []
        with count_newton_iterations(sink):
            run = rollout(auto, params, n, args.steps).lower(jax.random.key(1)).compile()
        datas = run(jax.random.key(1))
        jax.block_until_ready(datas)
        iters = np.stack(sink).reshape(-1, n) if sink else np.zeros((1, n), int)
        last = jax.tree.map(lambda x: x[-1], datas)
        impl = datas._impl
        within = np.asarray(impl.contact.dist < impl.contact.includemargin).sum(-1)
        active = np.asarray(impl.efc_force != 0).sum(-1)
        stages = stage_times(raw, last)
        step_s = env_step_seconds(raw, params, last, n)
        physics_s = physics_seconds(raw, params, last, n)
        forwards = raw.frame_skip * (4 if raw.model.opt.integrator == 1 else 1)
        row = {
            "robot": name, "variant": "default",
            "pairs": len(list(collision_driver.geom_pairs(raw.model))),
            "contacts": int(impl.contact.dist.shape[-1]), "efc": int(impl.efc_J.shape[-2]),
            "nv": raw.model.nv, "forwards": forwards,
            "niter_mean": float(iters.mean()), "niter_max": int(iters.max()),
            "niter_batch": float(iters.max(1).mean()),
            "touching": float(within.mean()), "active_rows": float(active.mean()),
            **{f"t_{k}": v * 1e3 for k, v in stages.items()},
            "t_forward": sum(stages.values()) * 1e3, "t_step": step_s * 1e3,
            "outside": 1 - physics_s / step_s, "sps": n / step_s,
        }
        for k in stages:
            row[f"t_{k}"] = stages[k] / sum(stages.values())
        rows.append(row)
        print(f"  {name}: {row}", flush=True)
        for label in variants:
            env = variant_env(name, VARIANTS[label])
            step_s = env_step_seconds(env, params, same_states(env, last), n)
            rows.append({"robot": name, "variant": label, "t_step": step_s * 1e3,
                         "sps": n / step_s, "speedup": row["t_step"] / (step_s * 1e3)})
            print(f"  {name} {label}: {n / step_s:.3e} env steps/s", flush=True)

    columns = [
        ("robot", "robot", ""), ("variant", "variant", ""), ("pairs", "pairs", "d"),
        ("contacts", "contacts", "d"), ("efc", "efc rows", "d"), ("nv", "nv", "d"),
        ("touching", "touching/env", ".1f"), ("active_rows", "active rows/env", ".1f"),
        ("niter_mean", "Newton it/env", ".2f"), ("niter_batch", "Newton it/batch", ".2f"),
        ("niter_max", "Newton max", "d"), ("forwards", "forwards/step", "d"),
        ("t_positions", "pos", ".0%"), ("t_collision", "collision", ".0%"),
        ("t_constraints", "constraints", ".0%"), ("t_dynamics", "dynamics", ".0%"),
        ("t_solve", "solve", ".0%"), ("t_forward", "forward ms", ".2f"),
        ("t_step", "env step ms", ".2f"), ("outside", "outside physics", ".0%"),
        ("sps", "env steps/s", ".3e"), ("speedup", "x default", ".2f"),
    ]
    summary = {
        "what": f"{n} envs on one device; rollout: {args.steps} autoresetting random-action "
                "steps; stage and step times: one vmapped call on the rollout's last states",
        "Newton it/env": "Newton iterations per forward pass per env (mean); /batch: the "
                         "batch's maximum per forward pass (what vmap runs), mean over passes",
        "touching": "contacts within margin per env; active rows: constraint rows with "
                    "nonzero force",
        "stages": "pos .. solve: shares of one forward pass, each stage jitted alone (so "
                  "forward ms, their sum, includes per-call overheads a fused step does not "
                  "pay)",
        "outside physics": "share of the raw env step not in its frame_skip physics steps "
                           "(reward, observation, Ant's rne_postconstraint)",
        "variants": "one setting changed from the default (raw env, same states); "
                    "'fast contacts only': physics='fast''s colliding geoms, nothing else; "
                    "'static bodies not fused': physics='fast' but for fuse_static",
    }
    common.record("mjx_profile", info, common.markdown_table(rows, columns), summary, rows,
                  save=not args.no_record)


if __name__ == "__main__":
    main()
