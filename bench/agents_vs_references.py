"""jaxnat's PPO, A2C and DQN against rejax's, side by side: same settings, same device, one run.

Issue #18: "jaxnat's PPO, A2C and DQN against rejax on gymnax CartPole-v1, Acrobot-v1 and two
MinAtar games [...]: the same hyperparameters on both sides, 5 seeds, one run, final return
with a 95% CI and wall time, both as ratios. Target: jaxnat's final return within the CI of
the reference or above on every task, at equal or better wall time."

- The reference is rejax 0.1.3 (`pip install 'jaxnat[bench]'`). Its settings per env are its
  own tuned configs, copied below (`REJAX_CONFIGS`: rejax v0.1.3's configs/gymnax/cartpole.yaml
  and acrobot.yaml; for MinAtar its benchmark/breakout_1m.yaml, also for SpaceInvaders, which
  has none), and mapped field by field onto jaxnat's configs (`jaxnat_config`). What one side
  cannot express is printed as a "differences" list above the table.
- rejax 0.1.3 has PPO, DQN, IQN, PQN, SAC and TD3, but no A2C: jaxnat's A2C runs alone with
  its own defaults (the classic synchronous A2C: RMSprop 7e-4, 16 envs x 5 steps, n-step
  returns, value coef 0.5, entropy 0.01), trunk and the env's gamma and step budget from
  rejax's PPO config; its row reads "no reference".
- Networks (`--rejax-network matched`, the default): jaxnat's networks on both sides: 64x64
  tanh MLPs for PPO; for DQN jaxnat's Q-network (`networks.Q_MLP`: 120x84 ReLU, CleanRL's and
  PureJaxRL's), rejax's plain `QNetwork` then taking those sizes instead of its configs'
  `DuelingQNetwork` with swish (jaxnat has no dueling head). `--rejax-network config` keeps rejax's configs' networks.
  MinAtar observations are [10, 10, C] float grids: rejax's MLP flattens them; jaxnat's default
  trunk for a 10x10 image is a ResNet-18, so jaxnat trains on a flattened view
  (`FlatObservation`, a `jaxnat.wrappers.Wrapper`) with its "mlp" trunk;
  `--minatar-trunk default` lets jaxnat pick its own trunk instead.
- DQN's target network: rejax moves it softly (polyak), every `target_update_freq` env
  steps; jaxnat the same way (`tau = 1 - polyak`, every `target_update_period` gradient steps:
  `target_update` converts). Exploration, warm-up and buffer are in env steps per seed on both
  sides.
- gymnax 1.0's `step` returns six values (terminated, truncated); rejax 0.1.3 unpacks five
  (gymnax 0.0.x's `done`), so rejax trains on `FiveValueStep(env)`, whose `done` is
  `terminated | truncated`: rejax treats time limits as terminal, jaxnat bootstraps them.
- Seeds: `--seeds` per side, vmapped in one jitted program per side
  (`jax.jit(jax.vmap(train)).lower(keys).compile()`, then `--repeats` calls, 3 by default).
  Wall times: training alone (the median call, compile excluded) and trace + compile +
  training (compile included). rejax's
  in-training evaluation is switched off (its `eval_callback` returns a constant and
  `eval_freq` is the whole run), so both sides take exactly the same env steps and time
  nothing but training.
- Final return: the same code (`evaluate`) plays `--eval-episodes` fresh episodes per seed with
  each side's final parameters, greedily (argmax of the policy's logits, of Q for DQN; where
  the config turns observation normalisation on, each side's PPO reads observations through
  its own final running moments, frozen), on the plain gymnax env; seed i of both sides plays
  the same episodes (the same keys). Mean over seeds with a 95% t-interval over the per-seed
  means. A uniformly random policy is scored by the same code ("random"), for the ratio of returns
  above random: `(jaxnat - random) / (rejax - random)` (the plain ratio misleads for Acrobot's
  negative returns).

    python bench/agents_vs_references.py          # everything; MinAtar DQN (1M steps of one
                                                  # env, sequential) takes most of the time
    python bench/agents_vs_references.py --envs CartPole-v1 --algos ppo --budget-scale 0.02
    python bench/agents_vs_references.py --envs Breakout-MinAtar --algos dqn --seeds 5

Continuous actions (`--envs brax/halfcheetah --algos ppo`; not in the default `--envs`, brax
being one more optional install: `pip install 'jaxnat[bench]'` brings it): jaxnat's Gaussian PPO
against rejax's on Brax's HalfCheetah, with rejax v0.1.3's tuned configs/brax/halfcheetah.yaml
(32 envs x 32 steps, 2 epochs x 2 minibatches, lr 1.72e-3 constant, GAE lambda 0.8, grad
clip 5, observation normalisation on; 5,242,880 steps per seed). That is 163,840 sequential
steps of brax's generalized HalfCheetah, whose step compiles to some 17,000 XLA ops (brax's
positional Hopper's: 2,300), latency-bound at 32 envs x 5 seeds: on one GPU `--budget-scale`
well below 1 is the practical setting.

- The env is rejax's own, built by rejax: `rejax.compat.create("brax/halfcheetah",
  auto_reset=False)`, i.e. brax's `envs.create` (brax's generalized backend, the env's
  default; a 1000-step `EpisodeWrapper` that flags time limits in `info["truncation"]`) inside
  rejax's `Brax2GymnaxEnv`. rejax wrote that adapter for gymnax 0.0.x, whose `step` reset the
  env wherever `step_env` said done; gymnax 1.0's `step` also reads the time limit from
  `state.time`, which a brax `State` has not, so rejax 0.1.3 cannot step a brax env under
  gymnax 1.0 at all. Both sides train on `BraxSixValueStep(env)`, which steps it as gymnax
  0.0.x did (`step_env`, then a fresh `reset_env` where done) and splits `done` into
  terminated and truncated with brax's truncation flag (rejax again through `FiveValueStep`,
  so it sees exactly what gymnax 0.0.x gave it). brax's own `AutoResetWrapper` (`create`'s
  default, left out by `auto_reset=False`) would put the episode's first observation where
  the final one belongs and be overridden by that fresh reset anyway: without it rejax sees
  the same steps, and jaxnat bootstraps a time limit from the true final observation.
  HalfCheetah never terminates: every episode ends at the 1000-step limit, so the two sides'
  time-limit handling (the list below) differs on every episode end.
- Both policies are diagonal Gaussians with a state-independent log-std starting at 0 over
  64x64 tanh actor and critic MLPs; both clip the sampled action to the Box's [-1, 1] at the
  env boundary and train on the log-prob of the unclipped sample; neither squashes.
- Final return: the same `evaluate`, each side's deterministic policy (the Gaussian's mean,
  clipped to [-1, 1]; observations through each side's running normalisation), 1000-step
  episodes; "random" draws uniformly from the Box. (rejax's own `eval_callback` samples
  instead; it is switched off here as on every row.)
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.metadata
import math
import pathlib
import subprocess
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import common  # noqa: E402


def _plotting_stand_ins() -> list[str]:
    """gymnax 1.0.1 imports matplotlib and seaborn when it is imported, only to render envs
    (nothing here renders). Where they are not installed (a GPU host given only rejax's and
    gymnax's wheels: matplotlib, seaborn and pandas alone are ~35 MB), empty stand-in modules
    let gymnax import. Returns the names stood in for."""
    import importlib
    import types

    stood_in = []
    for name, submodules in (("matplotlib", ("pyplot", "colors")), ("seaborn", ())):
        try:
            importlib.import_module(name)
            for sub in submodules:
                importlib.import_module(f"{name}.{sub}")
        except ImportError:
            module = types.ModuleType(name, f"stand-in for {name} (bench/agents_vs_references.py)")
            sys.modules[name] = module
            for sub in submodules:
                setattr(module, sub, types.ModuleType(f"{name}.{sub}"))
                sys.modules[f"{name}.{sub}"] = getattr(module, sub)
            stood_in.append(name)
    return stood_in


STAND_INS = _plotting_stand_ins()
try:
    import gymnax
    import rejax
except ImportError as err:  # pragma: no cover
    raise SystemExit(f"bench/agents_vs_references.py needs rejax and gymnax: pip install 'jaxnat[bench]' ({err})")

import flax.linen as nn  # noqa: E402
import jaxnat  # noqa: E402
from jaxnat.agents import A2CConfig, DQNConfig, PPOConfig, distributions, make_a2c, make_dqn, make_ppo  # noqa: E402
from jaxnat.agents.dqn import epsilon  # noqa: E402
from jaxnat.agents.normalize import normalize  # noqa: E402
from jaxnat.agents.networks import Q_MLP  # noqa: E402
from jaxnat.agents.networks import is_box  # noqa: E402
from jaxnat.agents.rollout import env_action  # noqa: E402
from jaxnat.wrappers import Wrapper  # noqa: E402

ENVS = ("CartPole-v1", "Acrobot-v1", "Breakout-MinAtar", "SpaceInvaders-MinAtar")
# Continuous rows (selectable with --envs, not in the default set): rejax's brax envs.
BRAX_ENVS = ("brax/halfcheetah",)
ALGOS = ("ppo", "a2c", "dqn")
REJAX_VERSION = "0.1.3"

# rejax v0.1.3's own settings (github.com/keraJLi/rejax at tag v0.1.3), as `Algo.create` takes
# them. eval_freq is left out: this benchmark switches rejax's in-training evaluation off.
_CLASSIC_PPO = dict(agent_kwargs={"activation": "tanh"}, num_envs=5, num_steps=100, num_epochs=5,
                    num_minibatches=5, learning_rate=0.00075, max_grad_norm=0.5, total_timesteps=100_000,
                    gamma=0.99, gae_lambda=0.95, clip_eps=0.2, ent_coef=0.01, vf_coef=0.5)
REJAX_CONFIGS = {
    # configs/gymnax/cartpole.yaml
    ("CartPole-v1", "ppo"): _CLASSIC_PPO,
    ("CartPole-v1", "dqn"): dict(
        agent="DuelingQNetwork", agent_kwargs={"activation": "swish"}, num_envs=10, buffer_size=50_000,
        fill_buffer=5_000, batch_size=100, max_grad_norm=10, learning_rate=0.001, num_epochs=5,
        total_timesteps=100_000, polyak=0.98, eps_start=1.0, eps_end=0.05, exploration_fraction=0.5,
        gamma=0.99, ddqn=True, normalize_observations=False),
    # configs/gymnax/acrobot.yaml
    ("Acrobot-v1", "ppo"): {**_CLASSIC_PPO, "normalize_observations": True},
    ("Acrobot-v1", "dqn"): dict(
        agent="DuelingQNetwork", agent_kwargs={"activation": "swish"}, num_envs=10, buffer_size=10_000,
        fill_buffer=1_000, batch_size=100, max_grad_norm=10, learning_rate=0.001, num_epochs=5,
        total_timesteps=100_000, target_update_freq=200, eps_start=1.0, eps_end=0.05,
        exploration_fraction=0.5, gamma=0.99, ddqn=True, normalize_observations=False),
    # benchmark/breakout_1m.yaml. Its DQN names an older rejax: `agent: ConvQNetwork` (0.1.3 has
    # QNetwork and DuelingQNetwork, both MLPs: QNetwork here) and `gradient_steps: 1` (0.1.3:
    # num_epochs); its `target_update_freq: 1000` meant hard copies, which 0.1.3 does with
    # polyak 0 (its default 0.99 would move the target 1% per 1000 steps).
    ("MinAtar", "ppo"): dict(
        agent_kwargs={"activation": "tanh"}, num_envs=32, num_steps=32, num_epochs=4, num_minibatches=4,
        learning_rate=0.00025674088686342003, max_grad_norm=1, total_timesteps=1_000_000, gamma=0.995,
        gae_lambda=0.95, clip_eps=0.2, ent_coef=0.01, vf_coef=0.5),
    ("MinAtar", "dqn"): dict(
        agent="QNetwork", agent_kwargs={"activation": "tanh"}, num_envs=1, buffer_size=100_000,
        fill_buffer=20_000, batch_size=100, max_grad_norm=10, learning_rate=0.0005, num_epochs=1,
        total_timesteps=1_000_000, target_update_freq=1000, polyak=0.0, eps_start=1.0, eps_end=0.05,
        exploration_fraction=0.5, gamma=1.0, ddqn=False),
    # configs/brax/halfcheetah.yaml ("tuned")
    ("brax/halfcheetah", "ppo"): dict(
        agent_kwargs={"activation": "tanh"}, num_envs=32, num_steps=32, num_epochs=2, num_minibatches=2,
        learning_rate=0.0017203361125365498, max_grad_norm=5, total_timesteps=5_242_880, gamma=0.99,
        gae_lambda=0.8, clip_eps=0.2, ent_coef=0.01, vf_coef=0.5, normalize_observations=True),
}


def config_key(env_id: str, algo: str) -> tuple[str, str]:
    return ("MinAtar" if env_id.endswith("-MinAtar") else env_id, algo)


# ---------------------------------------------------------------------------------------------
# Env adapters


class FiveValueStep:
    """A gymnax 1.0 env with gymnax 0.0.x's five-value `step` (`done = terminated | truncated`),
    the form rejax 0.1.3 unpacks. Everything else is the wrapped env's (but dunders: rejax
    deep-copies its config, and the wrapped env's `__deepcopy__` would return that env alone)."""

    def __init__(self, env):
        self._env = env

    def __getattr__(self, name):
        if name == "_env" or name.startswith("__"):
            raise AttributeError(name)
        return getattr(self._env, name)

    def step(self, key, state, action, params=None):
        obs, state, reward, terminated, truncated, info = self._env.step(key, state, action, params)
        return obs, state, reward, terminated | truncated, info

    def reset(self, key, params=None):
        return self._env.reset(key, params)


class BraxSixValueStep:
    """rejax's brax env (`rejax.compat.create("brax/<name>", auto_reset=False)`: brax's
    `envs.create` in rejax's `Brax2GymnaxEnv`) with gymnax 1.0's six-value `step`, stepped as
    gymnax 0.0.x's `Environment.step` stepped it: `step_env`, then where the episode ended a
    fresh `reset_env` with the other half of the key. `done` splits into `truncated` (brax's
    `EpisodeWrapper` time limit, `info["truncation"]`) and `terminated` (the rest); `info`
    holds the final observation (the module docstring says why gymnax 1.0 cannot step the env
    itself, and why brax's auto-reset is left out)."""

    def __init__(self, env):
        self.env = env
        self.default_params = env.default_params

    def __deepcopy__(self, memo):  # rejax deep-copies its config; a brax env cannot be deep-copied
        return self

    def action_space(self, params=None):
        return self.env.action_space(params)

    def observation_space(self, params=None):
        return self.env.observation_space(params)

    def reset(self, key, params=None):
        return self.env.reset_env(key, params)

    def step(self, key, state, action, params=None):
        key_step, key_reset = jax.random.split(key)
        obs_step, state_step, reward, done, info = self.env.step_env(key_step, state, action, params)
        truncated = done & (info["truncation"] > 0)
        obs_reset, state_reset = self.env.reset_env(key_reset, params)
        obs, state = jax.tree.map(lambda fresh, stepped: jnp.where(done, fresh, stepped),
                                  (obs_reset, state_reset), (obs_step, state_step))
        return obs, state, reward, done & ~truncated, truncated, {"final_observation": obs_step}


def is_brax(env_id: str) -> bool:
    return env_id.startswith("brax/")


def make_env(env_id: str):
    """`(env, env_params)` with gymnax 1.0's six-value `step`: gymnax's env, or rejax's brax env
    through `BraxSixValueStep`."""
    if not is_brax(env_id):
        return gymnax.make(env_id)
    try:
        from rejax.compat import create
        env, env_params = create(env_id, auto_reset=False)
    except ImportError as err:  # pragma: no cover
        raise SystemExit(f"{env_id} needs brax: pip install 'jaxnat[bench]' ({err})")
    return BraxSixValueStep(env), env_params


class FlatObservation(Wrapper):
    """Observations (and the final observation in `info`) flattened to vectors, for jaxnat's
    "mlp" trunk on MinAtar's [10, 10, C] grids, as rejax's MLP flattens them."""

    def observation_space(self, params):
        space = self._env.observation_space(params)
        return gymnax.environments.spaces.Box(np.min(space.low), np.max(space.high),
                                              (math.prod(space.shape),), space.dtype)

    def reset(self, key, params=None):
        obs, state = self._env.reset(key, params)
        return obs.reshape(-1), state

    def step(self, key, state, action, params=None):
        obs, state, reward, terminated, truncated, info = self._env.step(key, state, action, params)
        if "final_observation" in info:
            info = {**info, "final_observation": info["final_observation"].reshape(-1)}
        return obs.reshape(-1), state, reward, terminated, truncated, info


# ---------------------------------------------------------------------------------------------
# Settings


def rejax_settings(env_id: str, algo: str, scale: float, network: str) -> tuple[dict, list[str]]:
    """rejax's config for this (env, algo), with `total_timesteps` scaled by `scale` and rounded
    down to whole iterations (at least one), and (`network="matched"`) jaxnat's networks: 64x64
    tanh for PPO, DQN's Q-network (`networks.Q_MLP`, 120x84 ReLU) for DQN.
    Returns (config, notes on what was changed from rejax's file)."""
    config = {k: (dict(v) if isinstance(v, dict) else v) for k, v in REJAX_CONFIGS[config_key(env_id, algo)].items()}
    notes = []
    if network == "matched" and algo == "dqn":  # jaxnat's Q-network on vector observations
        sizes, activation = Q_MLP
        if config["agent_kwargs"].get("activation") != activation:
            notes.append(f"rejax activation {config['agent_kwargs']['activation']} -> {activation} "
                         "(matched networks: jaxnat's Q-network)")
        config["agent_kwargs"].update(activation=activation, hidden_layer_sizes=tuple(sizes))
        if config.get("agent", "QNetwork") != "QNetwork":
            notes.append(f"rejax {config['agent']} -> QNetwork (jaxnat has no dueling head)")
            config["agent"] = "QNetwork"
    elif network == "matched":
        if config["agent_kwargs"].get("activation") != "tanh":
            notes.append(f"rejax activation {config['agent_kwargs']['activation']} -> tanh (matched networks)")
            config["agent_kwargs"]["activation"] = "tanh"
        if algo == "ppo":
            config["agent_kwargs"]["hidden_layer_sizes"] = (64, 64)
    else:
        if config["agent_kwargs"].get("activation", "swish") != "tanh":
            notes.append(f"network: rejax {config['agent_kwargs'].get('activation', 'swish')}, jaxnat tanh")
        if algo == "dqn" and config.get("agent", "QNetwork") != "QNetwork":
            notes.append(f"network: rejax {config['agent']}, jaxnat has no dueling head")
    per_iteration = config["num_envs"] * config.get("num_steps", 1)
    iterations = max(1, int(config["total_timesteps"] * scale) // per_iteration)
    config["total_timesteps"] = iterations * per_iteration
    if algo == "dqn" and scale < 1:  # short runs still learn: scale the warm-up with the budget
        config["fill_buffer"] = max(config["batch_size"], int(config["fill_buffer"] * scale))
    return config, notes


def _fields(cls) -> set[str]:
    return {f.name for f in dataclasses.fields(cls)}


def _apply(cls, values: dict, differences: list[str]):
    """`cls(**values)` for the fields `cls` has; the others go to `differences`."""
    names = _fields(cls)
    for name in sorted(set(values) - names):
        differences.append(f"jaxnat's {cls.__name__} has no `{name}` (wanted {values[name]!r})")
    return cls(**{k: v for k, v in values.items() if k in names})


def target_update(config: dict) -> tuple[int, float]:
    """rejax DQN's target update as jaxnat's `(target_update_period, tau)`.

    rejax moves the target `target <- polyak * target + (1 - polyak) * online` each time its
    global step (env steps of all envs) crosses a multiple of `target_update_freq`, i.e. every
    G = num_epochs * max(1, target_update_freq / num_envs) gradient steps: jaxnat's period G
    with `tau = 1 - polyak` (polyak 0, rejax's hard copies: tau 1, jaxnat's copies)."""
    polyak = config.get("polyak", 0.99)  # rejax's default
    every = config.get("num_epochs", 1) * max(1.0, config.get("target_update_freq", 1) / config["num_envs"])
    return max(1, round(every)), 1.0 - polyak


def jaxnat_config(env_id: str, algo: str, rejax_config: dict, trunk: str | None) -> tuple[object, list[str]]:
    """jaxnat's config for this (env, algo) from rejax's (`algo="a2c"`: from rejax's PPO config,
    see the module docstring). Returns (config, differences that cannot be expressed)."""
    c = rejax_config
    differences: list[str] = []
    if algo == "ppo":
        config = _apply(PPOConfig, dict(
            total_timesteps=c["total_timesteps"], num_envs=c["num_envs"], num_steps=c["num_steps"],
            update_epochs=c["num_epochs"], num_minibatches=c["num_minibatches"], anneal_lr=False,
            trunk=trunk, lr=c["learning_rate"], gamma=c["gamma"], gae_lambda=c["gae_lambda"],
            clip_eps=c["clip_eps"], vf_coef=c["vf_coef"], ent_coef=c["ent_coef"], max_grad_norm=c["max_grad_norm"],
            normalize_observations=bool(c.get("normalize_observations", False)), normalize_rewards=False,
        ), differences)
        differences += [
            f"gradient clipping: rejax clips each gradient element to +-{c['max_grad_norm']} "
            f"(optax.clip), jaxnat the global norm to {c['max_grad_norm']}",
            "Adam eps: rejax 1e-8, jaxnat 1e-5",
            "optimizers: rejax's actor and critic each have their own Adam (vf_coef then only scales "
            "the critic's gradient); jaxnat's separate actor and critic MLPs share one",
        ]
        if c.get("normalize_observations"):
            differences.append("observation normalisation: rejax's is not clipped and its first step reads the "
                               "raw first observations, jaxnat's is clipped to +-10 (baselines' VecNormalize)")
    elif algo == "a2c":
        config = _apply(A2CConfig, dict(total_timesteps=c["total_timesteps"], trunk=trunk, gamma=c["gamma"],
                                        normalize_observations=False, normalize_rewards=False), differences)
        config = config.replace(total_timesteps=max(1, c["total_timesteps"] // (config.num_envs * config.num_steps))
                                * config.num_envs * config.num_steps)
        differences = ["no reference: rejax 0.1.3 has no A2C; jaxnat's A2C defaults, gamma and steps "
                       "from rejax's PPO config"]
    else:
        num_envs = c["num_envs"]
        # rejax's first gradient step: the first iteration whose global step before it exceeds
        # fill_buffer; jaxnat learns in updates whose env steps after them reach learning_starts.
        learning_starts = math.ceil((c["fill_buffer"] + 1) / num_envs) * num_envs + num_envs
        values = dict(
            total_timesteps=c["total_timesteps"], num_envs=num_envs, num_steps=1, gradient_steps=c["num_epochs"],
            batch_size=c["batch_size"], buffer_size=c["buffer_size"], optimizer="adam", adam_eps=1e-8,
            double_dqn=bool(c.get("ddqn", True)), trunk=trunk, lr=c["learning_rate"], gamma=c["gamma"],
            eps_start=float(c["eps_start"]), eps_end=float(c["eps_end"]),
            exploration_steps=int(c["exploration_fraction"] * c["total_timesteps"]),
            learning_starts=learning_starts,
        )
        values["target_update_period"], values["tau"] = target_update(c)
        values["loss"] = "mse"
        differences.append(f"gradient clipping: rejax clips each element to +-{c['max_grad_norm']}, jaxnat none")
        config = _apply(DQNConfig, values, differences)
        differences.append("parameters: jaxnat's count includes its network's value head, which DQN never "
                           "trains or reads (one dense unit on the last hidden layer)")
        if config.tau < 1:
            differences.append(
                f"target network: soft updates on both sides (rejax polyak {1 - config.tau:.2g} every "
                f"{c.get('target_update_freq', 1)} env steps, jaxnat tau {config.tau:.2g} every "
                f"{config.target_update_period} gradient steps, counted from its first gradient step)")
        floor = float(jax.device_get(epsilon(config, learning_starts)))
        differences.append("before learning starts rejax acts uniformly at random, jaxnat epsilon-greedily "
                           f"(epsilon >= {floor:.2f})")
    if algo != "a2c":
        differences.append("time limits: rejax treats them as terminal (gymnax 0.0.x `done`), "
                           "jaxnat bootstraps from the final observation"
                           + (" (HalfCheetah never terminates: every episode ends at its 1000-step limit)"
                              if env_id == "brax/halfcheetah" else ""))
        differences.append("initialisation: rejax flax's default (lecun normal), jaxnat orthogonal"
                           + (" (the Gaussian's mean head: scale 0.01, so jaxnat's first actions are near 0, "
                              "rejax's are not)" if is_brax(env_id) else ""))
    return config, differences


# ---------------------------------------------------------------------------------------------
# Training and evaluation


def evaluate(policy, env, env_params, key, episodes: int):
    """Mean undiscounted return of `episodes` fresh episodes of a gymnax 1.0 env (each env plays
    its first episode to the end); `policy(obs [E, ...], key) -> actions [E]` (or `[E, D]` for a
    Box, clipped to its bounds here, as both sides clip them at the env boundary in training)."""
    space = env.action_space(env_params)
    if is_box(space):
        policy = lambda obs, key, act=policy: jnp.clip(act(obs, key), space.low, space.high)  # noqa: E731
    reset = jax.vmap(env.reset, in_axes=(0, None))
    step = jax.vmap(env.step, in_axes=(0, 0, 0, None))
    key_reset, key_run = jax.random.split(key)
    obs, state = reset(jax.random.split(key_reset, episodes), env_params)

    def body(carry, key):
        obs, state, running, total = carry
        key_act, key_env = jax.random.split(key)
        action = policy(obs, key_act)
        obs, state, reward, terminated, truncated, _ = step(jax.random.split(key_env, episodes), state, action,
                                                            env_params)
        total = total + jnp.where(running, reward, 0.0)
        return (obs, state, running & ~(terminated | truncated), total), None

    carry = (obs, state, jnp.ones(episodes, bool), jnp.zeros(episodes))
    (_, _, _, total), _ = jax.lax.scan(body, carry, jax.random.split(key_run, int(env_params.max_steps_in_episode)))
    return total.mean()


# Timed calls of each compiled training program (`--repeats`); the median is reported, since a
# single call of a few seconds moves by several percent from run to run.
REPEATS = 3


def timed_train(train, keys):
    """(output, compile seconds, training seconds) of `jax.jit(jax.vmap(train))(keys)`: the
    median over `REPEATS` calls of the same compiled program (the same keys, so the same output)."""
    t0 = time.perf_counter()
    compiled = jax.jit(jax.vmap(train)).lower(keys).compile()
    compile_s = time.perf_counter() - t0
    times = []
    for _ in range(REPEATS):
        t0 = time.perf_counter()
        out = jax.block_until_ready(compiled(keys))
        times.append(time.perf_counter() - t0)
    return out, compile_s, float(np.median(times))


def count_params(tree) -> int:
    """Parameters of one seed in a seed-stacked pytree."""
    return int(sum(np.prod(x.shape[1:]) for x in jax.tree.leaves(tree)))


def scores(policy_of, params, env, env_params, keys, episodes: int) -> np.ndarray:
    """Per-seed greedy returns: `policy_of(params of one seed) -> policy`."""
    run = jax.jit(jax.vmap(lambda p, k: evaluate(policy_of(p), env, env_params, k, episodes)))
    return np.asarray(jax.device_get(run(params, keys)), np.float64)


def run_jaxnat(env_id, algo, config, seeds, episodes):
    env, env_params = make_env(env_id)
    flat = config.trunk == "mlp" and len(env.observation_space(env_params).shape) > 1
    train_env = FlatObservation(env) if flat else env
    make = {"ppo": make_ppo, "a2c": make_a2c, "dqn": make_dqn}[algo]
    learner = make(config, train_env, env_params)
    keys = jax.random.split(jax.random.key(0), seeds)
    (runner, _), compile_s, train_s = timed_train(learner.train, keys)
    network = learner.network
    action_space = env.action_space(env_params)

    def policy_of(state):
        params, normalizer = state

        def policy(obs, key):
            if flat:
                obs = obs.reshape(obs.shape[0], -1)
            logits, _ = network.apply(params, normalize(normalizer, obs))
            return env_action(distributions.mode(logits), action_space)
        return policy

    state = learner.policy_of(runner)
    returns = scores(policy_of, state, env, env_params, jax.random.split(jax.random.key(1), seeds), episodes)
    trunk = getattr(network, "trunk", None) or config.trunk or "default"
    trunk = f"{trunk} on flattened observations" if flat else trunk
    return {"returns": returns, "compile_s": compile_s, "train_s": train_s,
            "params": count_params(state[0]), "network": trunk}


class SizedDQN(rejax.DQN):
    """rejax 0.1.3's DQN, its Q-network's hidden sizes taken from `agent_kwargs`
    ("hidden_layer_sizes"; rejax's own `create_agent` fixes them at 64x64 and reads only the
    activation there): the algorithm is rejax's, the network can match jaxnat's."""

    @classmethod
    def create_agent(cls, config, env, env_params):
        from rejax.networks import DiscreteQNetwork, DuelingQNetwork, EpsilonGreedyPolicy

        network = {"QNetwork": DiscreteQNetwork, "DuelingQNetwork": DuelingQNetwork}[config.pop("agent", "QNetwork")]
        kwargs = dict(config.pop("agent_kwargs", {}))
        kwargs["activation"] = getattr(nn, kwargs.pop("activation", "swish"))
        kwargs["hidden_layer_sizes"] = tuple(kwargs.get("hidden_layer_sizes", (64, 64)))
        return {"agent": EpsilonGreedyPolicy(network)(action_dim=env.action_space(env_params).n, **kwargs)}


def run_rejax(env_id, algo, config, seeds, episodes):
    env, env_params = make_env(env_id)
    cls = {"ppo": rejax.PPO, "dqn": SizedDQN}[algo]
    config = {**config, "agent_kwargs": dict(config["agent_kwargs"])}
    algorithm = cls.create(env=FiveValueStep(env), env_params=env_params, eval_freq=config["total_timesteps"],
                           skip_initial_evaluation=True, **config)
    algorithm = algorithm.replace(eval_callback=lambda algo, ts, rng: jnp.zeros(()))
    keys = jax.random.split(jax.random.key(0), seeds)
    (ts, _), compile_s, train_s = timed_train(algorithm.train, keys)

    if algo == "ppo":
        def policy_of(ts):
            def policy(obs, key):
                if algorithm.normalize_observations:
                    obs = algorithm.normalize_obs(ts.obs_rms_state, obs)
                if not algorithm.discrete:  # GaussianPolicy: the mean, unclipped (`evaluate` clips)
                    return algorithm.actor.apply(ts.actor_ts.params, obs,
                                                 method=lambda m, o: m.action_mean(m.features(o)))
                logits = algorithm.actor.apply(ts.actor_ts.params, obs,
                                               method=lambda m, o: m.action_logits(m.features(o)))
                return jnp.argmax(logits, axis=-1)
            return policy
        params = (ts.actor_ts.params, ts.critic_ts.params)
    else:
        def policy_of(ts):
            def policy(obs, key):
                if algorithm.normalize_observations:
                    obs = algorithm.normalize_obs(ts.obs_rms_state, obs)
                return jnp.argmax(algorithm.agent.apply(ts.q_ts.params, obs), axis=-1)
            return policy
        params = ts.q_ts.params
    returns = scores(policy_of, ts, env, env_params, jax.random.split(jax.random.key(1), seeds), episodes)
    return {"returns": returns, "compile_s": compile_s, "train_s": train_s, "params": count_params(params)}


def random_return(env_id, seeds, episodes) -> float:
    env, env_params = make_env(env_id)
    space = env.action_space(env_params)
    if is_box(space):
        def policy(obs, key):
            return jax.random.uniform(key, (obs.shape[0], *space.shape), minval=space.low, maxval=space.high)
    else:
        def policy(obs, key):
            return jax.random.randint(key, obs.shape[:1], 0, space.n)
    run = jax.jit(jax.vmap(lambda k: evaluate(policy, env, env_params, k, episodes)))
    return float(np.mean(jax.device_get(run(jax.random.split(jax.random.key(2), seeds)))))


def versions() -> dict:
    out = {}
    for name in ("flax", "optax", "gymnax", "rejax", "chex", "distrax", "scipy", "brax", "mujoco"):
        try:
            out[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            out[name] = None
    root = pathlib.Path(jaxnat.__file__).resolve().parent.parent
    try:
        commit = subprocess.run(["git", "-C", str(root), "rev-parse", "--short=12", "HEAD"], capture_output=True,
                                text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--", "jaxnat"],
                               capture_output=True, text=True, check=True).stdout.strip()
        out["jaxnat_commit"] = commit + ("+dirty" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        out["jaxnat_commit"] = "unknown (no git)"
    return out


def _fmt(mean, half):
    if mean is None:
        return "no reference"
    return f"{mean:.1f} ± {half:.1f}" if not math.isnan(half) else f"{mean:.1f}"


def main(argv=None):
    global REPEATS
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", nargs="+", default=list(ENVS),
                        help=f"gymnax ids (default: {' '.join(ENVS)}), or {' '.join(BRAX_ENVS)} (ppo only)")
    parser.add_argument("--algos", nargs="+", default=list(ALGOS), choices=ALGOS)
    parser.add_argument("--seeds", type=int, default=5, help="seeds per side, vmapped")
    parser.add_argument("--budget-scale", type=float, default=1.0,
                        help="multiplies every total_timesteps (and, below 1, DQN's learning start)")
    parser.add_argument("--eval-episodes", type=int, default=100, help="greedy episodes per seed")
    parser.add_argument("--rejax-network", choices=("matched", "config"), default="matched",
                        help="matched: 64x64 tanh MLPs on both sides; config: rejax's configs' networks")
    parser.add_argument("--minatar-trunk", choices=("mlp", "default"), default="mlp",
                        help="jaxnat on MinAtar: mlp on flattened observations, or jaxnat's own pick")
    parser.add_argument("--repeats", type=int, default=REPEATS,
                        help="timed calls of each compiled training program; the median is reported")
    parser.add_argument("--out", type=pathlib.Path, default=common.RESULTS, help="results directory")
    parser.add_argument("--no-record", action="store_true")
    args = parser.parse_args(argv)
    REPEATS = max(1, args.repeats)
    unknown = sorted(set(args.envs) - set(gymnax.registered_envs) - set(BRAX_ENVS))
    if unknown:
        raise SystemExit(f"not gymnax envs, nor {' '.join(BRAX_ENVS)}: {unknown}")
    brax_envs = [env_id for env_id in args.envs if is_brax(env_id)]

    info = common.machine()
    info.update(versions())
    info["plotting_stand_ins"] = STAND_INS
    print(f"{info['backend']}: {info['device']} | jax {info['jax']} flax {info['flax']} optax {info['optax']} "
          f"gymnax {info['gymnax']} rejax {info['rejax']} | jaxnat {info['jaxnat_commit']}", flush=True)
    if STAND_INS:
        print(f"note: {', '.join(STAND_INS)} not installed: empty stand-ins let gymnax import", flush=True)
    if info["rejax"] != REJAX_VERSION:
        print(f"warning: the settings below are rejax {REJAX_VERSION}'s; this is rejax {info['rejax']}", flush=True)

    rows, notes = [], []
    for env_id in args.envs:
        minatar = env_id.endswith("-MinAtar")
        trunk = None if (minatar and args.minatar_trunk == "default") else "mlp"
        algos = args.algos
        if is_brax(env_id):  # rejax's brax configs tune PPO; jaxnat's DQN is discrete, its A2C has no reference
            algos = [algo for algo in args.algos if algo == "ppo"]
            if len(algos) < len(args.algos):
                print(f"{env_id}: ppo only (skipping {' '.join(a for a in args.algos if a != 'ppo')})", flush=True)
            if not algos:
                continue
        random_mean = random_return(env_id, args.seeds, args.eval_episodes)
        for algo in algos:
            reference = algo != "a2c"
            rejax_config, changed = rejax_settings(env_id, "ppo" if algo == "a2c" else algo, args.budget_scale,
                                                   args.rejax_network)
            config, differences = jaxnat_config(env_id, algo, rejax_config, trunk)
            label = f"{env_id} {algo}"
            print(f"{label}: {config.total_timesteps:,} steps per seed, {args.seeds} seeds", flush=True)
            ours = run_jaxnat(env_id, algo, config, args.seeds, args.eval_episodes)
            print(f"  jaxnat: return {ours['returns'].mean():.1f}, train {ours['train_s']:.1f} s "
                  f"(+ compile {ours['compile_s']:.1f} s)", flush=True)
            theirs = run_rejax(env_id, algo, rejax_config, args.seeds, args.eval_episodes) if reference else None
            if theirs:
                print(f"  rejax:  return {theirs['returns'].mean():.1f}, train {theirs['train_s']:.1f} s "
                      f"(+ compile {theirs['compile_s']:.1f} s)", flush=True)
            j_mean, j_half = common.mean_ci(ours["returns"])
            r_mean, r_half = common.mean_ci(theirs["returns"]) if theirs else (None, None)
            row = {
                "env": env_id, "algo": algo, "steps": config.total_timesteps,
                "jaxnat_return": j_mean, "jaxnat_ci": j_half, "jaxnat_returns": ours["returns"].tolist(),
                "jaxnat_train_s": ours["train_s"], "jaxnat_total_s": ours["train_s"] + ours["compile_s"],
                "jaxnat_params": ours["params"], "jaxnat_network": ours["network"],
                "random_return": random_mean,
                "jaxnat_return_text": _fmt(j_mean, j_half), "rejax_return_text": _fmt(r_mean, r_half),
                "jaxnat_config": {k: v for k, v in dataclasses.asdict(config).items()},
                "differences": differences + changed,
            }
            if theirs:
                row.update({
                    "rejax_return": r_mean, "rejax_ci": r_half, "rejax_returns": theirs["returns"].tolist(),
                    "rejax_train_s": theirs["train_s"], "rejax_total_s": theirs["train_s"] + theirs["compile_s"],
                    "rejax_params": theirs["params"], "rejax_config": rejax_config,
                    "return_ratio": j_mean / r_mean if r_mean else None,
                    "above_random_ratio": ((j_mean - random_mean) / (r_mean - random_mean)
                                           if r_mean != random_mean else None),
                    "train_ratio": ours["train_s"] / theirs["train_s"],
                    "total_ratio": row["jaxnat_total_s"] / (theirs["train_s"] + theirs["compile_s"]),
                })
                short = j_mean < r_mean - (0.0 if math.isnan(r_half) else r_half)
                slow = ours["train_s"] > theirs["train_s"]
                row["target"] = {(False, False): "met", (True, False): "return short",
                                 (False, True): "slower", (True, True): "short, slower"}[(short, slow)]
            else:
                row["target"] = "no reference"
            rows.append(row)
            notes.append(f"- {label} ({config.total_timesteps:,} steps; jaxnat {ours['network']} "
                         f"{ours['params']:,} params" + (f", rejax {theirs['params']:,} params" if theirs else "")
                         + "): " + "; ".join(row["differences"]))

    table = common.markdown_table(rows, [
        ("env", "env", ""), ("algo", "algo", ""), ("steps", "steps/seed", ","),
        ("jaxnat_return_text", "jaxnat return (95% CI)", ""), ("rejax_return_text", "rejax return (95% CI)", ""),
        ("random_return", "random", ".1f"), ("return_ratio", "return ratio", ".2f"),
        ("above_random_ratio", "above-random ratio", ".2f"),
        ("jaxnat_train_s", "jaxnat train s", ".1f"), ("rejax_train_s", "rejax train s", ".1f"),
        ("train_ratio", "train-time ratio", ".2f"),
        ("jaxnat_total_s", "jaxnat s incl. compile", ".1f"), ("rejax_total_s", "rejax s incl. compile", ".1f"),
        ("total_ratio", "ratio incl. compile", ".2f"), ("target", "target", ""),
    ])
    header = ("Settings: rejax 0.1.3's configs mapped onto jaxnat's (bench/agents_vs_references.py). "
              "Differences, per row:\n" + "\n".join(notes))
    summary = {
        "setup": f"{args.seeds} seeds per side vmapped in one jitted program; budget scale {args.budget_scale}; "
                 f"rejax networks {args.rejax_network}; jaxnat MinAtar trunk {args.minatar_trunk}",
        "final return": f"greedy, {args.eval_episodes} fresh episodes per seed, the same evaluation code for both "
                        "sides; mean over seeds ± 95% t-interval half-width",
        "ratios": "jaxnat / rejax; above-random ratio = (jaxnat - random) / (rejax - random); wall ratios < 1: "
                  "jaxnat faster",
        "target": "jaxnat's mean return >= rejax's CI lower bound, and jaxnat's training time <= rejax's",
        "versions": ", ".join(f"{k} {info[k]}" for k in ("jax", "jaxlib", "flax", "optax", "gymnax", "rejax",
                                                         "chex", "distrax", *(("brax", "mujoco") if brax_envs else ()),
                                                         "jaxnat_commit"))
                    + (f"; stand-ins for {', '.join(STAND_INS)} (not installed)" if STAND_INS else ""),
    }
    common.RESULTS = args.out
    common.record("agents_vs_references", info, header + "\n\n" + table, summary, rows, save=not args.no_record)


if __name__ == "__main__":
    main()
