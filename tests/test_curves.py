"""Curves: positions against the independent NumPy reference, derivatives against
finite differences, seam continuity, breakpoints and input validation."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import BEZIER_FREE, C_POINTS, to_reference
from jax.flatten_util import ravel_pytree
from reference import eval_curve

import ocp_jax as ocp

# A plain closed Bezier curve (not built by closed_c2), C1 but not C2 at the seam:
# P1 - P0 == P5 - P4 = (0.8, 0.6), second differences differ.
BEZIER_C1 = np.array(
    [[0.0, 0.0], [0.8, 0.6], [2.5, 1.8], [1.2, 3.0], [-1.6, 1.2], [-0.8, -0.6], [0.0, 0.0]]
)

CURVES = {
    "bezier_c2": lambda: ocp.BezierCurve.closed_c2(jnp.asarray(BEZIER_FREE)),
    "bezier_c1": lambda: ocp.BezierCurve(jnp.asarray(BEZIER_C1)),
    "banana": lambda: ocp.scenes.banana().curves[0],
    "bspline2": lambda: ocp.BSplineCurve(jnp.asarray(C_POINTS), degree=2),
    "bspline3": lambda: ocp.BSplineCurve(jnp.asarray(C_POINTS), degree=3),
    "bspline5": lambda: ocp.BSplineCurve(jnp.asarray(C_POINTS), degree=5),
    "circle": lambda: ocp.Circle(jnp.array([0.3, -0.2]), 1.7),
    "ellipse": lambda: ocp.Ellipse(jnp.array([1.0, -2.0]), jnp.array([2.0, 0.7]), 0.4),
}


def spec(curve):
    return to_reference(ocp.Scene([curve]))[0]


# parameters away from B-spline knots (multiples of 1/8) and from the seam
T_SMOOTH = np.array([0.013, 0.09, 0.21, 0.3333, 0.377, 0.52, 0.61, 0.699, 0.8, 0.93, 0.987])
# including the seam and knots (positions and first derivatives are continuous there)
T_ALL = np.concatenate([T_SMOOTH, [0.0, 0.125, 0.25, 0.5, 0.875]])


@pytest.fixture(params=sorted(CURVES))
def curve(request):
    return CURVES[request.param]()


def test_positions_match_reference(curve):
    x, dx, ddx = (np.asarray(a) for a in curve.derivatives(T_SMOOTH))
    rx, rdx, rddx = eval_curve(spec(curve), T_SMOOTH)
    scale = np.abs(rx).max()
    np.testing.assert_allclose(x, rx, rtol=0, atol=1e-13 * scale)
    np.testing.assert_allclose(dx, rdx, rtol=0, atol=1e-12 * np.abs(rdx).max())
    np.testing.assert_allclose(ddx, rddx, rtol=0, atol=1e-11 * np.abs(rddx).max())
    # __call__ is the position
    np.testing.assert_array_equal(np.asarray(curve(T_SMOOTH)), x)
    # positions and x' are continuous, so they also match at the seam and the knots
    x_all, dx_all, _ = (np.asarray(a) for a in curve.derivatives(T_ALL))
    rx_all, rdx_all, _ = eval_curve(spec(curve), T_ALL)
    np.testing.assert_allclose(x_all, rx_all, rtol=0, atol=1e-13 * scale)
    np.testing.assert_allclose(dx_all, rdx_all, rtol=0, atol=1e-12 * np.abs(rdx).max())


def test_point_and_tangent_rows_are_x_and_its_derivative(curve):
    """The rows (x, y, x', y') that the engine stores, against `derivatives`: at the
    knots and the seam too (B-splines compute them in one expression of their own). The
    scene's rows are those of the form it evaluates (a conic as an ellipse, `Scene`),
    bitwise; that form's rows are the curve's to rounding."""
    t = jnp.asarray(np.stack([T_ALL, T_ALL[::-1]]))  # (2, 16): any shape of t
    rows = np.asarray(curve.point_and_tangent(t))
    assert rows.shape == (4, *t.shape)
    x, dx, _ = (np.moveaxis(np.asarray(a), -1, 0) for a in curve.derivatives(t))
    np.testing.assert_allclose(rows[:2], x, rtol=0, atol=1e-15 * np.abs(x).max())
    np.testing.assert_allclose(rows[2:], dx, rtol=0, atol=1e-15 * np.abs(dx).max())
    far = ocp.Circle(jnp.array([1e3, 1e3]), 1.0)  # (apart from the curve: a valid scene)
    scene_rows = ocp.Scene([curve, far]).point_and_tangent(jnp.stack([t, t]))
    form = curve.as_ellipse() if isinstance(curve, ocp.AbstractConic) else curve
    form_rows = np.asarray(form.point_and_tangent(t))
    np.testing.assert_array_equal(np.asarray(scene_rows[0]), form_rows)
    np.testing.assert_allclose(form_rows[:2], x, rtol=0, atol=1e-15 * np.abs(x).max())
    np.testing.assert_allclose(form_rows[2:], dx, rtol=0, atol=1e-15 * np.abs(dx).max())


def _fd4(fn, t, h):
    """Fourth-order central difference of fn at t."""
    return (8 * (fn(t + h) - fn(t - h)) - (fn(t + 2 * h) - fn(t - 2 * h))) / (12 * h)


def test_derivatives_match_finite_differences(curve):
    h = 1e-4
    x, dx, ddx = (np.asarray(a) for a in curve.derivatives(T_SMOOTH))

    def pos(t):
        return np.asarray(curve(jnp.asarray(t)))

    def vel(t):
        return np.asarray(curve.tangent(jnp.asarray(t)))

    fd_dx = _fd4(pos, T_SMOOTH, h)
    fd_ddx = _fd4(vel, T_SMOOTH, h)
    assert np.abs(fd_dx - dx).max() <= 1e-8 * np.abs(dx).max()
    assert np.abs(fd_ddx - ddx).max() <= 1e-8 * np.abs(ddx).max()
    # and autodiff of the position agrees with the closed-form derivatives
    ad = jax.vmap(jax.jacfwd(curve))(jnp.asarray(T_SMOOTH))
    np.testing.assert_allclose(np.asarray(ad), dx, rtol=0, atol=1e-12 * np.abs(dx).max())


def test_derivatives_wrt_parameters_match_finite_differences(curve):
    """d x(t) / d(curve parameters) by autodiff against central differences."""
    flat, unravel = ravel_pytree(curve)
    t = jnp.asarray(T_SMOOTH)

    def pos(p):
        return unravel(p).derivatives(t)[1]  # x'(t): exercises every parameter

    jac = np.asarray(jax.jacfwd(pos)(flat))
    h = 1e-6 * max(1.0, float(jnp.abs(flat).max()))
    steps = h * jnp.eye(flat.shape[0], dtype=flat.dtype)
    plus, minus = jax.vmap(pos)(flat[None] + steps), jax.vmap(pos)(flat[None] - steps)
    fd = np.moveaxis(np.asarray(plus - minus) / (2 * h), 0, -1)
    assert np.abs(jac - fd).max() <= 1e-6 * np.abs(jac).max()


def test_normal_is_rotated_tangent(curve):
    dx = np.asarray(curve.tangent(T_SMOOTH))
    n = np.asarray(curve.normal(T_SMOOTH))
    np.testing.assert_array_equal(n, np.stack([-dx[:, 1], dx[:, 0]], -1))


def test_circle_closed_form():
    c, r = np.array([0.3, -0.2]), 1.7
    circle = ocp.Circle(c.tolist(), r)  # a list, as a user writes it
    t = np.linspace(0.0, 1.0, 9)
    a = 2 * np.pi * t
    x, dx, ddx = (np.asarray(v) for v in circle.derivatives(t))
    u = np.stack([np.cos(a), np.sin(a)], -1)
    np.testing.assert_allclose(x, c + r * u, atol=1e-15)
    np.testing.assert_allclose(
        dx, 2 * np.pi * r * np.stack([-np.sin(a), np.cos(a)], -1), atol=1e-13
    )
    np.testing.assert_allclose(ddx, -((2 * np.pi) ** 2) * r * u, atol=1e-12)
    # counter-clockwise: n = [[0, -1], [1, 0]] x' points inwards
    np.testing.assert_allclose(np.asarray(circle.normal(t)), -2 * np.pi * r * u, atol=1e-13)


def test_ellipse_closed_form():
    center, (a, b), phi = np.array([1.0, -2.0]), (2.0, 0.7), 0.4
    e = ocp.Ellipse(center.tolist(), [a, b], phi)
    x = np.asarray(e(np.linspace(0, 1, 13))) - center
    rot = np.array([[math.cos(phi), math.sin(phi)], [-math.sin(phi), math.cos(phi)]])
    y = x @ rot.T  # back into the ellipse's frame
    np.testing.assert_allclose((y[:, 0] / a) ** 2 + (y[:, 1] / b) ** 2, 1.0, atol=1e-14)
    np.testing.assert_allclose(x[0], a * np.array([math.cos(phi), math.sin(phi)]), atol=1e-15)


def test_bezier_de_casteljau():
    curve = CURVES["bezier_c1"]()
    for t in (0.0, 0.17, 0.5, 0.83):
        q = BEZIER_C1.copy()
        while len(q) > 1:
            q = (1 - t) * q[:-1] + t * q[1:]
        np.testing.assert_allclose(np.asarray(curve(t)), q[0], atol=1e-14)


def test_bspline_matches_cox_de_boor():
    """x(t) = sum_i P_i sum_m N_p(n t - i + m n) with the cardinal B-spline N_p."""

    def cardinal(u, p):
        if p == 0:
            return ((u >= 0) & (u < 1)).astype(float)
        return (u * cardinal(u, p - 1) + (p + 1 - u) * cardinal(u - 1, p - 1)) / p

    t = np.linspace(0, 1, 97, endpoint=False) + 1e-3
    n = C_POINTS.shape[0]
    for degree in (2, 3, 5):
        curve = ocp.BSplineCurve(jnp.asarray(C_POINTS), degree=degree)
        u = n * t
        want = sum(
            sum(cardinal(u - i + m * n, degree) for m in range(-2, 3))[:, None] * C_POINTS[i]
            for i in range(n)
        )
        np.testing.assert_allclose(np.asarray(curve(t)), want, atol=1e-13)


def test_evaluation_shapes_and_dtype():
    curve = CURVES["bspline3"]()
    t = jnp.linspace(0, 1, 12).reshape(3, 4)
    for out in curve.derivatives(t):
        assert out.shape == (3, 4, 2)
        assert out.dtype == jnp.float64
    assert curve(0.3).shape == (2,)
    c32 = ocp.Circle(jnp.array([0.3, -0.2], jnp.float32), 1.7)
    x32 = c32(jnp.linspace(0, 1, 5, dtype=jnp.float32))
    assert x32.dtype == jnp.float32
    np.testing.assert_allclose(
        np.asarray(x32), np.asarray(CURVES["circle"]()(np.linspace(0, 1, 5))), atol=1e-6
    )


def test_curves_jit_and_vmap():
    curve = CURVES["bezier_c2"]()
    t = jnp.asarray(T_SMOOTH)
    stacked = jax.tree.map(lambda a: jnp.stack([a, 2 * a]), curve)
    out = jax.jit(jax.vmap(lambda c: c(t)))(stacked)
    np.testing.assert_allclose(np.asarray(out[0]), np.asarray(curve(t)), atol=1e-14)
    np.testing.assert_allclose(np.asarray(out[1]), 2 * np.asarray(curve(t)), atol=1e-13)


# ---------------------------------------------------------------------------
# seam continuity and breakpoints
# ---------------------------------------------------------------------------
def test_closed_c2_is_c2_at_the_seam():
    for free in (BEZIER_FREE, np.asarray(ocp.scenes.BANANA_FREE_POINTS)):
        curve = ocp.BezierCurve.closed_c2(jnp.asarray(free))
        p = np.asarray(curve.control_points)
        # the free points are kept: seam point, then the inner points P_2..P_{n-2}
        np.testing.assert_array_equal(p[0], free[0])
        np.testing.assert_array_equal(p[-1], free[0])
        np.testing.assert_array_equal(p[2:-2], free[1:])
        assert curve.degree == len(free) + 2
        (x0, d0, dd0), (x1, d1, dd1) = (
            [np.asarray(a) for a in curve.derivatives(jnp.asarray(t))] for t in (0.0, 1.0)
        )
        np.testing.assert_allclose(x0, x1, atol=1e-13 * np.abs(x0).max())
        np.testing.assert_allclose(d0, d1, atol=1e-12 * np.abs(d0).max())
        np.testing.assert_allclose(dd0, dd1, atol=1e-12 * np.abs(dd0).max())
        assert np.linalg.norm(d0) > 0 and np.linalg.norm(dd0) > 0
        assert curve.seam_continuity() == 2


def test_seam_continuity_c1_and_g1():
    c1 = ocp.BezierCurve(jnp.asarray(BEZIER_C1))
    assert c1.seam_continuity() == 1
    _, d0, dd0 = (np.asarray(a) for a in c1.derivatives(0.0))
    _, d1, dd1 = (np.asarray(a) for a in c1.derivatives(1.0))
    np.testing.assert_allclose(d0, d1, atol=1e-12)
    assert np.linalg.norm(dd0 - dd1) > 1.0  # really not C2
    g1 = BEZIER_C1.copy()
    g1[1] = 0.5 * g1[1]  # same direction, different speed
    g1_curve = ocp.BezierCurve(jnp.asarray(g1))
    assert g1_curve.seam_continuity() == 0


def test_breakpoints():
    # uniform quadrature panels: max(4, degree) for a Bezier, 4 for a circle, 8 for an
    # ellipse, the knots j/n for a B-spline
    bezier = CURVES["bezier_c2"]()
    np.testing.assert_allclose(
        np.asarray(bezier.breakpoints()), np.arange(bezier.degree) / bezier.degree
    )
    np.testing.assert_allclose(np.asarray(CURVES["circle"]().breakpoints()), np.arange(4) / 4)
    np.testing.assert_allclose(np.asarray(CURVES["ellipse"]().breakpoints()), np.arange(8) / 8)
    n = C_POINTS.shape[0]
    for name in ("bspline2", "bspline3", "bspline5"):
        np.testing.assert_allclose(np.asarray(CURVES[name]().breakpoints()), np.arange(n) / n)
    # and they are genuine: x'' of a quadratic B-spline jumps at every knot, that of a
    # cubic one is continuous there (its x''' jumps)
    eps = 1e-9
    knots = np.arange(n) / n
    for degree, jumps in ((2, True), (3, False)):
        curve = ocp.BSplineCurve(jnp.asarray(C_POINTS), degree=degree)
        left = np.asarray(curve.derivatives(np.mod(knots - eps, 1.0))[2])
        right = np.asarray(curve.derivatives(knots + eps)[2])
        jump = np.linalg.norm(left - right, axis=-1)
        if jumps:
            assert np.all(jump > 1.0)
        else:
            assert np.all(jump < 1e-5)


def test_scene_evaluates_every_curve():
    names = ("bezier_c2", "bspline3", "circle", "ellipse", "banana")
    # each moved 200 units along x from the one before, so that none touches another
    curves = [
        CURVES[k]().in_frame(jnp.array([-200.0 * i, 0.0]), jnp.asarray(1.0))
        for i, k in enumerate(names)
    ]
    scene = ocp.Scene(curves)
    assert len(scene) == 5
    # a user's scene shows its curves and room, not the engine's evaluation groups
    assert "curves=" in repr(scene) and "groups" not in repr(scene)
    t = np.stack([T_SMOOTH + 0.001 * i for i in range(5)])
    x, dx, ddx = (np.asarray(a) for a in scene.derivatives(jnp.asarray(t)))
    for i, c in enumerate(curves):
        for got, want in zip((x, dx, ddx), c.derivatives(jnp.asarray(t[i]))):
            np.testing.assert_allclose(got[i], np.asarray(want), rtol=1e-14, atol=1e-14)
    # every curve's own breakpoints, padded with 1 (the end of [0, 1)) to a common length
    b = np.asarray(scene.breakpoints())
    assert b.shape == (5, max(c.panels() for c in curves))
    for row, c in zip(b, curves):
        own = np.asarray(c.breakpoints())
        np.testing.assert_array_equal(row[: own.size], own)
        assert np.all(row[own.size :] == 1.0)


def _de_casteljau(points, s):
    """Points (d + 1, 2) of one Bezier segment at s, by repeated interpolation."""
    while len(points) > 1:
        points = (1.0 - s) * points[:-1] + s * points[1:]
    return points[0]


PIECEWISE = {
    "rounded_rectangle": lambda: ocp.PiecewiseCurve.rounded_rectangle(
        jnp.array([0.5, -1.0]), 3.0, 2.0, 0.4
    ),
    "l_shaped_polygon": lambda: ocp.PiecewiseCurve.polygon(
        jnp.array([[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [1.0, 1.0], [1.0, 2.0], [0.0, 2.0]])
    ),
}


@pytest.mark.parametrize("name", sorted(CURVES) + sorted(PIECEWISE))
def test_bezier_pieces_trace_the_curve(name):
    """`bezier_pieces` (how a scene evaluates a `PiecewiseCurve`) is the same curve
    with the same parameter: de Casteljau on segment floor(n t) at n t - floor(n t)
    against the NumPy reference; the curves with a formula of their own have none."""
    curve = {**CURVES, **PIECEWISE}[name]()
    pieces = curve.bezier_pieces()
    if not isinstance(curve, ocp.PiecewiseCurve):
        assert pieces is None
        return
    pieces = np.asarray(pieces)
    n = pieces.shape[0]
    segment = np.minimum(np.floor(n * T_ALL), n - 1).astype(int)
    x = np.stack([_de_casteljau(pieces[j], n * t - j) for j, t in zip(segment, T_ALL)])
    want = eval_curve(spec(curve), T_ALL)[0]
    np.testing.assert_allclose(x, want, rtol=0, atol=1e-13 * np.abs(want).max())


# ---------------------------------------------------------------------------
# invalid input: ValueError naming the problem
# ---------------------------------------------------------------------------
SQUARE_OPEN = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]
# closed, but P1 - P0 = (1, 0) and P4 - P3 = (0, -1): a corner at the seam
SQUARE_CORNER = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0], [0.0, 0.0]]
# closed, P1 - P0 and P4 - P3 parallel but opposite: a cusp at the seam
CUSP = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [2.0, 0.0], [0.0, 0.0]]
NAN_POINTS = np.array(C_POINTS, float)
NAN_POINTS[3, 1] = np.nan


@pytest.mark.parametrize(
    "make,match",
    [
        (lambda: ocp.BezierCurve(SQUARE_OPEN), "must be closed"),
        (lambda: ocp.BezierCurve(SQUARE_CORNER), "corner at the seam"),
        (lambda: ocp.BezierCurve(CUSP), "corner at the seam"),
        (
            lambda: ocp.BezierCurve([[0.0, 0.0], [1.0, 1.0], [0.0, 0.0]]),
            "at least 4 control points",
        ),
        (lambda: ocp.BezierCurve(np.zeros((5, 3)).tolist()), r"shape \(n, 2\)"),
        (lambda: ocp.BezierCurve(np.r_[NAN_POINTS, NAN_POINTS[:1]]), "NaN or inf"),
        (lambda: ocp.BezierCurve.closed_c2([[0.0, 0.0], [1.0, 1.0]]), "at least 3 control points"),
        (lambda: ocp.BezierCurve.closed_c2([[0.0, 0.0], [1.0, np.inf], [2.0, 0.0]]), "NaN or inf"),
        (lambda: ocp.BSplineCurve(C_POINTS, degree=1), "degree must be an integer >= 2"),
        (lambda: ocp.BSplineCurve(C_POINTS, degree=0), "degree must be an integer >= 2"),
        (lambda: ocp.BSplineCurve(C_POINTS[:3], degree=3), "at least 4 control points"),
        (lambda: ocp.BSplineCurve(C_POINTS[:4], degree=5), "at least 6 control points"),
        (lambda: ocp.BSplineCurve(C_POINTS[:2], degree=2), "at least 3 control points"),
        (lambda: ocp.BSplineCurve(NAN_POINTS), "NaN or inf"),
        (lambda: ocp.BSplineCurve(np.ones((6, 2))), "not regular"),
        (lambda: ocp.Circle(jnp.zeros(2), 0.0), "radius must be positive"),
        (lambda: ocp.Circle(jnp.zeros(2), -1.5), "radius must be positive"),
        (lambda: ocp.Circle(jnp.array([np.nan, 0.0]), 1.0), "must be finite"),
        (lambda: ocp.Circle([0.0, 0.0, 0.0], 1.0), r"center of shape \(2,\)"),
        (lambda: ocp.Ellipse(jnp.zeros(2), jnp.array([1.0, 0.0])), "semi_axes must be positive"),
        (lambda: ocp.Ellipse(jnp.zeros(2), jnp.array([-1.0, 2.0])), "semi_axes must be positive"),
        (lambda: ocp.Ellipse(jnp.zeros(2), jnp.array([1.0, 2.0]), np.nan), "must be finite"),
        (lambda: ocp.Scene([]), "at least one curve"),
    ],
    ids=[
        "bezier-open",
        "bezier-corner",
        "bezier-cusp",
        "bezier-too-few",
        "bezier-shape",
        "bezier-nan",
        "closed_c2-too-few",
        "closed_c2-inf",
        "bspline-degree1",
        "bspline-degree0",
        "bspline3-too-few",
        "bspline5-too-few",
        "bspline2-too-few",
        "bspline-nan",
        "bspline-degenerate",
        "circle-zero-radius",
        "circle-negative-radius",
        "circle-nan",
        "circle-shape",
        "ellipse-zero-axis",
        "ellipse-negative-axis",
        "ellipse-nan-angle",
        "scene-empty",
    ],
)
def test_invalid_curves_raise_value_error(make, match):
    with pytest.raises(ValueError, match=match):
        make()


def test_curves_from_constants_can_be_built_inside_jit():
    """The concrete checks run eagerly while a traced function builds a curve from
    constant control points (they used to fail on traced intermediate values)."""
    points = jnp.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])

    @jax.jit
    def first_point(scale):
        return ocp.BSplineCurve(points)(jnp.zeros(1))[0] * scale

    np.testing.assert_allclose(
        first_point(2.0), 2 * np.asarray(ocp.BSplineCurve(points)(jnp.zeros(1))[0])
    )


def test_costly_evaluation_marks_long_polynomials_only():
    """Newton steps store F (`materialize`) only on scenes with a costly curve: a Bezier
    of degree >= 8 (the degree-18 banana), not cubic B-splines, low-degree Beziers or
    conics, whose stored copy's kernels cost more than recomputing F (benchmarks/HISTORY.md,
    "Each curve evaluation compiled once")."""
    banana = ocp.scenes.banana()
    assert banana.curves[0].degree == 18 and banana.costly_evaluation()
    cubic = ocp.BezierCurve.closed_c2(np.array([[0.0, 0.0], [2.0, 0.0], [1.0, 2.0]]))
    assert cubic.degree < 8 and not cubic.costly_evaluation()
    blobs = ocp.scenes.blobs(3)
    circle = ocp.Circle(jnp.array([5.0, 5.0]), jnp.array(1.0))
    assert not blobs.costly_evaluation() and not ocp.Scene([circle]).costly_evaluation()
    assert ocp.Scene([circle, *banana.curves]).costly_evaluation()
