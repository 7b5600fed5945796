"""Everything in ocp_jax that is there for XLA's CPU backend, in one module.

XLA's CPU backend runs a value and gradient of Q as a few hundred small kernels
(microseconds each), and some of its choices cost more than the work there:

- it duplicates cheap elementwise producers into every consumer and has no multi-output
  fusion (`materialize`: compute once and store);
- it splits kernels of microseconds between threads (`computed_on_one_thread`,
  `on_one_thread`);
- it splits reductions over more than 32 elements into three kernels (`fused_reduce`),
  and calls a comparator per comparison in a sort (`sorted_rows`);
- its default scheduler interleaves independent kernels where reusing buffers is cheaper
  (`compiler_options`).

Each function here is the plain JAX operation on every other backend (GPU, TPU): the
choice is made from `jax.default_backend()` when the program is traced.
"""

import functools
from collections.abc import Callable
from typing import overload

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .jvp import perturbed_jvp


def on_cpu() -> bool:
    """Whether programs are traced for XLA's CPU backend (the default backend)."""
    return jax.default_backend() == "cpu"


def on_one_thread(count: int, limit: int) -> bool:
    """Whether the kernels of a call with `count` cameras run on one thread
    (`computed_on_one_thread`), static: with at most `limit` cameras they take
    microseconds, and handing half of one to a second thread costs more than it saves.
    Never off the CPU backend."""
    return on_cpu() and count <= limit


def compiler_options() -> dict[str, str]:
    """XLA compile options for programs that evaluate ocp_jax: the CPU backend's
    memory-optimized scheduler (a field of XLA's debug options, which every backend
    accepts and only the CPU compiler reads).

    JAX takes compile options from the outermost `jax.jit` only (a nested jit with options
    is an error), so pass them to the one that wraps ocp_jax in your program:

        jax.jit(jax.vmap(jax.value_and_grad(f)), compiler_options=ocp.compiler_options())

    The batched programs of `ocp.place`'s solvers compile with
    them. `ocp.visibility` and `ocp.visible_intervals`, which run inside users' jits,
    cannot.
    """
    if not on_cpu():
        return {}
    return {"xla_cpu_scheduler_type": "CPU_SCHEDULER_TYPE_MEMORY_OPTIMIZED"}


def jit(fun):
    """`equinox.filter_jit` with `compiler_options()`, for functions that are only ever
    called outside any jit. The options are chosen at the first call or `lower`, when the
    backend is known (not at import)."""

    @functools.cache
    def compiled():
        # (filter_jit passes keywords on to jax.jit; its overloads do not list them)
        return eqx.filter_jit(fun, compiler_options=compiler_options())  # pyright: ignore[reportCallIssue]

    @functools.wraps(fun)
    def call(*args, **kwargs):
        return compiled()(*args, **kwargs)

    call.lower = lambda *args, **kwargs: compiled().lower(*args, **kwargs)  # pyright: ignore[reportAttributeAccessIssue]
    return call


# A vmap over at most this many elements (the cameras of one call) keeps
# `computed_on_one_thread` on one thread; over more (a batch of camera sets) it may split.
SMALL_BATCH = 4


@jax.custom_jvp
def materialize(tree, key):
    """Identity on `tree` that makes XLA compute it once and store it.

    XLA duplicates cheap elementwise producers (a curve evaluation is a few hundred
    multiply-adds) into every consumer fusion, and its CPU backend has no multi-output
    fusion. So a curve sampled once and broadcast against many rays would be re-evaluated
    per element, and a Newton step whose F feeds four updated arrays would evaluate F four
    times (each copy also costs compile time). `optimization_barrier` does not survive the
    CPU pipeline; a while loop whose trip count depends on the data (one trip) does.

    Leaves of one shape and dtype go through the loop stacked: a stack is computed in one
    kernel (one per leaf otherwise).

    **Arguments:**

    - `tree`: the pytree of arrays to compute once.
    - `key`: a pytree whose first leaf is an input of the computation (a scene parameter,
      say), computed before `tree`. The loop's condition reads its first entry: a leaf of
      `tree` there would be one more copy of the computation. Where `key` is not batched
      by `vmap`, the condition is no kernel of its own.
    """
    if not on_cpu():
        return tree
    leaves, treedef = jax.tree.flatten(tree)
    groups = _groups(leaves)

    def body(carry):
        first, values = carry
        return ~first, [jnp.where(first, v, v + v) for v in values]

    stacks = _stacks(leaves, groups)
    # Where the key is NaN the loop is skipped, which returns the same values.
    stacks = jax.lax.while_loop(lambda c: c[0], body, (_first_trip(key), stacks))[1]
    return jax.tree.unflatten(treedef, _unstack(stacks, groups, len(leaves)))


@materialize.defjvp
def _materialize_jvp(primals, tangents):
    tree, key = primals
    return materialize(tree, key), tangents[0]


@functools.partial(jax.custom_jvp, nondiff_argnums=(0,))
def computed_on_one_thread(fn, args, key):
    """fn(*args), computed once (as by `materialize`), each stack of its outputs by a
    kernel on one thread, except under a `vmap` over more than one element.

    XLA's CPU backend splits a kernel between threads where its cost model (flops plus
    ten times the bytes accessed, against 100,000 per thread) says it is worth it. For a
    kernel of microseconds, as in a call with one camera, handing half of it to another
    thread costs more than it saves. XLA never splits a kernel that
    writes into its operand in place (a dynamic_update_slice), so here fn's outputs,
    stacked by shape and dtype as in `materialize`, are written into buffers inside a
    one-trip while loop; fn is evaluated in the loop's body, tied to it by multiplying
    its float inputs by the loop's flag (1 there), so XLA cannot hoist it out. Each stack
    is then one kernel, fn's last operations fused into it (a reduction too); kernels
    fn launches before them may still be split. Under a `vmap` of up to `SMALL_BATCH`
    elements (the cameras of one call) fn is vmapped inside the loop; under a larger one
    (a batch of camera sets) the kernels are large and splitting pays: there fn's
    outputs are only stored (`materialize`).

    **Arguments:**

    - `fn`: a function of `args` returning a pytree of arrays; it is differentiated with
      respect to `args` (pass what it depends on there, not in a closure).
    - `args`: a tuple of pytrees of arrays.
    - `key`: as in `materialize`. Where its first entry is NaN the loop is skipped and
      the outputs are NaN (False, 0 for booleans, integers).
    """
    if not on_cpu():
        return fn(*args)
    in_place = jax.custom_batching.custom_vmap(functools.partial(_in_place, fn))

    @in_place.def_vmap
    def batched(axis_size, in_batched, args, key):
        args_batched, key_batched = in_batched
        if axis_size == 1:  # (the engine's vmap over one camera) in place, unbatched
            first = lambda a, b: a[0] if b else a
            args, key = (
                jax.tree.map(first, args, args_batched),
                jax.tree.map(first, key, key_batched),
            )
            out = in_place(args, key)
            return jax.tree.map(lambda a: a[None], out), jax.tree.map(lambda _: True, out)
        axes = jax.tree.map(lambda b: 0 if b else None, (args_batched, key_batched))
        if axis_size <= SMALL_BATCH:
            vmapped = lambda *a: jax.vmap(fn, in_axes=axes[0], axis_size=axis_size)(*a)
            out = computed_on_one_thread(vmapped, args, key)
            return out, jax.tree.map(lambda _: True, out)
        stored = lambda args, key: materialize(fn(*args), key)
        out = jax.vmap(stored, in_axes=axes, axis_size=axis_size)(args, key)
        return out, jax.tree.map(lambda _: True, out)

    return in_place(args, key)


def _in_place(fn, args, key):
    """fn(*args) written into loop-carried buffers in place (`computed_on_one_thread`)."""
    specs, treedef = jax.tree.flatten(jax.eval_shape(fn, *args))
    groups = _groups(specs)
    # One spare row: a dynamic_update_slice that covers its whole buffer is simplified to
    # its update, which XLA may split again.
    buffers = [
        jnp.full((len(group) + 1, *shape), _blank(dtype), dtype)
        for (shape, dtype), group in groups.items()
    ]

    def body(carry):
        first, buffers = carry
        tie = lambda a: a * first.astype(a.dtype) if _is_float_array(a) else a
        stacks = _stacks(jax.tree.leaves(fn(*jax.tree.map(tie, args))), groups)
        return ~first, [
            jax.lax.dynamic_update_slice(b, s, (0,) * b.ndim) for b, s in zip(buffers, stacks)
        ]

    buffers = jax.lax.while_loop(lambda c: c[0], body, (_first_trip(key), buffers))[1]
    return jax.tree.unflatten(treedef, _unstack(buffers, groups, len(specs)))


def _computed_on_one_thread_jvp(fn, primals, tangents):
    """The tangent of fn along its perturbed inputs only (`perturbed_jvp`)."""
    args, key = primals
    _, out_dot = perturbed_jvp(lambda a: fn(*a), args, tangents[0])
    return computed_on_one_thread(fn, args, key), out_dot


computed_on_one_thread.defjvp(_computed_on_one_thread_jvp, symbolic_zeros=True)


def _first_trip(key):
    """The loop's condition, carried as a flag: true on entry unless the key is NaN (then
    the loop is skipped), false after the first trip."""
    return ~jnp.isnan(jnp.ravel(jax.tree.leaves(key)[0])[0])


def _groups(leaves) -> dict:
    """The indices of the leaves of each (shape, dtype), in order of appearance."""
    groups = {}
    for i, leaf in enumerate(leaves):
        groups.setdefault((leaf.shape, leaf.dtype), []).append(i)
    return groups


def _stacks(leaves, groups):
    return [jnp.stack([leaves[i] for i in group]) for group in groups.values()]


def _unstack(stacks, groups, count):
    leaves = [None] * count
    for group, stack in zip(groups.values(), stacks):
        for row, i in enumerate(group):
            leaves[i] = stack[row]
    return leaves


def _is_float_array(a) -> bool:
    return isinstance(a, jax.Array) and jnp.issubdtype(a.dtype, jnp.inexact)


def _blank(dtype):
    return jnp.nan if jnp.issubdtype(dtype, jnp.inexact) else 0


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
    if not on_cpu():
        return reduction(x, axis=axis)
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


@overload
def sorted_rows(x: Float[Array, "*batch n"], labels: None = None) -> Float[Array, "*batch n"]: ...


@overload
def sorted_rows(
    x: Float[Array, "*batch n"], labels: Int[Array, "*batch n"]
) -> tuple[Float[Array, "*batch n"], Int[Array, "*batch n"]]: ...


def sorted_rows(x, labels=None):
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
    if n > _COUNTED or not on_cpu():
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
