"""Networks: the im2col convolution equals XLA's, trunks fit their observations, heads match."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnat import spaces
from jaxnat.agents.networks import _conv_im2col, default_trunk, make_actor_critic


@pytest.mark.parametrize("shape, kernel, stride", [((2, 28, 28, 3), 5, 2), ((1, 3, 12, 12, 10), 5, 1), ((2, 84, 84, 4), 8, 4)])
def test_im2col_equals_xla_convolution(shape, kernel, stride):
    x = jax.random.normal(jax.random.key(0), shape)
    k = jax.random.normal(jax.random.key(1), (kernel, kernel, shape[-1], 7))
    flat = x.reshape(-1, *shape[-3:])
    want = jax.lax.conv_general_dilated(flat, k, (stride, stride), "VALID",
                                        dimension_numbers=("NHWC", "HWIO", "NHWC"))
    got = _conv_im2col(x, k, stride)
    np.testing.assert_allclose(np.asarray(got).reshape(want.shape), np.asarray(want), rtol=1e-4, atol=1e-4)


def test_default_trunks():
    box = lambda *s: spaces.Box(0, 255, s, jnp.uint8)  # noqa: E731
    assert default_trunk(box(28, 28, 3)) == "mnist"
    assert default_trunk(box(32, 32, 5)) == "cifar"
    assert default_trunk(box(84, 84, 4)) == "atari"
    assert default_trunk(spaces.Box(-1, 1, (6,))) == "mlp"
    assert default_trunk(spaces.Dict({"pixels": box(256, 256, 4), "goal": spaces.Discrete(5)})) == "cityscapes"


def test_heads_and_dict_observation():
    obs_space = spaces.Dict({"pixels": spaces.Box(0, 255, (32, 32, 4), jnp.uint8), "goal": spaces.Discrete(5)})
    net = make_actor_critic(obs_space, spaces.MultiDiscrete([4, 7]), "cifar")
    obs = jax.tree_util.tree_map(lambda x: jnp.stack([x, x]), obs_space.sample(jax.random.key(0)))
    params = net.init(jax.random.key(1), obs)
    logits, value = net.apply(params, obs)
    assert [l.shape for l in logits] == [(2, 4), (2, 7)] and value.shape == (2,)


def test_incompatible_trunk_is_a_clear_error():
    with pytest.raises(ValueError, match="does not fit"):
        make_actor_critic(spaces.Box(0, 255, (20, 20, 3), jnp.uint8), spaces.Discrete(4), "atari")
    with pytest.raises(ValueError, match="mlp"):
        make_actor_critic(spaces.Box(0, 1, (6,)), spaces.Discrete(4), "mnist")
    with pytest.raises(ValueError, match="Unknown trunk"):
        make_actor_critic(spaces.Box(0, 1, (6,)), spaces.Discrete(4), "vgg")
