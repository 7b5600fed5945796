"""Gauss-Legendre quadrature on moving intervals, differentiated by the Leibniz rule.

For intervals [a, b] whose ends depend on parameters theta (event times),

    d/dtheta int_a^b f(t; theta) dt = int_a^b df/dtheta dt + f(b) db/dtheta - f(a) da/dtheta

(the thesis's Eq. 5.9). The rule is the derivative of the exact integral, evaluated with
the same quadrature; it needs f at the interval ends instead of df/dt at every node, so
reverse mode does not differentiate the curves with respect to their parameter t.
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .jvp import is_zero, perturbed_jvp


def _nodes(start, end, order: int):
    nodes, weights = np.polynomial.legendre.leggauss(order)
    shape = (1,) * start.ndim + (order,)
    nodes = jnp.asarray(nodes, start.dtype).reshape(shape)
    weights = jnp.asarray(weights, start.dtype).reshape(shape)
    half = 0.5 * (end - start)
    return start[..., None] + half[..., None] * (nodes + 1.0), weights, half


@functools.partial(jax.custom_jvp, nondiff_argnums=(0, 4))
def gauss_legendre(
    f, start: Float[Array, "*intervals"], end: Float[Array, "*intervals"], args, order: int
) -> Float[Array, "*intervals"]:
    """int_start^end f(t, args) dt on every interval, with `order` Gauss-Legendre nodes.

    `f(t, args)` maps parameters t of shape `start.shape + (g,)` (g = order, or 1 at the
    ends) to values of the same shape. Differentiable in `start`, `end` and `args`.
    """
    t, weights, half = _nodes(start, end, order)
    return half * jnp.sum(weights * f(t, args), -1)


@functools.partial(gauss_legendre.defjvp, symbolic_zeros=True)
def _gauss_legendre_jvp(f, order, primals, tangents):
    start, end, args = primals
    dstart, dend, dargs = tangents
    t, weights, half = _nodes(start, end, order)
    values, dvalues = perturbed_jvp(lambda a: f(t, a), args, dargs)
    integral = half * jnp.sum(weights * values, -1)
    derivative = half * jnp.sum(weights * dvalues, -1)
    if not (is_zero(dstart) and is_zero(dend)):  # the moving ends (Eq. 5.9)
        at_start, at_end = jnp.unstack(f(jnp.stack([start, end], -1), args), axis=-1)
        if not is_zero(dend):
            derivative = derivative + at_end * dend
        if not is_zero(dstart):
            derivative = derivative - at_start * dstart
    return integral, derivative
