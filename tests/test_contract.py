"""Every registered env whose data is on this machine keeps the env contract (`check_env`)."""

import pytest

import jaxnat
from jaxnat.datasets import DatasetNotFoundError
from jaxnat.testing import check_env


# Host-batched envs (NaturalAtari/*) have their own contract tests (tests/test_atari.py).
_JAX_IDS = [
    i for i in jaxnat.registered_envs() if not i.startswith("Test/") and not jaxnat.spec(i).batched
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
