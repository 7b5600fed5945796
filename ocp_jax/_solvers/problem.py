"""What every placement solver works on (`Problem`), what it returns (`Solution`), and
the steps they share: sizing the budgets for the starts, checking given starts, and
choosing the best admissible start."""

import abc
import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int, PRNGKeyArray

from .._geometry.camera import Camera
from .._geometry.scene import Scene
from .._objectives.local import AbstractLocalObjective
from .._placement.placement import AbstractPlacement
from .._types import RESULTS, where_each
from .._visibility.visibility import (
    VisibilityOptions,
    fit_options,
    valid_visibility,
    with_grown_budgets,
)
from .._visibility.xla_cpu import jit


class Problem(eqx.Module):
    """Maximise Q of `scene` over `placement` (Eq. 3.16): what every evaluation needs."""

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
        """-Q / L, NaN where Q is undefined (a line search then steps back)."""
        q, valid, _ = valid_visibility(
            self.scene, self.placement.cameras(params), self.objective, self.options
        )
        return jnp.where(valid, -q / self.scale, jnp.nan)

    def merit(self, params: Float[Array, "k p"], args) -> tuple[Array, None]:
        """The function minimised: the loss plus the augmented-Lagrangian terms of the
        placement's constraints (`MultiStart`)."""
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


class Solution(eqx.Module):
    """The outcome of `ocp.place`.

    - `cameras` (k, 2) (a `Camera` batched over k for a `DirectionalPlacement`), `value`:
      the best admissible placement found and its Q (as `visibility` computes it);
      `result`: a `RESULTS` item, how the best start ended (`successful` for the
      discrete searches).
    - `start_cameras` (s, k, 2), `start_values` (s,), `start_results` (s,): every start's
      final placement, its Q (-inf where inadmissible) and how it ended; `num_steps`
      (s,): steps per start. None for the discrete searches.
    - `num_evaluations`: evaluations of Q (with its gradient for the continuous
      solvers); `seconds`: wall time, compilation included on the first call of a
      problem shape.
    - `violation`: the best placement's constraint violation.
    - `history` (n, 3): seconds, evaluations and the best Q so far, after each chunk of
      steps (`MultiStart`; for constrained placements -L times the best augmented-
      Lagrangian merit), start (`SLSQP`), stage (`Greedy`) or chunk of sets
      (`Exhaustive`): the anytime curve.
    - `paths` (m, s, k, p): every start's parameters at the start and after each chunk
      (`MultiStart`, m = n + 1) or at its end (`SLSQP`, m = 2); `placement.cameras` maps
      them to positions (`plot.plot_optimization`). None for the discrete searches.
    - `candidates` (c, r) and `stage_values`: the discrete searches' admissible
      candidates (positions, or pose rows [x, y, heading, half_fov?, range?]) and Q
      over the candidates at each greedy stage (the thesis's Fig. 5.5); None for the
      continuous solvers.
    """

    cameras: Float[Array, "k 2"] | Camera
    value: Float[Array, ""]
    result: RESULTS
    start_cameras: Float[Array, "s k 2"] | Camera | None
    start_values: Float[Array, " s"] | None
    start_results: RESULTS | None
    num_steps: Int[Array, " s"] | None
    num_evaluations: int
    seconds: float
    violation: float
    history: Float[Array, "n 3"]
    paths: Float[Array, "m s k p"] | None
    candidates: Float[Array, "c r"] | None
    stage_values: tuple[Array, ...] | None


class AbstractPlacementSolver(eqx.Module):
    """A way to place cameras, passed to `ocp.place` as `solver=`: `MultiStart`,
    `SLSQP`, `Greedy` or `Exhaustive`. Their integer fields (counts, sizes) must be
    positive."""

    def __check_init__(self):
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if field.type in (int, "int") and (not isinstance(value, int) or value < 1):
                raise ValueError(
                    f"{type(self).__name__}: {field.name} must be a positive int, got {value!r}."
                )

    @abc.abstractmethod
    def solve(
        self, problem: Problem, n_cameras: int, key: PRNGKeyArray, progress: bool
    ) -> Solution:
        """Maximise Q of `problem` with `n_cameras` cameras."""


@jit
def start_values(problem: Problem, params):
    return problem.values(params)


def sized_for_starts(problem: Problem, starts) -> tuple[Problem, Array]:
    """`problem` with budgets that hold the starts' events (where they overflow: twice
    the starts' counts, room for the cameras to move), and whether each start is valid
    (Q defined there)."""

    def at_starts(options):
        sized = eqx.tree_at(lambda p: p.options, problem, options)
        _, valid, needs = start_values(sized, starts)
        return (sized, valid), needs

    placement = problem.placement
    (problem, valid), _ = with_grown_budgets(
        at_starts,
        lambda o: fit_options(
            problem.scene, jax.vmap(placement.cameras)(starts), problem.objective, o, 2.0
        ),
        problem.options,
    )
    return problem, valid


def checked_starts(
    problem: Problem, n_cameras: int, n_starts: int, starts, key: PRNGKeyArray
) -> Float[Array, "s k p"]:
    """The given starts (placement parameters), checked, or `n_starts` random ones."""
    placement = problem.placement
    if starts is None:
        return placement.sample(key, n_cameras, n_starts)
    starts = jnp.asarray(starts, problem.scene.dtype)
    p = jax.eval_shape(lambda k: placement.sample(k, n_cameras, 1), key).shape[-1]
    if starts.ndim != 3 or starts.shape[1:] != (n_cameras, p):
        raise ValueError(
            f"ocp_jax: starts are parameters of the placement, of shape (n_starts, "
            f"n_cameras={n_cameras}, {p}) for {type(placement).__name__}; got shape "
            f"{tuple(starts.shape)}. (placement.cameras maps parameters to cameras.)"
        )
    return starts


def admissible_tolerance(placement: AbstractPlacement, tolerance: float | None) -> float:
    """The largest admissible constraint violation: 1e-8, or 1e-6 where the
    augmented Lagrangian (or SLSQP) enforces constraints."""
    if tolerance is not None:
        return tolerance
    return 1e-6 if placement.has_constraints() else 1e-8


def best_start(
    problem: Problem,
    params,
    results: RESULTS,
    num_steps,
    evaluations: int,
    seconds: float,
    history,
    paths,
    tolerance: float,
) -> Solution:
    """The `Solution` of the best admissible start (Q from `start_values`, compiled
    already for the starts: no second compilation of Q for one set)."""
    placement, scene = problem.placement, problem.scene
    q, valid, _ = start_values(problem, params)
    cameras = jax.vmap(placement.cameras)(params)
    violation = jax.vmap(lambda c: placement.violation(c, scene))(cameras)
    admissible = np.asarray(valid & (violation <= tolerance))
    results = where_each(
        admissible | (results == RESULTS.infeasible_start), results, RESULTS.infeasible_end
    )
    values = jnp.where(admissible, q, -jnp.inf)
    if not admissible.any():
        if bool(jnp.all(results == RESULTS.infeasible_start)):
            raise ValueError(
                "ocp_jax.place: every start is infeasible (a camera inside an object, or "
                "where Q is undefined): check that the placement lies outside the objects."
            )
        raise RuntimeError(
            "ocp_jax.place: no start ended at an admissible placement (cameras outside "
            f"the objects, constraints met to {tolerance:g}). Try more starts or steps "
            "(MultiStart(n_starts=..., max_steps=...)), or a looser placement."
        )
    best = int(np.argmax(np.asarray(values)))
    return Solution(
        cameras=jax.tree.map(lambda a: a[best], cameras),
        value=q[best],
        result=jax.tree.map(lambda a: a[best], results),
        start_cameras=cameras,
        start_values=values,
        start_results=results,
        num_steps=jnp.asarray(num_steps),
        num_evaluations=int(evaluations),
        seconds=seconds,
        violation=float(violation[best]),
        history=jnp.asarray(np.array(history, float).reshape(-1, 3)),
        paths=jnp.stack(paths),
        candidates=None,
        stage_values=None,
    )
