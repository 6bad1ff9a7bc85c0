"""jaxnat: JAX-accelerated, vectorised natural-signal reinforcement-learning benchmarks.

    import jax, jaxnat
    env, params = jaxnat.make("Classify/Digits-v0")
    obs, state = env.reset(jax.random.key(0), params)
"""

from jaxnat import envs as _envs  # noqa: F401  (registers the ids)
from jaxnat.core import Environment, EnvParams, EnvState
from jaxnat.registration import (
    MissingDependencyError,
    UnknownEnvError,
    make,
    make_vec,
    register,
    registered_envs,
    spec,
)

__version__ = "0.1.0"

__all__ = [
    "Environment",
    "EnvParams",
    "EnvState",
    "make",
    "make_vec",
    "register",
    "registered_envs",
    "spec",
    "UnknownEnvError",
    "MissingDependencyError",
]
