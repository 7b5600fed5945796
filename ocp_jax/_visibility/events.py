"""Occlusion events of one camera (thesis Sec. 5.1.2, 5.2): the parameter values where
the visibility of a curve can change.

- Tangency times (Eqs. 5.21, 5.33): roots of F(t) = n(t) . (x(t) - C), written here as
  cross(x'(t), x(t) - C); the line of sight grazes the curve.
- Shadow times (Eqs. 5.22, 5.34): for every tangency point P = x_j(T), roots of
  F(s) = cross(P - C, x_i(s) - C) beyond P (the grazing ray hits curve i behind P); on
  a polygon's straight edges, the ray's crossing in closed form.
- Crossover times: with several cameras and a camera-dependent q, where two cameras'
  q are equal, so that max_c q_c is smooth between events.
- For a `Camera` with a view wedge, the wedge's two edges are rays from C as well
  (crossings of F(s) = cross(u_edge, x(s) - C) in front of C), found with the shadows;
  with a range R, the range circle's crossings are roots of |x(t) - C|^2 - R^2.

Each root carries the implicit-function derivative (see `_roots.py`); for tangency and
shadow times with respect to the camera it equals Eqs. 5.28/5.32 and 5.17/5.20. In a
scene of conics only, `_conics.py` gives the tangency and shadow times in closed form.
"""

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from .._geometry.vec import Vec, add, cross, dot, norm, sub
from .jvp import is_zero, perturbed_jvp
from .roots import (
    CHUNK_ELEMENTS,
    cell_ends,
    dip_probes,
    first_true,
    grid_brackets,
    over_chunks,
    solve_roots,
)
from .xla_cpu import fused_reduce, materialize


class Samples(NamedTuple):
    """Every curve sampled on the grid t_0 = 0 < ... < t_N = 1 (camera independent);
    `x`, `dx`, `ddx` have arrays of shape (m, N + 1). Where a curve has corners (grid
    nodes), `dx`, `ddx` are the right limits and `dx_end`, `ddx_end` the left limits
    (None for smooth scenes). A camera's grid (`with_nearest_node`) has one more node on
    every curve, its `t` an array (m, N + 2) as well."""

    t: Float[Array, "*m n1"]
    x: Vec
    dx: Vec
    ddx: Vec
    dx_end: Vec | None = None
    ddx_end: Vec | None = None

    def at_nodes(self, fn):
        """fn(x', x'') at the nodes: one array for smooth scenes, or the pair (right
        limits, left limits) that `grid_brackets` takes where x' jumps."""
        start = fn(self.dx, self.ddx)
        if self.dx_end is None:
            return start
        return start, fn(self.dx_end, self.ddx_end)


def sample(scene, cells: int) -> Samples:
    align = scene.grid_alignment()
    if cells % align:
        raise ValueError(
            f"The grid of {cells} cells per curve must be a multiple of {align} (the "
            "curves' segment counts), so that every corner is a grid node: pass "
            f"VisibilityOptions(grid={align * -(-cells // align)}) or leave grid=None."
        )
    t = jnp.arange(cells + 1, dtype=scene.dtype) / cells
    nodes = jnp.broadcast_to(t, (len(scene), cells + 1))
    x, dx, ddx = scene.components(nodes)
    if not scene.has_corners:
        return materialize(Samples(t, x, dx, ddx), scene)
    _, dx_end, ddx_end = scene.components_left(nodes)
    return materialize(Samples(t, x, dx, ddx, dx_end, ddx_end), scene)


class Roots(NamedTuple):
    t: Float[Array, "*batch r"]  # padded with 1.0 (the end of [0, 1))
    valid: Bool[Array, "*batch r"]
    count: Int[Array, "*batch"]  # roots found before packing into the budget
    settled: Bool[Array, ""]  # every root final within the Newton steps (closed forms: True)


def tangency_function(t, args):
    """F(t) = cross(x'(t), x(t) - C), F'(t) = cross(x''(t), x(t) - C)."""
    scene, camera = args
    x, dx, ddx = scene.components(t)
    sight = sub(x, camera)
    return cross(dx, sight), cross(ddx, sight), norm(dx) * norm(sight)


def shadow_function(s, args):
    """F(s) = cross(P - C, x(s) - C): x(s) on the line of sight through P; where P is a
    corner at T of this curve (`by_corner`: (whether, T)), F / |s - T| (`shadow_times`)."""
    scene, camera, point, by_corner = args
    x, dx, _ = scene.components(s)
    ray = sub(point, camera)
    sight = sub(x, camera)
    value, slope, scale = cross(ray, sight), cross(ray, dx), norm(ray) * norm(sight)
    if by_corner is None:
        return value, slope, scale
    is_corner, corner = by_corner
    u = s - corner
    u = u - jnp.round(u)
    distance = jnp.where(is_corner & (u != 0), jnp.abs(u), 1.0)
    value = value / distance
    slope = jnp.where(is_corner, (slope - value * jnp.sign(u)) / distance, slope)
    return value, slope, scale / distance


def crossover_terms(objective, group_a, group_b, x: Vec, dx: Vec, ddx: Vec):
    """q(x, x', G_a) - q(x, x', G_b) for two camera groups (tuples of cameras), its
    t-derivative (chain rule: one jvp along (x', x'')) and the scale |q_a| + |q_b|."""

    def both(x, dx):
        return objective.evaluate(x, dx, *group_a), objective.evaluate(x, dx, *group_b)

    (qa, qb), (dqa, dqb) = jax.jvp(both, (x, dx), (dx, ddx))
    return qa - qb, dqa - dqb, jnp.abs(qa) + jnp.abs(qb)


def crossover_function(t, args):
    """F(t) = q(x, x', G_a) - q(x, x', G_b) and F'(t) on the curves `curve` (an index per
    row of t; see `crossover_terms`)."""
    scene, curve, group_a, group_b, objective = args
    return crossover_terms(objective, group_a, group_b, *scene.components_at(curve, t))


def with_nearest_node(scene, samples: Samples, nearest: Float[Array, " m"]) -> Samples:
    """One camera's grid: the samples with one more node per curve, the camera's nearest
    point t* = `nearest` (no derivative), so that `t` and the components are arrays
    (m, N + 2). Where t* is a grid node (a corner; to 1e4 eps), the midpoint of its cell
    is the node.

    Close to the camera a curve bends more between the grid's nodes than the camera's
    distance to it, and interpolation from them misjudges what is near the camera: the
    camera sees a short arc between two tangency times that the cubic Hermite interpolant
    of F = cross(x', x - C) does not resolve (on the banana, a camera 1e-3 from a convex
    arc saw nothing), and the depth of a crossing just behind the camera interpolates to
    one in front of it (beside the kidney, a line of sight that left the curve behind the
    camera was taken for blocked). At t*, where x - C is normal to the curve,
    F = +-|x'| |x - C| has the sign opposite to F at both tangency times (as a node it
    puts each in a cell of its own, and near an inflection, where a third one lies close
    by, two in a cell of half the width). And a line of sight at an angle a to the curve
    crosses it within |x - C| / sin(a) of x(t*), at a depth (x - C) . d of -+|d| |x - C|
    / sin(a), which the interpolation from the node errs by about |d| |x - C| / tan(a)
    times half the angle the curve turns through in the cell (not by O(h^2))."""
    frozen = jax.lax.stop_gradient(scene)
    cells = samples.t.shape[0] - 1
    cell = grid_cell(nearest, samples)[:, None]  # (m, 1)
    # t* within rounding of a node (a corner, reached from one of its pieces) counts as
    # the node: a polygon evaluated 1 ulp before its corner at 0.75 gave the next edge's
    # x', F took its sign there, and the cell ending at t* showed a sign change of F
    # that is no root (the search bisected it to 1e-12 and returned that as a root).
    position = nearest[:, None] * cells
    on_node = jnp.abs(position - jnp.round(position)) <= 1e4 * jnp.finfo(position.dtype).eps * cells
    extra = jnp.where(on_node, (cell + 0.5) / cells, nearest[:, None])
    node = jnp.arange(cells + 2)[None]  # of the grid with the extra node, node c + 1
    from_grid = node - (node > cell + 1)  # (m, N + 2): the grid node each other one copies
    at_extra = frozen.components(extra)  # x, x', x'' there, (m, 1)

    def with_extra(at_nodes, at_extra):  # (m | 1, N + 1), (m, 1) -> (m, N + 2)
        at_nodes = jnp.broadcast_to(at_nodes, (extra.shape[0], cells + 1))
        copied = jnp.take_along_axis(at_nodes, from_grid, 1)
        return jnp.where(node == cell + 1, at_extra, copied)

    grid = Samples(
        with_extra(samples.t[None], extra),
        *jax.tree.map(with_extra, (samples.x, samples.dx, samples.ddx), at_extra),
    )
    if samples.dx_end is not None:  # the extra node is no corner: its left limits are x'
        ends = jax.tree.map(with_extra, (samples.dx_end, samples.ddx_end), at_extra[1:])
        grid = grid._replace(dx_end=ends[0], ddx_end=ends[1])
    # Computed once (see `materialize`), not in every consumer of the nodes.
    return materialize(grid, scene)


def tangency_times(scene, camera: Vec, grid: Samples, budget: int, iterations: int) -> Roots:
    """Tangency times on every curve: roots of F(t) = cross(x'(t), x(t) - C) (Eq. 5.21),
    bracketed on the camera's grid (`with_nearest_node`). A polygon has none (on a
    straight edge F is constant, and its corners are ray sources of their own): only
    the curved rows are searched."""
    curved = np.flatnonzero(~scene.straight())
    m = len(scene)
    if not len(curved):
        padding = jnp.ones((m, budget), grid.x.x.dtype)
        none = jnp.zeros((m, budget), bool)
        return Roots(padding, none, jnp.zeros(m, int), jnp.asarray(True))
    if len(curved) < m:
        grid = jax.tree.map(lambda a: a[curved], grid)
    sight = sub(grid.x, jax.lax.stop_gradient(camera))
    values = grid.at_nodes(lambda dx, _: cross(dx, sight)[:, None])
    slopes = grid.at_nodes(lambda _, ddx: cross(ddx, sight)[:, None])
    scale = grid.at_nodes(lambda dx, _: (norm(dx) * norm(sight))[:, None])
    brackets = grid_brackets(grid.t[:, None], values, slopes, budget, scale=scale)
    curves = scene.rows(curved)
    t, valid, settled = solve_roots(
        tangency_function, (curves, camera), brackets, iterations, 1.0, curves.costly_evaluation()
    )
    if len(curved) == m:
        return Roots(t, valid, brackets.count, settled)
    return Roots(
        jnp.ones((m, budget), t.dtype).at[curved].set(t),
        jnp.zeros((m, budget), bool).at[curved].set(valid),
        jnp.zeros(m, int).at[curved].set(brackets.count),
        settled,
    )


class RaySources(NamedTuple):
    """Points that cast rays from the camera, flattened to arrays of shape (l,): the
    tangency points and the silhouette corners of all curves (hits count beyond the
    point, `depth` 1) and the edges of a view wedge (the point C + u_edge, hits count
    anywhere in front, `depth` 0)."""

    point: Vec  # differentiable
    curvature: Vec  # x_j''(T) at a tangency point (no derivative needed)
    t: Float[Array, " l"]
    curve: Int[Array, " l"]  # the point's own curve; -1 for wedge edges
    valid: Bool[Array, " l"]
    depth: Float[Array, " l"]  # hits count at (x - C) . (P - C) / |P - C|^2 > depth
    tangent: Bool[Array, " l"]  # a tangency point (the ray touches its own curve)


@jax.custom_jvp
def curve_points(scene, t) -> tuple[Vec, Vec]:
    """(x_i(t[i]), x_i''(t[i])) for every curve i, from one evaluation. x is differentiated
    in t by x'(t) dt: autodiff through the curve evaluation would store every power of t
    for reverse mode, one kernel each on CPU (36 for the degree-18 banana). x'' is
    returned as a constant (no derivative, as under `lax.stop_gradient`)."""
    x, _, ddx = scene.components(t)
    return x, ddx


@functools.partial(curve_points.defjvp, symbolic_zeros=True)
def _curve_points_jvp(primals, tangents):
    scene, t = primals
    dscene, dt = tangents
    x, dx, ddx = scene.components(t)
    moved = Vec(jnp.zeros_like(x.x), jnp.zeros_like(x.y))
    if not is_zero(dt):
        moved = Vec(dx.x * dt, dx.y * dt)
    if not is_zero(dscene):
        moved = add(moved, perturbed_jvp(lambda s: s.components(t)[0], scene, dscene)[1])
    return (x, ddx), (moved, Vec(jnp.zeros_like(ddx.x), jnp.zeros_like(ddx.y)))


def tangency_points(scene, tangents: Roots) -> RaySources:
    x, ddx = curve_points(scene, tangents.t)
    m, r = tangents.t.shape
    flat = lambda v: v.map(jnp.ravel)  # noqa: E731
    curve = jnp.repeat(jnp.arange(m), r)
    return RaySources(
        flat(x),
        flat(ddx),
        jax.lax.stop_gradient(tangents.t).ravel(),
        curve,
        tangents.valid.ravel(),
        jnp.ones_like(tangents.t).ravel(),
        jnp.ones(tangents.t.size, bool),
    )


def tangency_sources(scene, points: RaySources) -> RaySources:
    """The `tangency_points` that cast rays: those of the curved rows (a polygon has no
    tangency point, `tangency_times`), so that its empty slots take no ray."""
    straight = scene.straight()
    if not straight.any():
        return points
    slots = points.t.shape[0] // len(scene)
    keep = np.flatnonzero(np.repeat(~straight, slots))
    return jax.tree.map(lambda a: a[keep], points)


def silhouette_corners(scene, camera: Vec, samples: Samples) -> RaySources:
    """The corners where the line of sight leaves an object: cross(x', x - C) has
    different signs (or a zero) on the two sides of the corner, so the camera sees one
    of its edges from the front and the other from behind."""
    padded, real = scene.corners()
    # Only the real corners (the curves' lists are padded to the longest).
    rows, columns = np.nonzero(real)
    times = padded[rows, columns]
    cells = samples.t.shape[0] - 1
    node = np.round(times * cells).astype(int)  # right limits at node, left at node or N
    node_end = np.where(node == 0, cells, node)
    sight = sub(samples.x, jax.lax.stop_gradient(camera)).map(lambda a: a[rows, node])
    right = cross(samples.dx.map(lambda a: a[rows, node]), sight)
    assert samples.dx_end is not None  # a scene with corners has left limits
    left = cross(samples.dx_end.map(lambda a: a[rows, node_end]), sight)
    point = scene.components(jnp.asarray(padded, scene.dtype))[0].map(lambda a: a[rows, columns])
    zero = jnp.zeros(times.shape, scene.dtype)
    return RaySources(
        point,
        Vec(zero, zero),
        jnp.asarray(times, scene.dtype),
        jnp.asarray(rows),
        right * left <= 0,
        jnp.ones_like(zero),
        jnp.zeros(times.shape, bool),
    )


def wedge_edges(camera: Vec, edges: Vec) -> RaySources:
    """The view wedge's edges as ray sources: points C + u for unit directions u (l,)."""
    zero = jnp.zeros_like(edges.x)
    return RaySources(
        add(camera, edges),
        Vec(zero, zero),
        zero,
        jnp.full(zero.shape, -1),
        jnp.ones(zero.shape, bool),
        zero,
        jnp.zeros(zero.shape, bool),
    )


def join_sources(*sources: RaySources) -> RaySources:
    return jax.tree.map(lambda *a: jnp.concatenate(a), *sources)


def bounding_discs(samples: Samples) -> tuple[Vec, Float[Array, " m"]]:
    """A disc around each curve: centre the mean of its grid points (the closing node
    counted once), radius to the farthest one plus the longest step between grid points
    (an arc never strays farther)."""
    centre = samples.x.map(lambda a: fused_reduce(jnp.sum, a[:, :-1], 1) / (a.shape[1] - 1))
    reach = norm(sub(samples.x, centre.map(lambda a: a[:, None])))
    step = norm(samples.x.map(lambda a: jnp.diff(a, axis=1)))
    return centre, fused_reduce(jnp.max, reach, 1) + fused_reduce(jnp.max, step, 1)


def foot_on_chord(offset: Vec, chord: Vec, margin: float = 0.0):
    """The foot of the perpendicular from a point on a segment (`offset`: the point less
    the segment's start; `chord`: its end less its start): the fraction u along the
    chord, clipped to [margin, 1 - margin], and the point's distance to x(u)."""
    length2 = dot(chord, chord)
    u = dot(offset, chord) / jnp.maximum(length2, jnp.finfo(length2.dtype).tiny)
    u = jnp.clip(u, margin, 1.0 - margin)
    return u, norm(sub(offset, chord.map(lambda v: u * v)))


def inscribed_radii(samples: Samples, centre: Vec, straight: np.ndarray) -> Float[Array, " m"]:
    """The radius of a disc around each `centre` that lies inside its curve, 0 where none
    is found: the centre's distance to the polygon of grid points, less the longest step
    between them (as in `bounding_discs`, an arc never strays farther) unless the curve is
    that polygon (`straight`, a static (m,) mask), where the centre lies inside that
    polygon (winding number +-1)."""
    p = sub(samples.x, centre.map(lambda a: a[:, None]))  # (m, N + 1), closed
    a, b = p.map(lambda v: v[:, :-1]), p.map(lambda v: v[:, 1:])
    winding = jnp.sum(jnp.arctan2(cross(a, b), dot(a, b)), 1) / (2 * jnp.pi)
    edge = sub(b, a)
    nearest = jnp.min(foot_on_chord(a.map(jnp.negative), edge)[1], 1)
    radius = nearest - jnp.where(straight, 0.0, jnp.max(norm(edge), 1))
    return jnp.where((jnp.abs(winding) > 0.5) & (radius > 0), radius, 0.0)


class PolygonEdges(NamedTuple):
    """The edges of the scene's polygons (`Scene.straight`), flattened over the scene:
    arrays (E,). On a grid through the corners, an edge is a straight run of cells."""

    start: Vec
    end: Vec
    curve: np.ndarray  # static: the edge's curve
    piece: np.ndarray  # static: its smooth piece (`Scene.pieces`)
    t_start: np.ndarray  # static: the curve's parameter at the edge's start ...
    t_end: np.ndarray  # ... and at its end (1 for the last edge): x is affine in t between


def polygon_edges(scene, samples: Samples) -> PolygonEdges | None:
    """The edges of the scene's polygons from the grid points at their corners (None
    where the scene has no polygon)."""
    polygons = np.flatnonzero(scene.straight())
    if not len(polygons):
        return None
    times, real = scene.corners()
    cells = samples.t.shape[-1] - 1
    # The grid nodes of every polygon's vertices, and of the next vertex along it.
    nodes = [np.rint(times[i, real[i]] * cells).astype(int) for i in polygons]
    curve = np.concatenate([np.full(len(n), i) for i, n in zip(polygons, nodes)])
    first, last = np.concatenate(nodes), np.concatenate([np.roll(n, -1) for n in nodes])
    piece = scene.pieces(cells)[curve, first]  # (the cell after the first corner)
    return PolygonEdges(
        samples.x.map(lambda v: v[curve, first]),
        samples.x.map(lambda v: v[curve, last]),
        curve,
        piece,
        first / cells,
        np.where(last == 0, cells, last) / cells,
    )


class PolygonCrossings(NamedTuple):
    """Each ray's first transversal crossing of a polygon's edge beyond its source:
    arrays (l,)."""

    depth: Float[Array, " l"]  # in units of the ray, from the camera (inf where none)
    edge: Int[Array, " l"]  # the edge crossed (0 where none)


def polygon_crossings(
    edges: PolygonEdges | None, camera: Vec, ray: Vec, depth: Float[Array, " l"]
) -> PolygonCrossings:
    """The first transversal crossing of each ray (from `camera`, along `ray`) with a
    polygon's edge beyond `depth`, in closed form: on the edge a + u e, the ray's point
    C + s r with s = cross(a - C, e) / cross(r, e), u = cross(a - C, r) / cross(r, e).
    Crossings at an edge's ends (u within 1e-9 of 0 or 1), or just beyond the source,
    are left out: a ray that only touches a vertex is not stopped by it, and one that
    passes through a vertex meets a corner, itself an event. No derivative."""
    if edges is None:
        none = jnp.full(depth.shape, jnp.inf, depth.dtype)
        return PolygonCrossings(none, jnp.zeros(depth.shape, int))
    a = sub(edges.start, camera).map(lambda v: v[None])  # (1, E)
    edge = sub(edges.end, edges.start).map(lambda v: v[None])
    ray = ray.map(lambda v: v[:, None])  # (l, 1)
    det = cross(ray, edge)
    safe = jnp.where(det == 0, 1.0, det)
    s, u = cross(a, edge) / safe, cross(a, ray) / safe
    tol = 1e-9
    crossed = (det != 0) & (u > tol) & (u < 1 - tol) & (s > depth[:, None] * (1 + tol))
    s = jnp.where(crossed, s, jnp.inf)
    return PolygonCrossings(jnp.min(s, 1), jnp.argmin(s, 1))


def polygon_shadow_times(
    scene, edges: PolygonEdges, camera: Vec, point: Vec, crossings: PolygonCrossings
) -> Float[Array, " l"]:
    """The parameter t of each ray's crossing (`polygon_crossings`) on its edge's curve,
    t = t_start + u (t_end - t_start), differentiable in the camera, the ray's source
    `point` and the scene (the edge's ends are evaluated on it); 1 where the ray crosses
    no edge. Its derivative is that of the shadow time's implicit function (Eq. 5.32) on
    a straight edge."""
    found = jnp.isfinite(crossings.depth)
    curve = jnp.asarray(edges.curve)[crossings.edge]
    start, end = (jnp.asarray(t, scene.dtype)[crossings.edge] for t in (edges.t_start, edges.t_end))
    ends = scene.components_at(curve, jnp.stack([start, end], -1))[0]
    a = sub(ends.map(lambda v: v[:, 0]), camera)
    edge = ends.map(lambda v: v[:, 1] - v[:, 0])
    ray = sub(point, camera)
    u = cross(a, ray) / jnp.where(found, cross(ray, edge), 1.0)
    return jnp.where(found, start + u * (end - start), 1.0)


class GrazingProbes(NamedTuple):
    """The camera's tangency points on every curve, arrays (m, r): where a line of sight
    from the camera may graze the curve (`grazing_probes`)."""

    t: Float[Array, "m r"]
    valid: Bool[Array, "m r"]
    cell: Int[Array, "m r"]  # the grid cell that holds t
    sight: Vec  # x_j(T) - C
    start: Vec  # x_j - C at the cell's start node
    end: Vec  # x_j - C at the cell's end node


def grid_cell(t, samples: Samples, curve=None) -> Int[Array, "..."]:
    """The index of the grid cell [t_c, t_c+1) that holds each t in [0, 1] (t = 1 in the
    last); on a camera's grid (`with_nearest_node`), t has a row per curve, or, given
    `curve` (of t's shape), lies on those curves."""
    if samples.t.ndim == 1:
        return _uniform_cell(t, samples.t.shape[0] - 1)
    # The cell c of the uniform grid, or the next where the extra node lies before t.
    cell = _uniform_cell(t, samples.t.shape[1] - 2)
    if curve is None:
        return cell + (jnp.take_along_axis(samples.t, cell + 1, 1) <= t)
    return cell + (samples.t[curve, cell + 1] <= t)


def _uniform_cell(t, cells: int):
    return jnp.clip(jnp.floor(t * cells).astype(jnp.int32), 0, cells - 1)


def grid_pieces(pieces: np.ndarray, grid: Samples) -> Int[Array, "m n"]:
    """The smooth piece of every cell of a camera's grid (`with_nearest_node`), from
    those of the uniform grid's cells (`Scene.pieces`)."""
    middle = 0.5 * (grid.t[:, :-1] + grid.t[:, 1:])
    return jnp.take_along_axis(jnp.asarray(pieces), _uniform_cell(middle, pieces.shape[1]), 1)


def grazing_probes(
    camera: Vec, samples: Samples, tangents: Roots, points: RaySources
) -> GrazingProbes:
    """Probes for crossings that the grid cannot resolve, from the camera's tangency
    times and their `tangency_points` (no derivative: they only decide).

    Where a line of sight grazes a curve, its two crossings can be closer together than
    the cubic Hermite interpolant of g = cross(d, x_j(s) - C) on the grid resolves (on
    a circle, pairs a tenth of a cell apart). Seen from C,
    the angle of x_j(s) - C is extremal at the tangency times T (where
    cross(x_j', x_j - C) = 0, Eq. 5.21), so sign g (that of the sine of the angle from d)
    is extreme there: two crossings inside a cell, however close together, straddle a
    tangency point, and g there has the sign opposite to both ends of the cell
    (`grid_brackets`' probes, and `_occlusion._grazing`, which also reads the points of
    the cell's ends, `start` and `end`)."""
    camera, tangents, point = jax.lax.stop_gradient(
        (camera, tangents, points.point.map(lambda a: a.reshape(tangents.t.shape)))
    )
    cell = grid_cell(tangents.t, samples)
    rows = jnp.arange(cell.shape[0])[:, None]

    def node(offset):
        return sub(samples.x.map(lambda a: a[rows, cell + offset]), camera)

    return GrazingProbes(tangents.t, tangents.valid, cell, sub(point, camera), node(0), node(1))


def shadow_times(
    scene,
    camera: Vec,
    samples: Samples,
    tangency: RaySources,
    probes: GrazingProbes,
    budget: int,
    iterations: int,
) -> Roots:
    """Shadow times on every curve of the rays from `camera` through the ray sources: the
    first transversal crossing of each ray beyond its source's `depth` (beyond a tangency
    point or corner, in front of the camera for a wedge edge). A ray changes visibility
    only there: the curve it first crosses covers both sides of the ray behind that
    point, so later crossings are seen on neither side. Each ray has at most one shadow
    time, the roots found behind another curve's being dropped.

    On a polygon the first crossings have a closed form (`polygon_crossings`,
    `polygon_shadow_times`): its row has a slot per ray, and no budget. On a curved
    object, only rays that pass through its bounding disc beyond their source, and
    before they surely have crossed a curve, are searched (at most `budget` of them per
    object; the count is returned with the roots' so that an overflow is reported). A
    curved room is met by every ray: its row is searched for all of them and has a slot
    per ray besides the `budget` (its count is that of the roots beyond one per ray).
    Cells of the room that cannot hold a ray's first crossing of it, whose depth range
    lies beyond that of a cell with a sign change (depths of the cell's nodes widened by
    the cell's chord, along which the arc runs), are not searched.

    On the tangency point's own curve j the ray function g(s) = cross(P - C, x_j(s) - C)
    has a double root at s = T (the ray touches the curve there). It is deflated,
    r(s) = g(s) / u^2 with u = s - T wrapped to [-1/2, 1/2) (r(T) = g''(T) / 2), so that
    only the genuine crossings remain, with no window around T excluded. A corner's ray
    has a simple root at its corner T, a grid node: deflated alike, r(s) = g(s) / |u|
    (the sign of g kept), with the one-sided limits +-g'(T+-) at T, so that a crossing
    right beside the corner is a root of r in the corner's cell, and is solved for as
    one (`shadow_function`), not taken for the corner's own root.

    Where a ray grazes a curve (near a bitangent line), its two crossings straddle the
    camera's tangency point on that curve (`grazing_probes`): g there, at the first
    probe of each cell, splits the cell when it has the sign opposite to both ends.
    """
    c0 = jax.lax.stop_gradient(camera)
    # Computed once (see `materialize`), not in every grid element of the search.
    ray, bend = materialize(
        jax.lax.stop_gradient((sub(tangency.point, camera), tangency.curvature)), scene
    )
    m, sources = len(scene), ray.x.shape[0]
    cells = samples.t.shape[0] - 1
    # The first probe of each cell of every curve (where the ray function is known
    # exactly; `grazing_probes`).
    in_cell = probes.valid[:, None] & (probes.cell[:, None] == jnp.arange(cells)[None, :, None])
    first = jnp.argmax(in_cell, -1)  # (m, cells)
    probe_t = jnp.take_along_axis(probes.t, first, -1)
    probe_sight = probes.sight.map(lambda a: jnp.take_along_axis(a, first, -1))
    probe_in = jnp.any(in_cell, -1)

    # Each ray against each curve's bounding disc centre: along the ray and across it.
    centre, radius = bounding_discs(samples)
    to_centre = sub(centre, c0).map(lambda a: a[:, None])  # (m, 1)
    ray_l = ray.map(lambda a: a[None])  # (1, l)
    length2 = dot(ray_l, ray_l)
    along, across = dot(ray_l, to_centre), cross(ray_l, to_centre)  # (m, l)

    def search(rows: np.ndarray, rays: int | None, slots: int, first_crossing: bool, stop=None):
        """Brackets of the rays' crossings on the curves `rows` (static indices), at
        most `slots` per curve: `rays` of those that pass each curve's bounding disc
        before their depth `stop` (None: every ray), and with `first_crossing` only the
        cells that can hold each ray's first crossing of the curve. Returns the
        brackets, the ray of each slot and the count per curve."""
        n = len(rows)
        length = jnp.sqrt(length2)
        if rays is None:
            passes = jnp.broadcast_to(tangency.valid[None], (n, sources))
        else:
            assert stop is not None  # (the rays are limited to those before their stop)
            reach = radius[rows, None] * length  # (n, l)
            passes = (
                (jnp.abs(across[rows]) <= reach)
                & (along[rows] + reach > tangency.depth[None] * length2)
                & (along[rows] - reach <= stop[None] * length2)
                & tangency.valid[None]
            )
        if rays is None or rays >= sources:  # every ray searched on every curve
            pick, chosen, ray_count = None, passes, passes.sum(1)
        else:  # the rays that pass each curve, packed into the budget
            pick, chosen, ray_count = first_true(passes, rays)

        def take(a):  # (l,) -> (n, rays, 1)
            if pick is None:
                return jnp.broadcast_to(a[None, :, None], (n, sources, 1))
            return a[pick][..., None]

        ray_grid = ray.map(take)  # (n, rays, 1)
        sight = sub(samples.x, c0).map(lambda a: a[rows, None])  # (n, 1, N + 1)
        values = cross(ray_grid, sight)

        def offset(t) -> tuple[Array, Array]:
            """t - T wrapped to [-1/2, 1/2) (divisor 1 where 0), and whether it is 0."""
            u = t - take(tangency.t)
            u = u - jnp.round(u)
            near = jnp.abs(u) <= 1e4 * jnp.finfo(u.dtype).eps
            return jnp.where(near, 1.0, u), near

        u, near = offset(samples.t[None, None])
        own = take(tangency.curve) == jnp.asarray(rows)[:, None, None]
        tangent = own & take(tangency.tangent)
        corner = own & ~take(tangency.tangent) if scene.has_corners else None
        deflated = tangent if corner is None else tangent | corner
        curvature = cross(ray_grid, bend.map(take))
        r = jnp.where(near, 0.5 * curvature, values / u**2)
        # Rays along a straight edge make F vanish on it up to rounding (deflated values
        # on a tangency point's own curve are exempt; a corner's are scaled alike).
        size = norm(ray_grid) * norm(sight)

        def deflated_at_nodes(dx, side):
            """F, F' and the scale of F's terms at the nodes, for the cells on one side
            of each (+1: after it, -1: before it; they differ at corners)."""
            dx = dx.map(lambda a: a[rows, None])  # (n, 1, N + 1)
            slope = cross(ray_grid, dx)
            value = jnp.where(tangent, r, values)
            dvalue = jnp.where(tangent, (slope - 2.0 * r * u) / u**2, slope)
            scale = jnp.where(tangent, 0.0, size)
            if corner is not None:
                distance = jnp.abs(u)
                over = values / distance
                value = jnp.where(corner, jnp.where(near, side * slope, over), value)
                dvalue = jnp.where(corner, (slope - over * jnp.sign(u)) / distance, dvalue)
                scale = jnp.where(
                    corner, jnp.where(near, norm(ray_grid) * norm(dx), size / distance), scale
                )
            return value, jnp.where(deflated & near, 0.0, dvalue), scale

        if samples.dx_end is None:
            node_values, slopes, scale = deflated_at_nodes(samples.dx, 1.0)
        else:  # (right limits, left limits), as `grid_brackets` takes them
            node_values, slopes, scale = zip(
                deflated_at_nodes(samples.dx, 1.0), deflated_at_nodes(samples.dx_end, -1.0)
            )

        # g of every ray at the first probe of each cell (deflated as above on the ray's
        # own curve, where its own tangency point is no probe).
        probe_u, probe_near = offset(probe_t[rows, None])
        probe_values = cross(ray_grid, probe_sight.map(lambda a: a[rows, None]))
        probe_values = jnp.where(tangent, probe_values / probe_u**2, probe_values)
        if corner is not None:
            probe_values = jnp.where(corner, probe_values / jnp.abs(probe_u), probe_values)
        present = probe_in[rows, None] & ~(deflated & probe_near)
        fraction = probe_t[rows, None] * cells - jnp.arange(cells)[None, None]
        # Computed once, not in every element of the brackets' masks that read them.
        probe = materialize(
            jnp.broadcast_arrays(fraction, jnp.where(present, probe_values, jnp.nan)), scene
        )

        depth = dot(ray_grid, sight) / dot(ray_grid, ray_grid)
        start = take(tangency.depth)
        keep = ((depth[..., :-1] > start) | (depth[..., 1:] > start)) & chosen[..., None]
        if first_crossing:
            chord = norm(samples.x.map(lambda a: jnp.diff(a[rows, None], axis=-1)))
            spread = chord / norm(ray_grid)  # (n, rays, N)
            near_end = jnp.minimum(depth[..., :-1], depth[..., 1:]) - spread
            far_end = jnp.maximum(depth[..., :-1], depth[..., 1:]) + spread
            (f0, f1), (s0, s1) = cell_ends(node_values), cell_ends(scale)
            noise = 1e3 * jnp.finfo(f0.dtype).eps
            crossed = (
                (f0 * f1 < 0)
                & ((jnp.abs(f0) > noise * s0) | (jnp.abs(f1) > noise * s1))
                & (near_end > start)
            )
            reach = jnp.min(jnp.where(crossed, far_end, jnp.inf), -1, keepdims=True)
            keep = keep & (near_end <= reach)
        brackets = grid_brackets(samples.t, node_values, slopes, slots, keep, scale, probe)
        line = brackets.source // (2 * cells)  # (n, slots)
        if pick is not None:
            line = jnp.take_along_axis(pick, line, 1)
        count = brackets.count if rays is None else jnp.maximum(brackets.count, ray_count)
        return brackets, line, count

    def solve(curves, brackets, line, rows: np.ndarray):
        """The roots in the brackets of the rays `line` on the curves `rows` (static),
        evaluated by `curves` (the scene, or the room alone), whether each lies beyond
        its source, its depth, and whether the search is done."""
        by_corner = None
        if scene.has_corners:  # which slots hold a corner's ray on its own curve, and T
            own = tangency.curve[line] == jnp.asarray(rows)[:, None]
            by_corner = (own & ~tangency.tangent[line], jax.lax.stop_gradient(tangency.t[line]))
        args = (curves, camera, Vec.of(tangency.point.stack()[line]), by_corner)  # one gather
        s, valid, settled = solve_roots(
            shadow_function, args, brackets, iterations, 1.0, scene.costly_evaluation()
        )
        x, _, _ = jax.lax.stop_gradient(curves).components(jax.lax.stop_gradient(s))
        hit_ray = ray.map(lambda a: a[line])
        depth = dot(hit_ray, sub(x, c0)) / dot(hit_ray, hit_ray)
        return s, valid & (depth > tangency.depth[line]), depth, settled

    def nearest_hits(lines, solved):
        """Each ray's nearest root beyond its source (inf where none)."""
        nearest = jnp.full(sources, jnp.inf, ray.x.dtype)
        for line, (_, beyond, depth, _) in zip(lines, solved):
            nearest = nearest.at[line].min(jnp.where(beyond, depth, jnp.inf))
        return nearest

    # Where each ray surely has crossed a curve: where it crosses an edge of a polygon
    # (in closed form: a polygon's shadow times are those crossings), enters an
    # object's inscribed disc, or crosses a curved room. Curved objects whose bounding
    # disc lies farther hold no first crossing and are not searched.
    straight = scene.straight()
    objects = np.arange(m - 1) if scene.room else np.arange(m)
    curved = objects[~straight[objects]]
    inner = inscribed_radii(samples, centre, straight)[curved, None]
    miss = inner**2 * length2 - across[curved] ** 2
    enter = (along[curved] - jnp.sqrt(jnp.maximum(miss, 0.0))) / length2
    stop = jnp.min(
        jnp.where((miss > 0) & (enter > tangency.depth[None]), enter, jnp.inf), 0, initial=jnp.inf
    )
    edges = polygon_edges(scene, samples)
    crossings = polygon_crossings(edges, c0, ray, tangency.depth)
    stop = jnp.minimum(stop, crossings.depth)
    rows, lines, solved = [], [], []  # the curved rows' searches
    count = jnp.zeros(m, int)
    if scene.room and not straight[-1]:  # a curved room (the last curve) for every ray
        room = np.array([m - 1])
        room_brackets, room_line, room_count = search(room, None, sources + budget, True)
        rows.append(room)
        lines.append(room_line)
        solved.append(solve(scene.curves[-1], room_brackets, room_line, room))
        count = count.at[m - 1].set(jnp.maximum(room_count[0] - sources, 0))
        stop = jnp.minimum(stop, nearest_hits(lines, solved))
    if len(curved):
        brackets, line, curved_count = search(curved, budget, budget, False, stop * (1 + 1e-6))
        rows.append(curved)
        lines.append(line)
        solved.append(solve(scene.rows(curved), brackets, line, curved))
        count = count.at[curved].set(curved_count)
    # Each ray's first hit beyond its source, over the scene (near ties kept).
    nearest = jnp.minimum(crossings.depth, nearest_hits(lines, solved))
    width = shadow_slots(scene, sources, budget)[0]
    t = jnp.ones((m, width), ray.x.dtype)
    first_hit = jnp.zeros((m, width), bool)

    def near(depth, nearest):
        return depth <= nearest + 1e-9 * jnp.abs(nearest)

    for row, line, (s, beyond, depth, _) in zip(rows, lines, solved):
        hit = beyond & near(depth, nearest[line])
        t = t.at[row, : line.shape[-1]].set(jnp.where(hit, s, 1.0))
        first_hit = first_hit.at[row, : line.shape[-1]].set(hit)
    if edges is not None:  # a slot per ray on every polygon: its crossing, if first
        polygons = np.flatnonzero(straight)
        hit = tangency.valid & jnp.isfinite(crossings.depth) & near(crossings.depth, nearest)
        hit = hit[None] & (jnp.asarray(edges.curve)[crossings.edge][None] == polygons[:, None])
        times = polygon_shadow_times(scene, edges, camera, tangency.point, crossings)
        t = t.at[polygons, :sources].set(jnp.where(hit, times[None], 1.0))
        first_hit = first_hit.at[polygons, :sources].set(hit)
    settled = jnp.all(jnp.stack([jnp.asarray(True)] + [done for *_, done in solved]))
    return Roots(t, first_hit, count, settled)


def shadow_slots(scene, rays: int, budget: int) -> tuple[int, int]:
    """The width of `shadow_times`' rows for `rays` ray sources, and how many of the
    scene's slots can hold a shadow time: a ray has one first crossing, so the
    polygons (closed form, a slot per ray on each) hold `rays` together; a curved
    object holds `budget`, a curved room a slot per ray besides the `budget`."""
    straight = scene.straight()
    curved_room = scene.room and not straight[-1]
    curved = int((~straight).sum()) - curved_room
    width = max(
        rays if straight.any() else 0,
        budget if curved else 0,
        rays + budget if curved_room else 0,
    )
    return width, (rays if straight.any() else 0) + curved * budget + curved_room * (rays + budget)


def range_function(t, args):
    """F(t) = |x(t) - C|^2 - R^2, F'(t) = 2 (x(t) - C) . x'(t)."""
    scene, camera, reach = args
    x, dx, _ = scene.components(t)
    sight = sub(x, camera)
    return dot(sight, sight) - reach**2, 2.0 * dot(sight, dx), dot(sight, sight) + reach**2


def range_times(scene, camera: Vec, reach, samples: Samples, budget: int, iterations: int) -> Roots:
    """Where the range circle |x - C| = R crosses every curve."""
    sight = sub(samples.x, jax.lax.stop_gradient(camera))
    values = (dot(sight, sight) - jax.lax.stop_gradient(reach) ** 2)[:, None]
    slopes = samples.at_nodes(lambda dx, _: 2.0 * dot(sight, dx)[:, None])
    brackets = grid_brackets(samples.t, values, slopes, budget)
    t, valid, settled = solve_roots(
        range_function, (scene, camera, reach), brackets, iterations, 1.0, scene.costly_evaluation()
    )
    return Roots(t, valid, brackets.count, settled)


CROSSOVER_CELLS = 4
CROSSOVER_LEVELS = 8


def crossover_nodes(
    samples: Samples, cameras: Vec
) -> tuple[Float[Array, "m k R"], Bool[Array, "m k"]]:
    """Nodes that refine the grid where it is coarse for a camera's q: on every curve,
    for every camera, in the `CROSSOVER_CELLS` grid cells whose chord is longest
    relative to its distance d from the camera.

    Near a camera its q changes over the camera's distance to the curve (on a straight
    edge the foreshortening h^2 / (h^2 + s^2) of a camera at h is a peak of width h
    about the foot of the perpendicular), which may be far shorter than a grid cell, and
    the cubic Hermite interpolant of two cameras' q_a - q_b on the cell misses their
    crossovers. So each such cell gets `CROSSOVER_LEVELS` nodes on either side of the
    foot f of the camera's perpendicular on its chord, at f -+ (side) rho^-i: a
    geometric grid toward f whose finest step is at most d / 4 (rho >= 2). Every cell it
    makes is then shorter than its distance from f, so than its distance from the
    camera (up to the chord's sagitta). A curve near a camera in two places (a camera in
    a slot) gets both.

    **Returns:**

    - (m, k, R) nodes, R = K (2J + 1), strictly inside the grid's cells (f is kept 1e-6
      of the cell from its ends): with the grid's nodes, which stay (the corners among
      them), they make cells inside the grid's.
    - Whether the camera is near the curve, (m, k): a cell's chord is longer than its
      distance from the camera. Elsewhere the grid resolves q and needs no refinement.
    """
    start = samples.x.map(lambda v: v[:, None, :-1])  # (m, 1, N)
    chord = samples.x.map(lambda v: jnp.diff(v, axis=1)[:, None])
    to_camera = sub(cameras.map(lambda v: v[None, :, None]), start)  # (m, k, N)
    u, distance = foot_on_chord(to_camera, chord, margin=1e-6)
    ratio = norm(chord) / jnp.maximum(distance, jnp.finfo(distance.dtype).tiny)
    cells = min(CROSSOVER_CELLS, samples.t.shape[0] - 1)
    ratio, cell = jax.lax.top_k(ratio, cells)  # (m, k, K)
    u = jnp.take_along_axis(u, cell, -1)
    width = jnp.diff(samples.t)[cell]
    foot = samples.t[cell] + u * width
    sides = jnp.stack([u, 1.0 - u], -1)  # fractions of the cell, before and after f
    # the finest step, side rho^-J of the chord, at most d / 4
    rho = jnp.maximum(2.0, (4.0 * sides * ratio[..., None]) ** (1.0 / CROSSOVER_LEVELS))
    levels = jnp.arange(1, CROSSOVER_LEVELS + 1, dtype=u.dtype).reshape(1, 1, 1, 1, -1)
    steps = (sides * width[..., None])[..., None] * rho[..., None] ** -levels  # (m, k, K, 2, J)
    direction = jnp.asarray([-1.0, 1.0], u.dtype).reshape(1, 1, 1, 2, 1)
    ladder = foot[..., None, None] + direction * steps
    nodes = jnp.concatenate([ladder.reshape(*foot.shape, -1), foot[..., None]], -1)
    return nodes.reshape(*foot.shape[:2], -1), ratio[..., 0] > 1.0


def crossover_times(
    scene,
    members: tuple[tuple[Vec, ...], tuple[Vec, ...]],
    refinement: tuple[Float[Array, "m k R"], Bool[Array, "m k"], Int[np.ndarray, "p l2"]],
    seen: Bool[Array, "p m"],
    objective,
    samples: Samples,
    budget: int,
    iterations: int,
) -> Roots:
    """Where two camera groups' q are equal: the kinks of the max in Eq. 3.15, for every
    pair of groups (`members`: the cameras of each pair's first and of its second group,
    `Vec`s (p,)) on every curve, arrays (p, m, budget).

    Only the observed curves that both groups of a pair see something of (`seen`) are
    searched: elsewhere no interval is seen by both, and a kink would cut nothing. These
    (pair, curve) items are packed and searched a chunk at a time, so that the search
    costs what the cameras see together, not every pair on every curve.

    Near a camera its q changes over the camera's distance to the curve, which may be
    far shorter than a grid cell: the grid is refined where it is coarse for the members
    of each pair (`refinement`: every camera's `crossover_nodes` and whether it is near
    each curve, and the 2l members of every pair). The items with a member near their
    curve, few, are searched on the refined grid in a loop of their own.

    They carry no derivative: the integrand is continuous across a crossover (both
    groups' q are equal there), so the Leibniz terms of the two intervals that meet at it
    cancel (Eq. 5.9); the cut only keeps the kink out of the quadrature."""
    scene, objective, members, refinement = jax.lax.stop_gradient(
        (scene, objective, members, refinement)
    )
    refined, near, member_cameras = refinement
    pairs, m = seen.shape
    candidates = seen & jnp.asarray(scene.observed())[None]
    near = jnp.any(near[:, member_cameras], -1).T  # (p, m)

    def resolved(values, slopes, scale):
        # Where the two cameras' q agree to rounding (equal cameras, plateaus of a user
        # q) either camera is the best one: count F as just positive (by more than the
        # Hermite interpolant of the noise can dip), so that rounding noise brackets no
        # roots.
        rounding = 1e3 * jnp.finfo(values.dtype).eps * scale + jnp.finfo(values.dtype).tiny
        return jnp.where(jnp.abs(values) <= rounding, rounding, values), slopes

    def search(pair, curve, live, refine: bool):
        """The roots of the items (pair, curve), index arrays (c,): arrays (c, budget), on
        the grid or (`refine`) on the grid with its refinement for the pair's members;
        none for the items that are not `live`."""
        group_a, group_b = (tuple(v.map(lambda a: a[pair, None]) for v in g) for g in members)
        args = (scene, curve, group_a, group_b, objective)

        def function(t):
            return resolved(*crossover_function(t, args))

        def values_and_slopes(dx, ddx):  # from the sampled derivatives
            x, dx, ddx = (v.map(lambda a: a[curve]) for v in (samples.x, dx, ddx))
            return resolved(*crossover_terms(objective, group_a, group_b, x, dx, ddx))

        # (F, F') at the grid's nodes: right limits and left limits
        nodes = samples.at_nodes(values_and_slopes)
        starts, ends = (nodes, nodes) if samples.dx_end is None else nodes
        t = samples.t
        if refine:  # and at the refinement's nodes, inside cells (no corners), by t
            extra = refined[curve[:, None], member_cameras[pair]].reshape(curve.shape[0], -1)
            at_extra = function(extra)
            t = jnp.concatenate([jnp.broadcast_to(t, (curve.shape[0], t.shape[0])), extra], 1)
            order = jnp.argsort(t, axis=1)
            t = jnp.take_along_axis(t, order, 1)

            def merged(at_grid):
                return tuple(
                    jnp.take_along_axis(jnp.concatenate([g, e], 1), order, 1)
                    for g, e in zip(at_grid, at_extra)
                )

            starts, ends = merged(starts), merged(ends)
        values, slopes = zip(starts, ends)
        probes = dip_probes(function, t, values, slopes)
        values, slopes, probes = jax.tree.map(lambda a: a[:, None], (values, slopes, probes))
        t = t[:, None] if refine else t
        keep = jnp.broadcast_to(live[:, None, None], probes[0].shape)
        brackets = grid_brackets(t, values, slopes, budget, keep, probes=probes)
        t, valid, settled = solve_roots(
            crossover_function, args, brackets, iterations, 1.0, scene.costly_evaluation()
        )
        return t, valid, brackets.count, settled

    def step(carry, item, live, refine=False):
        t, valid, found, settled = carry
        pair, curve = item // m, item % m
        roots, ok, number, done = search(pair, curve, live, refine)
        pair = jnp.where(live, pair, pairs)  # (out of range: dropped)
        return (
            t.at[pair, curve].set(roots, mode="drop"),
            valid.at[pair, curve].set(ok, mode="drop"),
            found.at[pair, curve].set(number, mode="drop"),
            settled & done,
        )

    init = (
        jnp.ones((pairs, m, budget), samples.t.dtype),
        jnp.zeros((pairs, m, budget), bool),
        jnp.zeros((pairs, m), int),
        jnp.asarray(True),
    )
    # items per chunk: a node of the grid or of the refinement is an element
    size = max(1, CHUNK_ELEMENTS // samples.t.shape[0])
    coarse = over_chunks((candidates & ~near).ravel(), size, step, init)
    elements = samples.t.shape[0] + member_cameras.shape[1] * refined.shape[2]
    size = max(1, CHUNK_ELEMENTS // (8 * elements))  # (small: a lone item computes little)
    fine = functools.partial(step, refine=True)
    return Roots(*over_chunks((candidates & near).ravel(), size, fine, coarse, sparse=True))
