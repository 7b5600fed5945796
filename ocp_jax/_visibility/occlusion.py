"""The visibility indicator chi (Eqs. 3.7, 3.9) at one point per interval.

Between two consecutive events of a camera, an arc is wholly visible or wholly hidden, so
one test at its midpoint m = x_i(t_m) decides it:

1. **Facing.** On a closed curve, a point whose outward normal faces away from the camera
   is hidden by its own object; this is decided exactly first.
2. **Occluders.** Otherwise m is hidden iff some curve crosses the open segment (C, m). For
   the ray direction d = m - C, the crossings of curve j are the roots of
   g(s) = cross(d, x_j(s) - C) with depth lambda(s) = (x_j(s) - C) . d / |d|^2 in (0, 1).
   They are read off the camera's grid like the tangency times: sign changes of g, and
   near-grazing pairs of crossings inside one cell from the cubic Hermite interpolant of
   (g, g'). Its extra node, the camera's nearest point on each curve
   (`_events.with_nearest_node`), keeps the depth of a crossing just behind the camera
   from being interpolated to one in front of it.
3. **Own curve.** On curve i itself, g has its trivial root at t_m, and on the grid
   [0, 1] of a closed curve its periodic images t_m -+ 1 too. There the test uses the
   deflated r(s) = g(s) / p(s), p = u (1 - u) (1 + u) with u = s - t_m (r(t_m) = g'(t_m)
   != 0 for a facing point), whose roots are exactly the other crossings, so no window
   around t_m (or the seam) is excluded and a grid node at (or next to) t_m needs no
   special case. Their depths are deflated too
   (`deflated_depth`), so that a crossing just beyond a point near a tangency is not
   taken for one in front of it.
4. **Grazing.** A pair of crossings too close together for the interpolant, where the
   line of sight grazes a curve, straddles the camera's tangency point on that curve:
   g there has the sign opposite to both ends of its cell (`_events.grazing_probes`).

The test is a decision only: it carries no derivative (the derivatives of Q come from the
event times and the integrand).
"""

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from .._geometry.vec import Vec, cross, dot, norm, sub
from .conics import ConicOccluders, conic_occluded
from .events import GrazingProbes, PolygonEdges, Samples, bounding_discs, grid_cell
from .roots import CHUNK_ELEMENTS, cell_ends, hermite_extremum, over_chunks
from .xla_cpu import computed_on_one_thread, fused_reduce

# Edges whose bounding disc is tested before the edges themselves (`_edge_chunks`).
_EDGES_PER_CHUNK = 8


def in_view(camera, point: Vec) -> Bool[Array, "..."]:
    """Whether points (a `Vec` of arrays) lie in the view wedge and range of one `Camera`
    pose: (x - C) . u >= |x - C| cos(half_fov) and |x - C| <= range (occlusion aside)."""
    d = sub(point, Vec.of(camera.position))
    distance = jnp.sqrt(dot(d, d))
    seen = jnp.ones(distance.shape, bool)
    if camera.half_fov is not None:
        seen = seen & (dot(d, Vec.of(camera.direction())) >= distance * jnp.cos(camera.half_fov))
    if camera.range is not None:
        seen = seen & (distance <= camera.range)
    return seen


def orientation(samples: Samples) -> Float[Array, " m"]:
    """+1 for counter-clockwise curves, -1 for clockwise (sign of the shoelace area)."""
    x = samples.x
    return jnp.sign(fused_reduce(jnp.sum, x.x[:, :-1] * x.y[:, 1:] - x.y[:, :-1] * x.x[:, 1:]))


def _crosses_segment(g, dg, h, in_segment):
    """Per cell of a grid: does the curve cross the open segment from the camera to the
    query point? `g` (sign: side of the line of sight), `dg` its t-derivative;
    `in_segment(a, b, single)`: whether the curve's point at the fraction a / b of each
    cell lies between the camera and the query point, `single` where it is the one root
    of g in the cell (`linear_depth`, `deflated_depth`).

    A sign change of g is a crossing at the fraction g0 / (g0 - g1) of the cell. A pair of
    crossings inside one cell (a grazing occluder) shows as the cubic Hermite interpolant
    of (g, g') changing sign at its extremum, tested there."""
    g0, g1 = cell_ends(g)
    crossing = (g0 >= 0) != (g1 >= 0)
    h = jnp.broadcast_to(h, g0.shape)
    split, peak, turning = hermite_extremum(g0, g1, *cell_ends(dg), h)
    pair = turning & ~crossing & (g0 * peak < 0)
    return (crossing & in_segment(g0, g0 - g1, True)) | (pair & in_segment(split, 1.0, False))


def linear_depth(depth, reach):
    """`in_segment` of `_crosses_segment` for the depth D = (x - C) . d along the line of
    sight, interpolated linearly in each cell: D in (0, reach = |d|^2), tested without
    division (D b = D0 b + a (D1 - D0) for the fraction a / b)."""
    d0, d1 = depth[..., :-1], depth[..., 1:]

    def in_segment(a, b, single):
        scaled = d0 * b + a * (d1 - d0)
        return (scaled * b > 0) & (jnp.abs(scaled) < reach * jnp.abs(b))

    return in_segment


def deflated_depth(excess, deflator, reach, r, r_mid):
    """`in_segment` of `_crosses_segment` on the query point's own curve, where the depth
    is written D - reach = (x(s) - m) . d = e(s) p(s), with the deflator p of the trivial
    root (p = u (1 - u) (1 + u), u = s - t_m: negative before t_m, positive after it).

    Interpolating D linearly errs by O(h^2) D'', more than the margin D - reach of the
    crossing just beyond a query point near a tangency (which was then taken for an
    occluder). Here the crossing lies between the camera and m iff e and p have
    opposite signs there: e (smooth through t_m, -> x'(t_m) . d) and p are interpolated
    linearly. In the cell around t_m the side of a single crossing is instead the side
    where the deflated r changes sign (r(t_m) = `r_mid` is known exactly), not that of
    the interpolated root. Tested without division: for the fraction a / b,
    (D - reach) b^2 = (e0 b + a (e1 - e0)) (o0 b + a (o1 - o0)), o = p at the nodes."""
    e0, e1 = excess[..., :-1], excess[..., 1:]
    o0, o1 = deflator[..., :-1], deflator[..., 1:]
    around = (o0 < 0) & (o1 > 0)
    after = r[..., :-1] * r_mid > 0

    def in_segment(a, b, single):
        excess_b = e0 * b + a * (e1 - e0)
        beyond = excess_b * (o0 * b + a * (o1 - o0))
        ahead = beyond < 0
        if single:
            ahead = jnp.where(around, (excess_b * b > 0) != after, ahead)
        return ahead & (reach * b * b + beyond > 0)

    return in_segment


def _crosses_edges(d: Vec, reach, start: Vec, end: Vec) -> Bool[Array, "..."]:
    """Whether straight edges (start, end relative to the camera) cross the open segment
    from the camera to query points (d = m - C, reach = |d|^2), all arrays broadcast
    against each other: the sign change of g = cross(d, x - C) between the edge's ends,
    the one cell of `_crosses_segment` with the depth of `linear_depth`."""
    g0, g1 = cross(d, start), cross(d, end)
    depth = jnp.stack(jnp.broadcast_arrays(dot(d, start), dot(d, end)), -1)
    in_segment = linear_depth(depth, jnp.asarray(reach)[..., None])
    crossing = (g0 >= 0) != (g1 >= 0)
    return crossing & in_segment(g0[..., None], (g0 - g1)[..., None], True)[..., 0]


def _passes_disc(d: Vec, reach, centre: Vec, radius) -> Bool[Array, "..."]:
    """Whether the segment from the camera to each query point (d = m - C, reach =
    |d|^2) meets a disc (centre relative to the camera), arrays broadcast against each
    other: the distance from the centre to the segment's nearest point is at most the
    radius (widened by 1e-9 of it, so that rounding keeps every occluder that touches)."""
    along = jnp.clip(dot(centre, d) / reach, 0.0, 1.0)
    off = sub(centre, d.map(lambda a: along * a))
    return dot(off, off) <= (radius * (1.0 + 1e-9)) ** 2


def _edge_chunks(curve: np.ndarray) -> np.ndarray:
    """Runs of at most `_EDGES_PER_CHUNK` consecutive edges of one polygon (`curve`: the
    polygon of each edge, static): indices (K, _EDGES_PER_CHUNK), padded with -1."""
    chunks = []
    for i in np.unique(curve):
        edges = np.flatnonzero(curve == i)
        chunks.extend(np.array_split(edges, -(-len(edges) // _EDGES_PER_CHUNK)))
    table = np.full((len(chunks), _EDGES_PER_CHUNK), -1)
    for row, edges in zip(table, chunks):
        row[: len(edges)] = edges
    return table


def _any_blocking(candidates: Bool[Array, "q n"], blocks, cost: int) -> Bool[Array, " q"]:
    """Whether some occluder blocks each query: `blocks(query, occluder)` (index arrays
    (p,) -> bool (p,), each pair's test about `cost` elements of work) over the pairs
    where `candidates` hold. The candidate pairs are packed and tested a chunk at a time
    (about `CHUNK_ELEMENTS` elements each, `over_chunks`), so that the test costs what
    the candidates are, not every query against every occluder."""
    q, n = candidates.shape
    size = max(1, CHUNK_ELEMENTS // cost)

    def step(blocked, pair, live):
        query = pair // n
        hit = live & blocks(query, pair % n)
        return blocked.at[jnp.where(hit, query, q)].set(True, mode="drop")

    return over_chunks(candidates.ravel(), size, step, jnp.zeros(q, bool))


def _deflator(u):
    """p = u (1 - u) (1 + u), u = s - t_m in [-1, 1]: the roots of the own curve's line of
    sight at t_m and at its periodic images t_m -+ 1, negative before t_m, positive after."""
    return u * (1.0 - u) * (1.0 + u)


def _grazing(value, start, end, depth, reach):
    """Probes whose line-of-sight function (`value`) has the sign opposite to both ends
    of the probe's cell (two crossings in it, one on either side), with the probe's depth
    D = (x - C) . d inside the segment (0, reach = |d|^2)."""
    return (value * start < 0) & (value * end < 0) & (depth > 0) & (depth < reach)


def facing(camera: Vec, sense: Float[Array, "..."], x_mid: Vec, dx_mid: Vec) -> Bool[Array, "..."]:
    """Whether the free side of each query point faces the camera (`sense`: that of each
    point's curve, broadcast against the points); a point facing away is hidden by its
    own object."""
    return sense * cross(dx_mid, sub(x_mid, camera)) > 0


def _blocked_by_edges(
    edges: PolygonEdges, camera: Vec, d: Vec, reach, curve, query_piece
) -> Bool[Array, " q"]:
    """Whether a polygon's edge crosses the segment from the camera to each query point
    (d = m - C, reach = |d|^2, arrays (q,)), its own edge aside (the query's `curve` and
    smooth piece): runs of edges (`_edge_chunks`) are tested only where the segment meets
    the disc around their ends."""
    chunks = _edge_chunks(edges.curve)
    filled = jnp.asarray(chunks >= 0)
    index = jnp.asarray(np.where(chunks >= 0, chunks, chunks[:, :1]))  # (K, c)
    start, end = sub(edges.start, camera), sub(edges.end, camera)  # (E,)
    ends = Vec(*(jnp.concatenate([a[index], b[index]], 1) for a, b in zip(start, end)))
    centre = ends.map(lambda a: jnp.mean(a, 1))
    radius = jnp.max(norm(sub(ends, centre.map(lambda a: a[:, None]))), 1)
    candidates = _passes_disc(
        d.map(lambda a: a[:, None]), reach[:, None], centre.map(lambda a: a[None]), radius[None]
    )

    def chunk_blocks(query, chunk):
        e = index[chunk]  # (p, c)
        crosses = _crosses_edges(
            d.map(lambda a: a[query, None]),
            reach[query, None],
            start.map(lambda a: a[e]),
            end.map(lambda a: a[e]),
        )
        own = (jnp.asarray(edges.curve)[e] == curve[query, None]) & (
            jnp.asarray(edges.piece)[e] == query_piece[query, None]
        )
        return jnp.any(crosses & ~own & filled[chunk], 1)

    return _any_blocking(candidates, chunk_blocks, chunks.shape[1])


def _hidden_by_own_curve(
    camera: Vec,
    grid: Samples,
    sight: Vec,
    h: Float[Array, "m n"],
    probes: GrazingProbes,
    one_thread: bool,
    curve: Int[Array, " q"],
    t_mid: Float[Array, " q"],
    query_cell: Int[Array, " q"],
    d: Vec,
    reach: Float[Array, " q"],
    r_mid: Float[Array, " q"],
    slope_mid: Float[Array, " q"],
    same_piece: Bool[Array, "q n"] | None,
) -> Bool[Array, " q"]:
    """Whether the query point's own curve crosses the segment from the camera to it
    (`sight`: the grid's x - C, `h`: its cell widths; d = m - C, reach = |d|^2,
    r_mid = cross(d, x'(t_mid)), slope_mid = d . x'(t_mid), arrays (q,); `same_piece`:
    the cells of the query's smooth piece, the others being tested as other curves are).

    The trivial root at t_mid and its periodic images t_mid -+ 1 are deflated (the
    grid's ends are one point of the curve, and an image next to one would leave g a
    root there that rounding puts on either side of it), with p = u (1 - u) (1 + u),
    u = t - t_mid: r = g / p, r' = (g' - r p') / p; at a node on a root of p, r takes its
    limit g'(t_mid) / p' and r' is set to 0 (not its limit; the cell's interpolant only
    needs it roughly); and the depth's excess over the query point's,
    e = (D - reach) / p -> x'(t_mid) . d / p' there. Arrays (q, N + 2), the own curve's
    row of the grid."""
    dq = d.map(lambda a: a[:, None])
    own_sight = sight.map(lambda a: a[curve])
    g = cross(dq, own_sight)
    u = grid.t[curve] - t_mid[:, None]
    deflator = _deflator(u)
    deflator_slope = 1.0 - 3.0 * u * u
    tolerance = 1e4 * jnp.finfo(u.dtype).eps
    near = (jnp.abs(u) <= tolerance) | (jnp.abs(1.0 - jnp.abs(u)) <= tolerance)
    divisor = jnp.where(near, 1.0, deflator)
    r_mid = r_mid[:, None]
    r = jnp.where(near, r_mid / deflator_slope, g / divisor)
    reach_q = reach[:, None]
    excess = jnp.where(
        near, slope_mid[:, None] / deflator_slope, (dot(dq, own_sight) - reach_q) / divisor
    )

    # Next to a root of p, r' = (g' - r p') / p cancels: r's rounding error (eps |d|
    # |x - C| / |p|) is divided by p again. Within eps^(1/3) of one (6e-6 in float64,
    # 5e-3 in float32) r' is set to 0 too: a query point 1e-10 from a node (the
    # midpoint of an arc between two events beside corners) took a slope of -200 for
    # 0.14 there, and its cell's interpolant a pair of crossings that hid it.
    flat = float(jnp.finfo(u.dtype).eps) ** (1 / 3)
    flat = (jnp.abs(u) <= flat) | (jnp.abs(1.0 - jnp.abs(u)) <= flat)

    dg = grid.at_nodes(lambda dx, _: cross(dq, dx.map(lambda a: a[curve])))
    dr = jax.tree.map(lambda s: jnp.where(flat, 0.0, (s - r * deflator_slope) / divisor), dg)

    def crosses_own(r, dr, h, excess, deflator, reach, r_mid, same_piece):
        in_segment = deflated_depth(excess, deflator, reach, r, r_mid)
        crosses = _crosses_segment(r, dr, h, in_segment)
        if same_piece is not None:  # (the other pieces' cells are tested as other curves)
            crosses = crosses & same_piece
        return fused_reduce(jnp.any, crosses)

    args = (r, dr, h[curve], excess, deflator, reach_q, r_mid, same_piece)
    own = computed_on_one_thread(crosses_own, args, camera) if one_thread else crosses_own(*args)

    # Grazing crossings of the own curve, from r = g / p at its probes (the sign of g p)
    # and r at the ends of their cells; not in the query point's own cell, where r is
    # deflated and the side of a crossing is decided as above.
    on_own = jax.tree.map(lambda a: a[curve], probes)  # (q, r)
    return own | fused_reduce(
        jnp.any,
        on_own.valid
        & (on_own.cell != query_cell[:, None])
        & _grazing(
            cross(dq, on_own.sight) * _deflator(on_own.t - t_mid[:, None]),
            jnp.take_along_axis(r, on_own.cell, -1),
            jnp.take_along_axis(r, on_own.cell + 1, -1),
            dot(dq, on_own.sight),
            reach_q,
        ),
        -1,
    )


def visible_points(
    camera: Vec,
    grid: Samples,
    sense: Float[Array, " m"],
    curve: Int[Array, " q"],
    t_mid: Float[Array, " q"],
    x_mid: Vec,
    dx_mid: Vec,
    probes: GrazingProbes,
    pieces: Int[Array, "m n"] | None = None,
    edges: PolygonEdges | None = None,
    conics: ConicOccluders | None = None,
    one_thread: bool = False,
) -> Bool[Array, " q"]:
    """chi(t_mid[k], camera) for query points x_mid, x'_mid (arrays (q,)), point k on curve
    `curve[k]`, on the camera's grid (`_events.with_nearest_node`), with its tangency
    points as `probes` of grazing lines of sight (on that grid); `pieces`: the smooth piece
    of each cell of the grid (`_events.grid_pieces`, None where every curve is one); with
    `one_thread`, the test on the own curve is one kernel on one thread
    (`computed_on_one_thread`). The queries are a flat list over the scene, so that a
    camera's test costs what its intervals are, not the most any curve has.

    The polygons' `edges` (`_events.polygon_edges`) are tested whole, not cell by cell:
    on a straight edge g is affine, so the edge crosses the segment (C, m) iff g changes
    sign between its ends at a depth in (0, |d|^2), the test of its cells taken at once.
    The grid's rows of the polygons are then left out of the test of other curves, and so
    are those of the `conics` (`_conics.conic_occluders`), whose crossings of the segment
    are the roots of a quadratic (`conic_occluded`). An occluder is tested against a query
    only where the segment (C, m) meets its bounding disc (a run of edges, a curve's
    row), and a curve's row only for the queries that no closed form has blocked: the
    test costs what can block, not every query against every occluder (`over_chunks`)."""
    m = grid.t.shape[0]
    # The rows tested on the grid: every curve but the polygons and conics given.
    rows = np.arange(m)
    for closed_form in (edges, conics):
        if closed_form is not None:
            rows = np.setdiff1d(rows, closed_form.curve)
    h = jnp.diff(grid.t)  # (m, N + 1)
    d = sub(x_mid, camera)  # (q,)
    reach = dot(d, d)
    sight = sub(grid.x, camera)
    query_cell = grid_cell(t_mid, grid, curve)
    own_row = jnp.arange(m)[None] == curve[:, None]  # (q, m)
    # The cells tested with the own curve's deflated function below: on the query's own
    # curve, those of its smooth piece (across a corner g is no continuation of its
    # trivial root at t_m: r = g / p there is not smooth, its slope beside the corner
    # grows as the jump of g' over the distance to t_m, and the cell's Hermite
    # interpolant turns and shows a pair of crossings).
    same_piece = None
    if pieces is not None:
        query_piece = pieces[curve, query_cell]
        same_piece = pieces[curve] == query_piece[:, None]  # (q, N + 1)

    # Occluders in closed form first, then the grid's rows only for the queries they
    # leave unblocked, each row only where the line of sight meets its bounding disc.
    blocked = jnp.zeros(t_mid.shape, bool)
    if edges is not None:  # every edge but the query's own (tested deflated below)
        blocked = _blocked_by_edges(edges, camera, d, reach, curve, query_piece)
    if conics is not None:
        blocked = blocked | conic_occluded(conics, camera, x_mid, curve)
    if len(rows) and (m > 1 or pieces is not None):
        # Every row's cells but the query's deflated ones, and the grazing probes of the
        # other rows: arrays (p, N + 2) for p (query, row) pairs.
        centre, radius = bounding_discs(grid)
        own = own_row[:, rows]
        near = _passes_disc(
            d.map(lambda a: a[:, None]),
            reach[:, None],
            sub(centre, camera).map(lambda a: a[None, rows]),
            radius[None, rows],
        )
        candidates = (near & ~own if pieces is None else near | own) & ~blocked[:, None]

        def row_blocks(query, row):
            j = jnp.asarray(rows)[row]
            dq, reach_q = d.map(lambda a: a[query, None]), reach[query, None]
            sight_j = sight.map(lambda a: a[j])
            dg = grid.at_nodes(lambda dx, _: cross(dq, dx.map(lambda a: a[j])))
            depth = linear_depth(dot(dq, sight_j), reach_q)
            plain = _crosses_segment(cross(dq, sight_j), dg, h[j], depth)
            is_own = (j == curve[query])[:, None]
            deflated = is_own if same_piece is None else is_own & same_piece[query]
            on = jax.tree.map(lambda a: a[j], probes)  # (p, r)
            grazing = _grazing(
                cross(dq, on.sight),
                cross(dq, on.start),
                cross(dq, on.end),
                dot(dq, on.sight),
                reach_q,
            )
            return jnp.any(plain & ~deflated, 1) | jnp.any(on.valid & ~is_own & grazing, 1)

        blocked = blocked | _any_blocking(candidates, row_blocks, grid.t.shape[1])

    # The query's own curve, only where it can hide the query: a facing point of a
    # polygon is not hidden by its own edge (the others are among the edges above), nor
    # one of a conic by its convex curve; nor is a query already hidden tested again.
    # So the test costs what the curved queries left are (`over_chunks`).
    facing_queries = facing(camera, sense[curve], x_mid, dx_mid)
    if not len(rows):
        return facing_queries & ~blocked
    tested = jnp.asarray(np.isin(np.arange(m), rows))[curve] & facing_queries & ~blocked
    r_mid, slope_mid = cross(d, dx_mid), dot(d, dx_mid)

    def own_blocks(hidden, query, live):
        hit = _hidden_by_own_curve(
            camera,
            grid,
            sight,
            h,
            probes,
            one_thread,
            curve[query],
            t_mid[query],
            query_cell[query],
            d.map(lambda a: a[query]),
            reach[query],
            r_mid[query],
            slope_mid[query],
            None if same_piece is None else same_piece[query],
        )
        return hidden.at[jnp.where(live & hit, query, hidden.shape[0])].set(True, mode="drop")

    size = max(1, CHUNK_ELEMENTS // grid.t.shape[1])
    own = over_chunks(tested, size, own_blocks, jnp.zeros(t_mid.shape, bool))
    return facing_queries & ~blocked & ~own
