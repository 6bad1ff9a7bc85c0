"""Spaces: sampling stays inside, `contains` is exact and jittable, Gymnasium conversion."""

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnat import spaces


def test_discrete():
    s = spaces.Discrete(3)
    samples = jax.vmap(s.sample)(jax.random.split(jax.random.key(0), 300))
    assert samples.dtype == jnp.int32 and set(np.asarray(samples).tolist()) == {0, 1, 2}
    assert bool(s.contains(2)) and not bool(s.contains(3)) and not bool(s.contains(-1))
    assert not bool(s.contains(jnp.array([1])))
    assert isinstance(s.to_gymnasium(), gymnasium.spaces.Discrete)


def test_multidiscrete():
    s = spaces.MultiDiscrete([4, 10])
    samples = np.asarray(jax.vmap(s.sample)(jax.random.split(jax.random.key(0), 500)))
    assert samples.shape == (500, 2)
    assert set(samples[:, 0].tolist()) == {0, 1, 2, 3}
    assert set(samples[:, 1].tolist()) == set(range(10))
    assert bool(jax.jit(s.contains)(jnp.array([3, 9])))
    assert not bool(s.contains(jnp.array([4, 0])))
    assert not bool(s.contains(jnp.array([0, 10])))
    assert not bool(s.contains(jnp.array([0, 1, 2])))
    g = s.to_gymnasium()
    assert isinstance(g, gymnasium.spaces.MultiDiscrete) and g.nvec.tolist() == [4, 10]


def test_box_uint8():
    s = spaces.Box(0, 255, (2, 3, 4), jnp.uint8)
    x = s.sample(jax.random.key(0))
    assert x.shape == (2, 3, 4) and x.dtype == jnp.uint8
    assert bool(s.contains(x))
    assert not bool(s.contains(jnp.zeros((2, 3), jnp.uint8)))
    g = s.to_gymnasium()
    assert g.dtype == np.uint8 and g.shape == (2, 3, 4) and g.contains(np.asarray(x))


def test_box_float_bounds():
    s = spaces.Box(-1.0, 1.0, (5,))
    xs = jax.vmap(s.sample)(jax.random.split(jax.random.key(1), 100))
    assert float(xs.min()) >= -1 and float(xs.max()) <= 1
    assert not bool(s.contains(jnp.full((5,), 1.5)))


def test_dict():
    s = spaces.Dict({"pixels": spaces.Box(0, 255, (4, 4, 2), jnp.uint8), "goal": spaces.Discrete(5)})
    x = s.sample(jax.random.key(0))
    assert set(x) == {"pixels", "goal"} and bool(s.contains(x))
    assert not bool(s.contains({"pixels": x["pixels"]}))
    assert isinstance(s.to_gymnasium(), gymnasium.spaces.Dict)
    with pytest.raises(ValueError, match="keys"):
        s.check({"pixels": x["pixels"]}, "obs")


def test_check_names_shape_and_dtype_problems():
    s = spaces.MultiDiscrete([4, 10])
    s.check(jnp.array([1, 2]), "action")
    with pytest.raises(ValueError, match=r"shape \(3,\)"):
        s.check(jnp.array([1, 2, 3]), "action")
    with pytest.raises(TypeError, match="float32"):
        s.check(jnp.array([1.0, 2.0]), "action")


def test_bad_space_definitions():
    with pytest.raises(ValueError):
        spaces.Discrete(0)
    with pytest.raises(ValueError):
        spaces.MultiDiscrete([[2, 2]])
    with pytest.raises(ValueError):
        spaces.Box(1.0, 0.0, (2,))


def test_unbounded_float_box_converts_to_gymnasium_without_a_precision_warning():
    """A state vector's Box(-inf, inf) keeps its bounds exactly, with no "precision lowered"
    warning from Gymnasium (the MuJoCo adapters printed one per env)."""
    import warnings

    s = spaces.Box(-np.inf, np.inf, (17,), jnp.float32)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        g = s.to_gymnasium()
    assert g.dtype == np.float32 and g.low.dtype == np.float32 and np.all(np.isneginf(g.low))
    assert np.all(np.isposinf(g.high)) and g.shape == (17,)
