"""What makes a scene valid, checked where it is built from concrete arrays.

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
"""

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["check_scene", "inside_polygon"]

_REFINE = 8  # chords per grid cell of a curved piece


def _polyline(curve) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (n, 2) of a closed polyline through `curve` (not repeated at the end) and
    each chord's sag bound (n,), chord j from vertex j to j + 1."""
    points = getattr(curve, "points", None)
    if points is not None and points.shape[1] == 1:  # a polygon: exact
        vertices = np.asarray(points[:, 0], float)
        return vertices, np.zeros(len(vertices))
    n = _REFINE * curve.grid_cells()
    with jax.ensure_compile_time_eval():
        t = jnp.arange(2 * n) / (2 * n)
        x = np.asarray(_points(curve, t.astype(curve.dtype)), float)
    vertices, middles = x[0::2], x[1::2]
    ends = np.roll(vertices, -1, axis=0)
    return vertices, 1.5 * _point_segment_distance(middles, vertices, ends)


@jax.jit  # (compiled once per curve type and shape, not dispatched op by op)
def _points(curve, t):
    return curve(t)


def _point_segment_distance(p, a, b):
    ab = b - a
    length2 = np.sum(ab * ab, -1)
    s = np.clip(np.sum((p - a) * ab, -1) / np.where(length2 > 0, length2, 1.0), 0.0, 1.0)
    return np.linalg.norm(p - (a + s[..., None] * ab), axis=-1)


def _segment_distances(a0, a1, b0, b1):
    """Distances between the segments [a0, a1] and [b0, b1], pair by pair (arrays (n, 2)),
    0 where they cross."""

    def orient(p, q, r):
        return np.sign(
            (q[..., 0] - p[..., 0]) * (r[..., 1] - p[..., 1])
            - (q[..., 1] - p[..., 1]) * (r[..., 0] - p[..., 0])
        )

    crossing = (orient(a0, a1, b0) * orient(a0, a1, b1) < 0) & (
        orient(b0, b1, a0) * orient(b0, b1, a1) < 0
    )
    ends = np.minimum(
        np.minimum(_point_segment_distance(a0, b0, b1), _point_segment_distance(a1, b0, b1)),
        np.minimum(_point_segment_distance(b0, a0, a1), _point_segment_distance(b1, a0, a1)),
    )
    return np.where(crossing, 0.0, ends)


def inside_polygon(points, polygon) -> np.ndarray:
    """Whether each point lies inside the closed polygon (even-odd rule)."""
    a, b = polygon[None], np.roll(polygon, -1, axis=0)[None]
    px, py = points[:, None, 0], points[:, None, 1]
    straddles = (a[..., 1] > py) != (b[..., 1] > py)
    dy = np.where(b[..., 1] == a[..., 1], 1.0, b[..., 1] - a[..., 1])
    crosses = straddles & (px < a[..., 0] + (py - a[..., 1]) * (b[..., 0] - a[..., 0]) / dy)
    return np.count_nonzero(crosses, axis=1) % 2 == 1


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


def _zero_length_edge(curve) -> int | None:
    points = getattr(curve, "points", None)
    if points is None:
        return None
    control = np.asarray(curve.control_points, float)  # (n, d + 1, 2)
    extent = np.ptp(control, axis=1).max(-1)
    return int(np.argmax(extent == 0)) if np.any(extent == 0) else None


def check_scene(curves, room: bool) -> None:
    """Raise a ValueError that names the curves and the place where `curves` (the last
    one the room where `room`) do not form a valid scene (see the module's docstring)."""

    def name(i):
        return "the room" if room and i == len(curves) - 1 else f"curve {i}"

    for i, curve in enumerate(curves):
        edge = _zero_length_edge(curve)
        if edge is not None:
            raise ValueError(
                f"ocp_jax: {name(i)} has an edge of zero length (segment {edge}, at "
                f"{np.asarray(curve.control_points[edge, 0]).tolist()}): remove the repeated "
                "vertex."
            )
    lines = [_polyline(c) for c in curves]
    size = max(np.ptp(np.concatenate([v for v, _ in lines]), axis=0).max(), 1e-300)
    tolerance = 1e-9 * size
    boxes = [(v.min(0) - s.max(), v.max(0) + s.max()) for v, s in lines]
    for i, line in enumerate(lines):
        hit = _meet(line, line, tolerance, same=True)
        if hit is not None:
            raise ValueError(
                f"ocp_jax: {name(i)} crosses or touches itself near "
                f"{np.round(line[0][hit[0]], 6).tolist()}: a curve must be a simple closed "
                "curve."
            )
    objects = len(curves) - 1 if room else len(curves)
    for i in range(objects):
        for j in range(i + 1, len(curves)):
            overlap = np.all(boxes[i][0] <= boxes[j][1] + tolerance) and np.all(
                boxes[j][0] <= boxes[i][1] + tolerance
            )
            hit = _meet(lines[i], lines[j], tolerance) if overlap else None
            if hit is not None:
                where = np.round(lines[i][0][hit[0]], 6).tolist()
                raise ValueError(
                    f"ocp_jax: {name(i)} and {name(j)} cross or touch near {where}: objects "
                    "must be apart from each other and from the room's walls."
                )
            vi, vj = lines[i][0], lines[j][0]
            if room and j == len(curves) - 1:
                if not inside_polygon(vi[:1], vj)[0]:
                    raise ValueError(
                        f"ocp_jax: {name(i)} lies outside the room (near "
                        f"{np.round(vi[0], 6).tolist()}): every object must be inside it."
                    )
            elif overlap:
                # (curves that do not meet nest where one vertex of one is inside the other)
                for inner, outer in ((i, j), (j, i)):
                    if inside_polygon(lines[inner][0][:1], lines[outer][0])[0]:
                        raise ValueError(
                            f"ocp_jax: {name(inner)} lies inside {name(outer)}: objects must "
                            "not nest (model a hole as part of one object's outline)."
                        )
