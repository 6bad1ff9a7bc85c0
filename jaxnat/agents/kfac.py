"""A compact K-FAC (Martens & Grosse 2015; KFC for convolutions, Grosse & Martens 2016) for the
layers of jaxnat's networks, as an optax transformation.

Why not kfac-jax, and not Cholesky or eigh for the inverses: `docs/design.md`, "K-FAC of our
own". The pieces here are small so that a fixed kfac-jax can replace `kfac()` without touching
the learner.

K-FAC layers are the ones whose parameters are exactly `{"kernel", "bias"}`: `nn.Dense` and
`ValidConv` (an im2col matmul, so a conv is a dense layer applied at every output pixel), and
those whose parameters are exactly `{"bias"}`: a Gaussian policy's `LogStd`, a layer whose input
is the constant 1 (so `A = [1]` and `G` is the Fisher of the log-std itself), as the authors'
K-FAC treats its `AddBias`. Every other parameter (the goal embedding, the ResNet's
convolutions and GroupNorms) keeps its plain gradient. For a layer with inputs `a` (the im2col
patches for a conv, with a trailing 1 for the bias) and output gradients `g`, the Fisher block
is approximated by `A (x) G`:

    A = mean over examples and output pixels of a a^T
    G = pixels * mean over examples and output pixels of g g^T

where `g` is the gradient of the model's own log-likelihood of a *sampled* output (the true
Fisher, not the empirical one). The factors are running averages (`stats_decay`); each is
damped on its own (factored Tikhonov damping) and its inverse kept up to date by Newton-Schulz
steps (`refine_inverse`: matmuls only, fast on CPU and GPU).

    tx = optax.chain(kfac(lr_schedule, damping=0.01, stats_decay=0.99, kl_clip=0.001),
                     optax.sgd(...))
    (out, value), inputs, outputs = capture(network, params, obs, perturbations)
    ...  # gradients of the loss w.r.t. params; of the sampled log-likelihood w.r.t. perturbations
    updates, opt_state = tx.update(grads, opt_state, params,
                                   statistics=factor_statistics(inputs, output_grads))
"""

from __future__ import annotations

import math
from typing import Any, Callable, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax
from flax import traverse_util

from jaxnat.agents.networks import LogStd, ValidConv, im2col_patches

__all__ = ["KFACState", "capture", "zero_perturbations", "factor_statistics", "damped_factors",
           "refine_inverse", "natural_gradient", "kfac"]

_LAYERS = (nn.Dense, ValidConv, LogStd)


def _name(path: tuple[str, ...]) -> str:
    return "/".join(path)


def capture(network: nn.Module, params, obs, perturbations: dict | None = None):
    """Apply `network` and record what K-FAC needs from each Dense and ValidConv layer.

    Returns `(network output, inputs, outputs)`: `inputs[layer]` is `[examples, pixels, d_in]`
    (the im2col patches for a conv; pixels = 1 for a dense layer; d_in = 0 for a `LogStd`), `outputs[layer]` the layer's
    output. `perturbations[layer]`, shaped like the output, is added to it: the gradient of a
    loss w.r.t. a zero perturbation is the gradient w.r.t. the layer's output.
    Layers are named by their module path joined with "/" (their parameters' path).
    """
    inputs, outputs = {}, {}

    def interceptor(next_fun, args, kwargs, context):
        module = context.module
        if context.method_name != "__call__" or not isinstance(module, _LAYERS):
            return next_fun(*args, **kwargs)
        name = _name(module.path)
        x = args[0]
        out = next_fun(*args, **kwargs)
        if isinstance(module, ValidConv):
            patches = im2col_patches(x, module.kernel, module.kernel, module.stride)
            examples = x.shape[:-3]
            a = patches.reshape(-1, patches.shape[-3] * patches.shape[-2], patches.shape[-1])
        elif isinstance(module, LogStd):  # no input but the bias's constant 1
            examples = x.shape[:-1]
            a = jnp.zeros((math.prod(examples), 1, 0), x.dtype)
        else:
            examples = x.shape[:-1]
            a = x.reshape(-1, 1, x.shape[-1])
        if out.shape[: len(examples)] != examples:
            raise ValueError(f"K-FAC: layer {name} changes the batch shape {examples} to {out.shape}")
        inputs[name] = jax.lax.stop_gradient(a)
        outputs[name] = out
        if perturbations is not None:
            out = out + perturbations[name]
        return out

    with nn.intercept_methods(interceptor):
        result = network.apply(params, obs)
    return result, inputs, outputs


def zero_perturbations(network: nn.Module, params, obs) -> dict:
    """Zeros shaped like every K-FAC layer's output (for `capture`)."""
    shapes = jax.eval_shape(lambda p, o: capture(network, p, o)[2], params, obs)
    return jax.tree_util.tree_map(lambda s: jnp.zeros(s.shape, s.dtype), shapes)


def factor_statistics(inputs: dict, output_grads: dict) -> dict:
    """`{layer: (A, G)}` of one batch: `A` `[d_in + 1]^2` (bias column), `G` `[d_out]^2`.

    `output_grads[layer]` holds per-example gradients (of a loss *summed* over examples)."""
    stats = {}
    for name, a in inputs.items():
        examples, pixels, _ = a.shape
        a = jnp.concatenate([a, jnp.ones((examples, pixels, 1), a.dtype)], axis=-1).reshape(examples * pixels, -1)
        g = output_grads[name].reshape(examples * pixels, -1)
        stats[name] = (a.T @ a / (examples * pixels), pixels * (g.T @ g) / (examples * pixels))
    return stats


def damped_factors(a_factor, g_factor, damping):
    """`(A + pi sqrt(damping) I, G + sqrt(damping) / pi I)`: factored Tikhonov damping with
    Martens & Grosse's `pi = sqrt(mean eig A / mean eig G)` (section 6.3)."""
    d_a, d_g = a_factor.shape[0], g_factor.shape[0]
    pi = jnp.sqrt((jnp.trace(a_factor) / d_a) / jnp.maximum(jnp.trace(g_factor) / d_g, 1e-12))
    pi = jnp.clip(pi, 1e-6, 1e6)
    root = jnp.sqrt(damping)
    return (a_factor + pi * root * jnp.eye(d_a, dtype=a_factor.dtype),
            g_factor + root / pi * jnp.eye(d_g, dtype=g_factor.dtype))


def refine_inverse(matrix, inverse, iterations: int, key):
    """Newton-Schulz steps `X <- X (2I - B X)` towards `B^-1` for a symmetric positive definite
    `B`, warm-started from `inverse` (last update's, for slowly moving factors). The iteration
    converges when the spectral radius of `I - B X` is below 1, estimated here by power iteration; if the
    warm start fails that test it restarts from `X = I / |B|_F` (eigenvalues of `BX` in (0, 1]),
    which converges from below: a partly converged inverse is a more strongly damped one.
    """
    eye = jnp.eye(matrix.shape[0], dtype=matrix.dtype)
    product = matrix @ inverse
    residual = eye - product
    v = jax.random.normal(key, matrix.shape[:1], matrix.dtype)
    v = jax.lax.fori_loop(0, 8, lambda _, v: residual @ (v / jnp.maximum(jnp.linalg.norm(v), 1e-30)), v)
    radius = jnp.linalg.norm(v)  # of the last unit vector's image: about the spectral radius
    warm = (radius < 1.0) & jnp.all(jnp.isfinite(inverse))
    scale = 1.0 / jnp.linalg.norm(matrix)
    inverse = jnp.where(warm, inverse, scale * eye)
    product = jnp.where(warm, product, scale * matrix)
    for i in range(iterations):
        inverse = 2.0 * inverse - inverse @ product
        inverse = 0.5 * (inverse + inverse.T)
        if i + 1 < iterations:
            product = matrix @ inverse
    return inverse


def natural_gradient(a_inverse, g_inverse, grad):
    """`A^-1 grad G^-1` for `grad` `[d_in + 1, d_out]`: `(A (x) G)^-1` applied to it."""
    return a_inverse @ grad @ g_inverse


class KFACState(NamedTuple):
    count: jax.Array  # updates done (int32)
    factors: dict  # {layer: (A, G)}, running averages
    inverses: dict  # {layer: (A^-1, G^-1)} of the damped factors, refined every update


def _layers(params) -> dict[str, tuple[tuple | None, tuple]]:
    """`{layer: (kernel key, bias key)}` in the flattened params, for `{"kernel", "bias"}` modules,
    and `{layer: (None, bias key)}` for `{"bias"}` ones (`LogStd`). The layer name drops the
    leading "params" collection (as module paths do)."""
    flat = traverse_util.flatten_dict(params)
    layers = {}
    for key in flat:
        if key[-1] != "bias":
            continue
        siblings = {k[-1] for k in flat if k[:-1] == key[:-1]}
        if siblings in ({"kernel", "bias"}, {"bias"}):
            layers[_name(key[1:-1])] = (key[:-1] + ("kernel",) if "kernel" in siblings else None, key)
    return layers


def kfac(learning_rate: Callable[[jax.Array], jax.Array] | float, *, damping, stats_decay, kl_clip,
         inverse_iterations: int = 2) -> optax.GradientTransformationExtraArgs:
    """Natural gradients with a KL trust region (ACKTR's step-size rule).

    `update(grads, state, params, statistics=factor_statistics(...))` returns the
    preconditioned gradients scaled by `min(1, sqrt(kl_clip / (lr^2 g^T F^-1 g)))`, so the step
    `lr * update` changes the policy by about `kl_clip` in KL at most. Chain it with the
    learning rate and momentum (`optax.sgd`). The first update's statistics initialise the
    factors; later ones enter a running average with weight `1 - stats_decay`. The damped
    factors' inverses are refined by `inverse_iterations` Newton-Schulz steps per update
    (`refine_inverse`): after a cold start (the first updates) they converge within about ten
    updates, meanwhile damping low-curvature directions more strongly (as ACKTR's "cold" steps).
    """
    schedule = learning_rate if callable(learning_rate) else (lambda _: learning_rate)

    def init(params) -> KFACState:
        flat = traverse_util.flatten_dict(params)
        factors = {}
        for name, (kernel, bias) in _layers(params).items():
            inputs = 0 if kernel is None else math.prod(flat[kernel].shape[:-1])
            dtype = flat[bias].dtype
            factors[name] = (jnp.eye(inputs + 1, dtype=dtype), jnp.eye(flat[bias].shape[-1], dtype=dtype))
        return KFACState(jnp.zeros((), jnp.int32), factors, factors)

    def update(grads, state: KFACState, params=None, *, statistics: dict, **_) -> tuple[Any, KFACState]:
        del params
        if set(statistics) != set(state.factors):
            raise ValueError(
                f"K-FAC: statistics for layers {sorted(statistics)} but the parameters have "
                f"K-FAC layers {sorted(state.factors)}; every module with exactly a kernel and a bias "
                f"must be an nn.Dense or a ValidConv, and one with only a bias a LogStd (see jaxnat.agents.kfac)."
            )
        first = state.count == 0
        key = jax.random.fold_in(jax.random.key(0x4B464143), state.count)
        factors, inverses = {}, {}
        for index, name in enumerate(sorted(state.factors)):
            factors[name] = tuple(jnp.where(first, new, stats_decay * old + (1.0 - stats_decay) * new)
                                  for old, new in zip(state.factors[name], statistics[name]))
            keys = jax.random.split(jax.random.fold_in(key, index))
            inverses[name] = tuple(refine_inverse(m, x, inverse_iterations, k) for m, x, k in
                                   zip(damped_factors(*factors[name], damping), state.inverses[name], keys))
        flat = traverse_util.flatten_dict(grads)
        for name, (kernel_key, bias_key) in _layers(grads).items():
            bias = flat[bias_key]
            rows = [] if kernel_key is None else [flat[kernel_key].reshape(-1, bias.shape[-1])]
            natural = natural_gradient(*inverses[name], jnp.concatenate([*rows, bias[None]], axis=0))
            if kernel_key is not None:
                flat[kernel_key] = natural[:-1].reshape(flat[kernel_key].shape)
            flat[bias_key] = natural[-1]
        natural = traverse_util.unflatten_dict(flat)
        lr = schedule(state.count)
        quadratic = sum(jnp.vdot(n, g) for n, g in zip(jax.tree.leaves(natural), jax.tree.leaves(grads)))
        scale = jnp.minimum(1.0, jnp.sqrt(kl_clip / jnp.maximum(lr**2 * quadratic, 1e-20)))
        natural = jax.tree.map(lambda n: n * scale, natural)
        return natural, KFACState(state.count + 1, factors, inverses)

    return optax.GradientTransformationExtraArgs(init, update)
