"""`place`: the one entry point for placing cameras, whatever the solver."""

from collections.abc import Callable

import jax
from jaxtyping import PRNGKeyArray

from .._geometry.scene import Scene
from .._objectives.local import AbstractLocalObjective, as_local_objective, camera_groups
from .._placement.placement import AbstractPlacement
from .._visibility.visibility import VisibilityOptions
from .multistart import MultiStart
from .problem import AbstractPlacementSolver, Problem, Solution, scene_length


def place(
    scene: Scene,
    objective: AbstractLocalObjective | Callable,
    placement: AbstractPlacement,
    n_cameras: int,
    *,
    solver: AbstractPlacementSolver = MultiStart(),
    key: PRNGKeyArray | None = None,
    options: VisibilityOptions | None = None,
    progress: bool = False,
) -> Solution:
    """Place `n_cameras` cameras on `placement` to maximise Q (Eq. 3.16).

        maximise Q(C_1, ..., C_k)  over C_j in the placement set, subject to its
        constraints,

    with Q the global visibility objective of `ocp.visibility` (Eq. 3.15).

    **Arguments:**

    - `scene`, `objective`: what is seen and how it is valued (as for `visibility`).
    - `placement`: where cameras may go (`RectangleBoundary`, `PolygonBoundary`,
      `Region`, `FreePlacement`, `EqualityConstraint`, `DirectionalPlacement`).
    - `n_cameras`: k.
    - `solver`: `MultiStart()` (default: batched multi-start BFGS with exact gradients),
      `SLSQP()` (the thesis's pipeline), `Greedy()` or `Exhaustive()` (the discrete
      baselines over a candidate grid).
    - `key`: the random starts' key (default `jax.random.key(0)`).
    - `options`: the engine's `VisibilityOptions`. Budgets that the starts or the
      candidates overflow are grown and the program compiled again, with a warning.
    - `progress`: report progress on stderr.

    **Returns:** a `Solution`: `cameras`, `value`, `result` and, per start, what each
    solver has.

    Raises ValueError for invalid arguments and for a placement with no feasible start
    or candidate, RuntimeError where no start ends at an admissible placement.
    """
    if not isinstance(placement, AbstractPlacement):
        raise TypeError(
            "ocp_jax.place: `placement` says where cameras may go, e.g. "
            f"ocp.RectangleBoundary(center, width, height); got {type(placement).__name__}."
        )
    if not isinstance(solver, AbstractPlacementSolver):
        raise TypeError(
            "ocp_jax.place: `solver` is one of ocp.MultiStart(), ocp.SLSQP(), ocp.Greedy(), "
            f"ocp.Exhaustive(); got {type(solver).__name__}."
        )
    if not isinstance(n_cameras, int) or n_cameras < 1:
        raise ValueError(f"ocp_jax.place: n_cameras must be a positive int, got {n_cameras!r}.")
    objective = as_local_objective(objective)
    camera_groups(objective, n_cameras)  # enough cameras for the objective's groups
    options = VisibilityOptions() if options is None else options
    problem = Problem(scene, objective, placement, options, scene_length(scene))
    key = jax.random.key(0) if key is None else key
    return solver.solve(problem, n_cameras, key, progress)
