"""The word-wise observation writer equals the byte-wise specification, for every layout."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnat.vision_envs.observation import (
    WRITERS,
    masked_image_observation,
    masked_image_observation_reference,
    wordwise_observation,
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
    writer = wordwise_observation if w % 4 == 0 else masked_image_observation
    for index in range(3):
        got = jax.jit(writer)(images, index, mask, planes)
        want = masked_image_observation_reference(images, index, mask, planes)
        assert got.dtype == jnp.uint8 and got.shape == (h, w, c + k)
        np.testing.assert_array_equal(np.asarray(got), np.asarray(want))


def test_batched_under_vmap():
    images = jax.random.randint(jax.random.key(0), (5, 8, 8, 1), 0, 256).astype(jnp.uint8)
    masks = jax.random.bernoulli(jax.random.key(1), 0.5, (4, 8, 8))
    index = jnp.array([0, 4, 2, 2])
    got = jax.vmap(lambda i, m: wordwise_observation(images, i, m, [m]))(index, masks)
    want = jax.vmap(lambda i, m: masked_image_observation_reference(images, i, m, [m]))(index, masks)
    np.testing.assert_array_equal(np.asarray(got), np.asarray(want))


def test_platform_dispatch_gives_the_same_bytes():
    images = jax.random.randint(jax.random.key(3), (2, 4, 8, 3), 0, 256).astype(jnp.uint8)
    mask = jax.random.bernoulli(jax.random.key(4), 0.5, (4, 8))
    got = jax.jit(masked_image_observation)(images, 1, mask, [mask, ~mask])
    want = masked_image_observation_reference(images, 1, mask, [mask, ~mask])
    np.testing.assert_array_equal(np.asarray(got), np.asarray(want))


@pytest.mark.parametrize("writer", WRITERS)
def test_every_writer_gives_the_same_bytes(writer):
    images = jax.random.randint(jax.random.key(5), (2, 4, 8, 3), 0, 256).astype(jnp.uint8)
    mask = jax.random.bernoulli(jax.random.key(6), 0.5, (4, 8))
    write = jax.jit(lambda i, m: masked_image_observation(images, i, m, [m, ~m], writer=writer))
    want = masked_image_observation_reference(images, 1, mask, [mask, ~mask])
    np.testing.assert_array_equal(np.asarray(write(1, mask)), np.asarray(want))
    with pytest.raises(ValueError, match="writer must be one of"):
        masked_image_observation(images, 1, mask, [mask], writer="fast")


def test_envs_take_their_writer_as_an_argument():
    """`observation_writer` picks the path by hand (the benches time each); same observations."""
    from jaxnat.datasets import ImageDataset
    from jaxnat.datasets.segmentation import SegmentationDataset
    from jaxnat.vision_envs.classify import Classify
    from jaxnat.vision_envs.localize import Localize

    rng = np.random.default_rng(0)
    images = rng.integers(0, 256, (3, 16, 20, 3), dtype=np.uint8)
    maps = np.full((3, 16, 20), 255, np.uint8)
    maps[:, :2, :2] = 0  # a goal class in a corner, away from the start footprint
    envs = {
        "classify": lambda **kw: Classify(
            ImageDataset("d", "train", images, np.zeros(3, np.int32), ("a",)), w=4, **kw),
        "localize": lambda **kw: Localize(
            SegmentationDataset("s", "train", images, maps, ("a",)), w=4, **kw),
    }
    for make in envs.values():
        default = make()
        params = default.default_params
        _, state = jax.vmap(default.reset, in_axes=(0, None))(
            jax.random.split(jax.random.key(7), 4), params)
        want = jax.vmap(default.get_obs, in_axes=(0, None))(state, params)
        for writer in WRITERS:
            env = make(observation_writer=writer)
            assert env.observation_writer == writer
            got = jax.vmap(env.get_obs, in_axes=(0, None))(state, params)
            jax.tree_util.tree_map(np.testing.assert_array_equal, got, want)
        with pytest.raises(ValueError, match="observation_writer"):
            make(observation_writer="fast")
