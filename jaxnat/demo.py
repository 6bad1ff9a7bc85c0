"""`python -m jaxnat.demo`: a random policy over many vmapped `Classify/Digits-v0` envs.

The main job of `make run` until the agents land: it shows the env running on the embedded
real digits, prints throughput and the random policy's mean return, and writes a PNG of a few
observations (image where revealed, red outline of the current window).
"""

from __future__ import annotations

import argparse
import pathlib
import time

import jax
import jax.numpy as jnp
import numpy as np

import jaxnat
from jaxnat.wrappers import LogWrapper, VmapWrapper


def rollout_fn(env, params, num_steps: int):
    """A jitted `(key) -> (final obs, episode returns info)` scan of a uniform random policy."""
    action_space = env.action_space(params)

    def run(key):
        key_reset, key_steps = jax.random.split(key)
        obs, state = env.reset(key_reset, params)

        def body(carry, key):
            obs, state = carry
            key_act, key_step = jax.random.split(key)
            actions = jax.vmap(action_space.sample)(jax.random.split(key_act, env.num_envs))
            obs, state, reward, terminated, truncated, info = env.step(key_step, state, actions, params)
            ended = info["returned_episode"]
            return (obs, state), (jnp.sum(ended), jnp.sum(jnp.where(ended, info["returned_episode_returns"], 0.0)), jnp.sum(terminated))

        (obs, state), (ended, returns, correct) = jax.lax.scan(
            body, (obs, state), jax.random.split(key_steps, num_steps)
        )
        return obs, ended.sum(), returns.sum(), correct.sum()

    return jax.jit(run)


def chance_return(num_classes: int, max_steps: int, correct: float, wrong: float) -> float:
    """Expected return of uniformly random labels: step t is reached with (1-p)^(t-1)."""
    p = 1.0 / num_classes
    return sum((1 - p) ** t * (p * correct + (1 - p) * wrong) for t in range(max_steps))


def observation_grid(obs: np.ndarray, columns: int = 8, scale: int = 4) -> np.ndarray:
    """RGB grid (uint8) of observations `[N, H, W, C+2]`: revealed pixels in gray, unrevealed in
    dark blue, the current window outlined in red."""
    tiles = []
    for o in obs:
        image, revealed, window = o[..., :-2], o[..., -2] > 0, o[..., -1] > 0
        gray = image.mean(axis=-1) if image.shape[-1] > 1 else image[..., 0]
        rgb = np.stack([gray] * 3, axis=-1).astype(np.uint8)
        rgb[~revealed] = (40, 20, 20)  # BGR dark blue
        tile = np.kron(rgb, np.ones((scale, scale, 1), np.uint8))
        rows, cols = np.nonzero(window)
        if rows.size:
            r0, r1, c0, c1 = rows.min() * scale, (rows.max() + 1) * scale - 1, cols.min() * scale, (cols.max() + 1) * scale - 1
            tile[[r0, r1], c0 : c1 + 1] = (0, 0, 255)
            tile[r0 : r1 + 1, [c0, c1]] = (0, 0, 255)
        tiles.append(np.pad(tile, ((2, 2), (2, 2), (0, 0)), constant_values=255))
    while len(tiles) % columns:
        tiles.append(np.full_like(tiles[0], 255))
    rows = [np.concatenate(tiles[i : i + columns], axis=1) for i in range(0, len(tiles), columns)]
    return np.concatenate(rows, axis=0)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env-id", default="Classify/Digits-v0")
    parser.add_argument("--num-envs", type=int, default=4096)
    parser.add_argument("--num-steps", type=int, default=1000)
    parser.add_argument("--out", type=pathlib.Path, default=pathlib.Path("out/demo"))
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)

    env, params = jaxnat.make(args.env_id)
    env = VmapWrapper(LogWrapper(env), args.num_envs)
    run = rollout_fn(env, params, args.num_steps)
    key = jax.random.key(args.seed)

    t0 = time.perf_counter()
    jax.block_until_ready(run(key))
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    obs, episodes, returns, correct = jax.block_until_ready(run(jax.random.fold_in(key, 1)))
    seconds = time.perf_counter() - t0
    steps = args.num_envs * args.num_steps

    print(f"jaxnat {jaxnat.__version__} | {args.env_id} | {env.unwrapped.num_classes} classes | "
          f"JAX {jax.__version__} on {jax.devices()[0].platform}")
    print(f"random policy, {args.num_envs} envs x {args.num_steps} steps (jit(vmap(step)) in lax.scan)")
    print(f"  compile + first run : {compile_s:8.2f} s")
    print(f"  throughput          : {steps / seconds:12,.0f} env steps/s")
    print(f"  episodes finished   : {int(episodes):,}")
    chance = chance_return(env.unwrapped.num_classes, int(params.max_steps_in_episode),
                           float(params.correct_reward), float(params.wrong_reward))
    print(f"  mean episode return : {float(returns) / max(int(episodes), 1):+.3f}  "
          f"(expected for uniform random labels: {chance:+.3f}; perfect: +1.000)")
    print(f"  episodes classified : {int(correct) / max(int(episodes), 1):.1%}")

    import cv2

    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "observations.png"
    cv2.imwrite(str(path), observation_grid(np.asarray(obs[:16])))
    print(f"  observations        : {path}")


if __name__ == "__main__":
    main()
