"""Every registered env whose data is on this machine keeps the env contract (`check_env`)."""

import pytest

import jaxnat
from jaxnat.datasets import DatasetNotFoundError
from jaxnat.testing import check_env


# Covered by their own contract tests instead: host-batched envs (NaturalAtari/*,
# tests/test_atari.py), and the MJX envs, which compile for minutes on a CI CPU
# (tests/test_mjx_physics.py runs check_env on every MuJoCo/* robot once; tests/test_pixel_mujoco.py
# on the registered Swimmer and on every observation/floor mode with light physics).
_JAX_IDS = [
    i for i in jaxnat.registered_envs()
    if not i.startswith(("Test/", "PixelMuJoCo/", "MuJoCo/")) and not jaxnat.spec(i).batched
]


@pytest.mark.parametrize("env_id", _JAX_IDS)
def test_registered_env_keeps_the_contract(env_id):
    try:
        env, params = jaxnat.make(env_id, autoreset=False)
    except DatasetNotFoundError as err:
        pytest.skip(f"data not present: {str(err).splitlines()[0]}")
    except (TypeError, ValueError) as err:
        if "root" in str(err):  # e.g. ImageFolder needs a root= argument
            pytest.skip(str(err).splitlines()[0])
        raise
    check_env(env, params, num_steps=10)
    check_env(jaxnat.make(env_id)[0], params, num_steps=10)
