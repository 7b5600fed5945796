"""Independent NumPy/SciPy reference for the 2D visibility objective Q.

Nothing in this module imports JAX or ``ocp_jax``; it is meant to be an
independent check for the library.

Problem
-------
Scenes are closed parametric curves ``x_i(t)``, ``t in [0, 1)`` (dicts, see
:func:`eval_curve`) and point cameras ``C_c``.  A point ``x_i(t)`` is visible
from ``C`` iff the *open* segment ``(C, x_i(t))`` meets no curve (curve ``i``
included, so back-facing points are hidden by their own object).  The
objective is

    Q = sum_i  int_0^1  max_{c : x_i(t) visible from C_c} q(x_i, x_i', C_c) |x_i'| dt

with ``q = 1`` ("visible_length") or ``q = (n.(x-C))^2 / (|n|^2 |x-C|^2)``,
``n`` perpendicular to ``x'`` ("foreshortened"), and 0 where no camera sees
the point.  Objectives of camera groups (Eq. 3.15 with l > 1) take the max over
the l-subsets of cameras that all see the point: ``("reconstruction", area,
delta)`` values pairs by the triangulation error region (``q = 1 / (1 + (A /
area)^2)``, ``A = delta^2 d1 d2 / sin(theta)``), ``("coverage", m)`` is the
length seen by at least m cameras.

Method (exact event points + high-order quadrature; no Richardson needed)
-------------------------------------------------------------------------
For one camera ``C`` the visibility of ``x_i(t)`` can only change at

1. *silhouette points* of any curve: roots of ``f(t) = x'(t) x (x(t) - C)``
   (tangency of the line of sight, cusps included), plus *corners* (parameter
   values where ``x'`` jumps: the seam of a closed Bezier curve, the knots of a
   degree-1 B-spline);
2. *shadow points*: parameters ``s`` on any curve with
   ``(P - C) x (x_i(s) - C) = 0`` and ``(P - C).(x_i(s) - C) > 0`` for a
   silhouette/corner point ``P`` (the line of sight through ``P`` hits the
   curve there).

Indeed the open segment ``(C, x_i(t))`` can only start/stop meeting a curve
when its interior sweeps over a tangency point or a corner of that curve, or
when its end point ``x_i(t)`` turns from front- to back-facing (a silhouette of
curve ``i`` itself).  All these points are computed on the *true* curves:
each scalar function is sampled on a fine uniform grid (default 4096 points per
curve, aligned with the B-spline knots; one-sided evaluation on each smooth
piece), every sign change is bracketed and bisected to machine precision, and
every discrete local minimum of ``|F|`` that is not far from zero (relative to
the neighbouring differences) is polished by a golden-section search, so that a
pair of close roots (or a double root) inside one grid cell is not missed.
Extra event points are harmless; only missing ones would be wrong.

Between consecutive event points visibility is constant, so each sub-interval
is classified by one exact ray cast at its midpoint ``X``: the roots ``s`` of
``(X - C) x (x_j(s) - C)`` are found on every curve ``j`` (same robust root
finder) and the segment is blocked iff one of them has
``lambda = (x_j(s)-C).(X-C)/|X-C|^2`` in ``(0, 1)`` (the root ``s = t`` of the
point itself excluded).

Several cameras: the event points of all cameras are merged; on each
resulting sub-interval the set of cameras that see it is constant.  For
"foreshortened" the sub-intervals seen by >= 2 cameras are further split at
the roots of ``q_a - q_b`` (kinks of the max), found by the same root finder,
so that the arg-max camera is constant on every final piece.  Each final
piece lies inside one smooth piece of the curve, where the integrand is
analytic, and is integrated by adaptive Gauss-Legendre quadrature (16 nodes,
bisection until the 16-node and 2x16-node results agree to ``quad_tol``
relative).

Accuracy / convergence order
----------------------------
The event points are located to ~1e-16 in ``t`` (bisection to machine
precision on functions with simple roots), and the Gauss-Legendre quadrature
converges exponentially on each analytic piece, so the method has no algebraic
convergence order in the grid size: the result is exact to ~1e-14 relative
as long as no event point is missed.  The only discretisation parameter,
``n_grid``, controls *root detection* (not accuracy): a root is only missed
if the sampled function has two extrema inside one grid cell.
:func:`reference_visibility_with_error` evaluates with two unrelated grids
(``n_grid`` and ``~1.618 n_grid``) and reports ``|Q_1 - Q_2|`` plus the
quadrature error estimate as the error estimate (a missed event would show
up as a large difference).  Typical cost: 0.02-0.7 s per evaluation for
1-4 curves and 1-3 cameras (2 CPU cores); measured agreement with closed
forms (circles, shadowing circles, two cameras) is ~1e-15 relative.

Limitations: the curves must be simple, pairwise disjoint and at least C^0;
cameras must lie outside all objects (not on a curve).  Breakpoints closer
than 1e-12 in t are merged, and a minimum of |F| within 1e-13 (relative to
the function's range) of zero is treated as one double root, so genuinely
distinct events closer than ~1e-7 in t in *near-degenerate* configurations
(e.g. a line of sight almost exactly bitangent to two curves) may be
misclassified over that tiny width.  Degenerate configurations (a straight
piece collinear with a camera, exactly coincident tangents) are handled up to
measure-zero ambiguities.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

__all__ = [
    "eval_curve",
    "reference_visibility",
    "reference_visibility_with_error",
    "reference_visible_intervals",
]

_TWO_PI = 2.0 * np.pi


# ---------------------------------------------------------------------------
# curve evaluation
# ---------------------------------------------------------------------------
def _n_pieces(curve):
    """Number of smooth pieces (uniform in t) of a curve."""
    if curve["type"] == "bspline":
        return int(np.asarray(curve["points"]).shape[0])
    if curve["type"] == "piecewise":
        return int(np.asarray(curve["segments"]).shape[0])
    return 1


def _bernstein(s, deg, pts):
    """sum_i C(deg, i) s^i (1 - s)^(deg - i) pts[..., i, :] for control points of
    shape s.shape + (deg + 1, 2)."""
    if deg < 0:
        return np.zeros(s.shape + (2,))
    i = np.arange(deg + 1)
    coef = np.array([math.comb(deg, k) for k in i], dtype=float)
    B = coef * s[..., None] ** i * (1.0 - s[..., None]) ** (deg - i)
    return np.einsum("...i,...ij->...j", B, pts)


def _de_boor(Q, w, p):
    """De Boor on one span of a uniform spline with integer knots.

    Q: (..., p+1, 2) control points P_{j-p..j}; w: (...,) local parameter
    u - j (may be 1 at the right end: the span's polynomial is evaluated)."""
    d = np.array(Q, dtype=float, copy=True)
    w = w[..., None]
    for r in range(1, p + 1):
        for k in range(p, r - 1, -1):
            alpha = (w + p - k) / (p + 1 - r)
            d[..., k, :] = (1.0 - alpha) * d[..., k - 1, :] + alpha * d[..., k, :]
    return d[..., p, :]


def _eval_local(curve, t, piece):
    """Evaluate x, x', x'' at parameters t using the formulas of smooth piece
    ``piece`` (only meaningful for B-splines; t is not reduced mod 1)."""
    typ = curve["type"]
    t = np.asarray(t, dtype=float)
    if typ == "circle":
        c = np.asarray(curve["center"], dtype=float)
        r = float(curve["radius"])
        th = _TWO_PI * t
        co, si = np.cos(th), np.sin(th)
        x = c + r * np.stack([co, si], -1)
        dx = _TWO_PI * r * np.stack([-si, co], -1)
        ddx = -(_TWO_PI**2) * r * np.stack([co, si], -1)
        return x, dx, ddx
    if typ == "ellipse":
        c = np.asarray(curve["center"], dtype=float)
        a, b = (float(v) for v in curve["axes"])
        phi = float(curve.get("angle", 0.0))
        R = np.array([[math.cos(phi), -math.sin(phi)], [math.sin(phi), math.cos(phi)]])
        th = _TWO_PI * t
        co, si = np.cos(th), np.sin(th)
        v = np.stack([a * co, b * si], -1)
        dv = _TWO_PI * np.stack([-a * si, b * co], -1)
        x = c + v @ R.T
        dx = dv @ R.T
        ddx = -(_TWO_PI**2) * (v @ R.T)
        return x, dx, ddx
    if typ == "bezier":
        P = np.asarray(curve["points"], dtype=float)
        n = P.shape[0] - 1

        def bern(deg, pts):
            if deg < 0:
                return np.zeros(t.shape + (2,))
            i = np.arange(deg + 1)
            coef = np.array([math.comb(deg, k) for k in i], dtype=float)
            tt = t[..., None]
            B = coef * tt**i * (1.0 - tt) ** (deg - i)
            return B @ pts

        x = bern(n, P)
        D1 = np.diff(P, axis=0)
        dx = n * bern(n - 1, D1)
        if n >= 2:
            ddx = n * (n - 1) * bern(n - 2, np.diff(P, n=2, axis=0))
        else:
            ddx = np.zeros_like(x)
        return x, dx, ddx
    if typ == "bspline":
        P = np.asarray(curve["points"], dtype=float)
        p = int(curve["degree"])
        n = P.shape[0]
        if p < 1:
            raise ValueError("B-spline degree must be >= 1")
        piece = np.broadcast_to(np.asarray(piece, dtype=np.int64), t.shape)
        w = n * t - piece
        D = P - np.roll(P, 1, axis=0)  # D_i = P_i - P_{i-1}
        E = D - np.roll(D, 1, axis=0)  # E_i = D_i - D_{i-1}
        idx = (piece[..., None] - p + np.arange(p + 1)) % n
        x = _de_boor(P[idx], w, p)
        idx = (piece[..., None] - (p - 1) + np.arange(p)) % n
        dx = n * _de_boor(D[idx], w, p - 1)
        if p >= 2:
            idx = (piece[..., None] - (p - 2) + np.arange(p - 1)) % n
            ddx = n * n * _de_boor(E[idx], w, p - 2)
        else:
            ddx = np.zeros_like(x)
        return x, dx, ddx
    if typ == "piecewise":
        # Closed path of n Bezier segments of degree d, segment j on [j/n, (j+1)/n).
        P = np.asarray(curve["segments"], dtype=float)
        n, d = P.shape[0], P.shape[1] - 1
        piece = np.broadcast_to(np.asarray(piece, dtype=np.int64), t.shape)
        s = n * t - piece
        Q = P[piece % n]
        x = _bernstein(s, d, Q)
        dx = n * d * _bernstein(s, d - 1, np.diff(Q, axis=-2))
        if d >= 2:
            ddx = n * n * d * (d - 1) * _bernstein(s, d - 2, np.diff(Q, n=2, axis=-2))
        else:
            ddx = np.zeros_like(x)
        return x, dx, ddx
    raise ValueError(f"unknown curve type {typ!r}")


def _piece_of(curve, t):
    """Smooth piece index containing t (t already in [0, 1))."""
    m = _n_pieces(curve)
    if m == 1:
        return np.zeros(np.shape(t), dtype=np.int64)
    return np.clip(np.floor(m * t).astype(np.int64), 0, m - 1)


def eval_curve(curve: dict, t):
    """Return ``(x, dx, ddx)``, each of shape ``t.shape + (2,)`` (derivatives
    with respect to t).  t is taken modulo 1 (the curves are closed)."""
    t = np.mod(np.asarray(t, dtype=float), 1.0)
    return _eval_local(curve, t, _piece_of(curve, t))


def _eval_x(curve, t):
    return eval_curve(curve, t)[0]


def _cross(a, b):
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def _dot(a, b):
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1]


# ---------------------------------------------------------------------------
# robust vectorised root finding
# ---------------------------------------------------------------------------
_GOLD = (math.sqrt(5.0) - 1.0) / 2.0


def _bisect(F, rows, lo, hi, flo):
    """Bisect brackets [lo, hi] (F(lo) has sign of flo, F(hi) the other)."""
    lo = lo.astype(float).copy()
    hi = hi.astype(float).copy()
    slo = np.sign(flo)
    if lo.size == 0:
        return lo
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        done = (mid <= lo) | (mid >= hi)
        if np.all(done):
            break
        fm = F(rows, mid)
        same = np.sign(fm) == slo
        lo = np.where(same & ~done, mid, lo)
        hi = np.where(~same & ~done, mid, hi)
    return 0.5 * (lo + hi)


def _golden_min(G, rows, a, b, n_iter=60):
    """Vectorised golden-section search for a minimum of G(rows, s) on [a, b]."""
    a = a.astype(float).copy()
    b = b.astype(float).copy()
    c = b - _GOLD * (b - a)
    d = a + _GOLD * (b - a)
    fc = G(rows, c)
    fd = G(rows, d)
    for _ in range(n_iter):
        left = fc < fd
        # left: minimum in [a, d] -> b = d, d = c, new c
        b = np.where(left, d, b)
        a = np.where(left, a, c)
        newpt = np.where(left, b - _GOLD * (b - a), a + _GOLD * (b - a))
        fnew = G(rows, newpt)
        d_new = np.where(left, c, newpt)
        c_new = np.where(left, newpt, d)
        fd_new = np.where(left, fc, fnew)
        fc_new = np.where(left, fnew, fd)
        c, d, fc, fd = c_new, d_new, fc_new, fd_new
        if np.all(b - a <= 1e-15):
            break
    take_c = fc <= fd
    return np.where(take_c, c, d), np.where(take_c, fc, fd)


def _roots_rows(F, S, V, dF=None, touch_rel=1e-13):
    """All roots of B independent scalar functions sampled on grids.

    F(rows, s) evaluates function ``rows`` at ``s`` (vectorised); S, V: (B, m+1)
    grids (increasing along axis 1) and sampled values.  Returns (rows, roots).
    Sign changes are bisected to machine precision; every discrete local
    minimum of |F| that is small compared with the neighbouring differences is
    polished by golden-section search (two close roots in one cell, or a double
    root, are then found as well)."""
    B, m1 = V.shape
    out_r, out_s = [], []
    # exact zeros on the grid
    r, k = np.nonzero(V == 0.0)
    out_r.append(r)
    out_s.append(S[r, k])
    # sign changes
    r, k = np.nonzero(V[:, :-1] * V[:, 1:] < 0.0)
    if r.size:
        out_r.append(r)
        out_s.append(_bisect(F, r, S[r, k], S[r, k + 1], V[r, k]))
    # candidate hidden pairs of roots / double roots
    A = np.abs(V)
    sg = np.sign(V)
    scale = np.max(A, axis=1)
    cand_r, cand_a, cand_b, cand_sg = [], [], [], []
    if m1 >= 3:
        Am, A0, Ap = A[:, :-2], A[:, 1:-1], A[:, 2:]
        Vm, V0, Vp = V[:, :-2], V[:, 1:-1], V[:, 2:]
        same = (sg[:, :-2] == sg[:, 1:-1]) & (sg[:, 1:-1] == sg[:, 2:]) & (sg[:, 1:-1] != 0)
        locmin = (A0 <= Am) & (A0 <= Ap)
        near = A0 <= 2.0 * np.maximum(np.abs(Vm - V0), np.abs(Vp - V0))
        r, k = np.nonzero(same & locmin & near)
        k = k + 1
        cand_r.append(r)
        cand_a.append(S[r, k - 1])
        cand_b.append(S[r, k + 1])
        cand_sg.append(sg[r, k])
    for k0, k1 in ((0, 1), (m1 - 1, m1 - 2)):
        ok = (sg[:, k0] == sg[:, k1]) & (sg[:, k0] != 0) & (A[:, k0] <= A[:, k1])
        ok &= A[:, k0] <= 2.0 * np.abs(V[:, k1] - V[:, k0])
        r = np.nonzero(ok)[0]
        cand_r.append(r)
        cand_a.append(S[r, min(k0, k1)])
        cand_b.append(S[r, max(k0, k1)])
        cand_sg.append(sg[r, k0])
    cr = np.concatenate(cand_r)
    if cr.size:
        ca = np.concatenate(cand_a)
        cb = np.concatenate(cand_b)
        csg = np.concatenate(cand_sg)

        def G(rows_idx, s, _csg=csg, _cr=cr):
            return _csg[rows_idx] * F(_cr[rows_idx], s)

        loc = np.arange(cr.size)
        xm, fm = _golden_min(G, loc, ca, cb)
        if dF is not None:
            # polish the extremum as a (simple) root of F' where it is bracketed:
            # this locates double roots to machine precision (golden section
            # only gives ~sqrt(eps))
            def Gd(rows_idx, s, _csg=csg, _cr=cr):
                return _csg[rows_idx] * dF(_cr[rows_idx], s)

            da, db = Gd(loc, ca), Gd(loc, cb)
            br = np.nonzero((da < 0.0) & (db > 0.0))[0]
            if br.size:
                xb = _bisect(Gd, br, ca[br], cb[br], da[br])
                fb = G(br, xb)
                better = fb <= fm[br]
                xm[br[better]] = xb[better]
                fm[br[better]] = fb[better]
        touch = np.abs(fm) <= touch_rel * scale[cr]
        neg = (fm < 0.0) & ~touch
        if np.any(neg):
            i = np.nonzero(neg)[0]
            rr = cr[i]
            fa = csg[i]  # sign at a and b
            out_r.append(rr)
            out_s.append(_bisect(F, rr, ca[i], xm[i], fa))
            out_r.append(rr)
            out_s.append(_bisect(F, rr, xm[i], cb[i], -fa))
        if np.any(touch):
            i = np.nonzero(touch)[0]
            out_r.append(cr[i])
            out_s.append(xm[i])
    return np.concatenate(out_r).astype(np.int64), np.concatenate(out_s).astype(float)


# ---------------------------------------------------------------------------
# geometry helpers
# ---------------------------------------------------------------------------
class _Geo:
    """Per-curve data: piece boundaries, a dense grid of points and corners."""

    def __init__(self, curves, n_grid):
        self.curves = curves
        self.n = len(curves)
        self.npieces = [_n_pieces(c) for c in curves]
        self.m_piece = [max(16, int(math.ceil(n_grid / k))) for k in self.npieces]
        self.bounds = [np.arange(k + 1) / k for k in self.npieces]
        # x-only grid over [0, 1] (x is continuous and periodic)
        self.tg, self.xg = [], []
        for c, k, m in zip(curves, self.npieces, self.m_piece):
            tg = np.linspace(0.0, 1.0, k * m + 1)
            self.tg.append(tg)
            self.xg.append(_eval_x(c, tg))
        # corners: piece boundaries where x' jumps (direction or magnitude 0)
        self.corners = []
        for c, k in zip(curves, self.npieces):
            tb = np.arange(k) / k
            right = _eval_local(c, tb, np.arange(k))[1]
            left = _eval_local(c, np.arange(1, k + 1) / k, np.arange(k))[1]
            left = np.roll(left, 1, axis=0)  # left derivative at boundary j
            nl = np.linalg.norm(left, axis=-1)
            nr = np.linalg.norm(right, axis=-1)
            sc = np.maximum(np.maximum(nl, nr), 1e-300)
            jump = np.linalg.norm(
                left / np.maximum(nl, 1e-300)[:, None] - right / np.maximum(nr, 1e-300)[:, None],
                axis=-1,
            )
            is_corner = (jump > 1e-12) | (np.minimum(nl, nr) <= 1e-12 * sc)
            if c["type"] in ("circle", "ellipse"):
                is_corner[:] = False
            self.corners.append(tb[is_corner])

    def piece_grid(self, i, lo, hi, piece, m):
        """(B, m+1) grids on [lo, hi] with their piece indices."""
        u = np.linspace(0.0, 1.0, m + 1)
        S = lo[:, None] + (hi - lo)[:, None] * u[None, :]
        return S, np.broadcast_to(piece[:, None], S.shape)


def _silhouettes(geo, C):
    """Silhouette/corner parameters per curve for camera C."""
    out = []
    for i, c in enumerate(geo.curves):
        k = geo.npieces[i]
        pieces = np.arange(k)
        S, Pc = geo.piece_grid(i, geo.bounds[i][:-1], geo.bounds[i][1:], pieces, geo.m_piece[i])

        def F(rows, s, _c=c):
            x, dx, _ = _eval_local(_c, s, rows)
            return _cross(dx, x - C)

        def dF(rows, s, _c=c):
            x, _, ddx = _eval_local(_c, s, rows)
            return _cross(ddx, x - C)

        V = F(Pc, S)
        _, roots = _roots_rows(F, S, V, dF)
        ts = np.concatenate([np.mod(roots, 1.0), geo.corners[i]])
        out.append(np.unique(ts))
    return out


def _merge(pts, tol):
    """Sorted unique breakpoints in [0, 1] (0 and 1 included); points closer
    than ``tol`` to the previously kept one are dropped (0 and 1 are kept)."""
    b = np.unique(np.clip(pts, 0.0, 1.0))
    keep = [0.0]
    for v in b[1:-1]:
        if v - keep[-1] > tol and 1.0 - v > tol:
            keep.append(float(v))
    keep.append(1.0)
    return np.array(keep)


def _in_view(X, C, pose):
    """Inside the view wedge and range of a pose dict (heading, half_fov, range)."""
    D = X - C
    dist = np.sqrt(_dot(D, D))
    ok = np.ones(X.shape[0], dtype=bool)
    if pose.get("half_fov") is not None:
        u = np.array([np.cos(pose["heading"]), np.sin(pose["heading"])])
        ok &= D @ u >= dist * np.cos(pose["half_fov"])
    if pose.get("range") is not None:
        ok &= dist <= pose["range"]
    return ok


def _pose_breakpoints(geo, i, C, pose):
    """Where curve i crosses the edges of the view wedge (in front of C) and the range
    circle: the only other places where a pose's view of it can change."""
    c = geo.curves[i]
    S = geo.tg[i][None, :]
    XC = geo.xg[i][None, :, :] - C
    out = []
    if pose.get("half_fov") is not None:
        for a in (pose["heading"] + pose["half_fov"], pose["heading"] - pose["half_fov"]):
            e = np.array([np.cos(a), np.sin(a)])

            def F(rows, s, _e=e):
                return _cross(_e, _eval_x(c, s) - C)

            _, roots = _roots_rows(F, S, _cross(e, XC))
            if roots.size:
                out.append(roots[_dot(_eval_x(c, roots) - C, e) > 0])
    if pose.get("range") is not None:
        R2 = pose["range"] ** 2

        def G(rows, s):
            d = _eval_x(c, s) - C
            return _dot(d, d) - R2

        _, roots = _roots_rows(G, S, _dot(XC, XC) - R2)
        out.append(roots)
    return [np.mod(r, 1.0) for r in out]


def _camera_partition(geo, C, merge_tol=1e-12, pose=None):
    """For one camera: per curve, the sorted breakpoints b (b[0]=0, b[-1]=1)
    and a boolean array vis (len(b)-1) of sub-interval visibility. `pose`: optional
    dict with heading, half_fov (or None) and range (or None)."""
    C = np.asarray(C, dtype=float)
    pose = pose or {}
    sil = _silhouettes(geo, C)
    Ppts = [
        (_eval_x(geo.curves[i], sil[i]) if sil[i].size else np.zeros((0, 2))) for i in range(geo.n)
    ]
    P = np.concatenate(Ppts, axis=0)
    P_curve = np.concatenate([np.full(sil[i].size, i) for i in range(geo.n)])
    P_t = np.concatenate(sil)
    PC = P - C
    bps = []
    for i, c in enumerate(geo.curves):
        pts = [np.array([0.0, 1.0]), geo.bounds[i], sil[i]]
        if P.shape[0]:
            XC = geo.xg[i] - C
            S = np.broadcast_to(geo.tg[i][None, :], (P.shape[0], geo.tg[i].size))
            # A corner's ray on its own curve touches it at the corner T (a grid node,
            # where F is rounding noise of either sign) and may cross it right beside:
            # F / |s - T| there, whose limits at T (taken from the piece after T) keep
            # the sign of F on both sides of a silhouette corner.
            # (Smooth curves have no corner rays: F is the plain cross product there.)
            at_corner = (P_curve == i) & np.isin(P_t, geo.corners[i])
            corner_rays = bool(np.any(at_corner))

            def deflated(rows, s, value):
                """(value / |s - T| on corner rays, |s - T|) for values of rows' F at s."""
                u = np.abs(np.mod(s - P_t[rows] + 0.5, 1.0) - 0.5)
                deflate = at_corner[rows] & (u > 0)
                return np.where(deflate, value / np.where(deflate, u, 1.0), value), u

            def F(rows, s, _c=c):
                value = _cross(PC[rows], _eval_x(_c, s) - C)
                return deflated(rows, s, value)[0] if corner_rays else value

            # F at the grid nodes from the curve's points there (F evaluated anew on
            # every row's grid made the reference 1.3x slower)
            V = _cross(PC[:, None, :], XC[None, :, :])
            if corner_rays:
                k_after = np.minimum(
                    (np.mod(P_t, 1.0) * geo.npieces[i]).round().astype(int), geo.npieces[i] - 1
                )
                limit = _cross(PC, _eval_local(c, np.mod(P_t, 1.0), k_after)[1])
                V, U = deflated(np.arange(P.shape[0])[:, None], S, V)
                V = np.where(at_corner[:, None] & (U == 0), limit[:, None], V)

            def dF(rows, s, _c=c):
                slope = _cross(PC[rows], eval_curve(_c, s)[1])
                if not corner_rays:
                    return slope
                u = np.mod(s - P_t[rows] + 0.5, 1.0) - 0.5
                deflate = at_corner[rows] & (u != 0)
                distance = np.where(deflate, np.abs(u), 1.0)
                deflated = (slope - F(rows, s) * np.sign(u)) / distance
                return np.where(deflate, deflated, slope)

            rows, roots = _roots_rows(F, S, V, dF)
            if roots.size:
                xr = _eval_x(c, roots) - C
                keep = _dot(xr, PC[rows]) > 0.0
                # the tangency point itself is a (numerically fuzzy) double root
                # of its own shadow function; it is already a breakpoint
                dist = np.abs(np.mod(roots - P_t[rows] + 0.5, 1.0) - 0.5)
                keep &= ~((P_curve[rows] == i) & (dist < 1e-7))
                pts.append(np.mod(roots[keep], 1.0))
        pts.extend(_pose_breakpoints(geo, i, C, pose))
        b = _merge(np.concatenate(pts), merge_tol)
        bps.append(b)
    # classify sub-intervals by a ray cast at their midpoints
    mids, owner = [], []
    for i, b in enumerate(bps):
        mids.append(0.5 * (b[:-1] + b[1:]))
        owner.append(np.full(b.size - 1, i))
    tm = np.concatenate(mids)
    own = np.concatenate(owner)
    X = np.empty((tm.size, 2))
    for i in range(geo.n):
        sel = own == i
        X[sel] = _eval_x(geo.curves[i], tm[sel])
    vis = _ray_clear(geo, C, X, own, tm) & _in_view(X, C, pose)
    out = []
    pos = 0
    for b in bps:
        nb = b.size - 1
        out.append((b, vis[pos : pos + nb]))
        pos += nb
    return out


def _ray_clear(geo, C, X, own, tm, chunk=256):
    """True where the open segment (C, X_k) meets no curve (X_k = x_own(tm))."""
    D = X - C
    D2 = _dot(D, D)
    clear = np.ones(X.shape[0], dtype=bool)
    for j, c in enumerate(geo.curves):
        XC = geo.xg[j] - C
        for s0 in range(0, X.shape[0], chunk):
            Dk = D[s0 : s0 + chunk]
            V = _cross(Dk[:, None, :], XC[None, :, :])
            S = np.broadcast_to(geo.tg[j][None, :], V.shape)

            def F(rows, s, _c=c, _Dk=Dk):
                return _cross(_Dk[rows], _eval_x(_c, s) - C)

            def dF(rows, s, _c=c, _Dk=Dk):
                return _cross(_Dk[rows], eval_curve(_c, s)[1])

            rows, roots = _roots_rows(F, S, V, dF)
            if roots.size == 0:
                continue
            g = rows + s0
            lam = _dot(_eval_x(c, roots) - C, D[g]) / D2[g]
            hit = (lam > 1e-12) & (lam < 1.0 - 1e-10)
            dist = np.abs(np.mod(roots - tm[g] + 0.5, 1.0) - 0.5)
            hit &= ~((own[g] == j) & (dist < 1e-9))
            clear[g[hit]] = False
    return clear


# ---------------------------------------------------------------------------
# quadrature
# ---------------------------------------------------------------------------
_GL_X, _GL_W = np.polynomial.legendre.leggauss(16)


def _local_q(objective, x, dx, cams, group):
    """q at points x (tangents dx) for camera groups ``group`` (index rows, (..., l))."""
    if objective[0] in ("visible_length", "coverage"):
        return np.ones(x.shape[:-1])
    if objective[0] == "foreshortened":
        d = x - cams[group[..., 0]]
        cr = _cross(dx, d)
        den = _dot(dx, dx) * _dot(d, d)
        return np.where(den > 0, cr * cr / np.where(den > 0, den, 1.0), 0.0)
    # reconstruction: error parallelogram of two wedges of angle delta, area
    # A = delta^2 d1 d2 / sin(theta); q = 1 / (1 + (A / area)^2)
    _, area, delta = objective
    u1, u2 = x - cams[group[..., 0]], x - cams[group[..., 1]]
    d1, d2 = np.sqrt(_dot(u1, u1)), np.sqrt(_dot(u2, u2))
    sin_theta = np.abs(_cross(u1, u2)) / (d1 * d2)
    with np.errstate(divide="ignore"):
        A = delta**2 * d1 * d2 / sin_theta
    return 1.0 / (1.0 + (A / area) ** 2)


def _integrand(curve, t, piece, cam, cams, objective, groups):
    x, dx, _ = _eval_local(curve, t, piece)
    sp = np.sqrt(_dot(dx, dx))
    return _local_q(objective, x, dx, cams, groups[cam]) * sp


def _adaptive_gl(curve, a, b, piece, cam, cams, objective, groups, tol, max_level=60):
    """Adaptive 16-point Gauss-Legendre over many intervals at once.
    Returns (integral, error_estimate)."""
    total, err = 0.0, 0.0
    if a.size == 0:
        return total, err

    def gl(a_, b_):
        h = 0.5 * (b_ - a_)
        tt = 0.5 * (a_ + b_)[:, None] + h[:, None] * _GL_X[None, :]
        f = _integrand(curve, tt, piece[:, None], cam[:, None], cams, objective, groups)
        return h * (f @ _GL_W)

    whole = gl(a, b)
    # scale for the absolute tolerance: mean |x'| of the curve
    tq = (np.arange(256) + 0.5) / 256
    xs = eval_curve(curve, tq)[1]
    scale = max(float(np.mean(np.sqrt(_dot(xs, xs)))), 1e-300)
    for _ in range(max_level):
        m = 0.5 * (a + b)
        left, right = gl(a, m), gl(m, b)
        fine = left + right
        diff = np.abs(fine - whole)
        ok = diff <= tol * np.maximum(scale * (b - a), np.abs(fine))
        total += float(np.sum(fine[ok]))
        err += float(np.sum(diff[ok]))
        if np.all(ok):
            return total, err
        nk = ~ok
        a = np.concatenate([a[nk], m[nk]])
        b = np.concatenate([m[nk], b[nk]])
        piece = np.concatenate([piece[nk], piece[nk]])
        cam = np.concatenate([cam[nk], cam[nk]])
        whole = np.concatenate([left[nk], right[nk]])
    total += float(np.sum(whole))
    err += float(np.sum(np.abs(whole)))  # not converged: pessimistic
    return total, err


# ---------------------------------------------------------------------------
# public API
# ---------------------------------------------------------------------------
def _check_objective(objective):
    """("visible_length",), ("foreshortened",), ("reconstruction", area, delta) or
    ("coverage", m), from a name or a tuple."""
    objective = (objective,) if isinstance(objective, str) else tuple(objective)
    sizes = {"visible_length": 1, "foreshortened": 1, "reconstruction": 3, "coverage": 2}
    if objective[0] not in sizes or len(objective) != sizes[objective[0]]:
        raise ValueError(f"unknown objective {objective!r}")
    return objective


def _group_size(objective):
    return {"reconstruction": 2, "coverage": objective[-1]}.get(objective[0], 1)


def reference_visible_intervals(curves, camera, n_grid: int = 4096):
    """Visible parameter intervals per curve for ONE camera.

    Returns a list (per curve) of lists of ``(t0, t1)`` with
    ``0 <= t0 < t1 <= 1``; an arc through the seam is split at t = 0."""
    geo = _Geo(curves, n_grid)
    part = _camera_partition(geo, np.asarray(camera, dtype=float))
    res = []
    for b, vis in part:
        ivs = []
        for k in np.nonzero(vis)[0]:
            t0, t1 = float(b[k]), float(b[k + 1])
            if t1 <= t0:
                continue
            if ivs and ivs[-1][1] == t0:
                ivs[-1] = (ivs[-1][0], t1)
            else:
                ivs.append((t0, t1))
        res.append(ivs)
    return res


def _evaluate(curves, cameras, objective, n_grid, quad_tol, poses=None, observed=None):
    objective = _check_objective(objective)
    cams = np.atleast_2d(np.asarray(cameras, dtype=float))
    geo = _Geo(curves, n_grid)
    poses = poses or [None] * len(cams)
    parts = [_camera_partition(geo, C, pose=p) for C, p in zip(cams, poses)]
    total, err = 0.0, 0.0
    ncam = cams.shape[0]
    # Eq. 3.15: the integrand is the best group of l cameras that all see the point.
    groups = np.array(list(itertools.combinations(range(ncam), _group_size(objective))))
    varying = objective[0] in ("foreshortened", "reconstruction")
    for i, c in enumerate(geo.curves):
        if observed is not None and not observed[i]:
            continue  # a room's walls: they occlude but are not integrated
        b = np.unique(np.concatenate([geo.bounds[i]] + [parts[k][i][0] for k in range(ncam)]))
        tm = 0.5 * (b[:-1] + b[1:])
        seen = np.zeros((ncam, tm.size), dtype=bool)
        for k in range(ncam):
            bk, vk = parts[k][i]
            j = np.clip(np.searchsorted(bk, tm, side="right") - 1, 0, vk.size - 1)
            seen[k] = vk[j]
        seen = seen[groups].all(axis=1)  # (groups, intervals)
        a_, b_ = b[:-1], b[1:]
        keep = seen.any(axis=0) & (b_ > a_)
        a_, b_, seen = a_[keep], b_[keep], seen[:, keep]
        piece = _piece_of(c, 0.5 * (a_ + b_))
        if varying and len(groups) > 1 and a_.size:
            a_, b_, piece, seen = _split_at_kinks(c, cams, objective, groups, a_, b_, piece, seen)
        # arg-max group on each final piece (first seeing group for constant q)
        tmid = 0.5 * (a_ + b_)
        x, dx, _ = _eval_local(c, tmid, piece)
        q = _local_q(objective, x[None], dx[None], cams, groups[:, None, :])
        cam = np.argmax(np.where(seen, q, -1.0), axis=0)
        val, e = _adaptive_gl(c, a_, b_, piece, cam, cams, objective, groups, quad_tol)
        total += val
        err += e
    return total, err


def _split_at_kinks(curve, cams, objective, groups, a, b, piece, seen, m=128):
    """Split intervals seen by >= 2 camera groups at the roots of q_a - q_b."""
    rows_i, pa, pb = [], [], []
    for k1 in range(len(groups)):
        for k2 in range(k1 + 1, len(groups)):
            both = np.nonzero(seen[k1] & seen[k2])[0]
            rows_i.append(both)
            pa.append(np.full(both.size, k1))
            pb.append(np.full(both.size, k2))
    ri = np.concatenate(rows_i)
    if ri.size == 0:
        return a, b, piece, seen
    pa = np.concatenate(pa)
    pb = np.concatenate(pb)

    def qfun(t, pc, g):
        x, dx, _ = _eval_local(curve, t, pc)
        return _local_q(objective, x, dx, cams, groups[g])

    def F(rows, s):
        pc = piece[ri[rows]]
        return qfun(s, pc, pa[rows]) - qfun(s, pc, pb[rows])

    u = np.linspace(0.0, 1.0, m + 1)
    S = a[ri][:, None] + (b[ri] - a[ri])[:, None] * u[None, :]
    rows_full = np.broadcast_to(np.arange(ri.size)[:, None], S.shape)
    V = F(rows_full, S)
    rows, roots = _roots_rows(F, S, V)
    if roots.size == 0:
        return a, b, piece, seen
    owner = ri[rows]
    inside = (roots > a[owner]) & (roots < b[owner])
    owner, roots = owner[inside], roots[inside]
    na, nb, npc, ns = [], [], [], []
    order = np.argsort(owner, kind="stable")
    owner, roots = owner[order], roots[order]
    for idx in range(a.size):
        rts = roots[owner == idx]
        if rts.size == 0:
            na.append([a[idx]])
            nb.append([b[idx]])
            npc.append([piece[idx]])
            ns.append(seen[:, idx : idx + 1])
            continue
        pts = np.unique(np.concatenate([[a[idx]], rts, [b[idx]]]))
        na.append(pts[:-1])
        nb.append(pts[1:])
        npc.append(np.full(pts.size - 1, piece[idx]))
        ns.append(np.repeat(seen[:, idx : idx + 1], pts.size - 1, axis=1))
    return (
        np.concatenate(na),
        np.concatenate(nb),
        np.concatenate(npc).astype(np.int64),
        np.concatenate(ns, axis=1),
    )


def reference_visibility(
    curves,
    cameras,
    objective="foreshortened",
    n_grid: int = 4096,
    quad_tol: float = 1e-14,
    poses=None,
    observed=None,
) -> float:
    """Reference value of Q (see module docstring).

    objective: "visible_length", "foreshortened", ("reconstruction", area, delta) (pairs
    of cameras) or ("coverage", m) (length seen by >= m cameras);
    n_grid: grid points per curve used to *detect* roots (not an accuracy
    parameter); quad_tol: relative tolerance of the adaptive quadrature; poses: optional
    list (one per camera) of dicts with heading, half_fov and range (None: unlimited),
    restricting each camera to its view wedge and range; observed: optional list of
    bools, False for curves that occlude but are not integrated (a room's walls)."""
    return _evaluate(curves, cameras, objective, n_grid, quad_tol, poses, observed)[0]


def reference_visibility_with_error(
    curves, cameras, objective="foreshortened", n_grid: int = 4096, quad_tol: float = 1e-14
):
    """Return ``(Q, error_estimate)``: Q from grid ``n_grid``; the estimate is
    the difference to an evaluation with an unrelated grid (~1.618 n_grid),
    plus the accumulated quadrature error estimates."""
    v1, e1 = _evaluate(curves, cameras, objective, n_grid, quad_tol)
    v2, e2 = _evaluate(curves, cameras, objective, int(n_grid * 1.618) + 7, quad_tol)
    return v1, abs(v1 - v2) + max(e1, e2)
