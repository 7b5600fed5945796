"""Occlusion events of scenes of conics in closed form (circles and ellipses).

An affine map p' = M (p - c) takes a conic onto the unit circle, x(t) to (cos 2 pi t,
sin 2 pi t) (`AbstractConic.unit_frame`); it maps lines to lines and keeps tangency and
the order of points along a line, so both kinds of event have closed forms there:

- Tangency times (Eqs. 5.21, 5.33): from the camera C' = M (C - c), |C'| > 1, the lines
  of sight touch the unit circle at the angles phi +- arccos(1 / |C'|), phi the polar
  angle of C'. (A camera inside the conic, |C'| < 1, has none: the room.)
- Shadow times (Eqs. 5.22, 5.34): the ray C + lambda (P - C) through a ray source P meets
  the conic where |C' + lambda u'|^2 = 1, u' = M (P - C): a quadratic in lambda, kept
  beyond the source's depth (lambda > 1 behind a tangency point, > 0 for a view wedge's
  edge). A conic is strictly convex, so the ray of a tangency point meets its own conic
  there only.

They replace the grid brackets and Newton steps of `_events.py` where every curve of the
scene is a conic: a few kernels instead of two loops, with exact derivatives by autodiff
of the closed forms (the same as the implicit-function rules of `_roots.py`).

The decisions have closed forms too, so that such a scene needs no grid of samples:

- Occlusion (`_occlusion.py`): the open segment from C to a query point P crosses conic j
  where |C' + lambda M_j (P - C)|^2 = 1 has a root lambda in (0, 1). A facing point is
  never hidden by its own conic (strictly convex).
- Camera checks: C is inside conic i where |C'| < 1; its distance to the conic is
  ||C'| - 1| |C'| / |M^T C'| (the unit frame's distance over the map's stretch along the
  normal), exact for circles and to first order in the distance for ellipses (the
  thresholds are 1e-8 of the scene for on a curve, 2% of the largest semi-axis for too
  close; near the tips of an eccentric ellipse the estimate is low, so too close errs
  towards raising).
"""

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._geometry.curves import TWO_PI, UnitFrame
from .._geometry.vec import Vec, dot, norm, sub
from .events import RaySources, Roots
from .roots import first_true, quadratic_roots


def _to_unit(frames: UnitFrame, v: Vec, shift: bool) -> Vec:
    """M_i (v_i - c_i) (or M_i v_i without `shift`) for every conic i, where the arrays of
    `v` have a leading axis of one row per conic (or of one row for all)."""
    center, matrix = frames.center, frames.to_unit
    ones = (1,) * (v.x.ndim - 1)

    def per_conic(a):  # (m,) -> (m, 1, ..., 1), against v's arrays
        return a.reshape(a.shape + ones)

    if shift:
        v = Vec(v.x - per_conic(center[:, 0]), v.y - per_conic(center[:, 1]))
    m = [[per_conic(matrix[:, i, j]) for j in range(2)] for i in range(2)]
    return Vec(m[0][0] * v.x + m[0][1] * v.y, m[1][0] * v.x + m[1][1] * v.y)


def _angle(point: Vec, valid) -> Array:
    """The polar angle of `point` where `valid`, 0 elsewhere (with a finite derivative:
    arctan2 has none at the origin)."""
    return jnp.arctan2(jnp.where(valid, point.y, 0.0), jnp.where(valid, point.x, 1.0))


def _unit_circle_crossings(origin: Vec, direction: Vec):
    """Where the line origin + lambda direction meets the unit circle: the roots of
    a lambda^2 + b lambda + c = 0 with a = |direction|^2, b = 2 origin . direction and
    c = |origin|^2 - 1 (< 0 inside the circle). Returns (real, c, roots); the roots are
    finite padding where they are not real."""
    a = dot(direction, direction)
    b = 2.0 * dot(origin, direction)
    c = dot(origin, origin) - 1.0
    disc = b * b - 4.0 * a * c
    real = disc > 0.0
    return real, c, quadratic_roots(a, b, c, jnp.where(real, disc, 1.0))


def conic_tangency_times(frames: UnitFrame, camera: Vec) -> Roots:
    """The two tangency times of every conic seen from `camera` (none from inside)."""
    origin = _to_unit(frames, camera.map(lambda a: a[None]), shift=True)  # (m,)
    squared = dot(origin, origin)
    outside = squared > 1.0
    half = jnp.arccos(1.0 / jnp.sqrt(jnp.where(outside, squared, 4.0)))
    angle = _angle(origin, outside)[:, None] + jnp.stack([half, -half], -1)
    t = jnp.mod(angle / TWO_PI, 1.0)
    valid = jnp.broadcast_to(outside[:, None], t.shape)
    return Roots(jnp.where(valid, t, 1.0), valid, jnp.where(outside, 2, 0), jnp.array(True))


def conic_shadow_times(frames: UnitFrame, camera: Vec, sources: RaySources, budget: int) -> Roots:
    """Where the rays from `camera` through the ray sources first meet the scene beyond
    the source's depth (`shadow_times`: each ray has one shadow at most): one slot per
    ray and conic, packed into `budget` slots per conic when there are more (the count
    of hits is returned, so that an overflow is reported).

    `sources` starts with the two tangency points of every conic in turn (as
    `tangency_points` gives them for `conic_tangency_times`), whose rays are not searched
    on their own conic. Only the first crossing in front of the camera is an event: the
    ray leaves an object on its far side, which faces away from the camera (hidden by the
    object itself on both sides of the crossing); a room's first crossing in front of a
    camera inside it is its only one.
    """
    m = frames.center.shape[0]
    lines = sources.depth.shape[0]
    assert lines - 2 * m in (0, 2), "sources: two tangency points per conic, wedge edges"
    # Static: for conic i, every source but its own two tangency points.
    other = np.array(
        [[s for s in range(lines) if s >= 2 * m or s // 2 != i] for i in range(m)], int
    ).reshape(m, lines - 2)
    ray = sub(sources.point, camera).map(lambda a: a[other])  # (m, l - 2)
    origin = _to_unit(frames, camera.map(lambda a: a[None, None]), shift=True)  # (m, 1)
    direction = _to_unit(frames, ray, shift=False)
    real, c, roots = _unit_circle_crossings(origin, direction)
    # The first crossing in front: the nearer root outside the conic (c > 0), the
    # positive one inside it (c < 0, a room).
    lam = jnp.where(c > 0.0, jnp.minimum(*roots), jnp.maximum(*roots))
    valid = real & (lam > sources.depth[other]) & sources.valid[other]
    # Each ray's first hit over the scene (lam is the depth along the ray on every conic;
    # near ties kept): behind it, the conic it meets hides both sides of the ray.
    nearest = jnp.full(lines, jnp.inf, lam.dtype).at[other].min(jnp.where(valid, lam, jnp.inf))
    valid = valid & (lam <= nearest[other] + 1e-9 * jnp.abs(nearest[other]))
    hit = Vec(*(o + lam * d for o, d in zip(origin, direction)))
    t = jnp.where(valid, jnp.mod(_angle(hit, valid) / TWO_PI, 1.0), 1.0)
    count = jnp.sum(valid, axis=-1)
    if t.shape[1] > budget:
        index, filled, _ = first_true(valid, budget)
        t = jnp.where(filled, jnp.take_along_axis(t, index, -1), 1.0)
        valid = filled
    return Roots(t, valid, count, jnp.array(True))


def _det(matrix: Float[Array, "m 2 2"]) -> Float[Array, " m"]:
    return matrix[:, 0, 0] * matrix[:, 1, 1] - matrix[:, 0, 1] * matrix[:, 1, 0]


def _singular_values(matrix: Float[Array, "m 2 2"]) -> tuple[Array, Array]:
    """The largest and smallest singular values of 2 x 2 matrices, from the sum of
    squares S of their entries and their determinants D: s_max^2 = (S + sqrt(S^2 - 4 D^2))
    / 2, and s_min = |D| / s_max (no cancellation)."""
    squares = jnp.sum(matrix * matrix, axis=(-1, -2))
    det = _det(matrix)
    largest = jnp.sqrt(0.5 * (squares + jnp.sqrt(jnp.maximum(squares**2 - 4.0 * det**2, 0.0))))
    return largest, jnp.abs(det) / largest


def conic_orientation(frames: UnitFrame) -> Float[Array, " m"]:
    """+1 for counter-clockwise conics, -1 for clockwise: the sign of det M^-1."""
    return jnp.sign(_det(frames.from_unit))


def conic_extent(frames: UnitFrame) -> tuple[Array, Float[Array, " m"]]:
    """max |x| + max |y| over the scene (its size) and each conic's radius about its
    centre, the largest semi-axis (the grid's checks take a bounding disc of the samples
    instead, whose radius also holds the longest step between them: up to 1.4x larger)."""
    half_widths = jnp.sqrt(jnp.sum(frames.from_unit**2, axis=-1))  # (m, 2): rows of M^-1
    size = jnp.sum(jnp.max(jnp.abs(frames.center) + half_widths, axis=0))
    return size, _singular_values(frames.from_unit)[0]


def conic_distances(
    frames: UnitFrame, sides: np.ndarray, cameras: Vec
) -> tuple[Array, Array, Array]:
    """(distance, outward, t) of every camera to every conic, arrays (m, k), as
    `_closest_points` gives them: the distance (exact for circles, to first order for
    ellipses, see the module docstring), a value that is negative where the camera is
    on the side of conic i that is not free space (inside an object, outside the room:
    `sides` = +1 for objects, -1 for the room), and the parameter of the nearest point
    (for an ellipse, of the point that the unit frame's radial projection gives)."""
    matrix = frames.to_unit
    unit = _to_unit(frames, cameras.map(lambda a: a[None]), shift=True)  # (m, k) C'
    stretch = Vec(  # M^T C'
        matrix[:, 0, 0, None] * unit.x + matrix[:, 1, 0, None] * unit.y,
        matrix[:, 0, 1, None] * unit.x + matrix[:, 1, 1, None] * unit.y,
    )
    radial = norm(unit)
    # At the centre (a camera in the middle of a room) |C'| / |M^T C'| has no limit:
    # the distance there is the smallest semi-axis.
    smallest = _singular_values(frames.from_unit)[1][:, None]
    at_centre = radial == 0.0
    ratio = jnp.where(at_centre, smallest, radial / jnp.where(at_centre, 1.0, norm(stretch)))
    outward = jnp.asarray(sides, radial.dtype)[:, None] * (radial - 1.0)
    t = jnp.mod(_angle(unit, ~at_centre) / TWO_PI, 1.0)
    return jnp.abs(radial - 1.0) * ratio, outward, t


class ConicOccluders(NamedTuple):
    """The conics of a scene with other curves, whose occlusions are tested in closed form."""

    frames: UnitFrame  # arrays (c,)
    curve: np.ndarray  # (c,) static: the scene's curve of each frame


def conic_occluders(scene) -> ConicOccluders | None:
    """The scene's conics (None where it has none)."""
    curve = np.flatnonzero(scene.conic())
    return ConicOccluders(scene.rows(curve).conic_frames(), curve) if len(curve) else None


def conic_occluded(occluders: ConicOccluders, camera: Vec, query: Vec, curve: Array) -> Array:
    """Whether another conic crosses the open segment from `camera` to each query point
    (arrays (q,), point k on curve `curve[k]`): a root lambda in (0, 1) of
    |C' + lambda M_j (P - C)|^2 = 1 for some conic j != curve[k]."""
    frames = occluders.frames
    origin = _to_unit(frames, camera.map(lambda a: a[None, None]), shift=True)
    direction = _to_unit(frames, sub(query, camera).map(lambda a: a[None]), shift=False)
    real, _, (near, far) = _unit_circle_crossings(origin, direction)  # (m_j, q)
    between = ((near > 0.0) & (near < 1.0)) | ((far > 0.0) & (far < 1.0))
    crossing = real & between & (occluders.curve[:, None] != curve[None])
    return jnp.any(crossing, axis=0)
