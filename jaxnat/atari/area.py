"""OpenCV's INTER_AREA downscaling, bit-exact and cheaper, fused with the background
compositing: `composite_resize(screens, backgrounds, out, plan)`.

Why: OpenCV resizes 210x160 -> 84x84 (a non-integer scale) with its generic INTER_AREA code, a
scalar float loop that was most of Natural Atari's host work (the "host pieces" lines of
bench/results/natural_atari.md time both). How: area weights are rational, so an output pixel
is `N / D` for an exact integer `N` (`D = 200` at 210x160 -> 84x84); the kernel sums rows, then
columns on the transposed rows, and rounds, redoing OpenCV's float32 sums only at exact ties.
`docs/design.md`, "Compositing and resizing", has the argument; tests/test_atari_area.py and
tests/test_atari.py check it against `cv2.resize`.

A plan exists where OpenCV takes that generic path and the argument holds: downscaling on both
axes, not by integer factors on both (OpenCV's fast integer path rounds differently), output
sides under 1,000 (OpenCV drops overlaps under 1e-3 pixel), `255 D < 2^31` and OpenCV's float32
error `E < 1 / (2D)` (`_opencv_error_bound`; `D` up to a few thousand). `area_plan` returns None
otherwise and callers use `cv2.resize`.

Compositing rides along: a source pixel at gray level 0 takes the background's pixel
(jaxnat.atari.compositor explains why gray 0 is exactly the all-channels-black RGB mask). Passing
the screens themselves as backgrounds composites nothing.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numba
import numpy as np

__all__ = ["AreaPlan", "area_plan", "check_out", "check_screens", "composite_resize", "kernel_arguments"]

_MAX_SIDE = 1000  # OpenCV drops overlaps under 1e-3 source pixel; 1/m stays above that


@dataclass(frozen=True, eq=False)
class AreaPlan:
    """The weights of one `src -> dst` INTER_AREA downscale (`area_plan` builds it).

    Exact integer weights: output row `r` sums source rows `y_first[r] + k` with weights
    `y_weights[r, k]`, output column `j` sums columns `x_first[j] + k` with `x_weights[j, k]`
    (zero-padded to a fixed tap count); an output is `round(N / denominator)`.
    OpenCV's float32 weights, for ties: `{x,y}_tab_source/alpha[i, k]`, `{x,y}_tab_count[i]`.
    """

    src_shape: tuple[int, int]
    dst_shape: tuple[int, int]
    denominator: int
    sum_dtype: type
    y_first: np.ndarray
    y_weights: np.ndarray
    x_first: np.ndarray
    x_weights: np.ndarray
    y_tab_source: np.ndarray
    y_tab_alpha: np.ndarray
    y_tab_count: np.ndarray
    x_tab_source: np.ndarray
    x_tab_alpha: np.ndarray
    x_tab_count: np.ndarray


def _integer_taps(n: int, m: int) -> tuple[np.ndarray, np.ndarray, int]:
    """Exact area weights of an `n -> m` axis: first source index and consecutive integer
    weights per output (zero-padded, kept inside the axis), and their common sum."""
    overlaps = np.zeros((m, n), np.int64)  # in units of 1/m source pixel
    for j in range(m):
        lo, hi = n * j, n * (j + 1)
        first, last = lo // m, (hi - 1) // m
        for i in range(first, last + 1):
            overlaps[j, i] = min(hi, m * (i + 1)) - max(lo, m * i)
    overlaps //= np.gcd.reduce(overlaps.ravel())
    starts = np.array([np.flatnonzero(row)[0] for row in overlaps])
    taps = max(int(np.flatnonzero(row)[-1] - s) + 1 for row, s in zip(overlaps, starts, strict=True))
    first = np.minimum(starts, n - taps)
    weights = np.stack([row[f:f + taps] for row, f in zip(overlaps, first, strict=True)])
    return first.astype(np.int64), weights, int(overlaps[0].sum())


def _opencv_tab(n: int, m: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """OpenCV's `computeResizeAreaTab` for an `n -> m` axis (double arithmetic, float32 weights,
    in its order), as `(source[m, K], alpha[m, K], count[m])`."""
    scale = 1.0 / (m / n)  # cv::resize: scale = 1 / inv_scale, inv_scale = dsize / ssize
    entries: list[list[tuple[int, np.float32]]] = []
    for d in range(m):
        f1 = d * scale
        f2 = f1 + scale
        cell = min(scale, n - f1)
        s2 = min(math.floor(f2), n - 1)
        s1 = min(math.ceil(f1), s2)
        row = []
        if s1 - f1 > 1e-3:
            row.append((s1 - 1, np.float32((s1 - f1) / cell)))
        row += [(s, np.float32(1.0 / cell)) for s in range(s1, s2)]
        if f2 - s2 > 1e-3:
            row.append((s2, np.float32(min(f2 - s2, 1.0, cell) / cell)))
        entries.append(row)
    k = max(len(row) for row in entries)
    source = np.zeros((m, k), np.int64)
    alpha = np.zeros((m, k), np.float32)
    for d, row in enumerate(entries):
        for t, (s, a) in enumerate(row):
            source[d, t], alpha[d, t] = s, a
    return source, alpha, np.array([len(row) for row in entries], np.int64)


def _opencv_error_bound(x_taps: int, y_taps: int) -> float:
    """A bound on |OpenCV's float32 area mean - the exact mean| for pixels <= 255 and at most
    `x_taps` x `y_taps` source pixels an output. Recursive float32 sums of `n` rounded products
    are within `n u` (relative, `u = 2^-24`) of the exact dot product (Higham, Accuracy and
    Stability of Numerical Algorithms, 3.1); the float32 weights add `u`, once per axis, and the
    rows' errors carry into the columns' sum: `255 u (x_taps + y_taps + 2)`, plus `2 u` margin
    for second-order terms and OpenCV's double-precision weights."""
    return 255 * 2.0**-24 * (x_taps + y_taps + 4)


def area_plan(src_shape, dst_shape) -> AreaPlan | None:
    """The plan for `src_shape -> dst_shape` (rows, columns), or None where the kernel would not
    be OpenCV's result bit for bit (see the module docstring) and `cv2.resize` should run."""
    return _area_plan(tuple(map(int, src_shape)), tuple(map(int, dst_shape)))


@functools.lru_cache(maxsize=16)
def _area_plan(src_shape: tuple[int, int], dst_shape: tuple[int, int]) -> AreaPlan | None:
    (h_in, w_in), (h, w) = src_shape, dst_shape
    if not (0 < h <= h_in and 0 < w <= w_in) or max(h, w) >= _MAX_SIDE:
        return None
    if h_in % h == 0 and w_in % w == 0:
        return None  # OpenCV's integer-factor path
    y_first, y_weights, dy = _integer_taps(h_in, h)
    x_first, x_weights, dx = _integer_taps(w_in, w)
    tabs = (*_opencv_tab(h_in, h), *_opencv_tab(w_in, w))
    denominator = dy * dx
    error = _opencv_error_bound(int(tabs[5].max()), int(tabs[2].max()))
    if 255 * denominator >= 2**31 or 2 * denominator * error >= 1:
        return None
    sum_dtype = np.uint16 if 255 * denominator < 2**16 else np.uint32
    arrays = (y_first, y_weights.astype(sum_dtype), x_first, x_weights.astype(sum_dtype), *tabs)
    for array in arrays:  # shared by every caller of the cached plan
        array.setflags(write=False)
    return AreaPlan((h_in, w_in), (h, w), denominator, sum_dtype, *arrays)


def composite_resize(screens: np.ndarray, backgrounds: np.ndarray, out: np.ndarray,
                     plan: AreaPlan) -> np.ndarray:
    """`out[i] = cv2.resize(where(screens[i] == 0, backgrounds[i], screens[i]), INTER_AREA)`,
    bit for bit, for `uint8[B, H, W]` screens and backgrounds (`backgrounds=screens`: no
    compositing) into C-contiguous `uint8[B, h, w]` `out`. Releases the GIL."""
    b = check_screens(screens, backgrounds, plan)
    _kernel(screens, backgrounds, check_out(out, (b, *plan.dst_shape)), *kernel_arguments(plan))
    return out


def check_out(out: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """`out`, checked to be a C-contiguous `uint8[shape]` that can be written in place (OpenCV
    would copy a non-contiguous one and the result would be lost); raises `ValueError`."""
    if out.shape != shape or out.dtype != np.uint8 or not out.flags.c_contiguous:
        raise ValueError(f"out must be a C-contiguous uint8 array of shape {shape}, got "
                         f"{out.dtype} {out.shape} (contiguous: {out.flags.c_contiguous})")
    return out


def check_screens(screens: np.ndarray, backgrounds: np.ndarray, plan: AreaPlan, batch: int | None = None) -> int:
    """The batch size of `screens` and `backgrounds`, which must both be `uint8[batch, H, W]`
    at the plan's source size (any batch for None); raises `ValueError` otherwise."""
    b = screens.shape[0] if batch is None and screens.ndim == 3 else batch
    if (screens.shape != (b, *plan.src_shape) or backgrounds.shape != screens.shape
            or screens.dtype != np.uint8 or backgrounds.dtype != np.uint8):
        raise ValueError(f"screens and backgrounds must be uint8[{'B' if batch is None else batch}, "
                         f"{plan.src_shape[0]}, {plan.src_shape[1]}], got {screens.dtype} {screens.shape} "
                         f"and {backgrounds.dtype} {backgrounds.shape}")
    return b


def kernel_arguments(plan: AreaPlan) -> tuple:
    """The arguments of `_kernel` after `(screens, backgrounds, out)`, from `plan`."""
    # floor(total / denominator) as total * reciprocal, not an int division (tens of cycles, 7k
    # times an image). Exact with the reciprocal rounded up: for total = k D + j (0 <= j < D),
    # total * reciprocal lies in [k, k + 1) with ~2^-44 to spare (1/D rounded to nearest would
    # put k D just below k: 49 * (1/49) < 1).
    reciprocal = float(np.nextafter(1.0 / plan.denominator, np.inf))
    return (plan.denominator, reciprocal, np.zeros(1, plan.sum_dtype),
            plan.y_first, plan.y_weights, plan.x_first, plan.x_weights,
            plan.y_tab_source, plan.y_tab_alpha, plan.y_tab_count,
            plan.x_tab_source, plan.x_tab_alpha, plan.x_tab_count)


@numba.njit(nogil=True, boundscheck=False, cache=True)
def _kernel(screens, backgrounds, out, denominator, reciprocal, dtype_of_sums, y_first,
            y_weights, x_first, x_weights, y_src, y_alpha, y_count, x_src, x_alpha,
            x_count):  # pragma: no cover
    # Per image: composite; weighted sums of source rows (one per output row), stored
    # transposed; weighted sums of those columns; round; fix ties. Loops are written so that
    # LLVM vectorises them: inner loops run over contiguous rows with few pointers, and the
    # mask is arithmetic (a data-dependent branch per pixel keeps the loop from vectorising).
    n_rows, n_cols = screens.shape[1], screens.shape[2]
    h, w = out.shape[1], out.shape[2]
    sum_type = dtype_of_sums.dtype
    row = np.empty(n_cols, sum_type)
    rows_t = np.empty((n_cols, h), sum_type)  # rows pass, transposed: columns are contiguous
    sums_t = np.empty((w, h), sum_type)
    values_t = np.empty((w, h), np.uint8)
    ties_in_column = np.empty(w, np.int64)
    half = np.int32(denominator // 2)
    denominator = np.int32(denominator)
    ties_possible = denominator % 2 == 0
    composited = np.empty((n_rows, n_cols), np.uint8)
    for b in range(screens.shape[0]):
        screen = screens[b]
        background = backgrounds[b]
        for i in range(n_rows):
            src = screen[i]
            bg = background[i]
            dst = composited[i]
            for c in range(n_cols):
                dst[c] = src[c] + (src[c] == 0) * bg[c]
        for r in range(h):
            _weighted_rows(row, composited, y_first[r], y_weights[r])
            for c in range(n_cols):
                rows_t[c, r] = row[c]
        for j in range(w):
            _weighted_rows(sums_t[j], rows_t, x_first[j], x_weights[j])
        for j in range(w):  # round, vectorised over the contiguous sums of column j
            sums = sums_t[j]
            values = values_t[j]
            ties = 0
            for r in range(h):
                total = np.int32(sums[r]) + half
                value = np.int32(total * reciprocal)
                values[r] = value
                ties += total == value * denominator
            ties_in_column[j] = ties
        image = out[b]
        for r in range(h):
            for j in range(w):
                image[r, j] = values_t[j, r]
        if not ties_possible:
            continue
        for j in range(w):
            if ties_in_column[j]:
                for r in range(h):
                    if np.int32(sums_t[j, r]) + half == np.int32(values_t[j, r]) * denominator:
                        image[r, j] = _opencv_float_pixel(composited, r, j, y_src, y_alpha,
                                                          y_count, x_src, x_alpha, x_count)


@numba.njit(nogil=True, boundscheck=False, cache=True, inline="always")
def _weighted_rows(out, matrix, first, weights):  # pragma: no cover
    """`out = sum_k weights[k] * matrix[first + k]`: a weighted sum of consecutive rows (zero
    weights, padding, skipped)."""
    for k in range(weights.shape[0]):
        weight = weights[k]
        source = matrix[first + k]
        if k == 0:
            for c in range(out.shape[0]):
                out[c] = weight * source[c]
        elif weight != 0:
            for c in range(out.shape[0]):
                out[c] += weight * source[c]


@numba.njit(nogil=True, boundscheck=False, cache=True, inline="always")
def _opencv_float_pixel(image, r, j, y_src, y_alpha, y_count, x_src, x_alpha,
                        x_count):  # pragma: no cover
    """Output pixel `(r, j)` of `image` as OpenCV's generic INTER_AREA computes it: per source
    row, the float32 sum of `pixel * alpha` over the row's taps in order; then the float32 sum
    of `beta * row_sum` over the rows in order (the first one assigned); rounded half to even."""
    total = np.float32(0)
    for ty in range(y_count[r]):
        sy = y_src[r, ty]
        row_sum = np.float32(0)
        for tx in range(x_count[j]):
            row_sum = row_sum + np.float32(image[sy, x_src[j, tx]]) * x_alpha[j, tx]
        if ty == 0:
            total = y_alpha[r, ty] * row_sum
        else:
            total = total + y_alpha[r, ty] * row_sum
    return np.int64(np.rint(total))


# -- the parallel host pass (jaxnat.atari.hostpass) -------------------------------------------
# Kept in this file with `_kernel`: numba's on-disk cache of a function is invalidated only when
# that function's own file changes, so a caller cached in another file would go on running an
# old `_kernel` after it is edited.


@numba.njit(parallel=True, nogil=True, boundscheck=False, cache=True)
def parallel_pass(screens, backgrounds, ring, slots, obs, chunks, denominator, reciprocal,
                  dtype_of_sums, y_first, y_weights, x_first, x_weights, y_src, y_alpha, y_count,
                  x_src, x_alpha, x_count):  # pragma: no cover
    """`_kernel` of `screens`/`backgrounds` into the ring's newest slot (`slots[-1]`), then
    the stacks interleaved into `obs`, over `chunks` contiguous chunks of envs in parallel.
    Unchecked: call it through `jaxnat.atari.hostpass.composite_resize_stack`."""
    b = screens.shape[0]
    newest = ring[slots[slots.shape[0] - 1]]
    for chunk in numba.prange(chunks):
        lo, hi = chunk * b // chunks, (chunk + 1) * b // chunks
        _kernel(screens[lo:hi], backgrounds[lo:hi], newest[lo:hi], denominator, reciprocal,
                dtype_of_sums, y_first, y_weights, x_first, x_weights, y_src, y_alpha, y_count,
                x_src, x_alpha, x_count)
        _interleave(ring, slots, lo, hi, obs)


@numba.njit(nogil=True, boundscheck=False, cache=True)
def _interleave(ring, slots, lo, hi, obs):  # pragma: no cover
    """`obs[i, :, :, k] = ring[slots[k], i]` for envs `lo <= i < hi`: the frame stack's
    channels-last observation, oldest first."""
    # Writes whole output rows; with 4 frames the four sources are named so that LLVM
    # vectorises the interleave (a loop over frames inside the pixel loop does not vectorise).
    depth, h, w = slots.shape[0], ring.shape[2], ring.shape[3]
    rows = obs.reshape(obs.shape[0], h, w * depth)
    for i in range(lo, hi):
        for r in range(h):
            out = rows[i, r]
            if depth == 4:
                a, b, c, d = (ring[slots[0], i, r], ring[slots[1], i, r], ring[slots[2], i, r],
                              ring[slots[3], i, r])
                for x in range(w):
                    out[4 * x] = a[x]
                    out[4 * x + 1] = b[x]
                    out[4 * x + 2] = c[x]
                    out[4 * x + 3] = d[x]
            else:
                for k in range(depth):
                    source = ring[slots[k], i, r]
                    for x in range(w):
                        out[depth * x + k] = source[x]
