"""The discrete baselines the continuous optimiser must beat (the thesis's Sec. 5.4 and
Table 5.1), over a grid of candidate cameras (128 per rectangle edge by default, as the
thesis did):

- `Greedy`: place one camera at a time, each at the candidate that maximises Q with the
  cameras already placed fixed (objectives of camera groups of l > 1 cameras start from
  the best l-subset, since fewer cameras have no value).
- `Exhaustive`: every k-subset of the candidates (the best discrete answer), evaluated in
  fixed-size chunks so memory stays bounded.

Evaluations are batched (`lax.map` over fixed-size chunks, one compilation per k).
"""

import itertools
import math
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import PRNGKeyArray

from .._geometry.camera import Camera
from .._objectives.local import camera_groups
from .._placement.placement import AbstractPlacement
from .._types import RESULTS
from .._visibility.visibility import fit_options, valid_visibility, with_grown_budgets
from .._visibility.xla_cpu import jit
from .problem import AbstractPlacementSolver, Problem, Solution


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


def values_of_sets(scene, objective, options, camera_sets: np.ndarray, chunk: int, layout=None):
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
            "ocp_jax.place: every candidate of the placement at resolution "
            f"{resolution} is inside an object or violates its constraints: raise the "
            "resolution or move the placement away from the objects."
        )
    return rows, layout


def _search_solution(rows, value, layout, evaluations, clock, history, candidates, stages):
    """The `Solution` of a search whose best set is `rows` with Q = `value` (as the
    batched evaluator computed it: no second compilation of Q for one set)."""
    if not np.isfinite(value):
        raise ValueError(
            "ocp_jax.place: Q is undefined for every candidate set (a camera on a curve or "
            "too close to it): move the placement away from the objects."
        )
    return Solution(
        cameras=_from_rows(jnp.asarray(rows), layout),
        value=jnp.asarray(value),
        result=RESULTS.successful,
        start_cameras=None,
        start_values=None,
        start_results=None,
        num_steps=None,
        num_evaluations=int(evaluations),
        seconds=time.perf_counter() - clock,
        violation=0.0,
        history=jnp.asarray(np.array(history, float).reshape(-1, 3)),
        paths=None,
        candidates=jnp.asarray(candidates),
        stage_values=tuple(jnp.asarray(s) for s in stages),
    )


def _report(progress: bool, what: str, history) -> None:
    if progress:
        seconds, evaluations, best = history[-1]
        print(
            f"  {what}: {evaluations} evaluations, best Q {best:.6g}, {seconds:.1f} s",
            file=sys.stderr,
            flush=True,
        )


class Greedy(AbstractPlacementSolver):
    """Greedy placement over a candidate grid (the thesis's baseline, Sec. 5.4): camera j
    goes to the candidate that maximises Q with cameras 1..j-1 fixed. k n evaluations for
    n candidates. For an objective of groups of l > 1 cameras (`Reconstruction`,
    `Coverage(m)`), fewer than l cameras have no value: the first l cameras are the best
    l-subset of the candidates (binomial(n, l) evaluations), the rest one at a time.

    **Arguments:**

    - `resolution`: candidates per edge (boundaries) or per axis (regions).
    - `chunk`: camera sets per compiled batch.
    """

    resolution: int = 128
    chunk: int = 512

    def solve(
        self, problem: Problem, n_cameras: int, key: PRNGKeyArray, progress: bool
    ) -> Solution:
        del key
        scene, objective, options = problem.scene, problem.objective, problem.options
        candidates, layout = _admissible_candidates(scene, problem.placement, self.resolution)
        clock = time.perf_counter()
        sets = candidates[camera_groups(objective, len(candidates))]  # every l-subset
        evaluations, stages, history = 0, [], []
        for _ in range(n_cameras - objective.group_size + 1):
            values, options = values_of_sets(scene, objective, options, sets, self.chunk, layout)
            evaluations += len(sets)
            stages.append(values)
            history.append((time.perf_counter() - clock, evaluations, values.max()))
            _report(progress, f"Greedy, stage {len(stages)}", history)
            chosen = sets[int(np.argmax(values))]
            sets = np.concatenate(
                [np.broadcast_to(chosen, (len(candidates), *chosen.shape)), candidates[:, None]],
                1,
            )
        return _search_solution(
            chosen, values.max(), layout, evaluations, clock, history, candidates, stages
        )


class Exhaustive(AbstractPlacementSolver):
    """The best k-subset of the candidates (binomial(n, k) evaluations), `chunk` sets at
    a time.

    **Arguments:**

    - `resolution`: candidates per edge (boundaries) or per axis (regions).
    - `chunk`: camera sets per compiled batch.
    - `max_evaluations`: more subsets than this are refused.
    """

    resolution: int = 128
    chunk: int = 4096
    max_evaluations: int = 10_000_000

    def solve(
        self, problem: Problem, n_cameras: int, key: PRNGKeyArray, progress: bool
    ) -> Solution:
        del key
        scene, objective, options = problem.scene, problem.objective, problem.options
        candidates, layout = _admissible_candidates(scene, problem.placement, self.resolution)
        total = math.comb(len(candidates), n_cameras)
        if total > self.max_evaluations:
            raise ValueError(
                f"ocp_jax.place: {total} subsets of {len(candidates)} candidates exceed "
                f"Exhaustive(max_evaluations={self.max_evaluations}); lower the resolution "
                "or raise the limit."
            )
        clock = time.perf_counter()
        subsets = itertools.combinations(range(len(candidates)), n_cameras)
        best_value, best_set, history, evaluations = -np.inf, None, [], 0
        while block := list(itertools.islice(subsets, self.chunk)):
            sets = candidates[np.asarray(block)]
            values, options = values_of_sets(scene, objective, options, sets, self.chunk, layout)
            evaluations += len(sets)
            if values.max() > best_value:
                best_value, best_set = values.max(), sets[int(np.argmax(values))]
            history.append((time.perf_counter() - clock, evaluations, best_value))
            _report(progress, "Exhaustive", history)
        return _search_solution(best_set, best_value, layout, total, clock, history, candidates, ())
