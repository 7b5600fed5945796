"""The baselines the optimiser must beat (the thesis's Sec. 5.4 and Table 5.1).

- `greedy`: discretise the placement set (128 candidates per rectangle edge, as the
  thesis did) and place one camera at a time, each at the candidate that maximises Q with
  the cameras already placed fixed (objectives of camera groups of l > 1 cameras start
  from the best l-subset, since fewer cameras have no value).
- `exhaustive`: every k-subset of the candidates (the best discrete answer), evaluated
  in fixed-size chunks so memory stays bounded.
- `slsqp`: the thesis's own pipeline, scipy's SLSQP on the same parameters and
  constraints from the same starts (one start at a time, on the host).

Evaluations are batched (`lax.map` over fixed-size chunks, one compilation per k).
"""

import itertools
import math
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import scipy.optimize
from jaxtyping import Array, Float, PRNGKeyArray

from ._camera import Camera
from ._compile import jit
from ._objectives import AbstractLocalObjective, Foreshortened, as_local_objective, camera_groups
from ._optimize import OptimizeResult, _best, _problem_and_starts, _tolerance
from ._placement import AbstractPlacement
from ._scene import Scene
from ._visibility import (
    VisibilityOptions,
    fit_options,
    valid_visibility,
    with_grown_budgets,
)

__all__ = ["SearchResult", "exhaustive", "greedy", "slsqp"]


class SearchResult(eqx.Module):
    """The outcome of a discrete search (`greedy`, `exhaustive`).

    - `cameras` (k, 2) (a `Camera` for a `DirectionalPlacement`), `value`: the best
      placement found and its Q;
    - `num_evaluations`: evaluations of Q; `seconds`: wall time (compilation excluded
      where a compiled evaluator already existed);
    - `candidates` (n, 2): the admissible candidate positions (for poses (n, r) rows
      [x, y, heading, half_fov, range], the last two where the cameras have them);
    - `stage_values`: greedy: Q over the candidates at each stage (k arrays of n; the
      thesis's Fig. 5.5; for groups of l > 1 cameras k - l + 1 arrays, the first over
      the binomial(n, l) l-subsets); exhaustive: the best Q found after each chunk.
    """

    cameras: Float[Array, "k 2"]
    value: Float[Array, ""]
    num_evaluations: int
    seconds: float
    candidates: Float[Array, "n 2"]
    stage_values: tuple[Array, ...]


def _to_rows(cameras) -> tuple[np.ndarray, tuple[bool, bool] | None]:
    """Cameras as rows of numbers, (k, 2) positions or (k, r) pose rows [x, y, heading,
    half_fov?, range?], with the layout that `_from_rows` needs (None for positions)."""
    if not isinstance(cameras, Camera):
        return np.atleast_2d(np.asarray(cameras, float)), None
    layout = (cameras.half_fov is not None, cameras.range is not None)
    columns = [cameras.position, cameras.heading[..., None]]
    columns += [a[..., None] for a in (cameras.half_fov, cameras.range) if a is not None]
    return np.concatenate([np.asarray(c, float) for c in columns], -1), layout


def _from_rows(rows, layout):
    """The inverse of `_to_rows`."""
    if layout is None:
        return rows
    has_fov, has_range = layout
    fov = rows[..., 3] if has_fov else None
    reach = rows[..., 3 + has_fov] if has_range else None
    return Camera(rows[..., :2], rows[..., 2], fov, reach)


@jit
def _set_values(scene, objective, options, layout, camera_sets):
    """Q of every camera set (rows (n, k, r), see `_to_rows`), -inf where undefined, and
    what each event budget needed ({option: (needed, budget)} per set)."""

    def one(rows):
        q, valid, needs = valid_visibility(scene, _from_rows(rows, layout), objective, options)
        return jnp.where(valid, q, -jnp.inf), needs

    return jax.lax.map(one, camera_sets, batch_size=64)


def _values_of_sets(scene, objective, options, camera_sets: np.ndarray, chunk: int, layout=None):
    """Q of many camera sets (rows, see `_to_rows`), `chunk` at a time (the last chunk
    padded), and the options used: where a chunk's events overflow the budgets, they are
    grown for its sets (`fit_options`, with a warning) and the chunk evaluated again.

    **Returns:** (values, options).
    """
    out = []
    for begin in range(0, len(camera_sets), chunk):
        part = camera_sets[begin : begin + chunk]
        pad = chunk - len(part)
        padded = jnp.asarray(np.concatenate([part, np.repeat(part[:1], pad, 0)]) if pad else part)
        values, options = with_grown_budgets(
            lambda o, sets=padded: _set_values(scene, objective, o, layout, sets),
            lambda o, sets=padded: fit_options(scene, _from_rows(sets, layout), objective, o),
            options,
        )
        out.append(np.asarray(values)[: len(part)])
    return np.concatenate(out), options


def _admissible_candidates(scene, placement: AbstractPlacement, resolution: int):
    """The placement's candidates that satisfy its constraints and are outside every
    object, as rows (see `_to_rows`), and their layout."""
    cameras = placement.cameras(placement.candidates(resolution))
    keep = np.asarray(placement.violations(cameras, scene)) <= 1e-9
    rows, layout = _to_rows(cameras)
    rows = rows[keep]
    if len(rows) == 0:
        raise ValueError(
            "ocp_jax: the placement has no admissible candidates at resolution "
            f"{resolution}; raise the resolution or loosen the placement."
        )
    return rows, layout


def _search_result(rows, value, layout, evaluations, seconds, candidates, stages):
    """The result of a search whose best set is `rows` with Q = `value` (as the batched
    evaluator computed it: no second compilation of Q for one set)."""
    if not np.isfinite(value):
        raise RuntimeError(
            "ocp_jax: Q is undefined for every candidate set (a camera inside an object, on "
            "a curve or too close to it, or an exceeded root budget): move the placement "
            "away from the objects, or pass options=ocp.VisibilityOptions(...) with larger "
            "budgets."
        )
    return SearchResult(
        cameras=_from_rows(jnp.asarray(rows), layout),
        value=jnp.asarray(value),
        num_evaluations=int(evaluations),
        seconds=seconds,
        candidates=jnp.asarray(candidates),
        stage_values=tuple(jnp.asarray(s) for s in stages),
    )


def greedy(
    scene: Scene,
    objective: AbstractLocalObjective = Foreshortened(),
    placement: AbstractPlacement | None = None,
    n_cameras: int = 1,
    *,
    resolution: int = 128,
    chunk: int = 512,
    options: VisibilityOptions = VisibilityOptions(),
) -> SearchResult:
    """Greedy placement over a candidate grid (the thesis's baseline, Sec. 5.4): camera j
    goes to the candidate that maximises Q with cameras 1..j-1 fixed. k n evaluations for
    n candidates. For an objective of groups of l > 1 cameras (`Reconstruction`,
    `Coverage(m)`), fewer than l cameras have no value: the first l cameras are the best
    l-subset of the candidates (binomial(n, l) evaluations), the rest one at a time.

    **Arguments:** as for `optimize`; `resolution`: candidates per edge (boundaries) or
    per axis (regions); `chunk`: camera sets per compiled batch.

    **Returns:** a `SearchResult`.
    """
    objective = as_local_objective(objective)
    camera_groups(objective, n_cameras)  # enough cameras for the objective's groups
    candidates, layout = _admissible_candidates(scene, placement, resolution)
    clock = time.perf_counter()
    sets = candidates[camera_groups(objective, len(candidates))]  # every l-subset
    evaluations, stages = 0, []
    for _ in range(n_cameras - objective.group_size + 1):
        values, options = _values_of_sets(scene, objective, options, sets, chunk, layout)
        evaluations += len(sets)
        stages.append(values)
        chosen = sets[int(np.argmax(values))]
        sets = np.concatenate(
            [np.broadcast_to(chosen, (len(candidates), *chosen.shape)), candidates[:, None]], 1
        )
    seconds = time.perf_counter() - clock
    return _search_result(chosen, values.max(), layout, evaluations, seconds, candidates, stages)


def exhaustive(
    scene: Scene,
    objective: AbstractLocalObjective = Foreshortened(),
    placement: AbstractPlacement | None = None,
    n_cameras: int = 1,
    *,
    resolution: int = 128,
    chunk: int = 4096,
    max_evaluations: int = 10_000_000,
    options: VisibilityOptions = VisibilityOptions(),
) -> SearchResult:
    """The best k-subset of the candidates (binomial(n, k) evaluations), `chunk` sets at a
    time. Refuses more than `max_evaluations` sets.

    **Returns:** a `SearchResult`.
    """
    objective = as_local_objective(objective)
    candidates, layout = _admissible_candidates(scene, placement, resolution)
    total = math.comb(len(candidates), n_cameras)
    if total > max_evaluations:
        raise ValueError(
            f"ocp_jax.exhaustive: {total} subsets of {len(candidates)} candidates exceed "
            f"max_evaluations={max_evaluations}; lower the resolution or raise the limit."
        )
    clock = time.perf_counter()
    subsets = itertools.combinations(range(len(candidates)), n_cameras)
    best_value, best_set, stages = -np.inf, None, []
    while block := list(itertools.islice(subsets, chunk)):
        sets = candidates[np.asarray(block)]
        values, options = _values_of_sets(scene, objective, options, sets, chunk, layout)
        if values.max() > best_value:
            best_value, best_set = values.max(), sets[int(np.argmax(values))]
        stages.append(best_value)
    seconds = time.perf_counter() - clock
    return _search_result(
        best_set, best_value, layout, total, seconds, candidates, (np.array(stages),)
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


def slsqp(
    scene: Scene,
    objective: AbstractLocalObjective = Foreshortened(),
    placement: AbstractPlacement | None = None,
    n_cameras: int = 1,
    *,
    n_starts: int = 16,
    key: PRNGKeyArray | None = None,
    starts: Float[Array, "s k p"] | None = None,
    max_steps: int = 100,
    tolerance: float | None = None,
    options: VisibilityOptions = VisibilityOptions(),
) -> OptimizeResult:
    """The thesis's pipeline: scipy's SLSQP on -Q / L (jit-compiled value and gradient)
    from each start in turn, with the placement's constraints passed to SLSQP. Same
    arguments and result as `optimize`; `num_evaluations` counts SLSQP's calls of the
    value-and-gradient function."""
    problem, starts, _ = _problem_and_starts(
        scene, objective, placement, n_cameras, n_starts, key, starts, max_steps, options
    )
    starts = np.asarray(starts)
    shape = starts.shape[1:]

    def host(fn, *extra):
        return lambda x: np.asarray(fn(problem, jnp.asarray(x).reshape(shape), *extra), float)

    constraints = []
    if placement.has_constraints():
        sizes = jax.eval_shape(problem.constraints, jnp.asarray(starts[0]))
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
    finals, status, steps = [], [], []
    for start in starts:
        out = scipy.optimize.minimize(
            fun,
            start.ravel(),
            jac=True,
            method="SLSQP",
            constraints=constraints,
            options={"maxiter": max_steps},
        )
        finals.append(out.x.reshape(shape))
        status.append("converged" if out.success else str(out.message))
        steps.append(out.nit)
    seconds = time.perf_counter() - clock
    finals = jnp.asarray(np.stack(finals))
    paths = [jnp.asarray(starts), finals]
    return _best(
        problem,
        finals,
        tuple(status),
        jnp.asarray(steps),
        calls,
        seconds,
        [],
        paths,
        _tolerance(placement, tolerance),
    )
