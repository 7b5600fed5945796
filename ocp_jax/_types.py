"""Types shared across ocp_jax's subpackages."""

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import ArrayLike, Bool


class RESULTS(eqx.Enumeration):
    """How a computation ended: `ocp.visibility(..., throw=False)` for one evaluation of
    Q, `ocp.place` for a placement and each of its starts.

    Compare with `==` (`solution.result == ocp.RESULTS.successful`); the message of an
    item is `ocp.RESULTS[item]`.
    """

    successful = ""
    invalid_cameras = (
        "A camera is NaN, inside an object, on a curve or too close to one, or a root "
        "search near it did not converge: Q is undefined there."
    )
    budget_exceeded = (
        "The events overflowed a budget of VisibilityOptions inside a jit: size the "
        "budgets with ocp.fit_options beforehand."
    )
    max_steps_reached = "The start stopped at the solver's max_steps before converging."
    solver_failed = "The minimiser failed (its line search or trust region made no progress)."
    infeasible_start = (
        "The start is infeasible: a camera inside an object, or where Q is undefined."
    )
    infeasible_end = (
        "The start ended outside the placement's constraints (beyond the tolerance) or "
        "where Q is undefined."
    )


def where_each(pred: Bool[ArrayLike, "..."], a, b):
    """`a` where `pred`, else `b`, element by element, for items `a` and `b` of one
    `equinox.Enumeration` (its `where` takes one scalar predicate; this takes a batch, as
    for the results of many starts)."""
    return jax.tree.map(lambda x, y: jnp.where(pred, x, y), a, b)
