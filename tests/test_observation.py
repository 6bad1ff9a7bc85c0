"""The word-wise observation writer equals the byte-wise specification, for every layout."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnat.vision_envs.observation import (
    _wordwise_observation,
    masked_image_observation,
    masked_image_observation_reference,
)


@pytest.mark.parametrize(
    "h, w, c, k",
    [(28, 28, 1, 2), (32, 32, 3, 2), (8, 12, 3, 1), (4, 8, 1, 3), (6, 10, 1, 2), (5, 7, 3, 2)],
)
def test_matches_reference(h, w, c, k):
    key_img, key_mask, key_planes = jax.random.split(jax.random.key(h * w + c + k), 3)
    images = jax.random.randint(key_img, (3, h, w, c), 0, 256).astype(jnp.uint8)
    mask = jax.random.bernoulli(key_mask, 0.5, (h, w))
    planes = list(jax.random.bernoulli(key_planes, 0.3, (k, h, w)))
    # The word-wise writer is what GPUs run; call it directly so CPU CI checks it too.
    writer = _wordwise_observation if w % 4 == 0 else masked_image_observation
    for index in range(3):
        got = jax.jit(writer)(images, index, mask, planes)
        want = masked_image_observation_reference(images, index, mask, planes)
        assert got.dtype == jnp.uint8 and got.shape == (h, w, c + k)
        np.testing.assert_array_equal(np.asarray(got), np.asarray(want))


def test_batched_under_vmap():
    images = jax.random.randint(jax.random.key(0), (5, 8, 8, 1), 0, 256).astype(jnp.uint8)
    masks = jax.random.bernoulli(jax.random.key(1), 0.5, (4, 8, 8))
    index = jnp.array([0, 4, 2, 2])
    got = jax.vmap(lambda i, m: _wordwise_observation(images, i, m, [m]))(index, masks)
    want = jax.vmap(lambda i, m: masked_image_observation_reference(images, i, m, [m]))(index, masks)
    np.testing.assert_array_equal(np.asarray(got), np.asarray(want))


def test_platform_dispatch_gives_the_same_bytes():
    images = jax.random.randint(jax.random.key(3), (2, 4, 8, 3), 0, 256).astype(jnp.uint8)
    mask = jax.random.bernoulli(jax.random.key(4), 0.5, (4, 8))
    got = jax.jit(masked_image_observation)(images, 1, mask, [mask, ~mask])
    want = masked_image_observation_reference(images, 1, mask, [mask, ~mask])
    np.testing.assert_array_equal(np.asarray(got), np.asarray(want))
