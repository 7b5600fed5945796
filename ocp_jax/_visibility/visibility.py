"""The global visibility objective Q (Eq. 3.15) and its exact gradient.

For cameras C_1..C_k, curves x_1..x_m and a local objective of groups of l cameras
(l = 1 for most objectives, 2 for `Reconstruction`),

    Q = sum_i int_0^1 max_G [chi_i(t, G) q(x_i(t), x_i'(t), G)] ||x_i'(t)|| dt,

the max over the l-subsets G of the cameras, chi_i(t, G) = 1 where every camera of G sees
x_i(t). The computation (Sec. 5.2): the events of every camera (tangency and shadow times,
the curves' breakpoints, and crossovers of the groups' q) cut each curve into intervals
on which the integrand is smooth. The continuous viewability matrix V (Eq. 5.35) says, per
interval and camera, whether the camera sees it: one test per interval of each camera's
own partition. On each interval one group has the largest q among those that see it (the
crossovers are cuts), decided at its midpoint. Gauss-Legendre quadrature of that group's
q on every interval then gives Q; since the interval ends are differentiable functions of
the cameras and the scene (implicit-function JVPs), reverse- or forward-mode autodiff
through the quadrature is exactly the Leibniz rule of Eq. 5.9. (Cuts where the integrand
is continuous, at crossovers and at the points nearest to the cameras, carry no
derivative: the Leibniz terms of the two intervals that meet there cancel.)
"""

import dataclasses
import functools
import itertools
import math
import warnings
from collections.abc import Callable, Sequence
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.core import Tracer
from jaxtyping import Array, ArrayLike, Bool, Float, Int, Real

from .._geometry.camera import Camera
from .._geometry.curves import to_frame
from .._geometry.frame import Frame, scene_frame
from .._geometry.scene import Scene
from .._geometry.vec import Vec, cross, dot, norm, scale, sub
from .._objectives.local import (
    AbstractLocalObjective,
    Foreshortened,
    VisibleLength,
    as_local_objective,
    camera_groups,
    group_members,
)
from .._objectives.smoothed import Smoothed, smoothed_value
from .._types import RESULTS
from .conics import (
    conic_distances,
    conic_extent,
    conic_occluded,
    conic_occluders,
    conic_orientation,
    conic_shadow_times,
    conic_tangency_times,
)
from .events import (
    Roots,
    Samples,
    bounding_discs,
    crossover_nodes,
    crossover_times,
    grazing_probes,
    grid_pieces,
    join_sources,
    polygon_edges,
    range_times,
    sample,
    shadow_slots,
    shadow_times,
    silhouette_corners,
    tangency_points,
    tangency_sources,
    tangency_times,
    wedge_edges,
    with_nearest_node,
)
from .occlusion import facing, in_view, orientation, visible_points
from .quadrature import gauss_legendre
from .roots import first_true, safe_divisor
from .xla_cpu import (
    SMALL_BATCH,
    computed_on_one_thread,
    fused_reduce,
    materialize,
    on_one_thread,
    sorted_rows,
)

__all__ = [
    "VisibilityOptions",
    "VisibleIntervals",
    "fit_options",
    "visibility",
    "visible_intervals",
]


class VisibilityOptions(eqx.Module):
    """Static sizes of the event computation (all Python ints; a pytree with no leaves).

    - `grid`: cells per curve for bracketing roots and occlusion tests; None (default)
      takes the scene's own choice (4 per B-spline knot span, 2 per Bezier degree but at
      least 16, 16 for conics). Two roots of one event function closer than a cell are
      still separated (Hermite split), but features much smaller than a cell need a finer
      grid.
    - `max_tangents`, `max_shadows` (shadows of tangency points and the crossings of a
      view wedge's edges), `max_range_crossings` (of a camera's range circle): root
      budgets per curve and camera; `max_crossovers`: per curve and pair of camera
      groups (of cameras, or of camera pairs for `Reconstruction`). A ray from a
      tangency point, a corner or a wedge edge casts one shadow at most, where it first
      crosses a curve beyond its source (behind that, the curve it crossed hides both
      sides of the ray). On a polygon (`PiecewiseCurve` of degree 1: walls, furniture)
      the crossings have a closed form and every ray has a slot, so no budget applies
      there, and a polygon has no tangency slots. On a curved object `max_shadows` bounds
      the rays that pass its bounding disc before they surely have crossed a curve (an
      edge of a polygon, an object's inscribed disc, a curved room), and a curved room,
      which every ray meets, has a slot for every ray besides it. On the random floors of
      `benchmarks/floors.py` (up to 128 cells, 64 objects, 64 cameras) an object holds at
      most 11 such rays, its own among them: this bound depends on the data (a large
      curved object that many rays pass close to needs more).
      Called outside any jit, `visibility`, `visible_intervals`, `place` and the plots
      grow an overflowed budget and compile again,
      with a warning; inside a jit an overflow raises an error naming the option
      (`fit_options` sizes every budget for given cameras). Every array after the root
      solves is sized by them, used or not: for scenes known to need fewer slots,
      smaller budgets can be a simple speed-up (the banana and 3 blobs use at most 4
      tangency and 6 shadow slots). In a scene of conics only
      (circles, ellipses) the tangency and shadow times have closed forms: two tangency
      times per conic, and one shadow slot per ray and conic, packed into `max_shadows`
      only where there are more rays.
    - `max_intervals`: the intervals between the events of all cameras that are
      integrated, over the whole scene (the budgets above are per camera and rarely all
      used at once); None (default) takes every curve's panels and real corners plus
      half of the cameras' event budgets (for a scene of conics, all of its closed-form
      event slots); `fit_options` sets it to what given cameras need.
    - `max_camera_intervals`: per camera, the intervals of its own partition (of
      positive length, over the whole scene) that are tested for visibility (the test of
      every query point against every curve is the costliest step of scenes with many
      objects); None (default) takes every interval a camera can have within the root
      budgets above: one per curve and one after each corner, tangency slot, ray (a ray
      has one first crossing) and range slot, so it holds wherever they do
      (`fit_options` sets it to what given cameras need).
    - `quadrature`: Gauss-Legendre nodes per interval; intervals are also cut at each
      curve's panel `breakpoints`. 16 nodes give ~1e-12 relative error for cameras at
      a fair distance; a camera very close to a curve makes q = cos^2 nearly singular
      there (1e-11 at 1.2 r from a circle of radius r, 2e-8 at 1.05 r, 5e-6 at 1.01 r):
      32 nodes bring these to 1e-15, 1e-15 and 7e-11. A camera closer to a curve than
      (2.5 / quadrature)^2 of its radius raises an error (for camera-dependent q).
    - `newton_iterations`: the most safeguarded Newton steps per root search (it stops
      once every root is final, mostly after 2-4); a search that is not done by then
      raises an error. A camera close to a curve needs more: its nearest point splits a
      cell, and a tangency time right beside that point is approached from the cell's
      far end, halving the distance per step (the banana from 1e-6, 1.7e-8 of its size,
      just outside the distance at which a camera counts as on the curve: up to 22).
    """

    grid: int | None = eqx.field(static=True, default=None)
    max_tangents: int = eqx.field(static=True, default=8)
    max_shadows: int = eqx.field(static=True, default=16)
    max_crossovers: int = eqx.field(static=True, default=16)
    max_range_crossings: int = eqx.field(static=True, default=8)
    max_intervals: int | None = eqx.field(static=True, default=None)
    max_camera_intervals: int | None = eqx.field(static=True, default=None)
    quadrature: int = eqx.field(static=True, default=16)
    newton_iterations: int = eqx.field(static=True, default=32)

    def __check_init__(self):
        for name in (
            "grid",
            "max_tangents",
            "max_shadows",
            "max_crossovers",
            "max_range_crossings",
            "max_intervals",
            "max_camera_intervals",
            "quadrature",
            "newton_iterations",
        ):
            value = getattr(self, name)
            if name in ("grid", "max_intervals", "max_camera_intervals") and value is None:
                continue
            if not isinstance(value, (int, np.integer)) or value < 1:
                raise ValueError(f"VisibilityOptions.{name} must be a positive int, got {value!r}.")
        if self.grid is not None and self.grid < 8:
            raise ValueError(f"VisibilityOptions.grid must be >= 8, got {self.grid}.")


class CameraPartition(NamedTuple):
    """One camera's events on every curve, sorted, and what it sees between them."""

    events: Float[Array, "m e"]  # interval k is [events[k], events[k+1]] (events[e] := 1)
    visible: Bool[Array, "m e"]
    tangents: Roots
    shadows: Roots  # of the tangency points and of the view wedge's edges
    ranges: Roots | None  # crossings of the range circle


class Nearest(NamedTuple):
    """The point of every curve i nearest to every camera c, arrays (m, k)."""

    distance: Float[Array, "m k"]
    outward: Float[Array, "m k"]  # negative where the camera is not in free space
    t: Float[Array, "m k"]


class Events(NamedTuple):
    """Every camera's partition of every curve, and what the checks and Q need with it
    (lengths in the coordinates of the scene and cameras given to `_events`: the scene's
    frame, `_frame.py`)."""

    partitions: CameraPartition  # batched over the cameras
    groups: np.ndarray  # (G, l) indices of the cameras of each group
    crossovers: Roots | None  # batched over the pairs of groups
    samples: Samples
    sense: Float[Array, " m"]
    cameras: Vec  # the positions
    poses: Camera
    nearest: Nearest  # the point of every curve nearest to every camera (no derivative)


def _poses(scene: Scene, cameras) -> Camera:
    """`cameras` as a `Camera` batched over k >= 1 cameras, in the scene's float type."""
    if not isinstance(scene, Scene):
        raise TypeError(f"scene must be an ocp_jax.Scene, got {type(scene).__name__}.")
    if not isinstance(cameras, Camera):
        cameras = jnp.asarray(cameras)
        if cameras.ndim == 1:
            cameras = cameras[None]
        if cameras.ndim != 2 or cameras.shape[-1] != 2 or cameras.shape[0] < 1:
            raise ValueError(
                "cameras must have shape (k, 2) with k >= 1 (one row per camera), or be an "
                f"ocp.Camera, got {cameras.shape}."
            )
        cameras = Camera(cameras)
    if cameras.position.ndim == 1:
        cameras = jax.tree.map(lambda a: a[None], cameras)
    if cameras.position.ndim != 2 or cameras.shape[0] < 1:
        raise ValueError(
            f"a Camera's position must have shape (k, 2) with k >= 1, got {cameras.position.shape}."
        )
    dtype = jnp.result_type(cameras.position.dtype, scene.dtype, float)
    return jax.tree.map(lambda a: a.astype(dtype), cameras)


def _sense(scene: Scene, samples: Samples) -> Float[Array, " m"]:
    """+1 where the free space lies to the left of x' (counter-clockwise objects,
    clockwise rooms), -1 where it lies to the right."""
    if scene.conics_only:  # (closed forms: a scene of conics needs no samples, `_conics.py`)
        turning = conic_orientation(jax.lax.stop_gradient(scene.conic_frames()))
    else:
        turning = orientation(samples)
    return turning * jnp.asarray(scene.sides(), samples.t.dtype)


def _as_input(cameras):
    return cameras if isinstance(cameras, Camera) else jnp.asarray(cameras)


def _intervals(events: Float[Array, "m e"]):
    ends = jnp.concatenate([events[:, 1:], jnp.ones_like(events[:, :1])], 1)
    return events, ends


def _fixed_slots(scene: Scene, events, ranges: Roots | None) -> int:
    """Of one camera's event slots (the last axis of `events`), those that the interval
    budgets keep whole. For a scene of conics, all but the range circle's crossings (a
    root budget, like those of other curves): the closed-form slots hold every event that
    can occur, and a room or a large object behind small ones fills them. Else the
    corners of each curve (every camera repeats them)."""
    if scene.conics_only:
        return events.shape[-1] - (0 if ranges is None else ranges.t.shape[-1])
    return scene.corners()[0].shape[1] if scene.has_corners else 0


def _real_fixed(scene: Scene, fixed: int) -> int:
    """Of one camera's `fixed` event slots on every curve (`_fixed_slots`), those that
    hold an event on some curve, over the whole scene: for a scene of conics all of
    them, else the real corners (the curves' corner lists are padded to the longest)."""
    if scene.conics_only:
        return len(scene) * fixed
    return int(scene.corners()[1].sum()) if scene.has_corners else 0


def _unused_slots(scene: Scene, shadows: Roots, options, wedge: bool) -> int:
    """Of one camera's event slots over the scene, those that never hold an event: of
    the shadow slots (`shadow_times`), all but those that can hold a first crossing of
    one of its rays (`shadow_slots`; `wedge`: whether the cameras have a view wedge)."""
    if scene.conics_only:
        return 0
    width, capacity = shadow_slots(scene, _ray_count(scene, options, wedge), options.max_shadows)
    assert width == shadows.t.shape[-1]
    return len(scene) * width - capacity


def _ray_count(scene: Scene, options, wedge: bool) -> int:
    """The number of one camera's ray sources (`_camera_partition`): its tangency slots
    on every curved curve (`tangency_sources`), the corners and a view wedge's two
    edges."""
    corners = int(scene.corners()[1].sum()) if scene.has_corners else 0
    curved = len(scene) - int(scene.straight().sum())
    return curved * options.max_tangents + corners + 2 * wedge


def _flat_budget(
    scene: Scene, option: int | None, slots: int, fixed: int, kept: int, unused: int
) -> int:
    """A static budget of the intervals of every curve's row of `slots` sorted events
    (padded with t = 1), over the whole scene, of which `unused` never hold one:
    `option`, or by default the `kept` ones (every curve's real fixed events:
    breakpoints, corners, closed-form events) plus half of the other slots, the cameras'
    root budgets, which are rarely all used at once."""
    m = len(scene)
    capacity = m * slots - unused
    if option is not None:
        return min(option, capacity)
    return min(capacity, kept + m * ((slots - fixed + 1) // 2) - (unused + 1) // 2)


def _camera_interval_budget(
    scene: Scene, options, events, shadows: Roots, ranges: Roots | None, wedge: bool
) -> int:
    """The static number of one camera's intervals (of positive length, over the whole
    scene) that are tested for visibility (the arrays may be batched over cameras;
    `wedge`: whether the cameras have a view wedge): `max_camera_intervals`, or by
    default every interval a camera can have within its root budgets, one on every curve
    before its first event and one after each event: the corners, the tangency slots of
    the curved curves, one first crossing per ray (`shadow_slots`; one more per curved
    object, where a ray grazes it and its two crossings tie) and the range slots. For a
    scene of conics, `_flat_budget` of its closed-form slots."""
    fixed = _fixed_slots(scene, events, ranges)
    slots, unused = events.shape[-1], _unused_slots(scene, shadows, options, wedge)
    if scene.conics_only or options.max_camera_intervals is not None:
        kept = _real_fixed(scene, fixed) + len(scene)
        return _flat_budget(scene, options.max_camera_intervals, slots, fixed, kept, unused)
    m, rays = len(scene), _ray_count(scene, options, wedge)
    curved = m - int(scene.straight().sum())
    crossings = min(rays + curved, shadow_slots(scene, rays, options.max_shadows)[1])
    in_range = 0 if ranges is None else m * ranges.t.shape[-1]
    every = m + _real_fixed(scene, fixed) + curved * options.max_tangents + crossings + in_range
    return min(m * slots - unused, every)


def _camera_partition(
    scene, pose: Camera, samples, sense, nearest, options, one_thread: bool
) -> CameraPartition:
    """One camera's events on every curve and which intervals between them it sees
    (`nearest`: the camera's nearest points t* on the curves, extra nodes of its grid for
    the tangency search and the occlusion test, `with_nearest_node`)."""
    iters = options.newton_iterations
    camera = Vec.of(pose.position)
    frozen = jax.lax.stop_gradient(pose)  # the visibility decisions carry no derivative
    conics = scene.conic_frames() if scene.conics_only else None  # closed-form events
    if conics is not None:
        tangents = conic_tangency_times(conics, camera)
    else:
        grid = with_nearest_node(scene, samples, nearest)
        tangents = tangency_times(scene, camera, grid, options.max_tangents, iters)
    points = tangency_points(scene, tangents)
    sources = tangency_sources(scene, points)
    pieces = [jnp.zeros_like(tangents.t[:, :1]), tangents.t]
    if scene.has_corners:
        sources = join_sources(sources, silhouette_corners(scene, camera, samples))
        pieces.append(jnp.asarray(scene.corners()[0], tangents.t.dtype))
    if pose.half_fov is not None:
        # Shadows of tangency points out of view fall where nothing is in view.
        sources = sources._replace(valid=sources.valid & in_view(frozen, sources.point))
        edges = pose.heading + jnp.stack([pose.half_fov, -pose.half_fov])
        sources = join_sources(sources, wedge_edges(camera, Vec(jnp.cos(edges), jnp.sin(edges))))
    if conics is not None:
        shadows = conic_shadow_times(conics, camera, sources, options.max_shadows)
    else:
        probes = grazing_probes(camera, samples, tangents, points)
        shadows = shadow_times(scene, camera, samples, sources, probes, options.max_shadows, iters)
    pieces.append(shadows.t)
    ranges = None
    if pose.range is not None:
        ranges = range_times(scene, camera, pose.range, samples, options.max_range_crossings, iters)
        pieces.append(ranges.t)
    events = sorted_rows(jnp.concatenate(pieces, 1))
    # The visibility decision carries no derivative. The intervals of positive length,
    # over the whole scene, are tested (at most `tested`: their count is checked in
    # `_budgets`), as one flat list of queries.
    start, end = jax.lax.stop_gradient(_intervals(events))
    m, slots = events.shape
    tested = _camera_interval_budget(
        scene, options, events, shadows, ranges, pose.half_fov is not None
    )
    index, filled, _ = first_true((end > start).ravel(), tested)
    curve = index // slots
    t_mid = (0.5 * (start + end)).ravel()[index]
    x_mid, dx_mid = jax.tree.map(
        lambda a: a.ravel()[index],
        _stored_points(jax.lax.stop_gradient(scene), 0.5 * (start + end)),
    )
    seen_from = Vec.of(frozen.position)
    if conics is not None:
        occluders = conic_occluders(jax.lax.stop_gradient(scene))
        assert occluders is not None  # (a scene of conics only)
        blocked = conic_occluded(occluders, seen_from, x_mid, curve)
        visible = facing(seen_from, sense[curve], x_mid, dx_mid) & ~blocked
    else:
        smooth = None  # the smooth piece of each cell of the camera's grid, for corners
        if scene.has_corners:
            smooth = grid_pieces(scene.pieces(samples.t.shape[0] - 1), grid)
        probes = grazing_probes(camera, grid, tangents, points)  # on the camera's grid
        edges = polygon_edges(scene, samples)
        occluders = conic_occluders(jax.lax.stop_gradient(scene))
        visible = visible_points(
            seen_from,
            grid,
            sense,
            curve,
            t_mid,
            x_mid,
            dx_mid,
            probes,
            smooth,
            edges,
            occluders,
            one_thread,
        )
    visible = visible & in_view(frozen, x_mid) & filled
    # (slots past the count drop out: their index is out of range)
    visible = (
        jnp.zeros(m * slots, bool).at[jnp.where(filled, index, m * slots)].set(visible, mode="drop")
    )
    visible = visible.reshape(m, slots)
    return CameraPartition(events, visible, tangents, shadows, ranges)


def _integrand(t, args, one_thread: bool):
    """q(x(t), x'(t), G) ||x'(t)|| of each interval's best group G (`_best_group`), zero
    where it does not see the interval, for t of shape (e, g) on the curves `curve` (e,)
    (the group's cameras: `Vec`s of shape (e, 1); whether it sees: `seen`, shape (e,))."""
    scene, curve, *rest = args
    if one_thread:
        # x, x' and q in one kernel: the four coordinates share the curve's powers of t
        # there, where stored as one stack (a concatenation, a branch per element) each
        # would compute them again, unvectorized.
        def integrand(scene, curve, t, rest):
            return _integrand_at(*scene.components_at(curve, t)[:2], *rest)

        return computed_on_one_thread(integrand, (scene, curve, t, rest), scene)
    rows = materialize(scene.point_and_tangent_at(curve, t), scene)
    return _integrand_at(Vec(rows[0], rows[1]), Vec(rows[2], rows[3]), *rest)


def _stored_points(scene: Scene, t) -> tuple[Vec, Vec]:
    """x(t) and x'(t) on every curve (row i of t on curve i), computed once and stored
    (`materialize`) as one array of rows (`Scene.point_and_tangent`)."""
    rows = materialize(scene.point_and_tangent(t), scene)
    return Vec(rows[:, 0], rows[:, 1]), Vec(rows[:, 2], rows[:, 3])


def _integrand_at(x: Vec, dx: Vec, cameras, objective, seen):
    """The integrand from the curve's points x and derivatives x' (see `_integrand`)."""
    return jnp.where(seen[..., None], objective.evaluate(x, dx, *cameras), 0.0) * norm(dx)


def _best_group(scene: Scene, curve, start, end, members, objective, seen):
    """The group whose q is largest on each interval among those that see it (Eq. 3.15's
    max), decided at its midpoint (a decision: no derivative). Between consecutive
    events no two groups' q cross (their crossovers are events), so one group is the
    best on the whole interval and the quadrature evaluates its q alone: G + g
    evaluations of q per interval of g nodes, not G g.

    **Arguments:**

    - `members`: the groups' cameras, one `Vec` of shape (G,) per member.
    - `seen`: (G, e), whether each group sees each interval.

    **Returns:** the best group's members, `Vec`s of shape (e, 1) (or (1, 1) for one
    group), and whether it sees each interval, (e,).
    """
    if seen.shape[0] == 1:
        return tuple(c.map(lambda a: a[:, None]) for c in members), seen[0]
    frozen_scene, middle, frozen_members, frozen_objective = jax.lax.stop_gradient(
        (scene, 0.5 * (start + end), members, objective)
    )
    rows = frozen_scene.point_and_tangent_at(curve, middle)
    x, dx = Vec(rows[0], rows[1]), Vec(rows[2], rows[3])

    def seen_by(g):  # chi q of group g on each interval, and whether g sees it
        q = frozen_objective.evaluate(x, dx, *(c.map(lambda a: a[g]) for c in frozen_members))
        return jnp.where(seen[g], q, 0.0), seen[g]

    def larger(g, best):  # the larger chi q; in a tie, a group that sees the interval
        q, sees, index = best
        q_g, sees_g = seen_by(g)
        better = (q_g > q) | ((q_g == q) & sees_g & ~sees)
        return tuple(jnp.where(better, new, old) for new, old in zip((q_g, sees_g, g), best))

    # (a loop over the groups: the program does not grow with their number)
    first = (*seen_by(0), jnp.zeros(curve.shape, int))
    best = jax.lax.fori_loop(1, seen.shape[0], larger, first)[2]
    chosen = tuple(c.map(lambda a: a[best][:, None]) for c in members)
    return chosen, jnp.take_along_axis(seen, best[None], 0)[0]


def _closest_points(scene, cameras: Vec, samples: Samples, sense):
    """For every curve i and camera c, the point x_i(t*) nearest to C_c: the nearest chord
    of the grid (exact for polygons, whose cells are straight), refined by safeguarded
    Newton on (x(t) - C) . x'(t) = 0 from the projection onto it, within that cell (and,
    for smooth curves, the cells beside it). The nearest grid node is not enough: on a
    coarse grid (a polygon's edges are one cell each) it may lie on another edge than the
    nearest point, whose outward side then says nothing about the camera's.
    Returns (distance, signed offset along the outward normal, t*), arrays (m, k)."""
    camera = cameras.map(lambda a: a[None, None])  # (1, 1, k)
    start = samples.x.map(lambda a: a[:, :-1, None])  # (m, N, 1): cell j is [t_j, t_j+1]
    chord = sub(samples.x.map(lambda a: a[:, 1:, None]), start)
    rel = sub(camera, start)
    along = jnp.clip(dot(rel, chord) / safe_divisor(dot(chord, chord)), 0.0, 1.0)
    gap = sub(rel, scale(along, chord))
    cell = jnp.argmin(dot(gap, gap), axis=1)  # (m, k)
    along = jnp.take_along_axis(along, cell[:, None], axis=1)[:, 0]
    h = samples.t[1] - samples.t[0]
    low = samples.t[cell]
    widen = 0.0 if scene.has_corners else h  # Newton cannot cross a corner
    camera = cameras.map(lambda a: a[None])  # (1, k)

    def newton(_, t):
        x, dx, ddx = scene.components(jnp.mod(t, 1.0))
        sight = sub(x, camera)
        step = dot(sight, dx) / safe_divisor(dot(dx, dx) + dot(sight, ddx))
        return jnp.clip(t - step, low - widen, low + h + widen)

    def outward(dx, offset):  # offset along the outward normal -J x' / |x'|
        return -sense[:, None] * cross(dx, offset) / safe_divisor(norm(dx))

    t = jax.lax.fori_loop(0, 6, newton, low + along * h)
    x, dx, _ = scene.components(jnp.mod(t, 1.0))
    offset = sub(camera, x)
    distance, side = norm(offset), outward(dx, offset)
    if scene.has_corners:
        # The nearest point may be a corner (an end of the cell), where x' jumps. There
        # the camera is outside if it is outside either edge at a convex corner, both
        # edges at a reflex one.
        node = jnp.where(along < 0.5, low, low + h)
        corner, right, _ = scene.components(jnp.where(node == 1.0, 0.0, node))
        _, left, _ = scene.components_left(jnp.where(node == 0.0, 1.0, node))
        offset = sub(camera, corner)
        out_right, out_left = outward(right, offset), outward(left, offset)
        convex = sense[:, None] * cross(left, right) >= 0
        corner_side = jnp.where(
            convex, jnp.maximum(out_right, out_left), jnp.minimum(out_right, out_left)
        )
        at_corner = norm(offset) <= distance
        distance = jnp.where(at_corner, norm(offset), distance)
        side = jnp.where(at_corner, corner_side, side)
        t = jnp.where(at_corner, node, t)
    return distance, side, jnp.mod(t, 1.0)


def _nearest_points(scene, cameras: Vec, samples: Samples, sense) -> Nearest:
    """`_closest_points`, or its closed forms for a scene of conics (`_conics.py`); no
    derivative (the checks are decisions, and the cuts at t* need none)."""
    scene, cameras = jax.lax.stop_gradient((scene, cameras))
    if scene.conics_only:
        return Nearest(*conic_distances(scene.conic_frames(), scene.sides(), cameras))
    return Nearest(*_closest_points(scene, cameras, samples, sense))


def _check_cameras(scene, cameras: Vec, nearest: Nearest, samples: Samples, quadrature: int):
    """Cameras must be finite, off every curve (closer than sqrt(eps) times the scene's
    size counts as on it) and outside every object (on the outward side of the nearest
    point of each curve).

    `too_close`: closer to a curve than (2.5 / quadrature)^2 of the curve's radius, where
    a camera-dependent q is so nearly singular that `quadrature` nodes per interval no
    longer reach ~1e-7 (measured on circles: 2e-8 at 5% of the radius, 5e-6 at 1%; Q's
    intervals are cut at the nearest points, `_value`)."""
    distance, outward = nearest.distance, nearest.outward
    if scene.conics_only:  # closed forms (`_conics.py`)
        size, radius = conic_extent(scene.conic_frames())
    else:
        size = fused_reduce(jnp.max, jnp.abs(samples.x.x), None)
        size = size + fused_reduce(jnp.max, jnp.abs(samples.x.y), None)
        _, radius = bounding_discs(samples)
    on_curve = jnp.any(distance <= jnp.sqrt(jnp.finfo(distance.dtype).eps) * size, axis=0)
    inside = jnp.any(outward < 0, axis=0) & ~on_curve
    near = distance < (2.5 / quadrature) ** 2 * radius[:, None]
    too_close = jnp.any(near & scene.observed()[:, None], axis=0) & ~on_curve
    finite = jnp.isfinite(cameras.x) & jnp.isfinite(cameras.y)
    return finite, inside, on_curve, too_close


def _events(scene: Scene, poses: Camera, objective, options: VisibilityOptions) -> Events:
    """The events of every camera on every curve, and their crossovers (for several
    cameras and a camera-dependent q)."""
    cameras = Vec.of(poses.position)
    samples = sample(jax.lax.stop_gradient(scene), options.grid or scene.grid_cells())
    sense = _sense(scene, samples)
    nearest = _nearest_points(scene, cameras, samples, sense)
    # the visibility test on one thread up to SMALL_BATCH cameras, the integrand for one
    one_thread = on_one_thread(cameras.x.shape[0], SMALL_BATCH)
    partition = functools.partial(_camera_partition, one_thread=one_thread)
    partitions = jax.vmap(partition, in_axes=(None, 0, None, None, 1, None))(
        scene, poses, samples, sense, nearest.t, options
    )
    groups = camera_groups(objective, cameras.x.shape[0])
    crossovers = None
    if len(groups) > 1 and not objective.is_constant:
        pairs = np.array(list(itertools.combinations(range(len(groups)), 2)))
        # A group sees something of a curve where each of its cameras does.
        sees = jnp.all(jnp.any(partitions.visible, -1)[groups], 1)  # (G, m)
        first, second = groups[pairs[:, 0]], groups[pairs[:, 1]]
        members = np.concatenate([first, second], 1)  # (pairs, 2l) camera indices
        crossovers = crossover_times(
            scene,
            (group_members(cameras, first), group_members(cameras, second)),
            (*crossover_nodes(samples, cameras), members),
            sees[pairs[:, 0]] & sees[pairs[:, 1]],
            objective,
            samples,
            options.max_crossovers,
            options.newton_iterations,
        )
    return Events(partitions, groups, crossovers, samples, sense, cameras, poses, nearest)


def _viewable(
    partitions: CameraPartition,
    curve: Int[Array, " e"],
    start: Float[Array, " e"],
    column: Int[Array, " e"],
    offset: int,
) -> Bool[Array, "k e"]:
    """Whether each camera sees each union interval (`_value`): interval j, on curve
    `curve[j]` from `start[j]`, lies in the interval of camera c that starts at the last
    of c's events at or before its start in the union's order (c's first interval if
    none). The union is sorted stably from the other pieces (columns before `offset`) and
    then every camera's row of events in turn (`column`: the union's column that starts
    interval j), so in a tie with the start, c's events come before it where c's row
    comes before the start's (after it for the other pieces and for cameras after c),
    and a start that is c's own slot s follows s + 1 of c's events. The count is a
    binary search of c's sorted row: O(k e log L), no array over the whole union per
    camera.

    Where an event ties with another piece (a panel breakpoint, say), the zero-length
    interval between them comes before the event and is looked up on the event's near
    side: its end carries the event's derivative, which belongs to the interval after it
    (Leibniz)."""
    events, visible = jax.lax.stop_gradient(partitions.events), partitions.visible
    k, _, slots = events.shape
    source = jnp.where(column >= offset, (column - offset) // slots, -1)
    camera = jnp.arange(k)[:, None]
    tie_before = camera < source[None]  # (k, e)
    row = curve[None]
    lo, hi = jnp.zeros((k, start.shape[0]), int), jnp.full((k, start.shape[0]), slots)
    for _ in range(int(slots).bit_length()):  # lo: the count of c's events before it
        mid = (lo + hi) // 2
        at = events[camera, row, jnp.minimum(mid, slots - 1)]
        before = (at < start[None]) | ((at == start[None]) & tie_before)
        active = lo < hi
        lo, hi = jnp.where(active & before, mid + 1, lo), jnp.where(active & ~before, mid, hi)
    own = (column - offset) % slots + 1
    count = jnp.where(camera == source[None], own[None], lo)
    return visible[camera, row, jnp.maximum(count - 1, 0)]


def _value(scene: Scene, events: Events, objective, options: VisibilityOptions):
    """Q by quadrature on the union of all events (with the curves' panel breakpoints),
    and the intervals used per curve with their static budget."""
    partitions, crossovers = events.partitions, events.crossovers
    pieces = [scene.breakpoints()]
    # A camera-dependent q is nearly singular at the point nearest to a close camera
    # (poles at about the relative distance from the real axis): cut there, so that the
    # Gauss-Legendre nodes crowd towards it from both sides.
    cut = not objective.is_constant
    if cut:
        pieces.append(events.nearest.t)
    if crossovers is not None:  # (pairs, m, budget): one row of m per curve
        pieces.append(jnp.moveaxis(crossovers.t, 0, 1).reshape(crossovers.t.shape[1], -1))
    # (the cameras' events last: in a tie, they come after the other pieces, as the
    # viewability lookup `_viewable` needs, which reads each union entry's column)
    camera_events = partitions.events  # (k, m, L)
    k, m, per_row = camera_events.shape
    others = jnp.concatenate(pieces, 1)
    rows = jnp.concatenate([others, jnp.moveaxis(camera_events, 0, 1).reshape(m, -1)], 1)
    # Padded events sit at t = 1 (the end of each row). Every camera repeats the corners
    # among its events (zero-length intervals); the closed-form events of conics and the
    # nearest points are kept whole.
    per_camera = _fixed_slots(scene, camera_events, partitions.ranges) + cut
    fixed = pieces[0].shape[1] + k * per_camera
    slots = rows.shape[1]
    kept = m * pieces[0].shape[1] + k * (_real_fixed(scene, per_camera - cut) + m * cut)
    wedge = events.poses.half_fov is not None
    unused = k * _unused_slots(scene, partitions.shadows, options, wedge)
    budget = _flat_budget(scene, options.max_intervals, slots, fixed, kept, unused)
    # The union is one flat list over the scene of the rows' events before t = 1 (at
    # most `budget` of them), sorted by curve, time and column (each row's stable
    # order), so that its sort costs what the events are, not the widest row times the
    # curves. Each event starts an interval that ends at the next event of its curve.
    index, filled, used = first_true((jax.lax.stop_gradient(rows) < 1.0).ravel(), budget)
    start = jnp.where(filled, rows.ravel()[index], 1.0)
    at = jax.lax.stop_gradient(jnp.where(start == 0.0, 0.0, start))  # (-0 and 0 tie)
    curve, _, column, start = jax.lax.sort(
        (jnp.where(filled, index // slots, m), at, index % slots, start), num_keys=3
    )
    next_on_curve = jnp.concatenate([curve[1:] == curve[:-1], jnp.zeros(1, bool)])
    filled = curve < m
    end = jnp.where(next_on_curve & filled, jnp.concatenate([start[1:], start[:1]]), 1.0)
    curve = jnp.where(filled, curve, 0)

    seen = _viewable(
        partitions,
        curve,
        jax.lax.stop_gradient(start),
        column,
        others.shape[1],
    )
    seen = seen & jnp.asarray(scene.observed())[curve][None] & filled[None]
    seen_by_group = jnp.all(seen[events.groups], axis=1)  # (G, e)

    members = group_members(events.cameras, events.groups)
    chosen, seen = _best_group(scene, curve, start, end, members, objective, seen_by_group)
    args = (scene, curve, chosen, objective, seen)
    integrand = functools.partial(
        _integrand, one_thread=on_one_thread(events.cameras.x.shape[0], 1)
    )
    integrals = gauss_legendre(integrand, start, end, args, options.quadrature)  # (e,)
    value = fused_reduce(jnp.sum, integrals, None)
    return value, (used, budget)


def _input_failures(scene, poses: Camera, nearest, samples, quadrature: int, camera_dependent):
    """The checks on the cameras and the scene: a list of (failure flag, message)
    (`camera_dependent`: whether q depends on the camera, see `_check_cameras`)."""
    pose_angles = [a for a in (poses.heading, poses.half_fov, poses.range) if a is not None]
    finite, inside, on_curve, too_close = _check_cameras(
        jax.lax.stop_gradient(scene), Vec.of(poses.position), nearest, samples, quadrature
    )
    return [
        (~jnp.all(finite), "ocp_jax: a camera position is NaN or inf; pass finite coordinates."),
        # (before the cameras' places: a NaN or inf curve puts them anywhere)
        (~_finite_scene(scene, samples), "ocp_jax: the scene contains NaN or inf control points."),
        (
            ~jnp.all(jnp.stack([jnp.all(jnp.isfinite(a)) for a in pose_angles])),
            "ocp_jax: a camera's heading, half_fov or range is NaN or inf (a range of inf: "
            "pass range=None for an unlimited one).",
        ),
        (
            jnp.any(inside),
            "ocp_jax: a camera lies inside an object (or outside the room); cameras must be "
            "outside every object and inside the room.",
        ),
        (jnp.any(on_curve), "ocp_jax: a camera lies on a curve; move it off the object."),
        (
            jnp.any(too_close) & camera_dependent,
            f"ocp_jax: a camera is closer to a curve than {(2.5 / quadrature) ** 2:.2g} "
            "of its radius, where the local objective is too nearly singular for "
            f"{quadrature} quadrature nodes: move it away or pass "
            "options=ocp.VisibilityOptions(quadrature=...) with more nodes.",
        ),
    ]


def _finite_scene(scene, samples) -> Array:
    """Whether the scene's samples are finite (for a scene of conics, which needs no
    samples, its parameters)."""
    if scene.conics_only:
        return jnp.all(jnp.stack([jnp.all(jnp.isfinite(a)) for a in jax.tree.leaves(scene)]))
    return fused_reduce(jnp.all, jnp.isfinite(samples.x.x) & jnp.isfinite(samples.x.y), None)


class Budget(NamedTuple):
    """One static size of the event computation and what a call needed of it."""

    option: str  # the `VisibilityOptions` field
    needed: Int[Array, ""]  # the largest count over the curves (and cameras)
    budget: int  # the size the call was compiled with
    what: str


def _budgets(scene, events: Events, options, intervals=None) -> list[Budget]:
    """Every budgeted size of the call, with the largest count it had to hold
    (`intervals`: the union intervals used and their budget, where Q was integrated)."""
    partitions, crossovers = events.partitions, events.crossovers
    budgets = [
        Budget(
            "max_tangents",
            jnp.max(partitions.tangents.count),
            options.max_tangents,
            "tangency times on one curve",
        ),
        Budget(
            "max_shadows",
            jnp.max(partitions.shadows.count),
            options.max_shadows,
            "shadow times on one curve",
        ),
    ]
    if partitions.ranges is not None:
        budgets.append(
            Budget(
                "max_range_crossings",
                jnp.max(partitions.ranges.count),
                options.max_range_crossings,
                "range circle crossings on one curve",
            )
        )
    wedge = events.poses.half_fov is not None
    tested = _camera_interval_budget(
        scene, options, partitions.events, partitions.shadows, partitions.ranges, wedge
    )
    start, end = jax.vmap(_intervals)(partitions.events)
    count = jnp.max(fused_reduce(jnp.sum, end > start, (-1, -2)))
    budgets.append(
        Budget("max_camera_intervals", count, tested, "event intervals of one camera in the scene")
    )
    if crossovers is not None:
        budgets.append(
            Budget(
                "max_crossovers",
                jnp.max(crossovers.count),
                options.max_crossovers,
                "crossover times on one curve",
            )
        )
    if intervals is not None:
        used, budget = intervals
        budgets.append(
            Budget("max_intervals", jnp.max(used), budget, "event intervals in the scene")
        )
    return budgets


def _budget_failures(budgets: list[Budget]):
    return [
        (
            b.needed > b.budget,
            f"ocp_jax: more {b.what} than the budget of {b.budget}, in a call "
            "compiled inside a jit (outside one, ocp_jax sizes its budgets itself): pass "
            f"options=ocp.VisibilityOptions({b.option}=...) with a larger value, or "
            "ocp.fit_options(scene, cameras) to size every budget for these cameras.",
        )
        for b in budgets
    ]


def _event_failures(scene, events: Events, options, camera_dependent: bool):
    """The checks on the input (`_input_failures`) and on the root searches: a list of
    (failure flag, message)."""
    partitions, crossovers = events.partitions, events.crossovers
    failures = _input_failures(
        scene, events.poses, events.nearest, events.samples, options.quadrature, camera_dependent
    )
    searches = [partitions.tangents, partitions.shadows, partitions.ranges, crossovers]
    unsettled = [~jnp.all(roots.settled) for roots in searches if roots is not None]
    failures.append(
        (
            jnp.any(jnp.stack(unsettled)),
            f"ocp_jax: a root search was not done in {options.newton_iterations} Newton "
            "steps (a camera very close to a curve?): pass "
            "options=ocp.VisibilityOptions(newton_iterations=...) with a larger value.",
        )
    )
    return failures


def _checked(carrier, failed, messages):
    """`carrier`, or an error with the first failure's message (see `_failures`)."""
    # One check for all (each error_if is a conditional in the compiled program).
    return eqx.branched_error_if(carrier, jnp.any(failed), jnp.argmax(failed), messages)


def _in_scene_frame(scene, cameras) -> tuple[Frame, Scene, Camera]:
    """The scene's frame, and the scene and the cameras' poses in it: there the engine's
    products of lengths neither underflow nor overflow (`_frame.py`)."""
    poses = _poses(scene, cameras)  # (first: it checks that `scene` is a Scene)
    frame = scene_frame(scene)
    return frame, scene.in_frame(*frame), poses.in_frame(*frame)


def _value_and_checks(scene, cameras, objective, options):
    """Q (exact, or smoothed for a `Smoothed` objective), the checks on the input (a list
    of (failure flag, message)) and the budgets of the call (`_budgets`)."""
    objective = as_local_objective(objective)
    frame, scene, poses = _in_scene_frame(scene, cameras)
    groups = camera_groups(objective, poses.shape[0])  # (its error names the user's q)
    objective = objective.in_frame(*frame)
    if isinstance(objective, Smoothed):
        samples = sample(jax.lax.stop_gradient(scene), options.grid or scene.grid_cells())
        sense = _sense(scene, samples)
        value = smoothed_value(scene, poses, objective, sense, groups, scene.observed())
        # (no too-close check: it concerns the exact engine's Gauss-Legendre nodes)
        nearest = _nearest_points(scene, Vec.of(poses.position), samples, sense)
        failures = _input_failures(scene, poses, nearest, samples, options.quadrature, False)
        return frame.scale * value, failures, []
    events = _events(scene, poses, objective, options)
    value, intervals = _value(scene, events, objective, options)
    failures = _event_failures(scene, events, options, not objective.is_constant)
    return frame.scale * value, failures, _budgets(scene, events, options, intervals)


def _stacked(failures):
    return jnp.stack([f for f, _ in failures]), [message for _, message in failures]


def _is_traced(*trees) -> bool:
    """Whether any array of `trees` is a tracer (the call is inside a jit, grad or vmap)."""
    leaves = jax.tree.leaves(eqx.filter(trees, eqx.is_array_like))
    return any(isinstance(leaf, Tracer) for leaf in leaves)


def visibility(
    scene: Scene,
    cameras: Real[ArrayLike, "k 2"] | Sequence | Camera,
    objective: AbstractLocalObjective | Callable = Foreshortened(),
    options: VisibilityOptions = VisibilityOptions(),
    *,
    throw: bool = True,
) -> Float[Array, ""] | tuple[Float[Array, ""], RESULTS]:
    """The global visibility objective Q of `scene` seen from `cameras` (Eq. 3.15).

    Q = sum_i int max_G [chi_i(t, G) q(x_i, x_i', G)] ||x_i'(t)|| dt over the groups G of
    `objective.group_size` cameras (single cameras for most objectives): exact up to
    floating point (events from refined roots, Gauss-Legendre on smooth intervals), and
    differentiable with respect to the cameras, the scene's parameters and the objective's
    parameters. Compiled on first use (`equinox.filter_jit`); works under `jax.jit`,
    `jax.vmap` and `jax.grad`.

    **Arguments:**

    - `scene`: the objects.
    - `cameras`: camera positions, shape (k, 2) (or (2,) for one camera), or
      directional poses, a `Camera` batched over (k,).
    - `objective`: local objective q (`VisibleLength()`, `Foreshortened()`,
      `Reconstruction(area)` and `Coverage(m)` of camera groups, or any
      `q(point, tangent, camera) -> scalar`); wrapped in `Smoothed(q, width)`, Q is the
      smoothed visibility of Chapter 6 instead (by quadrature, no events).
    - `options`: grid size and event budgets, see `VisibilityOptions`.
    - `throw`: raise where Q is undefined (default). With `throw=False`, return a
      status instead, as optimistix's `throw=False` does.

    **Returns:** the scalar Q; with `throw=False`, (Q, result): `result` is a `RESULTS`
    item (`successful`, `invalid_cameras` or `budget_exceeded`) and Q is NaN where it is
    not `successful` (so are its derivatives: select on `result`, not on Q).

    Raises a ValueError that names the cause when a camera is NaN, inside an object or on
    a curve (inside a jit, grad or vmap, through `equinox.error_if`). Called outside any
    transformation, a call whose events overflow the budgets of `options` is compiled
    again with budgets that hold them (`fit_options`), with a warning; inside a jit, grad
    or vmap an overflow raises an error that names the option (size the budgets
    beforehand with `fit_options`).
    """
    cameras = _as_input(cameras)
    traced = _is_traced(scene, cameras, objective)
    if not throw:
        if traced:
            return _visibility_and_result(scene, cameras, objective, options)[0]
        value_and_result, _ = with_grown_budgets(
            lambda o: _visibility_and_result(scene, cameras, objective, o),
            lambda o: fit_options(scene, cameras, objective, o),
            options,
        )
        return value_and_result
    if traced:
        return _visibility(scene, cameras, objective, options)
    (value, checks), _ = with_grown_budgets(
        lambda o: _visibility_and_needs(scene, cameras, objective, o),
        lambda o: fit_options(scene, cameras, objective, o),
        options,
    )
    return _raised(value, checks)


@eqx.filter_jit
def _visibility_and_result(scene, cameras, objective, options):
    """((Q, result), needs): Q NaN where the result is not successful (no error)."""
    value, failures, budgets = _value_and_checks(scene, cameras, objective, options)
    result = _outcome(failures, budgets)
    value = jnp.where(result == RESULTS.successful, value, jnp.nan)
    return (value, result), _needs(budgets)


@eqx.filter_jit
def _visibility(scene, cameras, objective, options):
    value, failures, budgets = _value_and_checks(scene, cameras, objective, options)
    return _checked(value, *_stacked(failures + _budget_failures(budgets)))


@eqx.filter_jit
def _visibility_and_needs(scene, cameras, objective, options):
    """(Q, the input checks' (failed, messages)) and what each budget needed ({option:
    (needed, budget)}): for calls outside any jit, which raise on the host (`_raised`)."""
    value, failures, budgets = _value_and_checks(scene, cameras, objective, options)
    return (value, _stacked(failures)), _needs(budgets)


def _raised(result, checks):
    """`result`, or a ValueError with the first failed check's message, raised on the host.

    Calls outside any jit check here rather than with `equinox.error_if`, whose host
    callback keeps a program out of JAX's persistent compilation cache."""
    failed, messages = checks
    failed = np.asarray(failed)
    if failed.any():
        raise ValueError(messages[int(np.argmax(failed))])
    return result


def _needs(budgets: list[Budget]) -> dict[str, tuple[Array, Array]]:
    return {b.option: (b.needed, jnp.asarray(b.budget)) for b in budgets}


def with_grown_budgets(compute, fit, options: "VisibilityOptions"):
    """`compute(options) -> (result, needs)` outside any jit, with budgets that hold its
    events: where `needs` ({option: (needed, budget)}) shows an overflow, `fit` sizes
    every budget from the grown options and `compute` runs once more with them, with a
    warning that names them.

    **Returns:** (result, the options it was computed with).
    """
    result, needs = compute(options)
    grown = _grown_options(options, needs)
    if grown is None:
        return result, options
    fitted = fit(grown)
    changed = {
        f.name: getattr(fitted, f.name)
        for f in dataclasses.fields(fitted)
        if getattr(fitted, f.name) != getattr(options, f.name)
    }
    warnings.warn(
        f"ocp_jax: the events of this scene overflowed the event budgets; compiled again "
        f"with VisibilityOptions({', '.join(f'{k}={v}' for k, v in changed.items())}) "
        "(pass these options, or ones from ocp.fit_options, to compile once).",
        stacklevel=3,
    )
    return compute(fitted)[0], fitted


def _grown_options(options: "VisibilityOptions", needs, headroom: float = 1.0):
    """`options` with every overflowed budget raised to hold `headroom` times what it
    needed (to a power of two, so that nearby needs share one compiled program), or None
    where none overflowed. `needs`: {option: (needed, budget)}, arrays of any shape."""
    raised = {}
    for name, (needed, budget) in needs.items():
        needed, budget = int(np.max(needed)), int(np.max(budget))
        if needed > budget:
            raised[name] = max(budget, 1 << max(0, math.ceil(headroom * needed) - 1).bit_length())
    return dataclasses.replace(options, **raised) if raised else None


def fit_options(
    scene: Scene,
    cameras,
    objective: AbstractLocalObjective | Callable = Foreshortened(),
    options: VisibilityOptions = VisibilityOptions(),
    headroom: float = 1.0,
) -> VisibilityOptions:
    """`options` with every event budget large enough for `scene` seen from each of a
    batch of camera sets (host-level: call it outside jit, then compile with the result).

    Root budgets only grow, each to a power of two that holds `headroom` times the
    largest count of any camera set whose cameras are valid (camera sets with a camera
    inside an object or on a curve are skipped). Counts can depend on each other (a
    camera's intervals on its shadow times), so sizing repeats until nothing overflows.
    Interval budgets left to the scene (`max_intervals`, `max_camera_intervals` None) are
    then set to the power of two that holds `headroom` times what the cameras need (at
    most the scene's default): the intervals tested and integrated are most of the cost
    of a scene with many objects.

    **Arguments:**

    - `scene`, `objective`, `options`: as for `visibility`.
    - `cameras`: one camera set, positions (k, 2) or a `Camera` batched over (k,), or a
      batch of sets, positions (n, k, 2) or a `Camera` batched over (n, k).
    - `headroom`: a factor >= 1 of room above the counts seen (for cameras that will
      move, as in an optimisation).

    **Returns:** a `VisibilityOptions`.
    """
    cameras = _as_input(cameras)
    positions = cameras.position if isinstance(cameras, Camera) else cameras
    if positions.ndim == 2:
        cameras = jax.tree.map(lambda a: a[None], cameras)
    for _ in range(8):
        needs = _set_needs(scene, cameras, objective, options)
        grown = _grown_options(options, needs, headroom)
        if grown is None:
            return _fitted_intervals(options, needs, headroom)
        options = grown
    raise RuntimeError("ocp_jax: fit_options did not settle in 8 rounds; please report this.")


def _fitted_intervals(options: VisibilityOptions, needs, headroom: float) -> VisibilityOptions:
    """`options` with the interval budgets left to the scene (None) set to what the
    cameras need, times `headroom`, to a power of two (at most the scene's default)."""
    fitted = {}
    for name in ("max_intervals", "max_camera_intervals"):
        if getattr(options, name) is None and name in needs:
            needed, default = (int(np.max(a)) for a in needs[name])
            if needed > 0:
                fitted[name] = min(default, 1 << (math.ceil(headroom * needed) - 1).bit_length())
    return dataclasses.replace(options, **fitted)


@eqx.filter_jit
def _set_needs(scene, camera_sets, objective, options):
    def one(cameras):
        _, failures, budgets = _value_and_checks(scene, cameras, objective, options)
        valid = ~jnp.any(_stacked(failures)[0])
        return {
            name: (jnp.where(valid, needed, 0), budget)
            for name, (needed, budget) in _needs(budgets).items()
        }

    return jax.lax.map(one, camera_sets)


def valid_visibility(scene, cameras, objective, options):
    """(Q, valid, needs) without raising: `valid` is False where `visibility` would raise
    (a camera inside an object, on a curve or too close to it, an overflowed budget);
    `needs` says what each budget needed ({option: (needed, budget)}, see `with_grown_budgets`). For
    optimisers and searches, which must step back from such placements, not stop."""
    value, failures, budgets = _value_and_checks(scene, cameras, objective, options)
    return value, _outcome(failures, budgets) == RESULTS.successful, _needs(budgets)


def _outcome(failures, budgets: list[Budget]) -> RESULTS:
    """How a call ends, without raising: `invalid_cameras` where an input check or a root
    search failed, else `budget_exceeded` where a budget overflowed, else `successful`."""
    invalid = jnp.any(_stacked(failures)[0])
    overflow = jnp.any(jnp.stack([b.needed > b.budget for b in budgets] + [jnp.asarray(False)]))
    result = RESULTS.where(overflow, RESULTS.budget_exceeded, RESULTS.successful)
    return RESULTS.where(invalid, RESULTS.invalid_cameras, result)


def signed_distances(scene: Scene, cameras: Float[Array, "k 2"], grid: int | None = None):
    """Distance from each camera to each curve, negative inside the object: shape (k, m).
    Differentiable in the cameras (the gradient is the unit vector from the nearest point)."""
    frame = scene_frame(scene)  # (computed in the scene's frame, as Q)
    scene = jax.lax.stop_gradient(scene).in_frame(*frame)
    samples = sample(scene, grid or scene.grid_cells())
    points = Vec.of(to_frame(jnp.asarray(cameras), *frame))
    distance, outward, _ = _closest_points(scene, points, samples, _sense(scene, samples))
    return frame.scale * jnp.where(outward >= 0, distance, -distance).T


class VisibleIntervals(eqx.Module):
    """What each camera sees: on curve i, camera c sees [start, end] where `visible`.

    Arrays of shape (k, m, e) (padded: zero-length intervals at t = 1); `to_list` gives
    merged Python intervals. The events that cut them: `tangents` (tangency times, where
    the line of sight grazes curve i) and `shadows` (where a grazing ray meets a curve
    again), each `Roots(t, valid, count, settled)` with t of shape (k, m, r).
    """

    start: Float[Array, "k m e"]
    end: Float[Array, "k m e"]
    visible: Bool[Array, "k m e"]
    tangents: Roots
    shadows: Roots

    def to_list(self, camera: int, curve: int) -> list[tuple[float, float]]:
        """Merged visible parameter intervals of `curve` seen by `camera` (a visible arc
        through the seam is split at t = 0)."""
        start = np.asarray(self.start[camera, curve])
        end = np.asarray(self.end[camera, curve])
        seen = np.asarray(self.visible[camera, curve]) & (end > start)
        merged: list[tuple[float, float]] = []
        for a, b in zip(start[seen], end[seen]):
            if merged and a <= merged[-1][1]:
                merged[-1] = (merged[-1][0], max(merged[-1][1], float(b)))
            else:
                merged.append((float(a), float(b)))
        return merged


def visible_intervals(
    scene: Scene,
    cameras: Real[ArrayLike, "k 2"] | Sequence | Camera,
    options: VisibilityOptions = VisibilityOptions(),
) -> VisibleIntervals:
    """The parameter arcs of every curve that each camera sees (occlusions included).

    **Returns:** a `VisibleIntervals`; `.to_list(c, i)` for plain intervals.
    """
    cameras = _as_input(cameras)
    if _is_traced(scene, cameras):
        (intervals, checks), _ = _visible_intervals(scene, cameras, options, True)
        return eqx.tree_at(lambda i: i.start, intervals, _checked(intervals.start, *checks))
    (intervals, checks), _ = with_grown_budgets(
        lambda o: _visible_intervals(scene, cameras, o, False),
        lambda o: fit_options(scene, cameras, VisibleLength(), o),
        options,
    )
    return _raised(intervals, checks)


@eqx.filter_jit
def _visible_intervals(scene, cameras, options, check_budgets: bool):
    """(The intervals, the input checks' (failed, messages), with the budgets' where
    `check_budgets`), and what each budget needed."""
    _, scene, poses = _in_scene_frame(scene, cameras)
    events = _events(scene, poses, VisibleLength(), options)
    partitions = events.partitions
    start, end = jax.vmap(_intervals)(partitions.events)
    failures = _event_failures(scene, events, options, False)
    budgets = _budgets(scene, events, options)
    if check_budgets:
        failures += _budget_failures(budgets)
    intervals = VisibleIntervals(
        start, end, partitions.visible, partitions.tangents, partitions.shadows
    )
    return (intervals, _stacked(failures)), _needs(budgets)
