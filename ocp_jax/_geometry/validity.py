"""What makes a scene valid, checked where it is built.

A valid scene's curves are simple closed curves (none crosses itself), no two objects
cross, touch or nest, every object lies strictly inside the room (where there is one), and
no edge of a piecewise curve has zero length. On such scenes every camera in free space
sees what Q integrates; on others Q would be a plausible but meaningless number.

The checks work on polylines through each curve: a polygon's own vertices (exact), and
for curved pieces chords fine enough that each lies within its `sag` of the arc, the
distance from the arc's midpoint to the chord times 1.5 (a conservative bound for arcs
that turn by little per chord). Two chords count as meeting when they come closer than
the sum of their sags plus 1e-9 of the scene's size: touching counts as crossing, and
curves closer than their chords can resolve are refused rather than misjudged.

A scene built from concrete arrays is checked on the host (`check_scene`), with a message
that names the curves and a point near the fault. A scene built from traced arrays (under
`jit`, `vmap` or `grad`, say while a shape is optimised) is checked by the same tests in
the traced program (`checked_under_trace`): every pair of chords, no box prefilter, and
`equinox.branched_error_if` names the curves (a point cannot enter its static message).
"""

import functools
import itertools
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool

__all__ = ["check_scene", "checked_under_trace", "inside_polygon"]

_REFINE = 8  # chords per grid cell of a curved piece


def _polyline(curve, xp=np):
    """Vertices (n, 2) of a closed polyline through `curve` (not repeated at the end) and
    each chord's sag bound (n,), chord j from vertex j to j + 1; NumPy arrays, or traced
    ones where `xp` is `jax.numpy`."""
    points = getattr(curve, "points", None)
    if points is not None and points.shape[1] == 1:  # a polygon: exact
        vertices = points[:, 0] if xp is jnp else np.asarray(points[:, 0], float)
        return vertices, xp.zeros(len(vertices), vertices.dtype)
    n = _REFINE * curve.grid_cells()
    t = jnp.asarray(np.arange(2 * n) / (2 * n), curve.dtype)
    if xp is jnp:
        x = curve(t)
    else:
        with jax.ensure_compile_time_eval():
            x = np.asarray(_points(curve, t), float)
    vertices, middles = x[0::2], x[1::2]
    ends = xp.roll(vertices, -1, axis=0)
    return vertices, 1.5 * _point_segment_distance(middles, vertices, ends, xp)


@jax.jit  # (compiled once per curve type and shape, not dispatched op by op)
def _points(curve, t):
    return curve(t)


def _point_segment_distance(p, a, b, xp=np):
    ab = b - a
    length2 = xp.sum(ab * ab, -1)
    s = xp.clip(xp.sum((p - a) * ab, -1) / xp.where(length2 > 0, length2, 1.0), 0.0, 1.0)
    return xp.linalg.norm(p - (a + s[..., None] * ab), axis=-1)


def _segment_distances(a0, a1, b0, b1, xp=np):
    """Distances between the segments [a0, a1] and [b0, b1], pair by pair (arrays (..., 2)
    that broadcast), 0 where they cross."""

    def orient(p, q, r):
        return xp.sign(
            (q[..., 0] - p[..., 0]) * (r[..., 1] - p[..., 1])
            - (q[..., 1] - p[..., 1]) * (r[..., 0] - p[..., 0])
        )

    crossing = (orient(a0, a1, b0) * orient(a0, a1, b1) < 0) & (
        orient(b0, b1, a0) * orient(b0, b1, a1) < 0
    )
    distance = functools.partial(_point_segment_distance, xp=xp)
    ends = xp.minimum(
        xp.minimum(distance(a0, b0, b1), distance(a1, b0, b1)),
        xp.minimum(distance(b0, a0, a1), distance(b1, a0, a1)),
    )
    return xp.where(crossing, 0.0, ends)


def _ray_crossings(points, a, b, xp=np):
    """Whether the ray from each point (n, 2) in the direction +x crosses each edge from
    a to b (arrays (e, 2)): booleans (n, e), the terms of the even-odd rule."""
    a, b = a[None], b[None]
    px, py = points[:, None, 0], points[:, None, 1]
    straddles = (a[..., 1] > py) != (b[..., 1] > py)
    dy = xp.where(b[..., 1] == a[..., 1], 1.0, b[..., 1] - a[..., 1])
    return straddles & (px < a[..., 0] + (py - a[..., 1]) * (b[..., 0] - a[..., 0]) / dy)


def inside_polygon(points, polygon, xp=np):
    """Whether each point (n, 2) lies inside the closed polygon (v, 2) (even-odd rule);
    NumPy, or `jax.numpy` as `xp`."""
    crosses = _ray_crossings(points, polygon, xp.roll(polygon, -1, axis=0), xp)
    return xp.count_nonzero(crosses, axis=1) % 2 == 1


def _meet(line_a, line_b, tolerance, same: bool = False):
    """Where two polylines meet: (index in a, index in b) of the first pair of chords
    closer than their sags plus `tolerance`, or None (`same`: one polyline, whose
    neighbouring chords are skipped). Only chords whose boxes, widened by that margin,
    overlap are measured."""
    (va, sa), (vb, sb) = line_a, line_b
    ea, eb = np.roll(va, -1, 0), np.roll(vb, -1, 0)
    margin = sa[:, None] + sb[None] + tolerance
    low_a, high_a = np.minimum(va, ea), np.maximum(va, ea)
    low_b, high_b = np.minimum(vb, eb), np.maximum(vb, eb)
    near = np.all(
        (low_a[:, None] <= high_b[None] + margin[..., None])
        & (low_b[None] <= high_a[:, None] + margin[..., None]),
        axis=-1,
    )
    if same:
        n = len(va)
        gap = np.abs(np.arange(n)[:, None] - np.arange(n)[None])
        near &= np.minimum(gap, n - gap) > 1
    i, j = np.nonzero(near)
    close = _segment_distances(va[i], ea[i], vb[j], eb[j]) <= margin[i, j]
    if not close.any():
        return None
    first = np.argmax(close)
    return i[first], j[first]


def _zero_length_edges(curve, xp=np):
    """Whether each segment of a piecewise curve has all its control points equal ((n,)
    booleans), or None for other curves."""
    if getattr(curve, "points", None) is None:
        return None
    control = curve.control_points if xp is jnp else np.asarray(curve.control_points, float)
    return xp.ptp(control, axis=1).max(-1) == 0  # control: (n, d + 1, 2)


def _zero_length_edge(curve) -> int | None:
    zero = _zero_length_edges(curve)
    return int(np.argmax(zero)) if zero is not None and np.any(zero) else None


_REFUSALS = {
    "zero": "{a} has an edge of zero length{near}: remove the repeated vertex.",
    "self": "{a} crosses or touches itself{near}: a curve must be a simple closed curve.",
    "meet": "{a} and {b} cross or touch{near}: objects must be apart from each other and "
    "from the room's walls.",
    "outside": "{a} lies outside the room{near}: every object must be inside it.",
    "nest": "{a} lies inside {b}: objects must not nest (model a hole as part of one "
    "object's outline).",
}


def _refusal(kind: str, curves, room: bool, a: int, b: int = 0, near: str = "") -> str:
    """The message of a fault of `kind` (`_REFUSALS`) between curves a and b."""

    def name(i):
        return "the room" if room and i == len(curves) - 1 else f"curve {i}"

    return "ocp_jax: " + _REFUSALS[kind].format(a=name(a), b=name(b), near=near)


def _at(point) -> str:
    return str(np.round(np.asarray(point), 6).tolist())


def check_scene(curves, room: bool) -> None:
    """Raise a ValueError that names the curves and the place where `curves` (the last
    one the room where `room`) do not form a valid scene (see the module's docstring)."""

    def refuse(kind, a, b=0, near=""):
        raise ValueError(_refusal(kind, curves, room, a, b, near))

    for i, curve in enumerate(curves):
        edge = _zero_length_edge(curve)
        if edge is not None:
            refuse("zero", i, near=f" (segment {edge}, at {_at(curve.control_points[edge, 0])})")
    lines = [_polyline(c) for c in curves]
    size = max(np.ptp(np.concatenate([v for v, _ in lines]), axis=0).max(), 1e-300)
    tolerance = 1e-9 * size
    boxes = [(v.min(0) - s.max(), v.max(0) + s.max()) for v, s in lines]
    for i, line in enumerate(lines):
        hit = _meet(line, line, tolerance, same=True)
        if hit is not None:
            refuse("self", i, near=f" near {_at(line[0][hit[0]])}")
    objects = len(curves) - 1 if room else len(curves)
    for i in range(objects):
        for j in range(i + 1, len(curves)):
            overlap = np.all(boxes[i][0] <= boxes[j][1] + tolerance) and np.all(
                boxes[j][0] <= boxes[i][1] + tolerance
            )
            hit = _meet(lines[i], lines[j], tolerance) if overlap else None
            if hit is not None:
                refuse("meet", i, j, near=f" near {_at(lines[i][0][hit[0]])}")
            vi, vj = lines[i][0], lines[j][0]
            if room and j == len(curves) - 1:
                if not inside_polygon(vi[:1], vj)[0]:
                    refuse("outside", i, near=f" (near {_at(vi[0])})")
            elif overlap:
                # (curves that do not meet nest where one vertex of one is inside the other)
                for inner, outer in ((i, j), (j, i)):
                    if inside_polygon(lines[inner][0][:1], lines[outer][0])[0]:
                        refuse("nest", inner, outer)


class _Chords(NamedTuple):
    """Every curve's polyline (`_polyline`) as one list of N chords, traced."""

    starts: Array  # (N, 2)
    ends: Array  # (N, 2)
    sags: Array  # (N,)
    curve: Array  # (N,) the chord's curve
    local: Array  # (N,) its index on that curve
    count: Array  # (N,) the number of chords of that curve

    @classmethod
    def of(cls, lines) -> "_Chords":
        counts = np.array([len(s) for _, s in lines])
        return cls(
            jnp.concatenate([v for v, _ in lines]),
            jnp.concatenate([jnp.roll(v, -1, axis=0) for v, _ in lines]),
            jnp.concatenate([s for _, s in lines]),
            jnp.asarray(np.repeat(np.arange(len(lines)), counts)),
            jnp.asarray(np.concatenate([np.arange(n) for n in counts])),
            jnp.asarray(np.repeat(counts, counts)),
        )


def _meetings(chords: _Chords, m: int, tolerance) -> Bool[Array, "m m"]:
    """Whether some chord of curve a comes closer to some chord of curve b than their
    sags plus `tolerance` (on the diagonal: two chords of one curve that are not
    neighbours). Every pair of chords is measured, one chord against all at a time."""
    c = chords

    def against_all(chord):  # (m,) whether this chord meets each curve
        a0, a1, sag, i, k, n = chord
        gap = jnp.abs(c.local - k)
        neighbour = (c.curve == i) & (jnp.minimum(gap, n - gap) <= 1)
        distance = _segment_distances(a0[None], a1[None], c.starts, c.ends, jnp)
        near = distance <= sag + c.sags + tolerance
        return jnp.zeros(m, bool).at[c.curve].max(near & ~neighbour)

    per_chord = jax.lax.map(against_all, tuple(chords), batch_size=64)  # (N, m)
    return jnp.zeros((m, m), bool).at[c.curve].max(per_chord)


def _insides(points, chords: _Chords, m: int) -> Bool[Array, "n m"]:
    """Whether each point (n, 2) lies inside each curve's polyline (even-odd rule)."""
    crosses = _ray_crossings(points, chords.starts, chords.ends, jnp).astype(jnp.int32)
    counts = jnp.zeros((len(points), m), jnp.int32).at[:, chords.curve].add(crosses)
    return counts % 2 == 1


def _pairs(pairs) -> tuple[np.ndarray, np.ndarray]:
    """Static index arrays (a, b) of pairs of curves (empty where there are none)."""
    a, b = np.reshape(np.asarray(list(pairs), int), (-1, 2)).T
    return a, b


def checked_under_trace(curves: tuple, room: bool) -> tuple:
    """`curves` (the last one the room where `room`) with the checks of `check_scene`
    attached by `equinox.branched_error_if` to their first array: for a scene built from
    traced arrays, refused when the program runs. The error names the first fault in the
    order: a zero-length edge, a curve crossing itself, two curves that meet, an object
    outside the room, nested objects."""
    m = len(curves)
    objects = m - 1 if room else m
    faults, messages = [], []

    def fault(flags, kind, a, b=None):  # flags (n,), a message per curve a[k] (and b[k])
        faults.append(jnp.reshape(flags, -1))
        b = np.zeros(len(a), int) if b is None else b
        messages.extend(_refusal(kind, curves, room, int(i), int(j)) for i, j in zip(a, b))

    for i, curve in enumerate(curves):
        zero = _zero_length_edges(curve, jnp)
        if zero is not None:
            fault(jnp.any(zero), "zero", [i])
    lines = [_polyline(c, jnp) for c in curves]
    chords = _Chords.of(lines)
    size = jnp.maximum(jnp.ptp(chords.starts, axis=0).max(), 1e-300)
    meets = _meetings(chords, m, 1e-9 * size)
    fault(jnp.diagonal(meets), "self", range(m))
    a, b = _pairs(itertools.combinations(range(m), 2))
    a, b = a[a < objects], b[a < objects]
    fault((meets | meets.T)[a, b], "meet", a, b)
    inside = _insides(jnp.stack([v[0] for v, _ in lines[:objects]]), chords, m)
    if room:
        fault(~inside[:, -1], "outside", range(objects))
    a, b = _pairs(itertools.permutations(range(objects), 2))
    fault(inside[a, b], "nest", a, b)
    found = jnp.concatenate(faults)
    leaves, treedef = jax.tree.flatten(curves)
    leaves[0] = eqx.branched_error_if(leaves[0], jnp.any(found), jnp.argmax(found), messages)
    return jax.tree.unflatten(treedef, leaves)
