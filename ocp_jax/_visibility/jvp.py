"""Forward-mode derivatives in the package's `custom_jvp` rules, over perturbed inputs only.

A `custom_jvp` rule defined with `symbolic_zeros=True` receives a `SymbolicZero` for
every input that carries no tangent: under `jax.grad` with respect to the cameras the
whole scene is such an input. With the default `symbolic_zeros=False` those tangents
arrive as arrays of zeros, and the rule's `jax.jvp` differentiates the curves with respect
to their control points on them: code that is traced, lowered and only then removed by
XLA (about 10% of the jaxpr of value+grad with respect to the cameras).
"""

import jax
from jax.custom_derivatives import SymbolicZero


def is_zero(tangent) -> bool:
    return isinstance(tangent, SymbolicZero)


def perturbed_jvp(fn, primals, tangents, has_aux: bool = False):
    """`jax.jvp(fn, (primals,), (tangents,), has_aux)` for a pytree `primals` whose
    tangent leaves may be symbolic zeros: those leaves are held constant."""
    leaves, treedef = jax.tree.flatten(primals)
    tangent_leaves = treedef.flatten_up_to(tangents)
    live = [not is_zero(d) for d in tangent_leaves]

    def of_live(*live_leaves):
        fill = iter(live_leaves)
        full = [next(fill) if keep else leaf for leaf, keep in zip(leaves, live)]
        return fn(jax.tree.unflatten(treedef, full))

    live_primals = [leaf for leaf, keep in zip(leaves, live) if keep]
    live_tangents = [d for d, keep in zip(tangent_leaves, live) if keep]
    return jax.jvp(of_live, live_primals, live_tangents, has_aux=has_aux)
