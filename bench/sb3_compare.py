"""jaxnat PPO against Stable-Baselines3 PPO on one classification env, same settings, same steps.

Issue #3: "Side by side in the same run, Stable-Baselines3 PPO (PyTorch, CPU build) on the same
env through the Gymnasium adapter for the same number of steps: print the ratio."

- jaxnat: `jaxnat.agents.ppo`, `--seeds` seeds vmapped in one jitted program, and 1 seed alone,
  on JAX's default backend (the GPU where there is one). Compile time is reported apart.
- SB3: `stable_baselines3.PPO` on the CPU (`device="cpu"`, `torch.set_num_threads(os.cpu_count())`),
  one seed, on `jaxnat.compat.GymnasiumVectorEnv` through `SB3VecEnv` below. Its env runs on
  JAX's CPU backend too (`--sb3-env-device default` puts it on JAX's default device instead).
  SB3 cannot vmap seeds: `--seeds` seeds take `--seeds` times its wall time.

Both sides: the main job's settings (Makefile `MAIN_JOB`): 32 envs x 32 steps per update, 4
epochs of 8 minibatches of 128, Adam lr 1e-3 (eps 1e-5) annealed linearly to 0, clip 0.1,
entropy 0.01, gamma 0.99, GAE lambda 0.95, max grad norm 0.5, the paper's MNIST trunk (conv
10@5x5/2, 20@5x5, 10@5x5 VALID, ReLU, dense 512 ReLU, pixels / 255) with one categorical per
action factor and a value head on it, orthogonal init. Time-limit truncations bootstrap from the
final observation on both sides. The one deliberate difference: SB3's value loss is
`mse(returns, values)` with no 1/2 factor and no value clipping, so its `vf_coef` is 0.5 to give
the same value-loss weight as our `0.5 * max(unclipped, clipped)` with `vf_coef` 1.0 (SB3's
`clip_range_vf` clips differently from ours: it drops the unclipped term).

Both are scored on the test split: the greedy (deterministic) policy plays `--eval-episodes`
fresh episodes, one per env, to the end.

    python bench/sb3_compare.py                  # ~60k steps per seed; GPU host: jaxnat on the GPU
    python bench/sb3_compare.py --steps 20480    # a short run (2-core CPU)
    python bench/sb3_compare.py --check          # the VecEnv shim's contract, then one SB3 update
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import jax
import numpy as np

sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parent))
import common  # noqa: E402

try:
    import stable_baselines3
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
    from stable_baselines3.common.vec_env import VecEnv
except ImportError as err:  # pragma: no cover
    raise SystemExit(f"bench/sb3_compare.py needs Stable-Baselines3 and PyTorch: pip install 'jaxnat[sb3]' ({err})")

import jaxnat  # noqa: E402
from jaxnat.agents import ppo  # noqa: E402
from jaxnat.agents.rollout import make_evaluate  # noqa: E402
from jaxnat.compat import GymnasiumVectorEnv, make_gymnasium_vec  # noqa: E402

# The main job's settings (Makefile MAIN_JOB), shared by both sides.
NUM_ENVS, NUM_STEPS, EPOCHS, MINIBATCHES = 32, 32, 4, 8
LR, CLIP, ENT, GAMMA, LAMBDA, MAX_GRAD_NORM, ADAM_EPS = 1e-3, 0.1, 0.01, 0.99, 0.95, 0.5, 1e-5
VF_COEF = 1.0  # ours; SB3 gets VF_COEF / 2 (module docstring)


class SB3VecEnv(VecEnv):
    """A `GymnasiumVectorEnv` (next-step autoreset) as an SB3 `VecEnv` (same-step autoreset).

    When sub-env `i` ends at a step, SB3 wants that step to return the *next* episode's first
    observation, with the final one in `infos[i]["terminal_observation"]` and
    `infos[i]["TimeLimit.truncated"] = truncated and not terminated` (SB3 then adds
    `gamma * V(final observation)` to the reward of a truncated step, as jaxnat's PPO bootstraps
    truncations). The adapter instead returns the final observation and resets at the next step,
    ignoring that step's action. So after a step in which some envs ended, this shim restarts
    exactly those at once with the adapter's partial reset (`options={"reset_mask": ended}`):
    no wasted steps, and every step SB3 sees is a real env step.

    `step_seconds` accumulates the wall time spent in the adapter (env steps and resets).
    """

    def __init__(self, vec: GymnasiumVectorEnv):
        self.vec = vec
        self.step_seconds = 0.0
        self._actions = None
        super().__init__(vec.num_envs, vec.single_observation_space, vec.single_action_space)

    def reset(self):
        seed = self._seeds[0] if self._seeds and self._seeds[0] is not None else None
        self._reset_seeds()
        t0 = time.perf_counter()
        obs, _ = self.vec.reset(seed=seed)
        self.step_seconds += time.perf_counter() - t0
        return obs

    def step_async(self, actions):
        self._actions = actions

    def step_wait(self):
        t0 = time.perf_counter()
        obs, rewards, terminated, truncated, _ = self.vec.step(self._actions)
        dones = terminated | truncated
        infos = [{} for _ in range(self.num_envs)]
        if dones.any():
            for i in np.flatnonzero(dones):
                infos[i]["terminal_observation"] = obs[i]
                infos[i]["TimeLimit.truncated"] = bool(truncated[i] and not terminated[i])
            obs, _ = self.vec.reset(options={"reset_mask": dones})
        self.step_seconds += time.perf_counter() - t0
        return obs, rewards.astype(np.float32), dones, infos

    def close(self):
        self.vec.close()

    def get_attr(self, attr_name, indices=None):
        value = None if attr_name == "render_mode" else getattr(self.vec, attr_name)
        return [value] * len(self._get_indices(indices))

    def set_attr(self, attr_name, value, indices=None):
        raise NotImplementedError("SB3VecEnv's sub-envs share one jaxnat env and its params")

    def env_method(self, method_name, *method_args, indices=None, **method_kwargs):
        raise NotImplementedError("SB3VecEnv's sub-envs are not separate Python envs")

    def env_is_wrapped(self, wrapper_class, indices=None):
        return [False] * len(self._get_indices(indices))


class PaperMNISTTrunk(BaseFeaturesExtractor):
    """The paper's MNIST trunk as `jaxnat.agents.networks` builds it: conv 10@5x5/2, 20@5x5,
    10@5x5 (VALID, ReLU), dense 512 (ReLU). SB3 hands it NCHW floats already divided by 255
    (it transposes channels-last image observations with `VecTransposeImage`)."""

    def __init__(self, observation_space, features_dim: int = 512):
        super().__init__(observation_space, features_dim)
        channels, height, width = observation_space.shape
        if not channels < min(height, width):
            raise ValueError(f"expected channels-first observations, got shape {observation_space.shape}")
        nn = torch.nn
        self.cnn = nn.Sequential(
            nn.Conv2d(channels, 10, 5, stride=2), nn.ReLU(),
            nn.Conv2d(10, 20, 5), nn.ReLU(),
            nn.Conv2d(20, 10, 5), nn.ReLU(),
            nn.Flatten(),
        )
        with torch.no_grad():
            flat = self.cnn(torch.zeros(1, *observation_space.shape)).shape[1]
        self.linear = nn.Sequential(nn.Linear(flat, features_dim), nn.ReLU())

    def forward(self, observations):
        return self.linear(self.cnn(observations))


def make_sb3(venv: SB3VecEnv, total_steps: int, seed: int) -> PPO:
    """SB3 PPO with the main job's settings (module docstring)."""
    num_updates = total_steps // (NUM_ENVS * NUM_STEPS)
    return PPO(
        "CnnPolicy", venv,
        # SB3 sets the lr before update k (from 0) with progress_remaining = 1 - (k+1)/U; ours
        # is lr * (1 - k/U): shift by 1/U to match.
        learning_rate=lambda remaining: LR * min(1.0, remaining + 1.0 / num_updates),
        n_steps=NUM_STEPS, batch_size=NUM_ENVS * NUM_STEPS // MINIBATCHES, n_epochs=EPOCHS,
        gamma=GAMMA, gae_lambda=LAMBDA, clip_range=CLIP, ent_coef=ENT, vf_coef=VF_COEF / 2,
        max_grad_norm=MAX_GRAD_NORM,
        policy_kwargs=dict(features_extractor_class=PaperMNISTTrunk, net_arch=[],
                           optimizer_kwargs=dict(eps=ADAM_EPS)),
        device="cpu", seed=seed, verbose=0,
    )


def sb3_evaluate(model: PPO, env_id: str, episodes: int, seed: int) -> dict:
    """Greedy (deterministic) test-split score: `episodes` envs each play their first episode."""
    vec = make_gymnasium_vec(env_id, episodes, seed=seed, split="test")
    obs, _ = vec.reset()
    running = np.ones(episodes, bool)
    total, correct = np.zeros(episodes), np.zeros(episodes, bool)
    for _ in range(int(vec.params.max_steps_in_episode)):
        action, _ = model.predict(obs, deterministic=True)
        obs, reward, terminated, truncated, _ = vec.step(action)
        total += np.where(running, reward, 0.0)
        correct |= running & terminated
        running &= ~(terminated | truncated)
    return {"test_return": float(total.mean()), "test_accuracy": float(correct.mean())}


def run_sb3(env_id: str, steps: int, seed: int, episodes: int, env_device) -> dict:
    with jax.default_device(env_device):
        t0 = time.perf_counter()
        venv = SB3VecEnv(make_gymnasium_vec(env_id, NUM_ENVS, seed=seed))
        # Compile the adapter's reset, step and partial reset before the clock starts.
        venv.reset()
        venv.step(np.zeros((NUM_ENVS, *venv.action_space.shape), np.int64))
        venv.vec.reset(options={"reset_mask": np.ones(NUM_ENVS, bool)})
        model = make_sb3(venv, steps, seed)
        setup_s = time.perf_counter() - t0
        venv.step_seconds = 0.0
        t0 = time.perf_counter()
        model.learn(total_timesteps=steps)
        train_s = time.perf_counter() - t0
        scores = sb3_evaluate(model, env_id, episodes, seed + 1)
    return {"side": "SB3 PPO (torch CPU)", "seeds": 1, "env_steps_per_seed": int(model.num_timesteps),
            "setup_s": setup_s, "train_s": train_s, "env_s": venv.step_seconds,
            "steps_per_s": model.num_timesteps / train_s, "steps_per_s_per_seed": model.num_timesteps / train_s,
            **scores}


def run_jaxnat(env_id: str, steps: int, seeds: int, episodes: int) -> dict:
    env, params = jaxnat.make(env_id)
    test_env, test_params = jaxnat.make(env_id, split="test", autoreset=False)
    config = ppo.PPOConfig(total_timesteps=steps, num_envs=NUM_ENVS, num_steps=NUM_STEPS,
                           update_epochs=EPOCHS, num_minibatches=MINIBATCHES, anneal_lr=True, lr=LR,
                           clip_eps=CLIP, ent_coef=ENT, vf_coef=VF_COEF, gamma=GAMMA,
                           gae_lambda=LAMBDA, max_grad_norm=MAX_GRAD_NORM)
    learner = ppo.make_ppo(config, env, params)
    evaluate = make_evaluate(learner.network, test_env, test_params, episodes)
    keys = jax.random.split(jax.random.key(0), seeds)
    train, score = jax.jit(jax.vmap(learner.train)), jax.jit(jax.vmap(evaluate))
    t0 = time.perf_counter()
    train = train.lower(keys).compile()
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    runner, _ = jax.block_until_ready(train(keys))
    train_s = time.perf_counter() - t0
    scores = jax.device_get(score(learner.policy_of(runner)[0], keys))
    env_steps = learner.num_updates * NUM_ENVS * NUM_STEPS
    return {"side": f"jaxnat PPO ({jax.default_backend()})", "seeds": seeds, "env_steps_per_seed": env_steps,
            "setup_s": compile_s, "train_s": train_s, "env_s": None,
            "steps_per_s": seeds * env_steps / train_s, "steps_per_s_per_seed": env_steps / train_s,
            "test_return": float(np.mean(scores["greedy_return"])),
            "test_accuracy": float(np.mean(scores["greedy_terminated_fraction"]))}


def check(env_id: str, seed: int = 0, num_envs: int = NUM_ENVS, steps: int = 45) -> None:
    """The shim's contract on the real env, under uniformly random actions:

    - every step SB3 sees is a real env step: reward is +1 (right label, terminated) or -0.1;
      never the 0 of the adapter's reset step;
    - an episode ends by termination exactly when the reward is +1, by truncation exactly at
      the time limit otherwise; `TimeLimit.truncated` says which, and `terminal_observation`
      is the final observation (at least as much revealed as the step before);
    - the observation returned with `done` is a fresh episode (one window revealed), and the
      same env's previous observation only grows otherwise;
    then one SB3 PPO update runs on the shim."""
    env, params = jaxnat.make(env_id)
    channels = env.observation_space(params).shape[-1] - 2  # image channels; then mask, window
    window = int(params.window) ** 2 * 255
    limit = int(params.max_steps_in_episode)
    venv = SB3VecEnv(make_gymnasium_vec(env_id, num_envs, seed=seed))
    venv.seed(seed)
    rng = np.random.default_rng(seed)

    def revealed(obs):
        return obs[..., channels].astype(np.int64).sum(axis=(-2, -1))

    obs = venv.reset()
    assert obs.shape == (num_envs, *env.observation_space(params).shape) and obs.dtype == np.uint8
    assert (revealed(obs) == window).all(), "reset reveals one window"
    length = np.zeros(num_envs, int)
    seen = {"terminated": 0, "truncated": 0}
    for _ in range(steps):
        previous = revealed(obs)
        venv.step_async(rng.integers(0, env.action_space(params).nvec, size=(num_envs, 2)))
        obs, rewards, dones, infos = venv.step_wait()
        length += 1
        right = np.isclose(rewards, float(params.correct_reward))
        assert (right | np.isclose(rewards, float(params.wrong_reward))).all(), f"not a real step: {rewards}"
        np.testing.assert_array_equal(dones, right | (length == limit))
        for i in range(num_envs):
            if dones[i]:
                assert infos[i]["TimeLimit.truncated"] == (not right[i])
                assert revealed(infos[i]["terminal_observation"]) >= previous[i]
                assert revealed(obs[i]) == window, "the next episode starts at once"
                seen["truncated" if infos[i]["TimeLimit.truncated"] else "terminated"] += 1
            else:
                assert infos[i] == {} and revealed(obs[i]) >= previous[i]
        length[dones] = 0
    assert seen["terminated"] and seen["truncated"], f"the check saw too few episode ends: {seen}"
    model = make_sb3(venv, num_envs * NUM_STEPS, seed)
    model.learn(total_timesteps=num_envs * NUM_STEPS)
    print(f"check passed: {steps} steps x {num_envs} envs, episode ends {seen}; one SB3 PPO update ran "
          f"({model.num_timesteps} steps)")


def _print_row(row: dict) -> None:
    print(f"  {row['setup_s']:.1f} s compile/setup, {row['train_s']:.1f} s training: "
          f"{row['steps_per_s']:.3g} env steps/s; test return {row['test_return']:+.3f}, "
          f"accuracy {row['test_accuracy']:.1%}", flush=True)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env-id", default="Classify/Digits-v0")
    parser.add_argument("--steps", type=int, default=61_440, help="env steps per seed (rounded down to whole updates of 1024)")
    parser.add_argument("--seeds", type=int, default=5, help="jaxnat seeds vmapped (also run: 1 seed)")
    parser.add_argument("--eval-episodes", type=int, default=500)
    parser.add_argument("--sb3-env-device", choices=["cpu", "default"], default="cpu",
                        help="where JAX runs SB3's env (the adapter): the CPU (default) or JAX's default device")
    parser.add_argument("--check", action="store_true", help="check the SB3 VecEnv shim and exit")
    parser.add_argument("--no-record", action="store_true")
    args = parser.parse_args(argv)
    threads = os.cpu_count()
    torch.set_num_threads(threads)  # SB3 gets every core of the host
    if args.check:
        with jax.default_device(jax.devices("cpu")[0]):
            check(args.env_id)
        return

    info = {**common.machine(), "torch": torch.__version__, "stable_baselines3": stable_baselines3.__version__,
            "torch_threads": torch.get_num_threads()}
    load_start = os.getloadavg()[0]
    env_device = jax.devices("cpu")[0] if args.sb3_env_device == "cpu" else jax.devices()[0]
    rows = []
    for seeds in (args.seeds, 1):
        print(f"jaxnat PPO, {seeds} seed(s) vmapped, {args.steps:,} steps per seed ...", flush=True)
        rows.append(run_jaxnat(args.env_id, args.steps, seeds, args.eval_episodes))
        _print_row(rows[-1])
    print(f"SB3 PPO, 1 seed, {args.steps:,} steps, torch threads {torch.get_num_threads()} ...", flush=True)
    sb3 = run_sb3(args.env_id, args.steps, 0, args.eval_episodes, env_device)
    rows.append(sb3)
    _print_row(sb3)
    for row in rows:
        row["ratio_total"] = row["steps_per_s"] / sb3["steps_per_s"]
        row["ratio_per_seed"] = row["steps_per_s_per_seed"] / sb3["steps_per_s_per_seed"]
    table = common.markdown_table(rows, [
        ("side", "", "s"), ("seeds", "seeds", "d"), ("env_steps_per_seed", "env steps per seed", ","),
        ("setup_s", "compile / setup s", ".1f"), ("train_s", "train s", ".1f"),
        ("env_s", "of which env s", ".1f"), ("steps_per_s", "env steps/s (all seeds)", ".3g"),
        ("steps_per_s_per_seed", "env steps/s per seed", ".3g"),
        ("ratio_total", "x SB3 (total)", ".1f"), ("ratio_per_seed", "x SB3 (per seed)", ".1f"),
        ("test_return", "test return (greedy)", "+.3f"), ("test_accuracy", "test accuracy", ".1%"),
    ])
    vmapped, single = rows[0], rows[1]
    summary = {
        "env": args.env_id,
        "setup": f"PPO, {NUM_ENVS} envs x {NUM_STEPS} steps per update, {EPOCHS} epochs x {MINIBATCHES} "
                 f"minibatches, lr {LR} annealed, clip {CLIP}, ent {ENT}, vf {VF_COEF} (SB3 {VF_COEF / 2}: "
                 f"its value loss has no 1/2), paper MNIST trunk; test score: {args.eval_episodes} greedy episodes",
        "SB3": f"stable-baselines3 {stable_baselines3.__version__}, torch {torch.__version__}, device cpu, "
               f"torch.set_num_threads({threads}); its env (jaxnat adapter) on JAX {env_device.platform}",
        "ratio jaxnat/SB3 env steps/s": (
            f"{vmapped['ratio_total']:.1f}x total with {vmapped['seeds']} seeds vmapped "
            f"({vmapped['ratio_per_seed']:.1f}x per seed); {single['ratio_total']:.1f}x with 1 seed"),
        f"{args.seeds} SB3 seeds one after another": f"{args.seeds * sb3['train_s']:.0f} s "
            f"(= {args.seeds} x {sb3['train_s']:.1f} s) vs jaxnat {vmapped['train_s']:.1f} s "
            f"(+ {vmapped['setup_s']:.1f} s compile)",
        "host load average (1 min) at start / end": f"{load_start:.1f} / {os.getloadavg()[0]:.1f} "
            f"on {os.cpu_count()} cores (other processes share them)",
    }
    common.record("sb3_compare", info, table, summary, rows, save=not args.no_record)


if __name__ == "__main__":
    main()
