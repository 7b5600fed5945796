"""Computing a value once where XLA's CPU backend would compute it in every consumer, and
on one thread where it would split a small kernel between threads."""

import functools

import jax
import jax.numpy as jnp

from ._jvp import perturbed_jvp

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
    thread costs more than it saves: two such kernels were about a quarter of the
    banana's call on two cores (benchmarks/HISTORY.md). XLA never splits a kernel that
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
