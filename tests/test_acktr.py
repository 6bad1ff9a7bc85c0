"""ACKTR and its K-FAC: the preconditioned step against the exact Fisher, the KL trust region,
probe environments under vmap over seeds, and exact resume through `jaxnat train`.

The exact-Fisher tests use one layer with a zero kernel: its softmax output is then the same
for every input, so its Fisher is exactly the Kronecker product `E[a a^T] (x) E[g g^T]` that
K-FAC assumes, and the K-FAC step must equal `F^-1 grad` up to sampling error (the output
gradients are drawn from the model's own distribution) and damping.
"""

import functools

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnat.agents import distributions, kfac
from jaxnat.agents.distributions import Gaussian
from jaxnat.agents.acktr import ACKTRConfig, make_acktr
from jaxnat.agents.networks import LogStd, ValidConv
from jaxnat.agents.probes import make_probe

_jit = functools.partial(jax.jit, compiler_options={"xla_backend_optimization_level": 0})

SEEDS = 5
CLASSES = 3


class DenseLayer(nn.Module):
    @nn.compact
    def __call__(self, x):
        return nn.Dense(CLASSES, kernel_init=nn.initializers.zeros, bias_init=nn.initializers.normal(1.0))(x)


class ConvLayer(nn.Module):
    """A ValidConv whose kernel covers the 2x2 image: one output pixel, logits `[..., CLASSES]`."""

    @nn.compact
    def __call__(self, x):
        out = ValidConv(CLASSES, kernel=2, stride=1)(x)
        return out[..., 0, 0, :] + self.param("shift", nn.initializers.normal(1.0), (CLASSES,))


def _inputs(key, module, n):
    if isinstance(module, DenseLayer):
        x = jax.random.normal(key, (n, 4))
    else:
        x = jax.random.normal(key, (n, 2, 2, 1))
    return x + 0.5 * x[..., :1] + 0.3  # correlated, non-zero mean: a non-diagonal A


def _zero_kernel(params):
    """Zero kernels (input-independent softmax); a ConvLayer's bias moved into its `shift`."""
    return jax.tree_util.tree_map_with_path(
        lambda path, x: jnp.zeros_like(x) if path[-1].key in ("kernel", "bias") and "ValidConv" in str(path) else x,
        params,
    )


def _layer_matrix(params):
    """The layer's `[d_in + 1, CLASSES]` matrix (kernel rows, then the bias row), as K-FAC sees it."""
    (kernel_key, bias_key), = kfac._layers(params).values()
    flat = dict(jax.tree_util.tree_flatten_with_path(params)[0])
    flat = {tuple(k.key for k in path): v for path, v in flat.items()}
    kernel, bias = flat[kernel_key], flat[bias_key]
    return jnp.concatenate([kernel.reshape(-1, CLASSES), bias[None]])


@pytest.mark.parametrize("module", [DenseLayer(), ConvLayer()], ids=["dense", "conv"])
def test_kfac_step_matches_exact_fisher_inverse_step(module):
    key_x, key_y, key_init, key_sample = jax.random.split(jax.random.key(0), 4)
    n = 40_000
    x = _inputs(key_x, module, n)
    labels = jax.random.randint(key_y, (n,), 0, CLASSES)
    params = _zero_kernel(module.init(key_init, x[:1]))
    # With a ConvLayer the layer's own bias is zero and unused by the shift: it still gets a
    # gradient, which the exact Fisher below includes through the bias row.

    def losses(params, perturbations):
        logits, inputs, _ = kfac.capture(module, params, x, perturbations)
        log_p = jax.nn.log_softmax(logits)
        loss = -jnp.take_along_axis(log_p, labels[:, None], 1).mean()
        sampled = jax.random.categorical(key_sample, jax.lax.stop_gradient(logits))
        return (loss, jnp.take_along_axis(log_p, sampled[:, None], 1).sum()), inputs

    zeros = kfac.zero_perturbations(module, params, x)
    _, backward, inputs = jax.vjp(losses, params, zeros, has_aux=True)
    grads, _ = backward((1.0, 0.0))
    _, output_grads = backward((0.0, 1.0))
    statistics = kfac.factor_statistics(inputs, output_grads)
    assert set(statistics) == set(kfac._layers(params))

    tx = kfac.kfac(1.0, damping=1e-6, stats_decay=0.9, kl_clip=1e9)
    state = tx.init(params)
    update = jax.jit(lambda g, s: tx.update(g, s, statistics=statistics))
    for _ in range(30):  # the Newton-Schulz inverses converge over updates
        natural, state = update(grads, state)
    kfac_step = np.asarray(_layer_matrix(natural), np.float64)

    # The exact Fisher of the layer's matrix, over the model's own label distribution.
    def log_probs(matrix, xi):
        features = jnp.concatenate([xi.reshape(-1), jnp.ones(1)])
        shift = params["params"].get("shift", 0.0)
        return jax.nn.log_softmax(features @ matrix + shift)

    matrix = _layer_matrix(params)
    jac = jax.vmap(jax.jacrev(log_probs), in_axes=(None, 0))(matrix, x)  # [n, classes, d_in+1, classes]
    jac = np.asarray(jac, np.float64).reshape(n, CLASSES, -1)
    p = np.exp(np.asarray(jax.vmap(log_probs, in_axes=(None, 0))(matrix, x), np.float64))
    fisher = np.einsum("nc,nci,ncj->ij", p, jac, jac) / n
    grad = np.asarray(_layer_matrix(grads), np.float64).reshape(-1)
    exact = (np.linalg.pinv(fisher, rcond=1e-8) @ grad).reshape(kfac_step.shape)

    error = np.linalg.norm(kfac_step - exact) / np.linalg.norm(exact)
    assert error < 0.03, error
    # ... and the natural gradient is far from the plain one (the test can tell them apart).
    plain = grad.reshape(exact.shape)
    cosine = np.sum(plain * exact) / (np.linalg.norm(plain) * np.linalg.norm(exact))
    assert cosine < 0.95, cosine


class GaussianHead(nn.Module):
    """A Gaussian policy's head as `ActorCritic` builds it: a Dense mean and a `LogStd`."""

    @nn.compact
    def __call__(self, x):
        mean = nn.Dense(2)(x)
        return Gaussian(mean, LogStd()(mean))


def test_kfac_step_with_a_gaussian_head_matches_the_exact_fisher():
    """For `N(W a, diag(s^2))` with a state-independent log-std the exact Fisher is block
    diagonal and Kronecker: `E[a a^T] (x) diag(1 / s^2)` for the mean layer's matrix and `2 I`
    for the log-std (a layer of constant input 1, as the authors' `AddBias`). The K-FAC step
    from sampled statistics must be `F^-1 grad` for both."""
    key_x, key_y, key_init, key_sample = jax.random.split(jax.random.key(0), 4)
    n = 200_000  # the sampled G's off-diagonal noise (~2 / sqrt(n)) couples the log-std's dims
    x = jax.random.normal(key_x, (n, 3))
    x = x + 0.5 * x[:, :1] + 0.3
    targets = jax.random.normal(key_y, (n, 2))
    module = GaussianHead()
    params = module.init(key_init, x[:1])
    params = {"params": {**params["params"], "LogStd_0": {"bias": jnp.array([0.3, -0.5])}}}

    def losses(params, perturbations):
        dist, inputs, _ = kfac.capture(module, params, x, perturbations)
        loss = -distributions.log_prob(dist, targets).mean()
        sampled = distributions.sample(key_sample, jax.lax.stop_gradient(dist))
        return (loss, distributions.log_prob(dist, sampled).sum()), inputs

    zeros = kfac.zero_perturbations(module, params, x)
    _, backward, inputs = jax.vjp(losses, params, zeros, has_aux=True)
    grads, _ = backward((1.0, 0.0))
    _, output_grads = backward((0.0, 1.0))
    statistics = kfac.factor_statistics(inputs, output_grads)
    assert set(statistics) == {"Dense_0", "LogStd_0"} == set(kfac._layers(params))
    assert statistics["LogStd_0"][0].shape == (1, 1)  # A = [1]: the constant input

    tx = kfac.kfac(1.0, damping=1e-6, stats_decay=0.9, kl_clip=1e9)
    state = tx.init(params)
    update = jax.jit(lambda g, s: tx.update(g, s, statistics=statistics))
    for _ in range(30):
        natural, state = update(grads, state)

    a = np.concatenate([np.asarray(x, np.float64), np.ones((n, 1))], axis=1)
    variance = np.exp(2 * np.array([0.3, -0.5]))
    dense = grads["params"]["Dense_0"]
    grad_matrix = np.concatenate([np.asarray(dense["kernel"]), np.asarray(dense["bias"])[None]], axis=0)
    exact_mean = np.linalg.solve(a.T @ a / n, grad_matrix) * variance  # A^-1 grad diag(s^2)
    step = natural["params"]["Dense_0"]
    kfac_mean = np.concatenate([np.asarray(step["kernel"]), np.asarray(step["bias"])[None]], axis=0)
    assert np.linalg.norm(kfac_mean - exact_mean) / np.linalg.norm(exact_mean) < 0.03
    exact_log_std = np.asarray(grads["params"]["LogStd_0"]["bias"]) / 2.0
    kfac_log_std = np.asarray(natural["params"]["LogStd_0"]["bias"])
    assert np.linalg.norm(kfac_log_std - exact_log_std) / np.linalg.norm(exact_log_std) < 0.03
    # ... and far from the plain gradient (the test can tell them apart).
    cosine = np.sum(grad_matrix * exact_mean) / (np.linalg.norm(grad_matrix) * np.linalg.norm(exact_mean))
    assert cosine < 0.95, cosine


def test_kl_trust_region_scales_the_step():
    """`lr^2 u^T F u` (twice the step's KL under the K-FAC Fisher F) is `kl_clip` when clipped,
    else less. Here `F = A (x) G = I`."""
    grads = {"params": {"Dense_0": {"kernel": jnp.ones((2, 3)), "bias": jnp.ones(3)}}}
    statistics = {"Dense_0": (jnp.eye(3) * 0.5, jnp.eye(3) * 2.0)}
    for lr, kl_clip, clipped in [(0.25, 1e-3, True), (1e-3, 1.0, False)]:
        tx = kfac.kfac(lr, damping=0.0, stats_decay=0.0, kl_clip=kl_clip, inverse_iterations=30)
        natural, _ = tx.update(grads, tx.init(grads), statistics=statistics)
        kl = lr**2 * sum(float(jnp.vdot(u, u)) for u in jax.tree.leaves(natural))
        if clipped:
            np.testing.assert_allclose(kl, kl_clip, rtol=1e-4)
        else:  # unclipped: exactly (A (x) G)^-1 g = g / (0.5 * 2.0)
            np.testing.assert_allclose(natural["params"]["Dense_0"]["kernel"], 1.0, rtol=1e-4)
            assert kl < kl_clip


def test_refine_inverse_restarts_from_a_bad_warm_start():
    matrix = jnp.diag(jnp.array([1e-3, 1.0, 10.0]))
    inverse = jnp.eye(3) * 5.0  # I - B X has eigenvalue -49: Newton-Schulz would diverge
    for _ in range(12):
        inverse = kfac.refine_inverse(matrix, inverse, 2, jax.random.key(0))
    np.testing.assert_allclose(np.diag(inverse), [1e3, 1.0, 0.1], rtol=1e-3)


def test_unknown_kernel_bias_module_is_a_clear_error():
    class Custom(nn.Module):
        @nn.compact
        def __call__(self, x):
            return x @ self.param("kernel", nn.initializers.ones, (2, 2)) + self.param("bias", nn.initializers.zeros, (2,))

    params = Custom().init(jax.random.key(0), jnp.ones((1, 2)))
    tx = kfac.kfac(0.1, damping=0.01, stats_decay=0.9, kl_clip=1e-3)
    with pytest.raises(ValueError, match="nn.Dense or a ValidConv"):
        tx.update(params, tx.init(params), statistics={})


# --- learning the probes ----------------------------------------------------------------------

# mlp trunk, 4 envs x 8 steps, the ACKTR defaults otherwise (lr 0.25, KL clip 0.001). Over 5
# seeds, sign and two_step were solved (mean return >= 0.95 over 8 updates) by update 63,
# factored by update 122: it gets 192 updates, the others 128.
# The probes check values in reward units: no normalisation (on by default for vector observations).
CONFIG = ACKTRConfig(total_timesteps=4096, num_envs=4, num_steps=8, trunk="mlp", normalize_observations=False,
                     normalize_rewards=False)
BUDGET = {"factored": 6144}


@functools.cache
def trained(probe: str):
    env, params = make_probe(probe)
    learner = make_acktr(CONFIG.replace(total_timesteps=BUDGET.get(probe, 4096)), env, params)
    runner, metrics = _jit(jax.vmap(learner.train))(jax.random.split(jax.random.key(0), SEEDS))
    return learner, runner.train_state.params, jax.tree_util.tree_map(np.asarray, metrics)


def greedy(learner, params, obs):
    logits, _ = jax.vmap(lambda p: learner.network.apply(p, jnp.asarray(obs, jnp.float32)))(params)
    return np.stack([np.asarray(jnp.argmax(l, -1)) for l in logits], axis=-1)


def final_return(metrics, last=10):
    return np.nanmean(metrics["episode_return"][:, -last:], axis=1)


def test_policy_reads_the_observation():
    learner, params, metrics = trained("sign")
    np.testing.assert_array_equal(greedy(learner, params, [[1.0], [-1.0]])[..., 0], [[1, 0]] * SEEDS)
    assert np.all(final_return(metrics) >= 0.9), final_return(metrics)
    assert np.all(np.isfinite(metrics["value_loss"]))


def test_credit_assignment_over_two_steps():
    learner, params, metrics = trained("two_step")
    np.testing.assert_array_equal(greedy(learner, params, [[1.0, 0.0], [-1.0, 0.0]])[..., 0], [[1, 0]] * SEEDS)
    assert np.all(final_return(metrics) >= 0.9), final_return(metrics)


def test_factored_multidiscrete_action():
    learner, params, metrics = trained("factored")
    targets = [(a, b) for a in range(2) for b in range(3)]
    obs = [np.concatenate([np.eye(2)[a], np.eye(3)[b]]) for a, b in targets]
    np.testing.assert_array_equal(greedy(learner, params, obs), np.broadcast_to(targets, (SEEDS, 6, 2)))
    assert np.all(final_return(metrics) >= 0.9), final_return(metrics)


def test_kfac_factors_are_in_the_checkpointed_state():
    learner, _, _ = trained("sign")
    env, params = make_probe("sign")
    runner = jax.eval_shape(learner.init, jax.random.key(0))
    kfac_state = runner.train_state.opt_state[0]
    assert isinstance(kfac_state, kfac.KFACState)
    # mlp trunk, actor and critic each: Dense 1->64, 64->64; policy head 64->2, value head 64->1.
    shapes = {name: (a.shape, g.shape) for name, (a, g) in kfac_state.factors.items()}
    assert sorted(shapes.values()) == sorted([((2, 2), (64, 64)), ((65, 65), (64, 64))] * 2
                                             + [((65, 65), (2, 2)), ((65, 65), (1, 1))])
