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

Placements where Q is undefined (a camera inside or on an object, an exceeded event
budget) give f = NaN, which the line search rejects: the solver steps back.
"""

import sys
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, Float, Int, PRNGKeyArray

from ._compile import jit
from ._objectives import (
    AbstractLocalObjective,
    Foreshortened,
    as_local_objective,
    camera_groups,
)
from ._placement import AbstractPlacement
from ._scene import Scene
from ._visibility import VisibilityOptions, fit_options, valid_visibility, with_grown_budgets

__all__ = ["OptimizeResult", "optimize"]

_NO_TAGS = frozenset()


class Problem(eqx.Module):
    """What every evaluation needs: maximise Q of `scene` over `placement`."""

    scene: Scene
    objective: AbstractLocalObjective
    placement: AbstractPlacement
    options: VisibilityOptions
    scale: Float[Array, ""]  # the scene's total length

    def values(self, params: Float[Array, "s k p"]) -> tuple[Array, Array, dict]:
        """(Q, valid, needs) of every parameter set, one at a time (`lax.map`; needs:
        what each event budget needed, see `valid_visibility`)."""
        return jax.lax.map(
            lambda p: valid_visibility(
                self.scene, self.placement.cameras(p), self.objective, self.options
            ),
            params,
        )

    def constraints(self, params: Float[Array, "k p"]):
        return self.placement.constraints(self.placement.cameras(params), self.scene)

    def loss(self, params: Float[Array, "k p"]) -> Float[Array, ""]:
        """-Q / L, NaN where Q is undefined."""
        q, valid, _ = valid_visibility(
            self.scene, self.placement.cameras(params), self.objective, self.options
        )
        return jnp.where(valid, -q / self.scale, jnp.nan)

    def merit(self, params: Float[Array, "k p"], args) -> tuple[Array, None]:
        """The function minimised: the loss plus the augmented-Lagrangian terms of the
        placement's constraints."""
        (lam, nu), mu = args
        f = self.loss(params)
        if self.placement.has_constraints():
            e, h = self.constraints(params)
            f = f + jnp.sum(lam * e) + 0.5 * mu * jnp.sum(e**2)
            f = f + jnp.sum(jnp.maximum(nu - mu * h, 0.0) ** 2 - nu**2) / (2 * mu)
        return f, None


def scene_length(scene: Scene) -> Float[Array, ""]:
    """Total length of the scene's curves (a 1024-gon per curve; only a scale)."""
    t = jnp.linspace(0.0, 1.0, 1025, dtype=scene.dtype)
    x = scene.derivatives(jnp.broadcast_to(t, (len(scene), t.shape[0])))[0]
    return jnp.sum(jnp.linalg.norm(jnp.diff(x, axis=1), axis=-1))


def _where_done(done, old, new):
    """Per start: `old` where done, else `new` (leaves batched along axis 0)."""

    def pick(a, b):
        return jnp.where(done.reshape(done.shape + (1,) * (a.ndim - 1)), a, b)

    return jax.tree.map(pick, old, new)


@jit
def _init(solver, problem, params, multipliers, penalty):
    def one(y, lam_nu, mu):
        f_struct = jax.ShapeDtypeStruct((), y.dtype)
        return solver.init(problem.merit, y, (lam_nu, mu), {}, f_struct, None, _NO_TAGS)

    return jax.vmap(one)(params, multipliers, penalty)


@jit
def _advance(solver, problem, carry, multipliers, penalty, n_steps, max_steps):
    """Up to `n_steps` steps of every start that has not stopped. `carry` = (params,
    solver state, done, steps, converged, result index)."""

    def step(y, state, lam_nu, mu):
        args = (lam_nu, mu)
        y, state, _ = solver.step(problem.merit, y, args, {}, state, _NO_TAGS)
        stop, result = solver.terminate(problem.merit, y, args, {}, state, _NO_TAGS)
        return y, state, stop, result._value

    def body(loop):
        i, (y, state, done, steps, stopped, result) = loop
        new_y, new_state, stop, new_result = jax.vmap(step)(y, state, multipliers, penalty)
        y, state = _where_done(done, (y, state), (new_y, new_state))
        stopped = stopped | (stop & ~done)
        result = jnp.where(done, result, new_result)
        steps = steps + jnp.where(done, 0, 1)
        done = done | stop | (steps >= max_steps)
        return i + 1, (y, state, done, steps, stopped, result)

    def cond(loop):
        i, (_, _, done, *_) = loop
        return (i < n_steps) & ~jnp.all(done)

    return jax.lax.while_loop(cond, body, (jnp.asarray(0), carry))[1]


@jit
def _values(problem, params):
    return problem.values(params)


@jit
def _constraint_values(problem, params):
    return jax.vmap(problem.constraints)(params)


def _status(stopped, result, valid_start) -> tuple[str, ...]:
    out = []
    for s, r, valid in zip(stopped, result, valid_start):
        if not valid:
            out.append("invalid start")
        elif s and r == 0:
            out.append("converged")
        elif s:
            out.append(optx.RESULTS._index_to_message[r].split("\n")[0])
        else:
            out.append("max_steps")
    return tuple(out)


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


class OptimizeResult(eqx.Module):
    """The outcome of a multi-start optimisation (`optimize`, `slsqp`).

    - `cameras` (k, 2), `value`: the best admissible placement and its Q (as
      `visibility` computes it); a `Camera` (batched likewise) for a
      `DirectionalPlacement`;
    - `start_cameras` (s, k, 2), `start_values` (s,): every start's final placement and
      Q (-inf where it ended inadmissible); `start_status`: "converged", "max_steps",
      "invalid start" or the solver's failure;
    - `num_steps` (s,): steps per start; `num_evaluations`: value-and-gradient
      evaluations over all starts (one per step; not counted: one value evaluation per
      start that screens out starts where Q is undefined);
    - `violation`: the best placement's constraint violation;
    - `seconds`: wall time (on the first call of a problem shape it includes the
      compilation, which dominates); `history` (n, 3): seconds, evaluations and best Q
      so far, after each chunk of steps (for constrained placements: -L times the best
      augmented-Lagrangian merit);
    - `paths` (n + 1, s, k, p): every start's parameters at the start and after each
      chunk (`placement.cameras` maps them to positions; `plot.plot_optimization`).
    """

    cameras: Float[Array, "k 2"]
    value: Float[Array, ""]
    start_cameras: Float[Array, "s k 2"]
    start_values: Float[Array, " s"]
    start_status: tuple[str, ...]
    num_steps: Int[Array, " s"]
    num_evaluations: int
    violation: float
    seconds: float
    history: Float[Array, "n 3"]
    paths: Float[Array, "n s k p"]


def _best(problem, params, status, num_steps, evaluations, seconds, history, paths, tolerance):
    """The best admissible start and its Q (from `_values`, compiled already for the
    starts: no second compilation of Q for one set)."""
    placement, scene = problem.placement, problem.scene
    q, valid, _ = _values(problem, params)
    cameras = jax.vmap(placement.cameras)(params)
    violation = jax.vmap(lambda c: placement.violation(c, scene))(cameras)
    admissible = np.asarray(valid & (violation <= tolerance))
    start_values = jnp.where(admissible, q, -jnp.inf)
    if not admissible.any():
        raise RuntimeError(
            "ocp_jax.optimize: no start ended at an admissible placement (every camera "
            f"outside the objects, constraints met to {tolerance:g}); statuses: "
            f"{sorted(set(status))}. Try more starts, more steps or a looser placement."
        )
    best = int(np.argmax(np.asarray(start_values)))
    chosen = jax.tree.map(lambda a: a[best], cameras)
    return OptimizeResult(
        cameras=chosen,
        value=q[best],
        start_cameras=cameras,
        start_values=start_values,
        start_status=status,
        num_steps=num_steps,
        num_evaluations=int(evaluations),
        violation=float(violation[best]),
        seconds=seconds,
        history=jnp.asarray(np.array(history).reshape(-1, 3)),
        paths=jnp.stack(paths),
    )


def _problem_and_starts(
    scene, objective, placement, n_cameras, n_starts, key, starts, max_steps, options
) -> tuple[Problem, Array]:
    """Check the arguments shared by the multi-start optimisers (`optimize`, `slsqp`)
    and build the problem, the starting parameters (s, k, p) and whether each start is
    valid."""
    if not isinstance(placement, AbstractPlacement):
        raise TypeError(
            "optimize needs a placement, e.g. ocp.RectangleBoundary(center, width, height); "
            f"got {type(placement).__name__}."
        )
    for name, value in (("n_cameras", n_cameras), ("n_starts", n_starts), ("max_steps", max_steps)):
        if not isinstance(value, int) or value < 1:
            raise ValueError(f"{name} must be a positive int, got {value!r}.")
    if starts is None:
        key = key if key is not None else jax.random.key(0)
        starts = placement.sample(key, n_cameras, n_starts)
    starts = jnp.asarray(starts, scene.dtype)
    if starts.ndim != 3 or starts.shape[1] != n_cameras:
        raise ValueError(
            f"starts must have shape (n_starts, n_cameras={n_cameras}, p), got {starts.shape}."
        )
    objective = as_local_objective(objective)
    camera_groups(objective, n_cameras)  # enough cameras for the objective's groups
    length = scene_length(scene)

    def at_starts(options):
        problem = Problem(scene, objective, placement, options, length)
        _, valid, needs = _values(problem, starts)
        return (problem, valid), needs

    # Where the starts' events overflow the budgets, budgets with room for the cameras
    # to move (twice the starts' counts).
    (problem, valid_start), _ = with_grown_budgets(
        at_starts,
        lambda o: fit_options(scene, jax.vmap(placement.cameras)(starts), objective, o, 2.0),
        options,
    )
    return problem, starts, valid_start


def _tolerance(placement: AbstractPlacement, tolerance: float | None) -> float:
    """The largest admissible constraint violation: 1e-8, or 1e-6 where the
    augmented Lagrangian (or SLSQP) enforces constraints."""
    if tolerance is not None:
        return tolerance
    return 1e-6 if placement.has_constraints() else 1e-8


def optimize(
    scene: Scene,
    objective: AbstractLocalObjective = Foreshortened(),
    placement: AbstractPlacement | None = None,
    n_cameras: int = 1,
    *,
    n_starts: int = 16,
    key: PRNGKeyArray | None = None,
    starts: Float[Array, "s k p"] | None = None,
    solver: optx.AbstractMinimiser | None = None,
    max_steps: int = 100,
    outer_iterations: int = 12,
    tolerance: float | None = None,
    options: VisibilityOptions = VisibilityOptions(),
    chunk: int = 4,
    progress: bool = False,
) -> OptimizeResult:
    """Place `n_cameras` cameras on `placement` to maximise Q (Eq. 3.16), from many
    starts at once.

    **Arguments:**
    - `scene`, `objective`: what is seen and how it is valued (as for `visibility`).
    - `placement`: where cameras may go (`RectangleBoundary`, `PolygonBoundary`,
      `Region`, `FreePlacement`, `EqualityConstraint`).
    - `n_cameras`: k.
    - `n_starts`, `key`: random starts from `placement.sample` (key defaults to 0);
      or `starts`, parameters of shape (s, k, p), to start from given places.
    - `solver`: an optimistix minimiser (default `optx.BFGS(rtol=1e-9, atol=1e-9)`);
      `max_steps`: per start (and per outer iteration).
    - `outer_iterations`: augmented-Lagrangian iterations (constrained placements).
    - `tolerance`: the largest constraint violation of an admissible result (default
      1e-8, or 1e-6 where the augmented Lagrangian runs).
    - `options`: the engine's `VisibilityOptions`.
    - `chunk`: steps between progress reports; `progress`: print them to stderr.

    **Returns:** an `OptimizeResult`.
    """
    problem, starts, valid_start = _problem_and_starts(
        scene, objective, placement, n_cameras, n_starts, key, starts, max_steps, options
    )
    constrained = placement.has_constraints()
    tolerance = _tolerance(placement, tolerance)
    solver = solver if solver is not None else optx.BFGS(rtol=1e-9, atol=1e-9)
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
    for outer in range(outer_iterations if constrained else 1):
        state = _init(solver, problem, params, multipliers, penalty)
        zeros = jnp.zeros(params.shape[:1], int)
        carry = (params, state, ~valid_start, zeros, zeros > 0, zeros)
        done = ~valid
        earlier = int(jnp.sum(total_steps[:count]))  # evaluations of earlier outer iterations
        while not done.all():
            carry = _advance(solver, problem, carry, multipliers, penalty, chunk, max_steps)
            # one transfer per chunk: what the loop, the history and the report need
            done, steps, merit = jax.device_get((carry[2], carry[3], carry[1].f_info.f))
            now = time.perf_counter()
            best = np.nanmax(np.where(valid, -merit, -np.inf)) * scale
            history.append((now - clock, earlier + int(steps[:count].sum()), best))
            paths.append(carry[0][:count])
            if progress and now - last_report > 1.0:
                print(
                    f"  optimize: outer {outer}, step {steps.max()}/{max_steps}, "
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

    params, total_steps = params[:count], total_steps[:count]
    status = _status(*(np.asarray(a[:count]) for a in (stopped, result, valid_start)))
    seconds = time.perf_counter() - clock
    evaluations = int(jnp.sum(total_steps))
    return _best(
        problem, params, status, total_steps, evaluations, seconds, history, paths, tolerance
    )
