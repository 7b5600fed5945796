"""The baselines the optimiser must beat (the thesis's Sec. 5.4 and Table 5.1).

- `greedy`: discretise the placement set (128 candidates per rectangle edge, as the
  thesis did) and place one camera at a time, each at the candidate that maximises Q with
  the cameras already placed fixed.
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

from ._objectives import AbstractLocalObjective, Foreshortened, as_local_objective
from ._optimize import OptimizeResult, _best, _problem_and_starts, _tolerance
from ._placement import AbstractPlacement
from ._scene import Scene
from ._visibility import VisibilityOptions, valid_visibility, visibility

__all__ = ["SearchResult", "exhaustive", "greedy", "slsqp"]


class SearchResult(eqx.Module):
    """The outcome of a discrete search (`greedy`, `exhaustive`).

    - `cameras` (k, 2), `value`: the best placement found and its Q;
    - `num_evaluations`: evaluations of Q; `seconds`: wall time (compilation excluded
      where a compiled evaluator already existed);
    - `candidates` (n, 2): the admissible candidate positions;
    - `stage_values`: greedy: Q over the candidates at each stage (k arrays of n; the
      thesis's Fig. 5.5); exhaustive: the best Q found after each chunk.
    """

    cameras: Float[Array, "k 2"]
    value: Float[Array, ""]
    num_evaluations: int
    seconds: float
    candidates: Float[Array, "n 2"]
    stage_values: tuple[Array, ...]


@eqx.filter_jit
def _set_values(scene, objective, options, camera_sets):
    """Q of every camera set (n, k, 2), -inf where undefined."""

    def one(cameras):
        q, valid = valid_visibility(scene, cameras, objective, options)
        return jnp.where(valid, q, -jnp.inf)

    return jax.lax.map(one, camera_sets, batch_size=64)


def _values_of_sets(scene, objective, options, camera_sets: np.ndarray, chunk: int):
    """Q of many camera sets, `chunk` at a time (the last chunk padded)."""
    out = []
    for begin in range(0, len(camera_sets), chunk):
        part = camera_sets[begin : begin + chunk]
        pad = chunk - len(part)
        padded = np.concatenate([part, np.repeat(part[:1], pad, 0)]) if pad else part
        out.append(
            np.asarray(_set_values(scene, objective, options, jnp.asarray(padded)))[: len(part)]
        )
    return np.concatenate(out)


def _admissible_candidates(scene, placement: AbstractPlacement, resolution: int) -> np.ndarray:
    """Positions of the placement's candidates that satisfy its constraints and are
    outside every object."""
    positions = placement.cameras(placement.candidates(resolution))
    keep = np.asarray(placement.violations(positions, scene)) <= 1e-9
    positions = np.asarray(positions)[keep]
    if len(positions) == 0:
        raise ValueError(
            "ocp_jax: the placement has no admissible candidates at resolution "
            f"{resolution}; raise the resolution or loosen the placement."
        )
    return positions


def _search_result(scene, objective, options, cameras, evaluations, seconds, candidates, stages):
    cameras = jnp.asarray(cameras)
    return SearchResult(
        cameras=cameras,
        value=visibility(scene, cameras, objective, options),
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
    n candidates.

    **Arguments:** as for `optimize`; `resolution`: candidates per edge (boundaries) or
    per axis (regions); `chunk`: camera sets per compiled batch.

    **Returns:** a `SearchResult`.
    """
    objective = as_local_objective(objective)
    candidates = _admissible_candidates(scene, placement, resolution)
    clock = time.perf_counter()
    chosen, stages = np.zeros((0, 2)), []
    for _ in range(n_cameras):
        sets = np.concatenate(
            [np.broadcast_to(chosen, (len(candidates), *chosen.shape)), candidates[:, None]], 1
        )
        values = _values_of_sets(scene, objective, options, sets, chunk)
        stages.append(values)
        chosen = sets[int(np.argmax(values))]
    seconds = time.perf_counter() - clock
    evaluations = n_cameras * len(candidates)
    return _search_result(
        scene, objective, options, chosen, evaluations, seconds, candidates, stages
    )


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
    candidates = _admissible_candidates(scene, placement, resolution)
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
        values = _values_of_sets(scene, objective, options, sets, chunk)
        if values.max() > best_value:
            best_value, best_set = values.max(), sets[int(np.argmax(values))]
        stages.append(best_value)
    seconds = time.perf_counter() - clock
    return _search_result(
        scene, objective, options, best_set, total, seconds, candidates, (np.array(stages),)
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
    problem, starts = _problem_and_starts(
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
