"""Tests of the independent NumPy reference (tests/reference.py) itself,
against closed forms and against an independent brute-force estimate."""

from __future__ import annotations

import math
import os
import sys

import numpy as np
import pytest
from scipy import integrate

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from reference import (  # noqa: E402
    eval_curve,
    reference_visibility,
    reference_visibility_with_error,
    reference_visible_intervals,
)


# ---------------------------------------------------------------------------
# closed forms
# ---------------------------------------------------------------------------
def circle(c, r):
    return {"type": "circle", "center": np.asarray(c, float), "radius": float(r)}


def fs_antiderivative(phi, r, d):
    """Antiderivative in phi of q * r for a circle of radius r seen from
    distance d, phi measured from the centre->camera direction (|phi| < pi).

    q = (r - d cos phi)^2 / (r^2 + d^2 - 2 r d cos phi)
      = -d/(2r) cos phi - (d^2 - 3r^2)/(4r^2) + (d^2-r^2)^2/(4r^2) / (d^2+r^2-2rd cos phi)
    """
    return r * (
        -d / (2 * r) * math.sin(phi)
        - (d * d - 3 * r * r) / (4 * r * r) * phi
        + (d * d - r * r) / (2 * r * r) * math.atan((d + r) / (d - r) * math.tan(phi / 2))
    )


def fs_q(phi, r, d):
    return (r - d * math.cos(phi)) ** 2 / (r * r + d * d - 2 * r * d * math.cos(phi))


def wrap(a):
    return (a + math.pi) % (2 * math.pi) - math.pi


def first_hit_circle(C, u, c, R):
    """First intersection of the ray C + lam u (|u| = 1) with circle (c, R)."""
    w = C - c
    b = float(u @ w)
    disc = b * b - (w @ w - R * R)
    assert disc > 0
    lam = -b - math.sqrt(disc)
    assert lam > 0
    return C + lam * u


def two_circle_closed_form(C, cb, R, cs, r):
    """Big circle (cb, R) partly shadowed by small circle (cs, r) from C.

    Returns (visible_length, foreshortened, big-circle visible arcs as angle
    pairs relative to the centre->camera direction)."""
    C, cb, cs = (np.asarray(v, float) for v in (C, cb, cs))
    # small circle: its own visible arc
    ds = np.linalg.norm(C - cs)
    a_s = math.acos(r / ds)
    # big circle: visible arc |phi| < a_b around the direction of C
    v = C - cb
    db = np.linalg.norm(v)
    a_b = math.acos(R / db)
    ang0 = math.atan2(v[1], v[0])
    # tangent rays from C to the small circle -> shadow edges on the big circle
    psi0 = math.atan2(*(cs - C)[::-1])
    beta = math.asin(r / ds)
    phis = []
    for psi in (psi0 - beta, psi0 + beta):
        y = first_hit_circle(C, np.array([math.cos(psi), math.sin(psi)]), cb, R)
        phis.append(wrap(math.atan2(y[1] - cb[1], y[0] - cb[0]) - ang0))
    p1, p2 = sorted(phis)
    assert -a_b < p1 < p2 < a_b
    length = R * (2 * a_b - (p2 - p1)) + r * 2 * a_s
    G = fs_antiderivative
    fs = (
        (G(p1, R, db) - G(-a_b, R, db))
        + (G(a_b, R, db) - G(p2, R, db))
        + (G(a_s, r, ds) - G(-a_s, r, ds))
    )
    return length, fs, [(-a_b + ang0, p1 + ang0), (p2 + ang0, a_b + ang0)]


def arcs_to_t(arcs):
    """Angle arcs -> sorted list of t-intervals in [0, 1) split at the seam."""
    out = []
    for a0, a1 in arcs:
        t0, t1 = a0 / (2 * math.pi), a1 / (2 * math.pi)
        k = math.floor(t0)
        t0, t1 = t0 - k, t1 - k
        if t1 > 1:
            out += [(t0, 1.0), (0.0, t1 - 1)]
        else:
            out.append((t0, t1))
    return sorted(out)


# ---------------------------------------------------------------------------
# independent brute force (sampling + exact ray casting against a polyline)
# ---------------------------------------------------------------------------
def brute_force(curves, cameras, objective, n=200_000):
    """Midpoint-rule estimate of Q with n samples per curve.  Every sample is
    tested by exact segment/segment intersection of (C, X) against the closed
    polyline through all samples (the two polyline edges incident to X are
    skipped; candidate edges are found by angular bucketing around C).  The
    error is O(1/n) per visibility boundary."""
    cams = np.atleast_2d(np.asarray(cameras, float))
    t = (np.arange(n) + 0.5) / n
    X, DX, cid = [], [], []
    for i, c in enumerate(curves):
        x, dx, _ = eval_curve(c, t)
        X.append(x)
        DX.append(dx)
        cid.append(np.full(n, i))
    X, DX, cid = np.concatenate(X), np.concatenate(DX), np.concatenate(cid)
    sp = np.hypot(DX[:, 0], DX[:, 1])
    k = np.arange(X.shape[0])
    nxt = cid * n + (k - cid * n + 1) % n  # edge k: X[k] -> X[nxt[k]]
    best = np.zeros(X.shape[0])
    for C in cams:
        th = np.arctan2(X[:, 1] - C[1], X[:, 0] - C[0])
        dth = np.angle(np.exp(1j * (th[nxt] - th)))
        lo, hi = np.minimum(th, th + dth), np.maximum(th, th + dth)
        w1, w2 = hi > np.pi, lo < -np.pi
        seg_lo = np.concatenate([lo, lo[w1] - 2 * np.pi, lo[w2] + 2 * np.pi])
        seg_hi = np.concatenate([hi, hi[w1] - 2 * np.pi, hi[w2] + 2 * np.pi])
        seg_id = np.concatenate([k, k[w1], k[w2]])
        order = np.argsort(th)
        ths = th[order]
        i0 = np.searchsorted(ths, seg_lo, "left")
        cnt = np.searchsorted(ths, seg_hi, "right") - i0
        sidx = np.repeat(seg_id, cnt)
        start = np.repeat(i0 - np.cumsum(np.r_[0, cnt[:-1]]), cnt)
        pidx = order[start + np.arange(cnt.sum())]
        ok = (sidx != pidx) & (nxt[sidx] != pidx)
        sidx, pidx = sidx[ok], pidx[ok]
        d = X[pidx] - C
        A = X[sidx]
        e = X[nxt[sidx]] - A
        wv = A - C
        den = d[:, 0] * e[:, 1] - d[:, 1] * e[:, 0]
        nz = den != 0
        den = np.where(nz, den, 1.0)
        lam = (wv[:, 0] * e[:, 1] - wv[:, 1] * e[:, 0]) / den
        mu = (wv[:, 0] * d[:, 1] - wv[:, 1] * d[:, 0]) / den
        hit = nz & (lam > 0) & (lam < 1 - 1e-12) & (mu >= 0) & (mu <= 1)
        vis = np.ones(X.shape[0], bool)
        vis[pidx[hit]] = False
        if objective == "visible_length":
            q = np.ones(X.shape[0])
        else:
            dd = X - C
            cr = DX[:, 0] * dd[:, 1] - DX[:, 1] * dd[:, 0]
            q = cr**2 / ((DX**2).sum(1) * (dd**2).sum(1))
        best = np.maximum(best, np.where(vis, q, 0.0))
    return float(np.sum(best * sp) / n)


# ---------------------------------------------------------------------------
# curve evaluation
# ---------------------------------------------------------------------------
C_SHAPE = np.array(
    [
        [1.2, 0.9],
        [0.0, 1.3],
        [-1.2, 0.8],
        [-1.3, -0.6],
        [0.0, -1.3],
        [1.2, -0.9],
        [0.0, -0.35],
        [0.0, 0.35],
    ]
)


def _cardinal_bspline(x, p):
    """Cox-de Boor for the cardinal B-spline N_p with knots 0..p+1."""
    if p == 0:
        return ((x >= 0) & (x < 1)).astype(float)
    return (x * _cardinal_bspline(x, p - 1) + (p + 1 - x) * _cardinal_bspline(x - 1, p - 1)) / p


@pytest.mark.parametrize("degree", [1, 2, 3, 5])
def test_bspline_matches_definition(degree):
    P = C_SHAPE
    n = P.shape[0]
    t = np.linspace(0, 1, 301, endpoint=False) + 1e-3
    u = n * (t % 1.0)
    x_def = np.zeros((t.size, 2))
    for i in range(n):
        w = sum(_cardinal_bspline(u - i + m * n, degree) for m in range(-2, 3))
        x_def += w[:, None] * P[i]
    x, dx, ddx = eval_curve({"type": "bspline", "points": P, "degree": degree}, t)
    np.testing.assert_allclose(x, x_def, atol=1e-13)


@pytest.mark.parametrize(
    "curve",
    [
        {"type": "bspline", "points": C_SHAPE, "degree": 3},
        {
            "type": "bezier",
            "points": np.array([[0, 0], [2, -1], [3, 2], [0.5, 3], [-1, 1], [0, 0]], float),
        },
        {"type": "ellipse", "center": np.array([1.0, -2.0]), "axes": (2.0, 0.7), "angle": 0.4},
        circle([0.3, 0.1], 1.7),
    ],
)
def test_derivatives_finite_difference(curve):
    t = np.array([0.013, 0.21, 0.377, 0.52, 0.699, 0.93])  # away from knots
    h = 1e-5
    x, dx, ddx = eval_curve(curve, t)
    xp, dxp, _ = eval_curve(curve, t + h)
    xm, dxm, _ = eval_curve(curve, t - h)
    np.testing.assert_allclose(dx, (xp - xm) / (2 * h), rtol=1e-7, atol=1e-7)
    np.testing.assert_allclose(ddx, (dxp - dxm) / (2 * h), rtol=1e-6, atol=1e-6)


def test_bezier_and_ellipse_points():
    P = np.array([[0, 0], [2, -1], [3, 2], [0.5, 3], [0, 0]], float)
    t = np.array([0.0, 0.25, 0.5, 0.8])
    x = eval_curve({"type": "bezier", "points": P}, t)[0]
    # de Casteljau
    for tk, xk in zip(t, x):
        Q = P.copy()
        while len(Q) > 1:
            Q = (1 - tk) * Q[:-1] + tk * Q[1:]
        np.testing.assert_allclose(xk, Q[0], atol=1e-14)
    e = {"type": "ellipse", "center": np.array([1.0, -2.0]), "axes": (2.0, 0.7), "angle": 0.4}
    x = eval_curve(e, np.linspace(0, 1, 7))[0] - e["center"]
    R = np.array([[math.cos(0.4), math.sin(0.4)], [-math.sin(0.4), math.cos(0.4)]])
    y = x @ R.T  # rotate back
    np.testing.assert_allclose((y[:, 0] / 2.0) ** 2 + (y[:, 1] / 0.7) ** 2, 1.0, atol=1e-14)
    np.testing.assert_allclose(x[0], 2.0 * np.array([math.cos(0.4), math.sin(0.4)]), atol=1e-14)


# ---------------------------------------------------------------------------
# one circle
# ---------------------------------------------------------------------------
@pytest.mark.parametrize(
    "center,r,cam",
    [
        ((0.0, 0.0), 1.0, (3.0, 0.0)),
        ((1.5, -0.7), 2.0, (1.5 + 5.0 * math.cos(2.0), -0.7 + 5.0 * math.sin(2.0))),
    ],
)
def test_circle_closed_form(center, r, cam):
    c = circle(center, r)
    cam = np.array(cam)
    d = float(np.linalg.norm(cam - np.array(center)))
    alpha = math.acos(r / d)
    L = reference_visibility([c], cam[None], "visible_length")
    assert abs(L / (2 * r * alpha) - 1) <= 1e-12
    exact = fs_antiderivative(alpha, r, d) - fs_antiderivative(-alpha, r, d)
    quad = integrate.quad(lambda p: fs_q(p, r, d) * r, -alpha, alpha, epsabs=0, epsrel=1e-13)[0]
    assert abs(exact / quad - 1) <= 1e-12  # the closed form itself
    F = reference_visibility([c], cam[None], "foreshortened")
    assert abs(F / exact - 1) <= 1e-12
    # intervals
    ang = math.atan2(cam[1] - center[1], cam[0] - center[0])
    got = sorted(reference_visible_intervals([c], cam)[0])
    want = arcs_to_t([(ang - alpha, ang + alpha)])
    assert len(got) == len(want)
    np.testing.assert_allclose(np.array(got), np.array(want), atol=1e-13)


def test_circle_two_cameras_max():
    r, d = 1.0, 3.0
    c = circle((0, 0), r)
    cams = np.array([[d, 0.0], [0.0, d]])
    alpha = math.acos(r / d)
    L = reference_visibility([c], cams, "visible_length")
    assert abs(L / (r * (math.pi / 2 + 2 * alpha)) - 1) <= 1e-12
    # by symmetry the max switches camera at phi = pi/4 (q decreases with |phi|)
    G = fs_antiderivative
    exact = 2 * (G(math.pi / 4, r, d) - G(-alpha, r, d))
    F = reference_visibility([c], cams, "foreshortened")
    assert abs(F / exact - 1) <= 1e-12


# ---------------------------------------------------------------------------
# two circles: shadow
# ---------------------------------------------------------------------------
@pytest.mark.parametrize(
    "C,cb,R,cs,r",
    [
        ((6.0, 0.0), (0.0, 0.0), 2.0, (3.5, 0.0), 0.5),
        ((5.0, 3.0), (-0.5, 0.2), 1.5, (2.4, 1.7), 0.4),
    ],
)
def test_two_circles_shadow(C, cb, R, cs, r):
    length, fs, arcs = two_circle_closed_form(C, cb, R, cs, r)
    curves = [circle(cb, R), circle(cs, r)]
    cams = np.array([C])
    L = reference_visibility(curves, cams, "visible_length")
    assert abs(L / length - 1) <= 1e-12
    F = reference_visibility(curves, cams, "foreshortened")
    assert abs(F / fs - 1) <= 1e-12
    # the big circle's two visible arcs (merged across the seam if needed)
    got = reference_visible_intervals(curves, np.array(C))[0]
    want = arcs_to_t(arcs)
    tot = lambda iv: sum(b - a for a, b in iv)  # noqa: E731
    assert abs(tot(got) - tot(want)) <= 1e-12
    ends = lambda iv: np.sort([v for ab in iv for v in ab if 0 < v < 1])  # noqa: E731
    np.testing.assert_allclose(ends(got), ends(want), atol=1e-12)


# ---------------------------------------------------------------------------
# non-convex B-spline (self-occlusion) and a mixed scene vs brute force
# ---------------------------------------------------------------------------
# a deep "C": outer arc of radius 1.3, inner arc of radius 0.6, mouth at +x
_A_OUT = np.deg2rad([35, 90, 140, 180, 220, 270, 325])
_A_IN = np.deg2rad([320, 270, 220, 180, 140, 90, 40])
DEEP_C = np.r_[
    1.3 * np.c_[np.cos(_A_OUT), np.sin(_A_OUT)], 0.6 * np.c_[np.cos(_A_IN), np.sin(_A_IN)]
]


@pytest.mark.parametrize("cam", [(1.6, -0.5), (2.5, 0.8)])
def test_cshape_bspline_vs_brute_force(cam):
    bs = {"type": "bspline", "points": DEEP_C, "degree": 3}
    cams = np.array([cam])  # looking into the mouth: the arms cast shadows
    ivs = reference_visible_intervals([bs], cams[0])[0]
    # number of visible arcs (an arc through the seam counts once): a closed
    # curve seen with >= 2 arcs is self-occluded beyond mere back-facing
    n_arcs = len(ivs) - (1 if ivs[0][0] == 0.0 and ivs[-1][1] == 1.0 else 0)
    assert n_arcs >= 2
    for obj in ("visible_length", "foreshortened"):
        v, err = reference_visibility_with_error([bs], cams, obj)
        assert err <= 1e-12 * v
        b = brute_force([bs], cams, obj)
        assert abs(v / b - 1) <= 1e-4, (obj, v, b)


def test_mixed_scene_vs_brute_force():
    curves = [
        {"type": "bspline", "points": C_SHAPE * 0.8 + [0.0, 0.2], "degree": 3},
        {"type": "ellipse", "center": np.array([2.6, 1.4]), "axes": (0.5, 0.25), "angle": 0.7},
        {
            "type": "bezier",
            "points": np.array([[2.0, -1.5], [3.4, -2.2], [3.6, -0.4], [2.5, -0.6], [2.0, -1.5]]),
        },
        circle((-0.5, 2.6), 0.45),
    ]
    cams = np.array([[4.6, 0.3], [0.4, 4.2], [-3.0, -2.0]])
    for obj in ("visible_length", "foreshortened"):
        v, err = reference_visibility_with_error(curves, cams, obj)
        assert err <= 1e-10 * v
        b = brute_force(curves, cams, obj, n=100_000)
        assert abs(v / b - 1) <= 1e-4, (obj, v, b)
