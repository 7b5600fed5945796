"""Constrained, batched multi-start maximisation of Q (the thesis's Eq. 3.16, Sec. 5.4).

    maximise Q(C(params))  over the parameters of a placement,  subject to
    e(C) = 0 and h(C) >= 0  (the placement's `constraints`, where it has any).

All starts advance together: one jit-compiled, vmapped step of an optimistix minimiser
(BFGS by default) on f = -Q / L (L: the scene's total length, so f is O(1)), laid out
over every available device along the batch of starts. The steps run in short chunks
under a `lax.while_loop` so that progress can be reported and the best value recorded
against time and evaluations (the anytime curve).

Constraints that the parametrisation does not enforce use the augmented Lagrangian of
Powell-Hestenes-Rockafellar, an outer loop around the inner minimiser:

    L(p; lam, mu) = f + lam . e + mu/2 |e|^2 + 1/(2 mu) sum (max(0, nu - mu h)^2 - nu^2),

    lam <- lam + mu e,   nu <- max(0, nu - mu h),   mu <- 10 mu unless the violation
    fell below a quarter of the last one.

Placements where Q is undefined (a camera inside or on an object) give f = NaN, which
the line search rejects: the solver steps back.
"""

import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, Float, PRNGKeyArray

from .._types import RESULTS, where_each
from .._visibility.xla_cpu import jit
from .problem import (
    AbstractPlacementSolver,
    Problem,
    Solution,
    admissible_tolerance,
    best_start,
    checked_starts,
    sized_for_starts,
)

_NO_TAGS = frozenset()


def _where_done(done, old, new):
    """Per start: `old` where done, else `new` (leaves batched along axis 0)."""

    def pick(a, b):
        return jnp.where(done.reshape(done.shape + (1,) * (a.ndim - 1)), a, b)

    return jax.tree.map(pick, old, new)


@jit
def _init(minimiser, problem, params, multipliers, penalty):
    def one(y, lam_nu, mu):
        f_struct = jax.ShapeDtypeStruct((), y.dtype)
        return minimiser.init(problem.merit, y, (lam_nu, mu), {}, f_struct, None, _NO_TAGS)

    return jax.vmap(one)(params, multipliers, penalty)


@jit
def _advance(minimiser, problem, carry, multipliers, penalty, n_steps, max_steps):
    """Up to `n_steps` steps of every start that has not stopped. `carry` = (params,
    solver state, done, steps, stopped, optimistix result)."""

    def step(y, state, lam_nu, mu):
        args = (lam_nu, mu)
        y, state, _ = minimiser.step(problem.merit, y, args, {}, state, _NO_TAGS)
        stop, result = minimiser.terminate(problem.merit, y, args, {}, state, _NO_TAGS)
        return y, state, stop, result

    def body(loop):
        i, (y, state, done, steps, stopped, result) = loop
        new_y, new_state, stop, new_result = jax.vmap(step)(y, state, multipliers, penalty)
        y, state = _where_done(done, (y, state), (new_y, new_state))
        stopped = stopped | (stop & ~done)
        result = where_each(done, result, new_result)
        steps = steps + jnp.where(done, 0, 1)
        done = done | stop | (steps >= max_steps)
        return i + 1, (y, state, done, steps, stopped, result)

    def cond(loop):
        i, (_, _, done, *_) = loop
        return (i < n_steps) & ~jnp.all(done)

    return jax.lax.while_loop(cond, body, (jnp.asarray(0), carry))[1]


@jit
def _constraint_values(problem, params):
    return jax.vmap(problem.constraints)(params)


def _start_results(stopped, result, valid_start) -> RESULTS:
    """How each start ended, from the optimistix minimiser's own result."""
    failed = result != optx.RESULTS.successful
    ended = where_each(failed, RESULTS.solver_failed, RESULTS.successful)
    ended = where_each(stopped, ended, RESULTS.max_steps_reached)
    return where_each(valid_start, ended, RESULTS.infeasible_start)


def _shard_starts(*arrays):
    """Lay the starts (axis 0) out over every device, padding to a multiple of them by
    repeating the first start. One device: unchanged."""
    devices = jax.devices()
    if len(devices) == 1:
        return arrays
    count = arrays[0].shape[0]
    pad = -count % len(devices)
    mesh = jax.sharding.Mesh(np.array(devices), ("starts",))
    spec = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("starts"))

    def place(a):
        a = jnp.concatenate([a, jnp.repeat(a[:1], pad, axis=0)]) if pad else a
        return jax.device_put(a, spec)

    return tuple(jax.tree.map(place, a) for a in arrays)


class MultiStart(AbstractPlacementSolver):
    """Many starts at once, each run by an optimistix minimiser on -Q / L (the thesis's
    Sec. 5.4, batched), with the augmented Lagrangian for placements with constraints.

    **Arguments:**

    - `minimiser`: an optimistix minimiser (default `optx.BFGS(rtol=1e-9, atol=1e-9)`).
    - `n_starts`: random starts from `placement.sample`; or `starts`, placement
      parameters of shape (s, k, p), to start from given places.
    - `max_steps`: per start (and per outer iteration).
    - `outer_iterations`: augmented-Lagrangian iterations (constrained placements).
    - `tolerance`: the largest constraint violation of an admissible result (default
      1e-8, or 1e-6 where the augmented Lagrangian runs).
    - `chunk`: steps between progress reports and `history` rows.
    """

    minimiser: optx.AbstractMinimiser = optx.BFGS(rtol=1e-9, atol=1e-9)
    n_starts: int = 16
    max_steps: int = 100
    starts: Float[Array, "s k p"] | None = None
    outer_iterations: int = 12
    tolerance: float | None = None
    chunk: int = 4

    def solve(
        self, problem: Problem, n_cameras: int, key: PRNGKeyArray, progress: bool
    ) -> Solution:
        starts = checked_starts(problem, n_cameras, self.n_starts, self.starts, key)
        problem, valid_start = sized_for_starts(problem, starts)
        placement = problem.placement
        constrained = placement.has_constraints()
        tolerance = admissible_tolerance(placement, self.tolerance)
        count = starts.shape[0]

        shapes = jax.eval_shape(problem.constraints, starts[0])
        multipliers = tuple(jnp.zeros((count, *s.shape), s.dtype) for s in shapes)
        penalty = jnp.ones((count,), starts.dtype)
        params, multipliers, penalty, valid_start = _shard_starts(
            starts, multipliers, penalty, valid_start
        )

        clock, history = time.perf_counter(), []
        total_steps = jnp.zeros(params.shape[:1], int)
        paths = [params[:count]]
        scale, valid = float(problem.scale), np.asarray(valid_start)
        last_report, last_violation = clock, None
        for outer in range(self.outer_iterations if constrained else 1):
            state = _init(self.minimiser, problem, params, multipliers, penalty)
            zeros = jnp.zeros(params.shape[:1], int)
            result = jax.tree.map(lambda v: jnp.full(zeros.shape, v), optx.RESULTS.successful)
            carry = (params, state, ~valid_start, zeros, zeros > 0, result)
            done = ~valid
            earlier = int(jnp.sum(total_steps[:count]))  # earlier outer iterations
            while not done.all():
                carry = _advance(
                    self.minimiser, problem, carry, multipliers, penalty, self.chunk, self.max_steps
                )
                # one transfer per chunk: what the loop, the history and the report need
                done, steps, merit = jax.device_get((carry[2], carry[3], carry[1].f_info.f))
                now = time.perf_counter()
                best = np.nanmax(np.where(valid, -merit, -np.inf)) * scale
                history.append((now - clock, earlier + int(steps[:count].sum()), best))
                paths.append(carry[0][:count])
                if progress and now - last_report > 1.0:
                    print(
                        f"  MultiStart: outer {outer}, step {steps.max()}/{self.max_steps}, "
                        f"{int((~done).sum())} of {count} starts running, best Q {best:.6g}",
                        file=sys.stderr,
                        flush=True,
                    )
                    last_report = now
            params, _, _, steps, stopped, result = carry
            total_steps = total_steps + steps
            if not constrained:
                break
            equal, at_least = jax.tree.map(
                lambda a: jnp.reshape(a, (a.shape[0], -1)), _constraint_values(problem, params)
            )
            violation = jnp.concatenate(
                [jnp.abs(equal), jnp.maximum(-at_least, 0.0), jnp.zeros_like(equal[:, :1])], 1
            ).max(1)
            lam, nu = multipliers
            multipliers = (
                lam + penalty[:, None] * equal,
                jnp.maximum(nu - penalty[:, None] * at_least, 0.0),
            )
            if last_violation is not None:
                penalty = jnp.where(violation > 0.25 * last_violation, 10 * penalty, penalty)
            last_violation = violation
            if bool(jnp.all((violation <= 0.1 * tolerance) | ~valid_start)):
                break

        params, stopped, result, valid_start, total_steps = jax.tree.map(
            lambda a: a[:count], (params, stopped, result, valid_start, total_steps)
        )
        return best_start(
            problem,
            params,
            _start_results(stopped, result, valid_start),
            total_steps,
            int(jnp.sum(total_steps)),
            time.perf_counter() - clock,
            history,
            paths,
            tolerance,
        )
