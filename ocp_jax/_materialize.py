"""Computing a value once where XLA's CPU backend would compute it in every consumer."""

import jax
import jax.numpy as jnp


@jax.custom_jvp
def materialize(tree, key):
    """Identity on `tree` that makes XLA compute it once and store it.

    XLA duplicates cheap elementwise producers (a curve evaluation is a few hundred
    multiply-adds) into every consumer fusion, and its CPU backend has no multi-output
    fusion. So a curve sampled once and broadcast against many rays would be re-evaluated
    per element, and a Newton step whose F feeds five updated arrays would evaluate F five
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
    groups = {}
    for i, leaf in enumerate(leaves):
        groups.setdefault((leaf.shape, leaf.dtype), []).append(i)
    stacks = [jnp.stack([leaves[i] for i in group]) for group in groups.values()]
    # The loop's condition is its carried flag: true on entry unless the key is NaN (then
    # the loop is skipped, which returns the same values), false after the first trip.
    first = ~jnp.isnan(jnp.ravel(jax.tree.leaves(key)[0])[0])

    def body(carry):
        first, values = carry
        return ~first, [jnp.where(first, v, v + v) for v in values]

    stacks = jax.lax.while_loop(lambda c: c[0], body, (first, stacks))[1]
    for group, stack in zip(groups.values(), stacks):
        for i, leaf in zip(group, stack):
            leaves[i] = leaf
    return jax.tree.unflatten(treedef, leaves)


@materialize.defjvp
def _materialize_jvp(primals, tangents):
    tree, key = primals
    return materialize(tree, key), tangents[0]
