"""The thesis's own pipeline (Sec. 5.4): scipy's SLSQP on the same parameters and
constraints, from each start in turn on the host."""

import sys
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import scipy.optimize
from jaxtyping import Array, Float, PRNGKeyArray

from .._types import RESULTS, where_each
from .problem import (
    AbstractPlacementSolver,
    Problem,
    Solution,
    admissible_tolerance,
    best_start,
    checked_starts,
    sized_for_starts,
)


@eqx.filter_jit
def _loss_and_grad(problem, params):
    return jax.value_and_grad(problem.loss)(params)


@eqx.filter_jit
def _constraint(problem, params, index: int):
    return problem.constraints(params)[index]


@eqx.filter_jit
def _constraint_jacobian(problem, params, index: int):
    return jax.jacrev(lambda p: problem.constraints(p)[index])(params)


class SLSQP(AbstractPlacementSolver):
    """scipy's SLSQP on -Q / L (jit-compiled value and gradient) from each start in turn,
    with the placement's constraints passed to SLSQP.

    **Arguments:** `n_starts`, `starts`, `max_steps` and `tolerance` as for `MultiStart`.
    `num_evaluations` counts SLSQP's calls of the value-and-gradient function.
    """

    n_starts: int = 16
    max_steps: int = 100
    starts: Float[Array, "s k p"] | None = None
    tolerance: float | None = None

    def solve(
        self, problem: Problem, n_cameras: int, key: PRNGKeyArray, progress: bool
    ) -> Solution:
        starts = checked_starts(problem, n_cameras, self.n_starts, self.starts, key)
        problem, valid_start = sized_for_starts(problem, starts)
        shape = starts.shape[1:]

        def host(fn, *extra):
            return lambda x: np.asarray(fn(problem, jnp.asarray(x).reshape(shape), *extra), float)

        constraints = []
        if problem.placement.has_constraints():
            sizes = jax.eval_shape(problem.constraints, starts[0])
            for index, kind in enumerate(("eq", "ineq")):
                if sizes[index].shape[0]:
                    jac = host(_constraint_jacobian, index)
                    constraints.append(
                        {
                            "type": kind,
                            "fun": host(_constraint, index),
                            "jac": lambda x, jac=jac: jac(x).reshape(-1, x.size),
                        }
                    )
        calls = 0

        def fun(x):
            nonlocal calls
            calls += 1
            value, grad = _loss_and_grad(problem, jnp.asarray(x).reshape(shape))
            return float(value), np.asarray(grad, float).ravel()

        clock = time.perf_counter()
        finals, ended, steps, history = [], [], [], []
        for start in np.asarray(starts):
            out = scipy.optimize.minimize(
                fun,
                start.ravel(),
                jac=True,
                method="SLSQP",
                constraints=constraints,
                options={"maxiter": self.max_steps},
            )
            finals.append(out.x.reshape(shape))
            ended.append(out.status)
            steps.append(out.nit)
            best = history[-1][2] if history else -np.inf
            value = -float(out.fun) * float(problem.scale) if np.isfinite(out.fun) else -np.inf
            history.append((time.perf_counter() - clock, calls, max(best, value)))
            if progress:
                seconds, evaluations, best = history[-1]
                print(
                    f"  SLSQP: start {len(history)} of {len(starts)}, {evaluations} "
                    f"evaluations, best Q {best:.6g}, {seconds:.1f} s",
                    file=sys.stderr,
                    flush=True,
                )
        # scipy's SLSQP status: 0 success, 9 iteration limit, others a failure
        ended = np.asarray(ended)
        results = where_each(
            jnp.asarray(ended == 9), RESULTS.max_steps_reached, RESULTS.solver_failed
        )
        results = where_each(jnp.asarray(ended == 0), RESULTS.successful, results)
        results = where_each(valid_start, results, RESULTS.infeasible_start)
        finals = jnp.asarray(np.stack(finals))
        return best_start(
            problem,
            finals,
            results,
            jnp.asarray(steps),
            calls,
            time.perf_counter() - clock,
            history,
            [starts, finals],
            admissible_tolerance(problem.placement, self.tolerance),
        )
