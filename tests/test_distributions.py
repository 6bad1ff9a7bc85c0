"""The action distributions: the diagonal Gaussian against closed forms, the categoricals'
contract, and dispatch on what a policy head returns."""

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.stats import norm

from jaxnat.agents import distributions
from jaxnat.agents.distributions import Gaussian


def test_gaussian_log_prob_and_entropy_match_closed_forms():
    mean = jnp.array([[0.0, 1.0, -2.0], [0.5, 0.0, 3.0]])
    log_std = jnp.array([0.0, -1.0, 0.7])
    dist = Gaussian(mean, log_std)
    actions = jnp.array([[0.3, 1.2, -1.0], [-0.5, 0.1, 2.0]])
    expected = norm.logpdf(actions, mean, jnp.exp(log_std)).sum(-1)
    np.testing.assert_allclose(distributions.log_prob(dist, actions), expected, rtol=1e-6)
    entropy = 0.5 * np.log(2 * np.pi * np.e * np.exp(2 * np.asarray(log_std)))  # per dimension
    np.testing.assert_allclose(distributions.entropy(dist), np.full(2, entropy.sum()), rtol=1e-6)
    np.testing.assert_array_equal(distributions.mode(dist), mean)


def test_gaussian_samples_have_its_moments():
    dist = Gaussian(jnp.broadcast_to(jnp.array([1.0, -3.0]), (200_000, 2)), jnp.log(jnp.array([0.5, 2.0])))
    x = np.asarray(distributions.sample(jax.random.key(0), dist))
    assert x.dtype == np.float32 and x.shape == (200_000, 2)
    np.testing.assert_allclose(x.mean(0), [1.0, -3.0], atol=0.02)
    np.testing.assert_allclose(x.std(0), [0.5, 2.0], rtol=0.01)


def test_categoricals_are_factored():
    logits = (jnp.log(jnp.array([[0.25, 0.75]])), jnp.log(jnp.array([[0.1, 0.2, 0.7]])))
    actions = jnp.array([[1, 2]])
    np.testing.assert_allclose(distributions.log_prob(logits, actions), np.log([0.75 * 0.7]), rtol=1e-6)
    h = -(0.25 * np.log(0.25) + 0.75 * np.log(0.75)) - (0.1 * np.log(0.1) + 0.2 * np.log(0.2) + 0.7 * np.log(0.7))
    np.testing.assert_allclose(distributions.entropy(logits), [h], rtol=1e-6)
    np.testing.assert_array_equal(distributions.mode(logits), [[1, 2]])
    sampled = distributions.sample(jax.random.key(0), logits)
    assert sampled.dtype == jnp.int32 and sampled.shape == (1, 2)
