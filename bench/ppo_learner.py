"""PPO's update alone from pixels: GAE and the epochs on a stored rollout, no env, per conv form.

    python bench/ppo_learner.py [--robot HalfCheetah] [--total-envs 16384 32768] [--seeds 5]
        [--dtypes bfloat16] [--convs s2d unrolled grouped] [--trace] [--hlo DIR]

`bench/pixel_ppo.py` times PPO from pixels end to end; with MuJoCo Warp's physics the env is
a small part of an update there and the learner holds the rate. This bench times the learner
by itself, so its forms can be compared without compiling an env: one call of `UpdateRule.learn`
(PPO's, `jaxnat.agents.ppo.RULE`) vmapped over `--seeds`, on a rollout of uint8 84x84x4
observations (`PixelMuJoCo/<robot>-v0`'s spaces; random pixels, actions and values: the
update's work does not depend on them) of `--total-envs` envs over all seeds x 16 steps, at the
paper profile's PixelMuJoCo PPO settings (4 epochs x 4 minibatches, `PAPER_SCALE`). One row
per trunk dtype and convolution form (`jaxnat.agents.conv`):

- **update s**: the median of 3 calls after the first; **learner steps/s**: the rollout's env
  steps over that time, the rate an update allows with an env that costs nothing;
- **learner TFLOP/s**: 3x the trunk's forward FLOPs per sample per epoch (forward, and
  backward for inputs and weights) over the update's time;
- with `--trace`, the update's device time by kernel class (`common.KERNEL_CLASSES`: copies,
  XLA's fusions, cuDNN's convolutions, cuBLAS) and its top kernels in the printed output; with
  `--hlo DIR`, each row's optimised program (XLA's HLO text) written to DIR.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import jax
import jax.numpy as jnp

sys.path.insert(0, os.path.dirname(__file__))
import common  # noqa: E402
from pixel_ppo import ROBOTS, ppo_config  # noqa: E402

from jaxnat.agents.conv import IMPLEMENTATIONS  # noqa: E402


def synthetic_rollout(key, num_steps: int, num_envs: int, observation_space, action_size: int):
    """One seed's `Transition` `[T, N, ...]`: random pixels, Gaussian actions and values, no
    episode ends."""
    from jaxnat.agents.rollout import EPISODE_KEYS, Transition

    keys = jax.random.split(key, 4)
    shape = (num_steps, num_envs)
    obs = jax.random.bits(keys[0], (*shape, *observation_space.shape), jnp.uint8)
    value = jax.random.normal(keys[1], shape)
    zeros, never = jnp.zeros(shape), jnp.zeros(shape, bool)
    info = {name: never if name == "returned_episode" else zeros for name in EPISODE_KEYS}
    return Transition(obs=obs, action=jax.random.normal(keys[2], (*shape, action_size)),
                      log_prob=jnp.full(shape, -8.0), value=value, reward=jax.random.normal(keys[3], shape),
                      done=zeros, next_value=value, info={**info, "terminated": never})


def measure(args, robot: str, total_envs: int, dtype: str, conv: str) -> dict:
    import jaxnat
    from jaxnat.agents import ppo
    from jaxnat.agents.networks import make_actor_critic

    env, params = jaxnat.make(f"PixelMuJoCo/{robot}-v0", physics="fast")
    observation_space, action_space = env.observation_space(params), env.action_space(params)
    per_seed = total_envs // args.seeds
    config = ppo_config(per_seed, 1, dtype)
    network = make_actor_critic(observation_space, action_space, config.trunk, dtype=dtype, conv=conv)
    row = {"robot": robot, "seeds": args.seeds, "envs_per_seed": per_seed, "total_envs": per_seed * args.seeds,
           "num_steps": config.num_steps, "dtype": dtype, "conv": conv}
    keys = jax.random.split(jax.random.key(0), args.seeds)
    train_states = jax.jit(jax.vmap(lambda k: ppo.RULE.train_state(config, network, observation_space, 1, k)))(keys)
    rollouts = jax.jit(jax.vmap(lambda k: synthetic_rollout(k, config.num_steps, per_seed, observation_space,
                                                            action_space.shape[0])))(keys)
    learn = jax.jit(jax.vmap(lambda state, rollout, key: ppo.RULE.learn(config, network, state, rollout, key)),
                    donate_argnums=0)
    start = time.perf_counter()
    compiled = learn.lower(train_states, rollouts, keys).compile()
    row["compile_s"] = time.perf_counter() - start
    if args.hlo:
        os.makedirs(args.hlo, exist_ok=True)
        with open(os.path.join(args.hlo, f"ppo_learner-{robot}-{row['total_envs']}-{dtype}-{conv}.hlo.txt"), "w") as f:
            f.write(compiled.as_text())
    state = [train_states]

    def call():
        state[0], metrics = compiled(state[0], rollouts, keys)
        jax.block_until_ready((state[0], metrics))

    call()
    row["update_s"] = common.median_seconds(call, repeats=3)
    steps = row["total_envs"] * row["num_steps"]
    row["learner_sps"] = steps / row["update_s"]
    one_seed = jax.tree_util.tree_map(lambda x: x[0], state[0].params)
    row["forward_mflop"] = common.forward_mflop(network, one_seed, observation_space)
    row["learner_tflops"] = 3 * row["forward_mflop"] * 1e6 * config.update_epochs * steps / row["update_s"] / 1e12
    if args.trace:
        import tempfile

        with tempfile.TemporaryDirectory() as trace_dir:
            with jax.profiler.trace(trace_dir, create_perfetto_trace=True):
                call()
            kernels = common.device_kernels(trace_dir)
        classes = common.kernel_classes(kernels)
        row["kernel_classes"] = {name: [round(ms, 2), round(share, 4)] for name, (ms, share) in classes.items()}
        row["device_ms"] = sum(ms for _, ms, _ in kernels)
        row["top_kernels"] = kernels[:25]
        for name, (ms, share) in classes.items():
            print(f"  {ms:9.2f} ms {share:6.1%}  {name}", flush=True)
        for name, ms, share in kernels[:25]:
            print(f"    {ms:9.2f} ms {share:6.1%}  {name[:120]}", flush=True)
    return row


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--robot", default="HalfCheetah", choices=ROBOTS)
    parser.add_argument("--total-envs", nargs="+", type=int, default=[16384, 32768])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--dtypes", nargs="+", default=["bfloat16"], choices=["float32", "bfloat16"])
    parser.add_argument("--convs", nargs="+", default=["s2d", "unrolled", "grouped"], choices=IMPLEMENTATIONS)
    parser.add_argument("--trace", action="store_true", help="profile one call per row: device time by kernel")
    parser.add_argument("--hlo", default=None, help="write each row's optimised HLO text to this folder")
    parser.add_argument("--no-record", action="store_true")
    args = parser.parse_args(argv)
    start = time.perf_counter()
    rows = []
    for total_envs in args.total_envs:
        for dtype in args.dtypes:
            for conv in args.convs:
                try:
                    row = measure(args, args.robot, total_envs, dtype, conv)
                except Exception as error:  # a row too big for the device is a row of the table
                    if "RESOURCE_EXHAUSTED" not in str(error):
                        raise
                    row = {"robot": args.robot, "total_envs": total_envs, "dtype": dtype, "conv": conv,
                           "outcome": "out of device memory"}
                for name, (ms, share) in row.get("kernel_classes", {}).items():
                    row[f"share {name}"] = share
                rows.append(row)
                print(json.dumps({k: v for k, v in row.items() if k != "top_kernels"}), flush=True)
    shares = sorted({k for r in rows for k in r if k.startswith("share ")})
    table = common.markdown_table(rows, [
        ("robot", "robot", ""), ("total_envs", "envs (all seeds)", ",d"), ("dtype", "trunk dtype", ""),
        ("conv", "conv", ""), ("compile_s", "compile s", ".0f"), ("update_s", "update s", ".3f"),
        ("learner_sps", "learner steps/s", ".3e"), ("learner_tflops", "learner TFLOP/s", ".1f"),
        *[(k, k.removeprefix("share "), ".1%") for k in shares], ("outcome", "outcome", "")])
    summary = {
        "settings": f"PPO's update (GAE + 4 epochs x 4 minibatches) on a stored rollout of {args.seeds} vmapped "
                    f"seeds x 16 steps of uint8 84x84x4 pixels, PixelMuJoCo/{args.robot}-v0's spaces, no env",
        "bench_seconds": round(time.perf_counter() - start),
    }
    common.record("ppo_learner", common.machine(), table, summary, rows, save=not args.no_record)


if __name__ == "__main__":
    main()
