"""The renderer's nearest-hit search as one Pallas kernel: `Renderer(kernel="pallas")`.

The XLA path (`Renderer.nearest` traced as plain `jnp`) leaves the fusion of the unrolled geom
loop to XLA, which may cut it into several kernels that pass `[N, H, W]` intermediates through
memory. This kernel runs the same `Renderer.nearest` code on a block of `BLOCK` pixels of one
frame, keeps them in registers through every geom and writes only the nearest `t` and geom id
(8 bytes a pixel); the normal, the floor texture and the shading stay in XLA, one pass over
those. A geom is skipped for the whole block when its bounding sphere cannot cover the block's
image rows (`Renderer.nearest(rows=...)`; the rows are worked out once per frame and geom, so
the test costs nothing per pixel): each robot part covers a small part of the frame. The
geoms' per-frame terms are read as scalars. Under `vmap` the frames become a grid axis; the
ray directions, the same for every frame, are read by all.

On a CPU (tests) the kernel runs through Pallas' interpreter: same arithmetic, slowly.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax.experimental import pallas as pl

__all__ = ["nearest_hit", "BLOCK", "CULL"]

# Pixels per kernel instance (a power of two, as Triton wants). Smaller blocks cull more geoms,
# until they get too small to keep the GPU busy; 256 was the fastest size for Ant (the block
# sizes compared: bench/results/pixel_mujoco.md).
BLOCK = 256
CULL = True  # skip a geom for a block of rows its bounding sphere cannot cover


def nearest_hit(renderer, terms, d):
    """`(t, geom)`, each `[H, W]`, of the nearest hit along the unit world rays `d` (three
    `[H, W]` arrays) for one frame whose geom terms are `terms [G, NUM_TERMS]`."""
    num_terms = terms.shape[-1]  # render.NUM_TERMS (read from the array: render imports this module)
    shape = d[0].shape
    pixels = int(np.prod(shape))
    padded = -(-pixels // BLOCK) * BLOCK
    rays = [_pad(jnp.ravel(jnp.asarray(c, jnp.float32)), padded) for c in d]
    flat_terms = jnp.ravel(jnp.asarray(terms, jnp.float32))
    flat_terms = _pad(flat_terms, 1 << max(int(flat_terms.shape[0]) - 1, 0).bit_length())

    width = shape[-1]
    cull = CULL

    def kernel(terms_ref, dx_ref, dy_ref, dz_ref, t_ref, g_ref):
        rays = (dx_ref[...], dy_ref[...], dz_ref[...])
        block = pl.program_id(0)
        rows = ((block * BLOCK // width).astype(jnp.float32),
                ((block * BLOCK + BLOCK - 1) // width).astype(jnp.float32)) if cull else None
        t, g = renderer.nearest(lambda geom, k: terms_ref[geom * num_terms + k], rays, rows)
        t_ref[...] = t
        g_ref[...] = g

    pixel_block = pl.BlockSpec((BLOCK,), lambda i: (i,))
    t, g = pl.pallas_call(
        kernel,
        grid=(padded // BLOCK,),
        in_specs=[pl.BlockSpec(flat_terms.shape, lambda i: (0,))] + [pixel_block] * 3,
        out_specs=[pixel_block, pixel_block],
        out_shape=[jax.ShapeDtypeStruct((padded,), jnp.float32),
                   jax.ShapeDtypeStruct((padded,), jnp.int32)],
        interpret=jax.default_backend() == "cpu",
        name="jaxnat_nearest_hit",
    )(flat_terms, *rays)
    return t[:pixels].reshape(shape), g[:pixels].reshape(shape)


def _pad(x, size: int):
    """`x` (1-D) padded with its last value to `size` (rays stay unit; terms are never read)."""
    if x.shape[0] == size:
        return x
    return jnp.concatenate([x, jnp.broadcast_to(x[-1:], (size - x.shape[0],))])
