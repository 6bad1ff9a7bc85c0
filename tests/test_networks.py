"""Networks: both convolution forms equal XLA's (values and gradients, under vmap), trunks fit
their observations, heads match."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnat import spaces
from jaxnat.agents.conv import conv2d
from jaxnat.agents.networks import Memory, default_trunk, init_params, make_actor_critic


@pytest.mark.parametrize("implementation", ["im2col", "native", "s2d", "unrolled", "grouped"])
@pytest.mark.parametrize("shape, kernel, stride", [((2, 28, 28, 3), 5, 2), ((1, 3, 12, 12, 10), 5, 1), ((2, 84, 84, 4), 8, 4),
                                                   ((2, 20, 20, 3), 4, 2), ((1, 23, 22, 2), 4, 2)])
def test_conv_equals_xla_convolution(implementation, shape, kernel, stride):
    x = jax.random.normal(jax.random.key(0), shape)
    k = jax.random.normal(jax.random.key(1), (kernel, kernel, shape[-1], 7))
    flat = x.reshape(-1, *shape[-3:])
    want = jax.lax.conv_general_dilated(flat, k, (stride, stride), "VALID",
                                        dimension_numbers=("NHWC", "HWIO", "NHWC"))
    got = conv2d(x, k, stride, implementation)
    np.testing.assert_allclose(np.asarray(got).reshape(want.shape), np.asarray(want), rtol=1e-4, atol=1e-4)


def _loss(implementation):
    return lambda x, k: jnp.sum(jnp.sin(conv2d(x, k, 2, implementation)))


def test_native_conv_vmapped_over_weights_matches_im2col():
    """One weight set per seed (as `vmap(train)`): values and both gradients agree."""
    x = jax.random.normal(jax.random.key(0), (3, 4, 12, 12, 3))  # seeds, batch, H, W, C
    k = jax.random.normal(jax.random.key(1), (3, 5, 5, 3, 2))
    for fun in (lambda impl: jax.vmap(_loss(impl)), lambda impl: jax.vmap(jax.grad(_loss(impl), (0, 1)))):
        want, got = fun("im2col")(x, k), jax.jit(fun("native"))(x, k)
        for w, g in zip(jax.tree_util.tree_leaves(want), jax.tree_util.tree_leaves(got)):
            np.testing.assert_allclose(np.asarray(g), np.asarray(w), rtol=1e-4, atol=1e-4)


def test_native_conv_shared_weights_and_per_example_gradients():
    """Inputs vmapped, weights shared: the forward folds the batch; per-example kernel gradients
    stay per example (not summed over the batch)."""
    x = jax.random.normal(jax.random.key(0), (3, 12, 12, 3))
    k = jax.random.normal(jax.random.key(1), (5, 5, 3, 2))
    forward = lambda impl: jax.vmap(lambda xi: conv2d(xi, k, 2, impl))(x)
    np.testing.assert_allclose(np.asarray(forward("native")), np.asarray(forward("im2col")), rtol=1e-4, atol=1e-4)
    per_example = lambda impl: jax.vmap(jax.grad(_loss(impl), 1), (0, None))(x, k)
    got = per_example("native")
    assert got.shape == (3, 5, 5, 3, 2)
    np.testing.assert_allclose(np.asarray(got), np.asarray(per_example("im2col")), rtol=1e-4, atol=1e-4)


@pytest.mark.parametrize("implementation", ["s2d", "unrolled"])
def test_space_to_depth_conv_vmapped_over_weights_matches_native(implementation):
    """The Atari trunk's first two layers (8x8 stride 4, 4x4 stride 2) as stride-1
    convolutions on tiled inputs, the seeds' convolutions in a loop or unrolled: values and
    both gradients under vmap over weight sets (`native` equals im2col above)."""
    x = jax.random.normal(jax.random.key(0), (2, 2, 44, 44, 4))
    k = jax.random.normal(jax.random.key(1), (2, 8, 8, 4, 5))
    loss = lambda impl: lambda x, k: jnp.sum(jnp.sin(conv2d(conv2d(x, k, 4, impl), k2, 2, impl)))
    k2 = jax.random.normal(jax.random.key(2), (4, 4, 5, 3)) * 0.1
    for fun in (lambda impl: jax.vmap(loss(impl)), lambda impl: jax.vmap(jax.grad(loss(impl), (0, 1)))):
        want, got = jax.jit(fun("native"))(x, k), jax.jit(fun(implementation))(x, k)
        for w, g in zip(jax.tree_util.tree_leaves(want), jax.tree_util.tree_leaves(got)):
            np.testing.assert_allclose(np.asarray(g), np.asarray(w), rtol=1e-4, atol=1e-4)


def test_grouped_conv_vmapped_over_weights_matches_native():
    """XLA's own batching of the s2d form (one grouped convolution for all weight sets): the
    Atari trunk's first two layers, values and both gradients under vmap over weight sets."""
    x = jax.random.normal(jax.random.key(0), (3, 2, 44, 44, 4))
    k = jax.random.normal(jax.random.key(1), (3, 8, 8, 4, 5))
    k2 = jax.random.normal(jax.random.key(2), (4, 4, 5, 3)) * 0.1
    loss = lambda impl: lambda x, k: jnp.sum(jnp.sin(conv2d(conv2d(x, k, 4, impl), k2, 2, impl)))
    for fun in (lambda impl: jax.vmap(loss(impl)), lambda impl: jax.vmap(jax.grad(loss(impl), (0, 1)))):
        want, got = jax.jit(fun("native"))(x, k), jax.jit(fun("grouped"))(x, k)
        for w, g in zip(jax.tree_util.tree_leaves(want), jax.tree_util.tree_leaves(got)):
            np.testing.assert_allclose(np.asarray(g), np.asarray(w), rtol=1e-4, atol=1e-4)


def test_conv_rejects_unknown_implementation():
    with pytest.raises(ValueError, match="im2col"):
        conv2d(jnp.zeros((1, 8, 8, 1)), jnp.zeros((3, 3, 1, 1)), 1, "winograd")


def test_default_trunks():
    box = lambda *s: spaces.Box(0, 255, s, jnp.uint8)
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


@pytest.mark.parametrize("trunk, shape", [("mnist", (28, 28, 3)), ("resnet18", (8, 8, 2)), ("mlp", (6,))])
def test_bfloat16_trunk_keeps_float32_parameters_and_heads(trunk, shape):
    obs_space = spaces.Box(0, 255, shape, jnp.uint8) if len(shape) > 1 else spaces.Box(-1, 1, shape)
    obs = jnp.stack([obs_space.sample(jax.random.key(i)) for i in range(3)])
    full = make_actor_critic(obs_space, spaces.MultiDiscrete([4, 10]), trunk)
    half = make_actor_critic(obs_space, spaces.MultiDiscrete([4, 10]), trunk, dtype="bfloat16")
    params = full.init(jax.random.key(1), obs)
    # Same parameters (float32) for both: a checkpoint moves freely between the two.
    half_params = half.init(jax.random.key(1), obs)
    assert jax.tree_util.tree_structure(half_params) == jax.tree_util.tree_structure(params)
    assert {x.dtype for x in jax.tree_util.tree_leaves(half_params)} == {jnp.dtype("float32")}
    (move, label), value = half.apply(params, obs)
    (move32, label32), value32 = full.apply(params, obs)
    assert move.dtype == label.dtype == value.dtype == jnp.float32
    np.testing.assert_allclose(value, value32, rtol=0.05, atol=0.02)
    np.testing.assert_allclose(label, label32, atol=2e-3)  # heads are scaled by 0.01 at init
    assert "bf16" in str(jax.make_jaxpr(half.apply)(params, obs))
    assert "bf16" not in str(jax.make_jaxpr(full.apply)(params, obs))


def test_unknown_dtype_is_a_clear_error():
    with pytest.raises(ValueError, match="dtype 'float16'.*bfloat16"):
        make_actor_critic(spaces.Box(0, 1, (6,)), spaces.Discrete(4), "mlp", dtype="float16")


def _moved_by(fn, params) -> set[str]:
    """The parameters (paths) that `fn(params)` has a non-zero gradient for."""
    grads = jax.grad(fn)(params)
    return {jax.tree_util.keystr(path) for path, g in jax.tree_util.tree_leaves_with_path(grads)
            if np.any(np.asarray(g) != 0)}


def _outputs(network, params, space, memory):
    """`(logits, value)` of `network` on 3 random observations (a 3-step sequence of 2 envs with
    an episode start in the middle, for a recurrent one)."""
    sample = lambda i: space.sample(jax.random.key(i))  # noqa: E731
    if not memory:
        return network.apply(params, jax.tree_util.tree_map(lambda *x: jnp.stack(x), *map(sample, range(3))))
    obs = jax.tree_util.tree_map(lambda *x: jnp.stack(x).reshape(3, 2, *x[0].shape), *map(sample, range(6)))
    state = Memory(hidden=jnp.ones((2, memory)), prev_action=jnp.ones((3, 2, 2), jnp.int32),
                   prev_reward=jnp.ones((3, 2)), start=jnp.array([[True, False], [False, True], [False, False]]))
    logits, value, _ = network.apply(params, obs, state)
    return logits, value


@pytest.mark.parametrize("memory", [0, 8])
@pytest.mark.parametrize("goal", [False, True])
def test_mlp_actor_and_critic_are_separate_networks(memory, goal):
    """The mlp trunk: the policy's logits depend on actor parameters only (the GRU included),
    the value on critic parameters only, and every parameter is one or the other; with a goal
    each network embeds it."""
    vector = spaces.Box(-1.0, 1.0, (4,), jnp.float32)
    space = spaces.Dict({"pixels": vector, "goal": spaces.Discrete(3)}) if goal else vector
    network = make_actor_critic(space, spaces.MultiDiscrete([2, 3]), "mlp", memory=memory)
    params = init_params(network, space, jax.random.key(0))
    actor = _moved_by(lambda p: sum(x.sum() for x in _outputs(network, p, space, memory)[0]), params)
    critic = _moved_by(lambda p: _outputs(network, p, space, memory)[1].sum(), params)
    every = {jax.tree_util.keystr(path) for path, _ in jax.tree_util.tree_leaves_with_path(params)}
    assert actor.isdisjoint(critic) and actor | critic == every
    assert all("'critic" not in name for name in actor) and all("'actor" not in name for name in critic)
    assert any("'memory'" in name for name in actor) == bool(memory)
    assert any("'critic_goal'" in name for name in critic) == goal


def test_paper_trunks_stay_shared_and_dqn_has_one_relu_mlp():
    """A CNN trunk (the authors' CNNBase) feeds both heads; DQN's Q-network on vectors is one
    ReLU MLP of 120 and 84 units under every head."""
    image = spaces.Box(0, 255, (28, 28, 1), jnp.uint8)
    network = make_actor_critic(image, spaces.Discrete(4), "mnist")
    params = init_params(network, image, jax.random.key(0))
    actor = _moved_by(lambda p: _outputs(network, p, image, 0)[0][0].sum(), params)
    critic = _moved_by(lambda p: _outputs(network, p, image, 0)[1].sum(), params)
    assert {name for name in actor & critic} == {name for name in actor if "PaperCNN_0" in name}

    vector = spaces.Box(-1.0, 1.0, (4,), jnp.float32)
    q = make_actor_critic(vector, spaces.Discrete(2), "mlp", q_network=True)
    params = init_params(q, vector, jax.random.key(0))
    kernels = {jax.tree_util.keystr(path): x.shape for path, x in jax.tree_util.tree_leaves_with_path(params)
               if "kernel" in jax.tree_util.keystr(path) and "MLP_0" in jax.tree_util.keystr(path)}
    assert sorted(kernels.values()) == [(4, 120), (120, 84)]
    assert "'actor'" not in str(params) and "'critic'" not in str(params)
    x = jnp.array([[-3.0, -3.0, -3.0, -3.0], [3.0, 3.0, 3.0, 3.0]])
    _, state = q.apply(params, x, capture_intermediates=True)
    (hidden,) = state["intermediates"]["MLP_0"]["__call__"]
    assert float(hidden.min()) == 0.0 and float(hidden.max()) > 1.0  # ReLU, not tanh


def test_auto_conv_on_gpu_is_one_unlooped_convolution_per_seed(monkeypatch):
    """Off CPU, `"auto"` is the unrolled form: under vmap over weight sets, one convolution per
    seed written out, no `lax.map` loop (whose operand copies were most of a pixel update's
    copies on a GPU: bench/results/ppo_learner.md)."""
    import jaxnat.agents.conv as conv_module

    monkeypatch.setattr(conv_module.jax, "default_backend", lambda: "gpu")
    seeds = 3
    x = jnp.zeros((seeds, 2, 84, 84, 4))
    k = jnp.zeros((seeds, 8, 8, 4, 32))
    text = str(jax.make_jaxpr(jax.vmap(lambda x, k: conv2d(x, k, 4)))(x, k))
    assert "while" not in text
    assert text.count("conv_general_dilated") == seeds
