"""Exact outside reference for polygon scenes: VisiLibity1 (PyPI `visilibity`, built
with SWIG) computes the visibility polygon of a camera; the visible length of each
obstacle is the part of its edges that lies on that polygon's boundary.

visible_lengths(outer, holes, camera, epsilon=1e-9) -> list[float], one per hole.

Polygons are (n, 2) arrays in any orientation; `outer=None` puts a large square around
the scene. VisiLibity needs epsilon > 0 (a distance tolerance in scene units) and
misses self-intersections through a polygon's closing edge, so simplicity is checked
here. A camera exactly on the line of an edge (measure zero) counts that edge as seen.
"""

from __future__ import annotations

import numpy as np
import visilibity as vis


def outline(curve, n: int = 64) -> np.ndarray:
    """The polygon VisiLibity sees for an ocp_jax curve: a polygon's own vertices, any
    other curve as the n-gon through x(j / n)."""
    points = getattr(curve, "points", None)
    if points is not None and points.shape[1] == 1:
        return np.asarray(points[:, 0], float)
    return np.asarray(curve(np.arange(n) / n), float)


def _clean(poly):
    p = np.asarray(poly, dtype=float).reshape(-1, 2)
    if len(p) > 1 and np.allclose(p[0], p[-1], rtol=0, atol=0):
        p = p[:-1]
    return p


def _signed_area(p):
    x, y = p[:, 0], p[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def _is_simple(p):
    """Own O(n^2) check (VisiLibity's Polygon::is_simple never tests the
    closing edge n-1 -> 0 against non-adjacent edges, so it misses some
    self-intersections)."""
    n = len(p)
    if n < 3:
        return False
    a, b = p, np.roll(p, -1, axis=0)
    for i in range(n):
        for j in range(i + 1, n):
            if j == i + 1 or (i == 0 and j == n - 1):
                continue
            d = b[i] - a[i]
            e = b[j] - a[j]
            d1 = _cross2(e, a[i] - a[j])
            d2 = _cross2(e, b[i] - a[j])
            d3 = _cross2(d, a[j] - a[i])
            d4 = _cross2(d, b[j] - a[i])
            if d1 * d2 > 0 or d3 * d4 > 0:
                continue
            if d1 == 0 and d2 == 0:  # collinear: overlap of projections?
                s0, s1 = sorted((float(np.dot(a[j] - a[i], d)), float(np.dot(b[j] - a[i], d))))
                if s1 < 0 or s0 > float(np.dot(d, d)):
                    continue
                return False
    return True


def _cross2(u, v):
    return float(u[0] * v[1] - u[1] * v[0])


def _default_outer(holes, camera):
    pts = np.vstack([camera[None, :]] + list(holes)) if holes else camera[None, :]
    lo, hi = pts.min(0), pts.max(0)
    c = 0.5 * (lo + hi)
    half = 10.0 * max(float(np.max(hi - lo)), 1.0)
    return np.array(
        [
            [c[0] - half, c[1] - half],
            [c[0] + half, c[1] - half],
            [c[0] + half, c[1] + half],
            [c[0] - half, c[1] + half],
        ]
    )


def _prepare(outer, holes, camera):
    camera = np.asarray(camera, dtype=float).reshape(2)
    holes = [_clean(h) for h in holes]
    outer = _default_outer(holes, camera) if outer is None else _clean(outer)
    return outer, holes, camera


def _union_length(intervals):
    if not intervals:
        return 0.0
    intervals.sort()
    total, (s, e) = 0.0, intervals[0]
    for a, b in intervals[1:]:
        if a > e:
            total += e - s
            s, e = a, b
        else:
            e = max(e, b)
    return total + (e - s)


def visible_lengths(outer, holes, camera, epsilon=1e-9, return_vp=False):
    """Visible boundary length of each hole, via visilibity.Visibility_Polygon."""
    intervals, V = _visible_edge_intervals(outer, holes, camera, epsilon)
    out = [sum(_union_length(ivs) for ivs in edges) for edges in intervals]
    return (out, V) if return_vp else out


def union_visible_length(outer, holes, cameras, epsilon=1e-9):
    """Total length of the holes' boundaries that at least one of `cameras` sees: the
    union, edge by edge, of each camera's visible parts."""
    per_camera = [_visible_edge_intervals(outer, holes, c, epsilon)[0] for c in cameras]
    return sum(
        _union_length([iv for camera in per_camera for iv in camera[h][e]])
        for h in range(len(holes))
        for e in range(len(per_camera[0][h]))
    )


def environment(outer, holes, epsilon=1e-9):
    """VisiLibity's environment of a room `outer` (None: a large square around the
    holes) and the obstacles `holes`, checked; and the two, oriented as VisiLibity
    needs (outer counter-clockwise, holes clockwise)."""
    outer, holes, _ = _prepare(outer, holes, np.zeros(2))
    if _signed_area(outer) < 0:
        outer = outer[::-1]
    holes = [h[::-1] if _signed_area(h) > 0 else h for h in holes]

    def P(arr):
        return vis.Polygon([vis.Point(float(x), float(y)) for x, y in arr])

    for poly in [outer] + holes:
        if not _is_simple(poly):
            raise ValueError("polygon is not simple")
    env = vis.Environment([P(outer)] + [P(h) for h in holes])
    if not env.is_valid(epsilon):
        raise ValueError(
            "environment not epsilon-valid (self-intersecting, "
            "touching/overlapping holes, or hole outside room)"
        )
    return env, outer, holes


def visibility_polygon(env, camera, epsilon=1e-9) -> np.ndarray:
    """The vertices of the camera's visibility polygon in `env` (`environment`)."""
    obs = vis.Point(float(camera[0]), float(camera[1]))
    if not obs._in(env, epsilon):
        raise ValueError("camera is not in free space")
    # Required order: boundary snap, then vertex snap.
    obs.snap_to_boundary_of(env, epsilon)
    obs.snap_to_vertices_of(env, epsilon)
    vp = vis.Visibility_Polygon(obs, env, epsilon)
    return np.array([[vp[i].x(), vp[i].y()] for i in range(vp.n())])


def _visible_edge_intervals(outer, holes, camera, epsilon):
    """For each hole and each of its edges, the intervals (distances from the edge's
    start) that lie on the camera's visibility polygon; and that polygon."""
    camera = np.asarray(camera, dtype=float).reshape(2)
    if outer is None:
        outer = _default_outer([_clean(h) for h in holes], camera)
    env, outer, holes = environment(outer, holes, epsilon)
    V = visibility_polygon(env, camera, epsilon)
    if len(V) < 3:
        return [[[] for _ in h] for h in holes], V
    A, B = V, np.roll(V, -1, axis=0)  # visibility polygon edges A[k]->B[k]

    scale = float(np.max(np.ptp(np.vstack([outer] + holes + [camera[None]]), 0)))
    tol = max(epsilon, 1e-12 * scale)  # distance tolerance "point on line"
    out = []
    for h in holes:
        edges = []
        # (holes were reoriented clockwise: an edge's intervals are measured from its
        # start in that orientation, the same for every camera)
        for a, b in zip(h, np.roll(h, -1, axis=0)):
            d = b - a
            L = float(np.hypot(*d))
            u = d / L
            # distance of VP-edge endpoints from the (infinite) line of a->b
            da = np.abs(u[0] * (A[:, 1] - a[1]) - u[1] * (A[:, 0] - a[0]))
            db = np.abs(u[0] * (B[:, 1] - a[1]) - u[1] * (B[:, 0] - a[0]))
            on = (da <= tol) & (db <= tol)
            ivs = []
            for k in np.nonzero(on)[0]:
                ta = float(np.dot(A[k] - a, u))
                tb = float(np.dot(B[k] - a, u))
                lo, hi = max(min(ta, tb), 0.0), min(max(ta, tb), L)
                if hi > lo:
                    ivs.append((lo, hi))
            edges.append(ivs)
        out.append(edges)
    return out, V
