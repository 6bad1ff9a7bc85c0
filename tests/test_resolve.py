"""`jaxnat.agents.resolve`: a config's values out of range are refused where every run's config
is resolved (`resolve_config`, `config_for`, `jaxnat train`), valid and traced ones are not."""

import dataclasses

import jax
import jax.numpy as jnp
import pytest

from jaxnat import spaces
from jaxnat.agents import ALGORITHMS, resolve_config

IMAGES = spaces.Box(0, 255, (28, 28, 1), jnp.uint8)
ACTIONS = spaces.Discrete(4)


@pytest.mark.parametrize("algo, name, value, rule", [
    ("ppo", "lr", -1.0, "> 0"),
    ("ppo", "lr", 0.0, "> 0"),
    ("ppo", "lr", float("nan"), "> 0"),
    ("ppo", "gamma", 1.5, "in (0, 1]"),
    ("ppo", "gamma", 0.0, "in (0, 1]"),
    ("ppo", "gae_lambda", -0.1, "in [0, 1]"),
    ("ppo", "clip_eps", -0.2, ">= 0"),
    ("ppo", "ent_coef", -0.01, ">= 0"),
    ("ppo", "vf_coef", -1.0, ">= 0"),
    ("ppo", "max_grad_norm", 0.0, "> 0"),
    ("ppo", "update_epochs", 0, ">= 1"),
    ("ppo", "num_minibatches", 0, ">= 1"),
    ("ppo", "num_envs", 0, ">= 1"),
    ("ppo", "num_steps", -4, ">= 1"),
    ("a2c", "lr", -7e-4, "> 0"),
    ("a2c", "rms_alpha", 1.5, "in [0, 1]"),
    ("acktr", "momentum", 1.0, "in [0, 1)"),
    ("acktr", "kl_clip", 0.0, "> 0"),
    ("acktr", "damping", -0.01, ">= 0"),
    ("dqn", "eps_start", 1.5, "in [0, 1]"),
    ("dqn", "eps_end", -0.1, "in [0, 1]"),
    ("dqn", "batch_size", 0, ">= 1"),
    ("dqn", "gamma", 2.0, "in (0, 1]"),
    ("dqn", "target_update_period", 0, ">= 1"),
    ("dqn", "learning_starts", -1, ">= 0"),
])
def test_out_of_range_values_are_refused_in_one_line(algo, name, value, rule):
    with pytest.raises(ValueError) as raised:
        resolve_config(algo, IMAGES, ACTIONS, {name: value})
    message = str(raised.value)
    assert f"{name}={value!r}" in message and rule in message and "\n" not in message, message


@pytest.mark.parametrize("algo", list(ALGORITHMS))
def test_defaults_and_boundaries_resolve_unchanged(algo):
    names = {f.name for f in dataclasses.fields(ALGORITHMS[algo].config)}
    edges = {"gamma": 1.0, "gae_lambda": 0.0, "clip_eps": 0.0, "ent_coef": 0.0, "vf_coef": 0.0,
             "eps_start": 0.0, "eps_end": 1.0, "learning_starts": 0, "momentum": 0.0, "tau": 1.0}
    given = {name: value for name, value in edges.items() if name in names}
    config = resolve_config(algo, IMAGES, ACTIONS, given).config
    assert all(getattr(config, name) == value for name, value in given.items())
    assert resolve_config(algo, IMAGES, ACTIONS).config == resolve_config(algo, IMAGES, ACTIONS).config


def test_traced_values_are_not_checked():
    """A sweep's values are arrays (vmapped), and a config resolved under a trace is not concrete:
    neither is checked (nor can it be)."""
    lrs = jnp.array([1e-3, 3e-4])
    assert resolve_config("ppo", IMAGES, ACTIONS, {"lr": lrs}).config.lr is lrs

    def lr_of(lr):
        return resolve_config("ppo", IMAGES, ACTIONS, {"lr": lr}).config.lr

    assert jax.vmap(lr_of)(lrs).shape == (2,)


def test_learners_built_directly_refuse_values_out_of_range():
    """The range check lives with the configs and runs where a learner is built, so a library
    user who skips `config_for` is refused too."""
    import jaxnat
    from jaxnat.agents import DQNConfig, PPOConfig, make_dqn, make_ppo

    env, params = jaxnat.make("Classify/Digits-v0")
    with pytest.raises(ValueError, match=r"^lr=-1.0 is out of range: lr must be > 0$"):
        make_ppo(PPOConfig(lr=-1.0, trunk="mnist"), env, params)
    with pytest.raises(ValueError, match=r"^n_step=0 is out of range: n_step must be >= 1$"):
        make_dqn(DQNConfig(n_step=0, trunk="mnist"), env, params)
