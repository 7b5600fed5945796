"""Reductions that XLA's CPU backend computes in one kernel.

The CPU backend rewrites a reduction over more than 32 elements into a windowed reduction
and a reduction of the windows (XLA's TreeReductionRewriter), and the windowed one fuses
with neither its elementwise producer nor its consumer: three kernels where one would do.
The grids of the built-in scenes are longer than that (the banana's 36 cells, 37 nodes).
Folding the reduced axis in halves first, with the reduction's own elementwise operation,
keeps every reduction at most 32 long, and the folds fuse into the reduction's kernel.

A short sort is two such reductions (`sorted_rows`).
"""

from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

_LONGEST = 32  # XLA's CPU backend splits longer reductions
# Each reduction's elementwise operation, and whether it is idempotent (op(a, a) = a), so
# that an odd axis may fold onto itself with one element in both halves.
_FOLDS = {
    jnp.sum: (jnp.add, False),
    jnp.max: (jnp.maximum, True),
    jnp.min: (jnp.minimum, True),
    jnp.any: (jnp.logical_or, True),
    jnp.all: (jnp.logical_and, True),
}


def fused_reduce(
    reduction: Callable[..., Array], x: Array, axis: int | tuple[int, ...] | None = -1
) -> Array:
    """`reduction(x, axis)` for `reduction` one of jnp.sum, max, min, any and all, over
    one axis, several or all (None), in one kernel on XLA's CPU backend: the reduced axes
    are merged into one and folded in halves (a_i op a_(i + n/2)) until it is at most 32
    long. (A sum of booleans counts them, as jnp.sum does.)"""
    combine, idempotent = _FOLDS[reduction]
    x = jnp.asarray(x)
    if reduction is jnp.sum and x.dtype == jnp.bool_:
        x = x.astype(int)
    axes = tuple(range(x.ndim)) if axis is None else np.atleast_1d(axis).tolist()
    axes = [a % x.ndim for a in axes]
    kept = [a for a in range(x.ndim) if a not in axes]
    x = jnp.transpose(x, kept + axes).reshape([x.shape[a] for a in kept] + [-1])
    while x.shape[-1] > _LONGEST:
        n = x.shape[-1]
        if n % 2 and not idempotent:
            x = jnp.pad(x, [(0, 0)] * (x.ndim - 1) + [(0, 1)])
            n += 1
        half = (n + 1) // 2
        x = combine(x[..., :half], x[..., n - half :])
    return reduction(x, axis=-1)


_COUNTED = 64  # the longest rows sorted by counting (n^2 comparisons each)


def sorted_rows(x: Float[Array, "*batch n"], labels: Int[Array, "*batch n"] | None = None):
    """`jnp.sort(x, axis=-1)` for x without NaN, stable; with `labels` (integers of x's
    shape), the pair (sorted x, the labels in the same order). Rows of at most 64
    entries are sorted from two reductions: the rank of x_i counts the x_j before it
    (x_j < x_i, or x_j = x_i with j < i), and the k-th sorted value is the x_i of rank k.
    XLA's CPU sort is a kernel of its own that calls a comparator per comparison; for the
    few dozen events of a curve seen by one camera the n^2 comparisons of the counts fuse
    into two short kernels (longer rows, the union of several cameras' events, keep
    `lax.sort`: there the counts made value+grad slower). Differentiable as `jnp.sort`
    (the ranks are constant)."""
    n = x.shape[-1]
    if n > _COUNTED:
        if labels is None:
            return jnp.sort(x, axis=-1)
        return jax.lax.sort((x, labels), dimension=x.ndim - 1, is_stable=True, num_keys=1)
    index = jnp.arange(n).reshape((1,) * x.ndim + (n,))  # (..., 1, n): j or i
    row = jnp.arange(n).reshape((1,) * (x.ndim - 1) + (n, 1))  # (..., n, 1): i or k
    xi, xj = x[..., :, None], x[..., None, :]
    before = (xj < xi) | ((xj == xi) & (index < row))  # [..., i, j]: x_j before x_i
    rank = fused_reduce(jnp.sum, before)
    of_rank = rank[..., None, :] == row  # [..., k, i]: x_i has rank k
    values = fused_reduce(jnp.sum, jnp.where(of_rank, x[..., None, :], 0.0))
    if labels is None:
        return values
    return values, fused_reduce(jnp.sum, jnp.where(of_rank, labels[..., None, :], 0))
