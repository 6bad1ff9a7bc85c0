"""VALID, strided 2-D convolutions for the paper's trunks, fast when vmapped over seeds.

`jit(vmap(train))(keys)` gives every seed its own weights, and XLA turns a convolution vmapped
over its weights into one *grouped* convolution, several times slower than the forms below
(`docs/design.md`, "Convolutions vmapped over seeds", says more):

- `"im2col"`: strided slices and one matmul per layer (a vmapped matmul is a batched matmul),
  chosen on CPU (XLA:CPU's conv gradients are slow inside loops, jax-ml/jax#12868);
- `"native"`: XLA's own convolution, with a batching rule that runs one convolution per weight
  set when the weights are vmapped and folds the batch into the convolution's batch when only
  the inputs are; chosen on GPU, where im2col's patch copies cost more.
- `"grouped"`: `"s2d"`'s rewrite, then XLA's convolution with XLA's own batching rule: under
  `vmap` over the weights, one grouped convolution for all the weight sets (the form the
  module's first paragraph says is slow for training batches; a candidate where the batch
  per weight set is a handful of envs, as Natural Atari's acting call, where one kernel a
  layer beats one per seed: `bench/host_overhead.py` times both).
- `"s2d"`: a strided convolution whose kernel is a multiple of its stride rewritten as a stride-1
  convolution on the space-to-depth input (`space_to_depth`): the Atari trunk's first layer,
  8x8 stride 4 over 4 channels, becomes 2x2 stride 1 over 64 channels, the same sums in the
  same products, in a shape a GPU's tensor cores fill (4 input channels leave them mostly
  idle). The stride-1 convolution is then `"native"`'s. Layers it cannot rewrite (a kernel not
  a multiple of its stride) run `"native"`.
- `"unrolled"`: `"s2d"` with its one convolution per weight set written out in the program
  (a static slice per seed, the outputs stacked) instead of a `lax.map` loop. In a loop each
  iteration copies its seed's operands out of the stacked batch before the convolution reads
  them, and copies the result back; unrolled, XLA can fuse each seed's slice into the
  elementwise work that produces it (the uint8-to-float scaling, the previous layer's bias and
  ReLU) and schedule the seeds' convolutions without the loop.

All compute the same function (tests check values and gradients under vmap); `"auto"` picks by
the backend at trace time: im2col on CPU, unrolled elsewhere (the GPU's pixel-PPO learner is
fastest in that form: 1.75x s2d's, whose loop copies were 43% of its device time;
`bench/results/ppo_learner.md`, `bench/results/pixel_ppo.md`).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

__all__ = ["IMPLEMENTATIONS", "conv2d", "im2col_patches", "space_to_depth"]

IMPLEMENTATIONS = ("auto", "im2col", "native", "s2d", "unrolled", "grouped")
_DIMENSIONS = ("NHWC", "HWIO", "NHWC")


def im2col_patches(x, kh: int, kw: int, stride: int):
    """`[..., H, W, C] -> [..., OH, OW, kh * kw * C]`: the input patch of every output pixel of
    a VALID convolution, in the order of an HWIO kernel reshaped to `[kh * kw * C, features]`
    (K-FAC reads a conv layer's inputs in this form)."""
    oh = (x.shape[-3] - kh) // stride + 1
    ow = (x.shape[-2] - kw) // stride + 1
    return jnp.concatenate(
        [x[..., i : i + stride * (oh - 1) + 1 : stride, j : j + stride * (ow - 1) + 1 : stride, :]
         for i in range(kh) for j in range(kw)],
        axis=-1,
    )


def space_to_depth(x, block: int):
    """`[..., H, W, C] -> [..., H / block, W / block, block * block * C]`: each block x block
    tile of pixels as one pixel of stacked channels (row in tile, column in tile, channel)."""
    *lead, h, w, c = x.shape
    x = x.reshape(*lead, h // block, block, w // block, block, c)
    return jnp.moveaxis(x, -4, -3).reshape(*lead, h // block, w // block, block * block * c)


def _s2d(x, kernel, stride: int, conv=None):
    """A VALID convolution with `kernel` a multiple of `stride`, as a stride-1 convolution on
    `space_to_depth(x, stride)` (output pixel (i, j) reads input rows stride*i + p, p < kh,
    which are rows i + P of the tiled input, P < kh / stride). `conv(x, kernel, stride)`
    computes the convolutions (default: `"native"`'s)."""
    conv = conv or (lambda x, kernel, stride: _native(int(stride))(x, kernel))
    kh, kw, cin, cout = kernel.shape
    if stride == 1 or kh % stride or kw % stride:
        return conv(x, kernel, stride)
    oh, ow = (x.shape[-3] - kh) // stride + 1, (x.shape[-2] - kw) // stride + 1
    # The rows and columns the convolution reads (a multiple of the stride); the rest are cut.
    x = x[..., : stride * (oh - 1) + kh, : stride * (ow - 1) + kw, :]
    tiled = kernel.reshape(kh // stride, stride, kw // stride, stride, cin, cout)
    tiled = jnp.transpose(tiled, (0, 2, 1, 3, 4, 5)).reshape(kh // stride, kw // stride, stride * stride * cin, cout)
    return conv(space_to_depth(x, stride), tiled, 1)


def _im2col(x, kernel, stride: int):
    kh, kw, cin, cout = kernel.shape
    return im2col_patches(x, kh, kw, stride) @ kernel.reshape(kh * kw * cin, cout)


def _xla_conv(x, kernel, stride: int):
    """XLA's convolution over any leading dims of `x` `[..., H, W, C]`."""
    lead = x.shape[:-3]
    y = jax.lax.conv_general_dilated(x.reshape(-1, *x.shape[-3:]), kernel, (stride, stride),
                                     "VALID", dimension_numbers=_DIMENSIONS)
    return y.reshape(*lead, *y.shape[1:])


def _one_per_weight_set(fun, axis_size, in_batched, args, unrolled: bool = False):
    """Batching rule body: `fun` applied to each batch element (unbatched arguments broadcast),
    outputs stacked along axis 0; in a `lax.map` loop, or with `unrolled` one call per element
    written out in the program."""
    if unrolled:
        outputs = [fun(*[a[i] if b else a for a, b in zip(args, in_batched)]) for i in range(axis_size)]
        return jax.tree_util.tree_map(lambda *ys: jnp.stack(ys), *outputs)
    args = [a if b else jnp.broadcast_to(a, (axis_size, *a.shape)) for a, b in zip(args, in_batched)]
    return jax.lax.map(lambda a: fun(*a), args)


@functools.cache
def _native(stride: int, unrolled: bool = False):
    """The `"native"` form for one stride: a custom_vjp whose forward and backward passes carry
    their own batching rules (JAX cannot differentiate through a custom_vmap function itself);
    `unrolled`: the rules' one convolution per weight set written out, not looped."""

    @jax.custom_batching.custom_vmap
    def forward(x, kernel):
        return _xla_conv(x, kernel, stride)

    @forward.def_vmap
    def _forward_rule(axis_size, in_batched, x, kernel):
        x_batched, kernel_batched = in_batched
        if not kernel_batched:  # shared weights: the batch is just more leading dims
            return forward(x, kernel), x_batched
        return _one_per_weight_set(forward, axis_size, in_batched, (x, kernel), unrolled), True

    @jax.custom_batching.custom_vmap
    def backward(x, kernel, grad):
        _, vjp = jax.vjp(functools.partial(_xla_conv, stride=stride), x, kernel)
        return vjp(grad)

    @backward.def_vmap
    def _backward_rule(axis_size, in_batched, x, kernel, grad):
        # Per-element kernel gradients: never fold the batch into one convolution (that would
        # sum them).
        return _one_per_weight_set(backward, axis_size, in_batched, (x, kernel, grad), unrolled), (True, True)

    @jax.custom_vjp
    def conv(x, kernel):
        return forward(x, kernel)

    conv.defvjp(lambda x, kernel: (forward(x, kernel), (x, kernel)),
                lambda residuals, grad: backward(*residuals, grad))
    return conv


def conv2d(x, kernel, stride: int, implementation: str = "auto"):
    """VALID convolution of `x` `[..., H, W, C]` with an HWIO `kernel`, any leading dims.

    `implementation`: `"im2col"`, `"native"`, `"s2d"`, `"unrolled"`, `"grouped"` or `"auto"` (im2col on
    CPU, unrolled elsewhere); see the module docstring for why each exists."""
    if implementation not in IMPLEMENTATIONS:
        raise ValueError(f"conv implementation must be one of {IMPLEMENTATIONS}, got {implementation!r}")
    if implementation == "auto":
        implementation = "im2col" if jax.default_backend() == "cpu" else "unrolled"
    if implementation == "im2col":
        return _im2col(x, kernel, stride)
    if implementation == "s2d":
        return _s2d(x, kernel, int(stride))
    if implementation == "unrolled":
        return _s2d(x, kernel, int(stride), lambda x, kernel, stride: _native(int(stride), True)(x, kernel))
    if implementation == "grouped":
        return _s2d(x, kernel, int(stride), _xla_conv)
    return _native(int(stride))(x, kernel)
