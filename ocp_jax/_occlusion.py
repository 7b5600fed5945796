"""The visibility indicator chi (Eqs. 3.7, 3.9) at one point per interval.

Between two consecutive events of a camera, an arc is wholly visible or wholly hidden, so
one test at its midpoint m = x_i(t_m) decides it:

1. **Facing.** On a closed curve, a point whose outward normal faces away from the camera
   is hidden by its own object; this is decided exactly first.
2. **Occluders.** Otherwise m is hidden iff some curve crosses the open segment (C, m). For
   the ray direction d = m - C, the crossings of curve j are the roots of
   g(s) = cross(d, x_j(s) - C) with depth lambda(s) = (x_j(s) - C) . d / |d|^2 in (0, 1).
   They are read off the grid like the event roots: sign changes of g, and near-grazing
   pairs of crossings inside one cell from the cubic Hermite interpolant of (g, g').
3. **Own curve.** On curve i itself, g has its trivial root at t_m. There the test uses
   the deflated r(s) = g(s) / (s - t_m) (r(t_m) = g'(t_m) != 0 for a facing point), whose
   roots are exactly the other crossings, so no window around t_m is excluded and a grid
   node at (or next to) t_m needs no special case.

The test is a decision only: it carries no derivative (the derivatives of Q come from the
event times and the integrand).
"""

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from ._events import Samples
from ._materialize import computed_on_one_thread
from ._reductions import fused_reduce
from ._roots import cell_ends, hermite_extremum
from ._vec import Vec, cross, dot, sub


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


def _crosses_segment(g, dg, depth, reach, h):
    """Per cell of a grid: does the curve cross the open segment from the camera to the
    query point? `g` (sign: side of the line of sight), `dg` its t-derivative, `depth`
    = (x - C) . d along the line of sight, `reach` = |d|^2 (the query point's depth).

    A sign change of g is a crossing at the linearly interpolated depth, tested without
    division: D_c = (g0 D1 - g1 D0) / (g0 - g1) lies in (0, reach). A pair of crossings
    inside one cell (a grazing occluder) shows as the cubic Hermite interpolant of (g, g')
    changing sign at its extremum."""
    g0, g1 = cell_ends(g)
    d0, d1 = depth[..., :-1], depth[..., 1:]
    crossing = (g0 >= 0) != (g1 >= 0)
    num, den = g0 * d1 - g1 * d0, g0 - g1
    inside = (num * den > 0) & (jnp.abs(num) < reach * jnp.abs(den))
    h = jnp.broadcast_to(h, g0.shape)
    split, peak, turning = hermite_extremum(g0, g1, *cell_ends(dg), h)
    pair = turning & ~crossing & (g0 * peak < 0)
    d_pair = d0 + split * (d1 - d0)
    return (crossing & inside) | (pair & (d_pair > 0) & (d_pair < reach))


def facing(camera: Vec, sense: Float[Array, " m"], x_mid: Vec, dx_mid: Vec) -> Bool[Array, "m q"]:
    """Whether the free side of each query point (arrays (m, q) on every curve i) faces
    the camera; a point facing away is hidden by its own object."""
    return sense[:, None] * cross(dx_mid, sub(x_mid, camera)) > 0


def visible_points(
    camera: Vec,
    samples: Samples,
    sense: Float[Array, " m"],
    t_mid: Float[Array, "m q"],
    x_mid: Vec,
    dx_mid: Vec,
    one_thread: bool = False,
) -> Bool[Array, "m q"]:
    """chi(t_mid[i, k], camera) for query points x_mid, x'_mid (arrays (m, q)) on every
    curve i; with `one_thread`, the test on the own curve is one kernel on one thread
    (`computed_on_one_thread`)."""
    m = t_mid.shape[0]
    h = jnp.diff(samples.t)
    d = sub(x_mid, camera)  # (m, q)
    reach = dot(d, d)
    sight = sub(samples.x, camera)

    # Every other curve j (static indices, none for a single curve): arrays
    # (m, q, m - 1, N + 1).
    other = np.array([[j for j in range(m) if j != i] for i in range(m)], int).reshape(m, m - 1)
    dd = d.map(lambda a: a[:, :, None, None])
    sight_j = sight.map(lambda a: a[other][:, None])
    dg_j = samples.at_nodes(lambda dx, _: cross(dd, dx.map(lambda a: a[other][:, None])))
    others = _crosses_segment(
        cross(dd, sight_j), dg_j, dot(dd, sight_j), reach[:, :, None, None], h
    )
    blocked = fused_reduce(jnp.any, others, (-1, -2))

    # The query's own curve: deflate the trivial root at t_mid, r = g / (t - t_mid),
    # r' = (g' - r) / (t - t_mid), with the limits r = g'(t_mid), r' = 0 there.
    dq = d.map(lambda a: a[:, :, None])
    own_sight = sight.map(lambda a: a[:, None])
    g = cross(dq, own_sight)  # (m, q, N + 1)
    offset = samples.t[None, None] - t_mid[:, :, None]
    near = jnp.abs(offset) <= 1e4 * jnp.finfo(offset.dtype).eps
    offset = jnp.where(near, 1.0, offset)
    r = jnp.where(near, cross(d, dx_mid)[:, :, None], g / offset)

    def slopes_at(dx, _):
        dg = cross(dq, dx.map(lambda a: a[:, None]))
        return jnp.where(near, 0.0, (dg - r) / offset)

    dr = samples.at_nodes(slopes_at)

    def crosses_own(*args):
        return fused_reduce(jnp.any, _crosses_segment(*args))

    args = (r, dr, dot(dq, own_sight), reach[:, :, None], h)
    own = computed_on_one_thread(crosses_own, args, camera) if one_thread else crosses_own(*args)
    return facing(camera, sense, x_mid, dx_mid) & ~blocked & ~own
