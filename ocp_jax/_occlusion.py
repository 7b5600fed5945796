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
from jaxtyping import Array, Bool, Float

from ._events import Samples
from ._roots import _safe, hermite_extremum
from ._vec import Vec, cross, dot, sub


def orientation(samples: Samples) -> Float[Array, " m"]:
    """+1 for counter-clockwise curves, -1 for clockwise (sign of the shoelace area)."""
    x = samples.x
    return jnp.sign(jnp.sum(x.x[:, :-1] * x.y[:, 1:] - x.y[:, :-1] * x.x[:, 1:], -1))


def _between(lam):
    return (lam > 0) & (lam < 1)


def visible_points(
    camera: Vec,
    samples: Samples,
    sense: Float[Array, " m"],
    t_mid: Float[Array, "m q"],
    x_mid: Vec,
    dx_mid: Vec,
) -> Bool[Array, "m q"]:
    """chi(t_mid[i, k], camera) for query points x_mid, x'_mid (arrays (m, q)) on every
    curve i."""
    m = samples.x.x.shape[0]
    d = sub(x_mid, camera)  # (m, q)
    facing = sense[:, None] * cross(dx_mid, d) > 0

    dd = d.map(lambda a: a[:, :, None, None])  # against the grid (m_j, N + 1)
    sight = sub(samples.x, camera)
    g = cross(dd, sight)  # (m, q, m_j, N + 1)
    dg = cross(dd, samples.dx)
    depth = dot(dd, sight) / dot(dd, dd)

    # On the query's own curve, deflate the trivial root at t_mid: r = g / (t - t_mid),
    # r' = (g' - r) / (t - t_mid), with the limits r = g'(t_mid), r' = 0 at t_mid.
    offset = samples.t - t_mid[:, :, None, None]
    near = jnp.abs(offset) <= 1e4 * jnp.finfo(offset.dtype).eps
    offset = jnp.where(near, 1.0, offset)
    r = jnp.where(near, cross(d, dx_mid)[:, :, None, None], g / offset)
    dr = jnp.where(near, 0.0, (dg - r) / offset)
    own = jnp.arange(m)[:, None, None, None] == jnp.arange(m)[None, None, :, None]
    g, dg = jnp.where(own, r, g), jnp.where(own, dr, dg)

    positive = g >= 0
    g0, g1, l0, l1 = g[..., :-1], g[..., 1:], depth[..., :-1], depth[..., 1:]
    h = jnp.diff(samples.t)
    split, peak, turning = hermite_extremum(g0, g1, dg[..., :-1], dg[..., 1:], h)
    crossing = positive[..., :-1] != positive[..., 1:]
    pair = turning & ~crossing & (g0 * peak < 0)
    blocked = (crossing & _between(l0 + g0 / _safe(g0 - g1) * (l1 - l0))) | (
        pair & _between(l0 + split * (l1 - l0))
    )
    return facing & ~jnp.any(blocked, axis=(-1, -2))
