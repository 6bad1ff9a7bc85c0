"""MJX physics throughput of the MuJoCo robots (state observations, no rendering).

Measures, in one run on the default JAX backend, for Ant, HalfCheetah, Hopper and Swimmer:
- env steps/s of `jit(vmap(step))` under `lax.scan` with uniformly random actions, for each
  batch size (GPU default: 1,024, 4,096, 16,384 envs) and each `physics=` setting
  (`--physics`: "default", Gymnasium v5's dynamics, and "fast"), raw; at the largest size also
  autoresetting (what `jaxnat.make` returns: under `vmap` every step also computes a reset;
  `--no-autoreset` skips it) and raw with `ls_iterations=--other-ls` (the models' own
  line-search bound, 50, against jaxnat's default 10; see `mjx_pixel/base.py`);
  physics steps/s is env steps/s x `frame_skip` (`mj_step` calls), and each row states its
  physics steps per env step and forward passes per physics step (RK4: 4, Euler: 1);
- Brax's MJX envs (`brax.envs.get_environment(name, backend="mjx")`: ant, hopper, halfcheetah,
  raw, the same random actions and batch sizes) in the same run, when brax is importable
  (an optional bench dependency; the table says when it is absent), and each jaxnat row's
  ratio to Brax's env steps/s at the same size;
- with `--warp`, MuJoCo Warp (MJX's `impl="warp"`: the optional `mujoco-warp` and `warp-lang`
  packages) stepping each `--physics` setting's model raw, at every size: MuJoCo C's
  algorithms as GPU kernels, through `mjx.step` under `vmap` (the table says when they are not
  importable); contact and constraint capacities from a MuJoCo C rollout, with room to spare;
- MuJoCo C's own `mj_step` on one CPU core (Gymnasium's physics), and the ratio;
- how far MJX rollouts (each raw `--physics` setting; with `--warp`, MuJoCo Warp's too, 4
  worlds under `vmap`) drift from MuJoCo C (max |qpos| error after 10 and `--drift-steps` env
  steps from the same state under the same random actions; CPU runs only, unless
  `--drift-steps` is given), next to how far MuJoCo C drifts from itself when its initial
  `qpos` is moved by 1e-7 (float32's resolution): contact-rich robots are chaotic, so a drift
  of the same size is rounding amplified, not a modelling difference.

    python bench/mjx_physics.py                    # GPU: the sizes above
    python bench/mjx_physics.py --sizes 16 64      # CPU (default there: 64)
    python bench/mjx_physics.py --robots Ant --no-autoreset --other-ls 0   # one robot, fewer compiles
    python bench/mjx_physics.py --robots HalfCheetah --physics fast --warp --no-brax   # and MuJoCo Warp
"""

from __future__ import annotations

import argparse
import sys
import time

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

_BENCH = __import__("pathlib").Path(__file__).resolve().parent
sys.path[:0] = [str(_BENCH), str(_BENCH.parent)]  # bench/common.py; this checkout's jaxnat
import common  # noqa: E402

import jaxnat  # noqa: E402
from jaxnat.mjx_pixel.warp_physics import capacity  # noqa: E402

ROBOTS = ("Ant", "HalfCheetah", "Hopper", "Swimmer")
BRAX = {"Ant": "ant", "HalfCheetah": "halfcheetah", "Hopper": "hopper"}  # Brax's env names


def brax_env(name: str):
    """Brax's MJX env for robot `name`, or a one-line reason it cannot be built."""
    if name not in BRAX:
        return None, "Brax has no such env"
    try:
        import warnings

        from brax import envs
    except ImportError as err:
        return None, f"brax not importable ({err.__class__.__name__}: pip install brax)"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # Brax's notice that it is no longer maintained
        return envs.get_environment(BRAX[name], backend="mjx"), None


def brax_rollout(env, num_envs: int, num_steps: int):
    """As `physics_rollout`, for a Brax env (actions uniform on [-1, 1], Brax's box)."""
    step, reset = jax.vmap(env.step), jax.vmap(env.reset)

    def run(key, params):
        state = reset(jax.random.split(key, num_envs))

        def body(state, key):
            actions = jax.random.uniform(key, (num_envs, env.action_size), minval=-1.0, maxval=1.0)
            state = step(state, actions)
            return state, state.reward.sum()

        state, rewards = jax.lax.scan(body, state, jax.random.split(key, num_steps))
        return rewards.sum(), state

    return jax.jit(run)


def physics_rollout(env, params, num_envs: int, num_steps: int):
    """A jitted `run(key, params)`: reset `num_envs` envs, then `num_steps` vmapped steps with
    uniformly random actions; returns the summed rewards and the final state. The state is
    returned, as a training loop keeps it, so that XLA cannot drop the fields of the state that
    no reward reads (with the rewards alone, it dropped the work that fills them: which fields
    those are differs between Brax's state and jaxnat's, so the ratio would not compare equal
    work)."""
    space = env.action_space(params)
    low, high = jnp.asarray(space.low), jnp.asarray(space.high)
    step = jax.vmap(env.step, in_axes=(0, 0, 0, None))
    reset = jax.vmap(env.reset, in_axes=(0, None))

    def run(key, params):
        _, state = reset(jax.random.split(key, num_envs), params)

        def body(state, key):
            key_act, key_step = jax.random.split(key)
            actions = jax.random.uniform(key_act, (num_envs, *space.shape), minval=low, maxval=high)
            _, state, reward, *_ = step(jax.random.split(key_step, num_envs), state, actions, params)
            return state, reward.sum()

        state, rewards = jax.lax.scan(body, state, jax.random.split(key, num_steps))
        return rewards.sum(), state

    return jax.jit(run)


def warp_worlds(env, num_envs: int):
    """`(start, advance)` for `num_envs` MuJoCo Warp worlds of `env`'s model, or `(None, why)`:
    `start(qpos)` is the worlds' data from `qpos` `[num_envs, nq]` (zero velocity), `advance(data,
    ctrl)` one env step (`env.frame_skip` x `mjx.step` under `vmap`). The contact pool is shared
    by all worlds (`naconmax`), sized from a MuJoCo C rollout."""
    try:
        from mujoco import mjx  # noqa: PLC0415
        model = mjx.put_model(env.model, impl="warp")
    except (ImportError, RuntimeError) as err:
        return None, f"MuJoCo Warp not usable ({err.__class__.__name__}: pip install mujoco-warp)"
    contacts, constraints = capacity(env.model, env.frame_skip)
    step = jax.vmap(mjx.step, in_axes=(None, 0))

    def start(qpos):
        return jax.vmap(lambda q: mjx.make_data(env.model, impl="warp", naconmax=num_envs * contacts,
                                                njmax=constraints).replace(qpos=q))(qpos)

    def advance(data, ctrl):
        return jax.lax.fori_loop(0, env.frame_skip, lambda _, d: step(model, d), data.replace(ctrl=ctrl))

    return start, advance


def warp_rollout(env, num_envs: int, num_steps: int):
    """As `physics_rollout`, with MuJoCo Warp stepping `env`'s model (`warp_worlds`, from `qpos0`
    with the env's reset noise), or a one-line reason it cannot run."""
    start, advance = warp_worlds(env, num_envs)
    if start is None:
        return None, advance
    low, high = (jnp.asarray(x, jnp.float32) for x in env.model.actuator_ctrlrange.T)
    scale = float(env.default_params.reset_noise_scale)

    def run(key, params):
        del params
        noise = jax.random.uniform(key, (num_envs, env.model.nq), minval=-scale, maxval=scale)
        data = start(jnp.asarray(env.model.qpos0, jnp.float32) + noise)

        def body(data, key):
            data = advance(data, jax.random.uniform(key, (num_envs, env.model.nu), minval=low, maxval=high))
            return data, data.qpos[:, 0].sum()

        data, positions = jax.lax.scan(body, data, jax.random.split(key, num_steps))
        return positions.sum(), data

    return jax.jit(run), None


def warp_drift_from_mujoco_c(env, num_steps: int, checkpoints, worlds: int = 4) -> dict[str, float]:
    """Max |qpos| difference between MuJoCo Warp (float32, `worlds` worlds, `warp_worlds`) and
    MuJoCo C (float64) after each checkpoint step, from the same reset states (`qpos0` plus
    the env's reset noise, zero velocity) under the same random actions: `{"warp@t": error}`,
    empty when Warp cannot run."""
    start, advance = warp_worlds(env, worlds)
    if start is None:
        return {}
    rng = np.random.default_rng(0)
    scale = float(env.default_params.reset_noise_scale)
    qpos0 = (env.model.qpos0 + rng.uniform(-scale, scale, (worlds, env.model.nq))).astype(np.float32)
    actions = rng.uniform(*env.model.actuator_ctrlrange.T, size=(num_steps, worlds, env.model.nu))

    def run(qpos, actions):
        def body(data, action):
            data = advance(data, action)
            return data, data.qpos

        return jax.lax.scan(body, start(qpos), actions)[1]

    qpos = np.asarray(jax.jit(run)(jnp.asarray(qpos0), jnp.asarray(actions, jnp.float32)))
    errors = {}
    for world in range(worlds):
        data = mujoco.MjData(env.model)
        data.qpos[:] = qpos0[world]
        for t in range(num_steps):
            data.ctrl[:] = actions[t, world]
            mujoco.mj_step(env.model, data, nstep=env.frame_skip)
            if t + 1 in checkpoints:
                error = float(np.abs(qpos[t, world] - data.qpos).max())
                errors[f"warp@{t + 1}"] = max(errors.get(f"warp@{t + 1}", 0.0), error)
    return errors


def mujoco_c_steps_per_second(env, seconds: float = 2.0) -> float:
    """Env steps/s of MuJoCo C (`frame_skip` x `mj_step`) on one core, random actions."""
    model = env.model
    data = mujoco.MjData(model)
    rng = np.random.default_rng(0)
    low, high = model.actuator_ctrlrange.T
    steps, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        for _ in range(100):
            data.ctrl[:] = rng.uniform(low, high)
            mujoco.mj_step(model, data, nstep=env.frame_skip)
        steps += 100
    return steps / (time.perf_counter() - t0)


def drift_from_mujoco_c(env, params, num_steps: int, checkpoints) -> dict[str, float]:
    """Max |qpos| difference between MJX and MuJoCo C (`mjx@t`), and between MuJoCo C and
    MuJoCo C started 1e-7 away (`c@t`), after each checkpoint step `t`, from the same reset
    state under the same random actions."""
    rng = np.random.default_rng(0)
    actions = rng.uniform(*env.model.actuator_ctrlrange.T, size=(num_steps, env.model.nu))
    _, state = jax.jit(env.reset)(jax.random.key(0), params)
    data, nudged = mujoco.MjData(env.model), mujoco.MjData(env.model)
    for d, offset in [(data, 0.0), (nudged, 1e-7 * rng.choice([-1.0, 1.0], env.model.nq))]:
        d.qpos[:] = np.asarray(state.data.qpos, np.float64) + offset
        d.qvel[:] = np.asarray(state.data.qvel, np.float64)
        mujoco.mj_forward(env.model, d)

    def body(state, action):
        _, state, *_ = env.step(jax.random.key(0), state, action, params)
        return state, state.data.qpos

    _, qpos = jax.jit(lambda s, a: jax.lax.scan(body, s, a))(state, jnp.asarray(actions, jnp.float32))
    qpos = np.asarray(qpos)
    errors = {}
    for t in range(num_steps):
        for d in (data, nudged):
            d.ctrl[:] = actions[t]
            mujoco.mj_step(env.model, d, nstep=env.frame_skip)
        if t + 1 in checkpoints:
            errors[f"mjx@{t + 1}"] = float(np.abs(qpos[t] - data.qpos).max())
            errors[f"c@{t + 1}"] = float(np.abs(nudged.qpos - data.qpos).max())
    return errors


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", nargs="+", default=list(ROBOTS), choices=ROBOTS)
    parser.add_argument("--sizes", nargs="+", type=int, default=None,
                        help="batch sizes (default: 1024 4096 16384 on GPU, 64 on CPU)")
    parser.add_argument("--steps", type=int, default=None,
                        help="env steps per timed scan (default: 100 on GPU, 10 on CPU)")
    parser.add_argument("--drift-steps", type=int, default=None,
                        help="MJX vs MuJoCo C drift over this many steps (default: 100 on CPU, "
                             "skipped on GPU)")
    parser.add_argument("--other-ls", type=int, default=50,
                        help="ls_iterations of the compared variant (0: skip it)")
    parser.add_argument("--physics", nargs="+", default=["default", "fast"],
                        choices=["default", "fast"], help="jaxnat physics= settings to run")
    parser.add_argument("--autoreset", action=argparse.BooleanOptionalAction, default=True,
                        help="also the autoresetting env at the largest size")
    parser.add_argument("--brax", action=argparse.BooleanOptionalAction, default=True,
                        help="also Brax's MJX envs (if brax is importable)")
    parser.add_argument("--warp", action="store_true",
                        help="also MuJoCo Warp on each --physics setting's model (if importable)")
    parser.add_argument("--no-record", action="store_true")
    args = parser.parse_args(argv)

    info = common.machine()
    on_gpu = info["backend"] != "cpu"
    sizes = args.sizes or ([1024, 4096, 16384] if on_gpu else [64])
    num_steps = args.steps or (100 if on_gpu else 10)
    drift_steps = args.drift_steps if args.drift_steps is not None else (0 if on_gpu else 100)
    print(f"MJX physics on {info['device']}: robots {args.robots}, sizes {sizes}, "
          f"{num_steps} steps per scan", flush=True)

    rows = []
    for name in args.robots:
        raw, params = jaxnat.make(f"MuJoCo/{name}-v0", autoreset=False)
        c_sps = mujoco_c_steps_per_second(raw)
        # (side, label, env, sizes, drift columns): each size and variant is a separate
        # compile, so the variants beyond the physics settings run at the largest size only.
        checkpoints = {10, drift_steps}
        variants = []
        for setting in args.physics:
            env, _ = jaxnat.make(f"MuJoCo/{name}-v0", autoreset=False, physics=setting)
            errors = drift_from_mujoco_c(env, params, drift_steps, checkpoints) if drift_steps else {}
            variants.append(("jaxnat", f"raw, {setting}", env, sizes, {
                "drift_10": errors.get("mjx@10"), "drift_n": errors.get(f"mjx@{drift_steps}"),
                "c_drift_10": errors.get("c@10"), "c_drift_n": errors.get(f"c@{drift_steps}")}))
            if args.warp:
                errors = warp_drift_from_mujoco_c(env, drift_steps, checkpoints) if drift_steps else {}
                variants.append(("warp", f"raw, {setting}, MuJoCo Warp", env, sizes, {
                    "drift_10": errors.get("warp@10"), "drift_n": errors.get(f"warp@{drift_steps}")}))
        if args.autoreset:
            variants.append(("jaxnat", "autoreset, default", jaxnat.make(f"MuJoCo/{name}-v0")[0],
                             sizes[-1:], {}))
        if args.other_ls:
            other, _ = jaxnat.make(f"MuJoCo/{name}-v0", autoreset=False, ls_iterations=args.other_ls)
            variants.append(("jaxnat", f"raw, default, ls_iterations={args.other_ls}", other,
                             sizes[-1:], {}))
        brax_sps = {}
        if args.brax:
            benv, why = brax_env(name)
            if benv is None:
                rows.append({"robot": name, "side": "brax", "variant": why})
                print(f"  {name} Brax: {why}", flush=True)
            else:
                variants.insert(0, ("brax", "raw, Brax MJX env", benv, sizes, {}))
        for side, label, env, env_sizes, drift_columns in variants:
            if side == "brax":
                substeps, forwards = env._n_frames, 1 if env.sys.opt.integrator == 0 else 4
            else:
                substeps = env.frame_skip
                forwards = 4 if env.model.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4 else 1
            for num_envs in env_sizes:
                if side == "warp":
                    run, why = warp_rollout(env, num_envs, num_steps)
                    if run is None:
                        rows.append({"robot": name, "side": side, "variant": f"{label}: {why}"})
                        print(f"  {name} {label}: {why}", flush=True)
                        break
                elif side == "brax":
                    run = brax_rollout(env, num_envs, num_steps)
                else:
                    run = physics_rollout(env, params, num_envs, num_steps)
                key = jax.random.key(0)
                t0 = time.perf_counter()
                try:
                    jax.block_until_ready(run(key, params))
                except Exception as err:  # noqa: BLE001  Warp's kernels are new here: a failed size is a row
                    if side != "warp":
                        raise
                    why = f"failed: {err.__class__.__name__}: {str(err).splitlines()[0][:200] if str(err) else ''}"
                    rows.append({"robot": name, "side": side, "envs": num_envs, "variant": f"{label}: {why}"})
                    print(f"  {name} {label} {num_envs} envs: {why}", flush=True)
                    continue
                compile_s = time.perf_counter() - t0
                seconds = common.median_seconds(lambda: jax.block_until_ready(run(key, params)), 3)
                sps = num_envs * num_steps / seconds
                if side == "brax":
                    brax_sps[num_envs] = sps
                row = {
                    "robot": name, "side": side, "envs": num_envs, "variant": label,
                    "steps": num_steps, "substeps": substeps, "forwards": forwards,
                    "sps": sps, "physics_sps": sps * substeps, "compile_s": compile_s,
                    "c_sps": c_sps, "vs_c": sps / c_sps,
                    "vs_brax": (sps / brax_sps[num_envs]
                                if side != "brax" and num_envs in brax_sps else None),
                }
                row.update(drift_columns)
                rows.append(row)
                ratio = f", {row['vs_brax']:.2f}x Brax" if row["vs_brax"] is not None else ""
                print(f"  {name} {side} {label} {num_envs} envs: {sps:.3e} env steps/s "
                      f"({sps / c_sps:.1f}x MuJoCo C on one core{ratio}), compile "
                      f"{compile_s:.1f}s", flush=True)

    columns = [
        ("robot", "robot", ""), ("side", "side", ""), ("variant", "variant", ""),
        ("envs", "envs", ","), ("substeps", "physics steps/env step", "d"),
        ("forwards", "forwards/physics step", "d"),
        ("sps", "env steps/s", ".3e"), ("physics_sps", "physics steps/s", ".3e"),
        ("vs_brax", "/ Brax", ".2f"),
        ("c_sps", "MuJoCo C env steps/s (1 core)", ".3e"), ("vs_c", "MJX / C", ".1f"),
        ("compile_s", "compile s", ".1f"), ("drift_10", "MJX-C qpos @10", ".1e"),
        ("drift_n", f"MJX-C qpos @{drift_steps}", ".1e"), ("c_drift_10", "C-C' qpos @10", ".1e"),
        ("c_drift_n", f"C-C' qpos @{drift_steps}", ".1e"),
    ]
    table = common.markdown_table(rows, columns)
    summary = {
        "what": ("physics only (state observations), jit(vmap(step)) in lax.scan, random actions, "
                 "the final state returned (kept live, as a training loop keeps it)"),
        "steps_per_scan": num_steps,
        "brax": "Brax's MJX envs, raw (no wrappers), their own models and settings (Euler; "
                "Ant: 1 Newton iteration, 4 line-search steps, feet-only contacts); / Brax: "
                "env steps/s over Brax's at the same size",
        "warp": "MuJoCo Warp rows (--warp): MJX's impl='warp' on the same model and options as "
                "the jaxnat row of that setting, raw, random actions; / Brax as for jaxnat's",
        "drift": "max |qpos| error of MJX (float32) vs MuJoCo C (float64) after N env steps, "
                 "same reset state and actions; C-C': MuJoCo C vs MuJoCo C started with qpos "
                 "moved by 1e-7 (chaos: rounding amplified); on Warp rows, MuJoCo Warp's error "
                 "instead (4 worlds under vmap, the row's physics setting, max over worlds)",
    }
    common.record("mjx_physics", info, table, summary, rows, save=not args.no_record)


if __name__ == "__main__":
    main()
