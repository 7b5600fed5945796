"""Closed parametric curves x: [0, 1) -> R^2 (the thesis's objects, Sec. 2.1).

Every curve gives its position x(t) and the derivatives x'(t), x''(t) (Eq. 2.2) for any
array of parameters t, and where integrals over it are cut into quadrature panels
(`breakpoints`: uniform panels that include the B-spline knots and the seam). All of them
are equinox Modules whose array fields are pytree leaves, so every quantity derived from
them is differentiable with respect to the curve's parameters too.
"""

import abc
import math
from collections.abc import Sequence
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.core import Tracer
from jaxtyping import Array, ArrayLike, Float, Int, Real

from .vec import Vec, add, scale

__all__ = [
    "AbstractConic",
    "AbstractCurve",
    "BSplineCurve",
    "BezierCurve",
    "Circle",
    "Ellipse",
    "PiecewiseCurve",
]

TWO_PI = 2.0 * math.pi


def is_concrete(*arrays) -> bool:
    """Whether no array is a tracer (the values are known: checks can run in Python)."""
    return not any(isinstance(a, Tracer) for a in arrays)


def _as_points(points, name: str, min_count: int) -> Array:
    points = jnp.asarray(points)
    if not jnp.issubdtype(points.dtype, jnp.floating):
        points = points.astype(jnp.result_type(float))
    if points.ndim != 2 or points.shape[1] != 2:
        raise ValueError(f"{name} must have shape (n, 2), got {points.shape}.")
    if points.shape[0] < min_count:
        raise ValueError(
            f"{name} needs at least {min_count} control points, got {points.shape[0]}."
        )
    if is_concrete(points) and not np.all(np.isfinite(np.asarray(points))):
        raise ValueError(f"{name} contains NaN or inf; every coordinate must be finite.")
    return points


def _point_bounds(points: Array) -> tuple[Array, Array]:
    """The bounding box of control points (..., 2): it holds a Bezier or B-spline curve
    (each point of one is a convex combination of its control points)."""
    points = points.reshape(-1, 2)
    return jnp.min(points, 0), jnp.max(points, 0)


def to_frame(points: Float[Array, "*n 2"], origin: Array, scale: Array) -> Array:
    """Points in the coordinates (p - origin) / scale."""
    return (points - origin.reshape((1,) * (points.ndim - 1) + (2,))) / scale


def _points_in_frame(curve, points, origin, scale):
    """`curve` with its control points (`points(curve)`) in the frame (p - origin) / scale."""
    return eqx.tree_at(points, curve, to_frame(points(curve), origin, scale))


def _powers(t: Array, degree: int) -> list[Array]:
    """[1, t, t^2, ..., t^degree] built by products (t**0 has a NaN derivative at 0)."""
    out = [jnp.ones_like(t)]
    for _ in range(degree):
        out.append(out[-1] * t)
    return out


def _bernstein_combination(tp, sp, degree: int, points: Array) -> Vec:
    """sum_i C(n,i) t^i (1-t)^(n-i) points[i] from precomputed powers, as an explicit sum
    (XLA's CPU dot is slow for such small shapes). The coordinates are split from the
    flattened points: splitting a column (points[..., 0]) first makes XLA materialise it,
    one kernel per column and call, even inside loops."""
    coordinates = jnp.unstack(points.reshape(points.shape[:-2] + (-1,)), axis=-1)
    basis = sp[degree]  # i = 0: binomial(degree, 0) tp[0] = 1
    x, y = basis * coordinates[0], basis * coordinates[1]
    for i in range(1, degree + 1):
        basis = math.comb(degree, i) * tp[i] * sp[degree - i]
        x = x + basis * coordinates[2 * i]
        y = y + basis * coordinates[2 * i + 1]
    return Vec(x, y)


def _rows(coefficients, t: Array) -> Array:
    """`coefficients` (..., rows) as an array (..., rows, 1, ..., 1) that broadcasts
    against t with a leading axis of rows."""
    coefficients = jnp.asarray(coefficients)
    return coefficients.reshape(coefficients.shape + (1,) * t.ndim)


class AbstractCurve(eqx.Module):
    """A closed, regular, twice differentiable curve x: [0, 1) -> R^2 (Eq. 2.1).

    Subclasses implement `components`; everything else derives from it (built-in curves
    also give exact `bounds` and `in_frame` from their parameters).
    """

    @abc.abstractmethod
    def components(self, t: Float[Array, "*shape"]) -> tuple[Vec, Vec, Vec]:
        """(x(t), x'(t), x''(t)) as `Vec`s of arrays shaped like t (the engine's layout).

        At t = 1 the left limits are returned (a closed curve has x(1) = x(0)).
        """

    def bounds(self) -> tuple[Float[Array, "2"], Float[Array, "2"]]:
        """The lower and upper corners of an axis-aligned box about the curve; here that of
        64 of its points (it only sets the engine's frame, `_frame.py`, for which any box
        of about the curve's size and place will do)."""
        x = self.components(jnp.arange(64, dtype=self.dtype) / 64)[0]
        return jnp.stack([x.x.min(), x.y.min()]), jnp.stack([x.x.max(), x.y.max()])

    def in_frame(self, origin: Float[Array, "2"], scale: Float[Array, ""]) -> "AbstractCurve":
        """The same curve in the coordinates (x - origin) / scale (same parameter t); here
        its points mapped after each evaluation."""
        return _CurveInFrame(self, origin, scale)

    def components_left(self, t: Float[Array, "*shape"]) -> tuple[Vec, Vec, Vec]:
        """Left limits of (x, x', x'') at t (they differ from `components` at corners)."""
        return self.components(t)

    def point_and_tangent(self, t: Float[Array, "*shape"]) -> Float[Array, "4 *shape"]:
        """x(t) and x'(t) as the rows (x, y, x', y') of one array, which the engine
        stores (`materialize`).

        Here a stack of `components`, which XLA's CPU backend computes as a branch per
        element (a concatenation). A curve whose rows share costly work computes them as
        one expression instead (`BSplineCurve`).
        """
        x, dx = self.components(t)[:2]
        return jnp.stack([x.x, x.y, dx.x, dx.y])

    def corners(self) -> np.ndarray:
        """Static parameters where x' may jump (corners): none for a smooth curve."""
        return np.zeros(0)

    def bezier_pieces(self) -> Float[Array, "n d1 2"] | None:
        """The curve as n Bezier segments of one degree d, segment j traced for t in
        [j/n, (j+1)/n) as in `PiecewiseCurve` (the same curve, the same parameter), as
        their full control points (n, d + 1, 2), or None for a curve evaluated by its own
        formula: conics; B-splines, whose blending formula is better conditioned for
        their derivatives than differences of their Bezier points; and Bezier curves,
        whose derivatives' control points are formed once per call, not at every point.
        The scene evaluates the curves that have them as one table per degree
        (`Scene`)."""
        return None

    def derivatives(
        self, t: Real[ArrayLike, "*shape"]
    ) -> tuple[Float[Array, "*shape 2"], Float[Array, "*shape 2"], Float[Array, "*shape 2"]]:
        """(x(t), x'(t), x''(t)), each of shape `t.shape + (2,)`."""
        x, dx, ddx = self.components(jnp.asarray(t, self.dtype))
        return x.stack(), dx.stack(), ddx.stack()

    @property
    def dtype(self):
        return jnp.result_type(*jax.tree.leaves(self))

    def panels(self) -> int:
        """Number of uniform quadrature panels [j/P, (j+1)/P) (static); see `breakpoints`."""
        return 4

    def breakpoints(self) -> Float[Array, " b"]:
        """Where the integrals over this curve are cut: t = j/P for the curve's `panels`
        P. They include the seam t = 0 and every parameter where x'' may jump (B-spline
        knots), and keep each panel short enough for Gauss-Legendre quadrature to reach
        ~1e-12 relative error (a degree-n Bezier needs about n panels)."""
        return jnp.arange(self.panels(), dtype=self.dtype) / self.panels()

    def grid_cells(self) -> int:
        """Default number of grid cells for root bracketing (static)."""
        return 16

    def costly_evaluation(self) -> bool:
        """Whether one evaluation of `components` costs more than launching a kernel (a
        long polynomial: hundreds of multiply-adds per point). Newton steps on such a
        curve compute their F once and store it (`materialize`), where XLA would compute
        it again in every update that reads it; on a cheap curve the stored copy's kernels
        cost more than the repeated arithmetic (static)."""
        return False

    def __call__(self, t: Real[ArrayLike, "*shape"]) -> Float[Array, "*shape 2"]:
        return self.derivatives(t)[0]

    def tangent(self, t: Real[ArrayLike, "*shape"]) -> Float[Array, "*shape 2"]:
        """x'(t)."""
        return self.derivatives(t)[1]

    def normal(self, t: Real[ArrayLike, "*shape"]) -> Float[Array, "*shape 2"]:
        """n(t) = [[0, -1], [1, 0]] x'(t) (Eq. 2.3): outward for a clockwise curve."""
        dx = self.tangent(t)
        return jnp.stack([-dx[..., 1], dx[..., 0]], -1)


def _check_regular(curve: AbstractCurve, name: str) -> None:
    """Concrete check that x'(t) never vanishes (a regular parametrisation). Evaluated
    eagerly even while a function that builds the curve from constants is traced."""
    with jax.ensure_compile_time_eval():
        x, dx, _ = curve.derivatives(jnp.linspace(0.0, 1.0, 257))
    speed = np.linalg.norm(np.asarray(dx), axis=-1)
    size = np.ptp(np.asarray(x), axis=0).max()
    if not np.all(speed > 1e-9 * max(size, 1e-300)):
        raise ValueError(
            f"{name} is not regular: x'(t) vanishes (the curve stops or degenerates to a "
            "point). Move the control points apart."
        )


class _CurveInFrame(AbstractCurve):
    """A curve without `in_frame` of its own, in the coordinates (x - origin) / scale."""

    curve: AbstractCurve
    origin: Float[Array, "2"]
    scale: Float[Array, ""]

    def _mapped(self, components):
        x, dx, ddx = components
        to = lambda a: a / self.scale
        return Vec(to(x.x - self.origin[0]), to(x.y - self.origin[1])), dx.map(to), ddx.map(to)

    def components(self, t):
        return self._mapped(self.curve.components(t))

    def components_left(self, t):
        return self._mapped(self.curve.components_left(t))

    def corners(self):
        return self.curve.corners()

    def panels(self):
        return self.curve.panels()

    def breakpoints(self):
        return self.curve.breakpoints()

    def grid_cells(self):
        return self.curve.grid_cells()

    def costly_evaluation(self):
        return self.curve.costly_evaluation()


class BezierCurve(AbstractCurve):
    """Closed Bezier curve of degree n (Eq. 5.4): x(t) = sum_i C(n,i) (1-t)^(n-i) t^i P_i.

    Derivatives use the standard forms (the thesis's Eqs. 5.5, 5.6 are misprinted):
    x' = n sum_i B_{i,n-1}(t) (P_{i+1} - P_i),
    x'' = n(n-1) sum_i B_{i,n-2}(t)(P_{i+2} - 2P_{i+1} + P_i).

    A closed curve needs P_0 == P_n. At the seam t = 0 the tangent directions must agree
    (no corner: the visibility events of a smooth curve would miss one); `seam_continuity`
    tells whether the curve is C1 or C2 there. `BezierCurve.closed_c2` builds a curve that
    is C2 at the seam from free points.

    **Arguments:**

    - `control_points`: shape (n + 1, 2), n >= 3, first == last.
    """

    control_points: Float[Array, "n 2"]

    def __init__(self, control_points: Real[ArrayLike, "n 2"] | Sequence):
        self.control_points = _as_points(control_points, "BezierCurve control_points", 4)

    def bounds(self):
        return _point_bounds(self.control_points)

    def in_frame(self, origin, scale):
        return _points_in_frame(self, lambda c: c.control_points, origin, scale)

    def __check_init__(self):
        p = self.control_points
        if not is_concrete(p):
            return
        p = np.asarray(p)
        scale = max(np.ptp(p, axis=0).max(), 1e-300)
        if np.abs(p[0] - p[-1]).max() > 1e-9 * scale:
            raise ValueError(
                "BezierCurve must be closed: the first control point "
                f"{p[0].tolist()} must equal the last {p[-1].tolist()}. Append the first "
                "point at the end, or build it with BezierCurve.closed_c2(points)."
            )
        start, end = p[1] - p[0], p[-1] - p[-2]
        cross = start[0] * end[1] - start[1] * end[0]
        if np.dot(start, end) <= 0 or abs(cross) > 1e-7 * np.linalg.norm(start) * np.linalg.norm(
            end
        ):
            raise ValueError(
                "BezierCurve has a corner at the seam t = 0: P1 - P0 and Pn - P(n-1) must "
                "point the same way. Use BezierCurve.closed_c2(points) for a curve that is "
                "C2 at the seam."
            )
        _check_regular(self, "BezierCurve")

    @property
    def degree(self) -> int:
        return self.control_points.shape[0] - 1

    def costly_evaluation(self) -> bool:
        # A high degree costs more to evaluate again than to store (the degree-18
        # banana); cubic B-splines and circles are cheaper to evaluate again.
        return self.degree >= 8

    @classmethod
    def closed_c2(cls, points: Real[ArrayLike, "m 2"] | Sequence) -> "BezierCurve":
        """A closed Bezier curve that is C2 at the seam, from m >= 3 free points.

        `points = [S, Q_2, ..., Q_{n-2}]`: S is the seam point P_0 = P_n and the Q are the
        inner control points P_2..P_{n-2} (degree n = m + 2). The two points next to the
        seam are solved for: P_1 = S + (Q_2 - Q_{n-2})/4, P_{n-1} = S - (Q_2 - Q_{n-2})/4,
        which makes x'(0) = x'(1) and x''(0) = x''(1).
        """
        points = _as_points(points, "BezierCurve.closed_c2 points", 3)
        seam, inner = points[0], points[1:]
        offset = (inner[0] - inner[-1]) / 4.0
        full = jnp.concatenate(
            [seam[None], (seam + offset)[None], inner, (seam - offset)[None], seam[None]]
        )
        return cls(full)

    def seam_continuity(self) -> int:
        """Parametric continuity at the seam: 2 (C2), 1 (C1) or 0 (only G1)."""
        p = np.asarray(self.control_points)
        scale = max(np.ptp(p, axis=0).max(), 1e-300) * 1e-9
        if np.abs((p[1] - p[0]) - (p[-1] - p[-2])).max() > scale:
            return 0
        if np.abs((p[2] - 2 * p[1] + p[0]) - (p[-1] - 2 * p[-2] + p[-3])).max() > scale:
            return 1
        return 2

    def components(self, t):
        p = self.control_points
        n = p.shape[0] - 1
        d1 = n * (p[1:] - p[:-1])
        d2 = (n - 1) * (d1[1:] - d1[:-1])
        tp, sp = _powers(t, n), _powers(1.0 - t, n)
        return (
            _bernstein_combination(tp, sp, n, p),
            _bernstein_combination(tp, sp, n - 1, d1),
            _bernstein_combination(tp, sp, n - 2, d2),
        )

    def panels(self):
        return max(4, self.degree)

    def grid_cells(self):
        # Two cells per degree n, and no fewer than a conic's 16. The tangency function
        # cross(x', x - C) is a polynomial of degree 2n - 1: at most 2n - 1 roots on 2n
        # cells, fewer per cell than a cubic B-spline may have on its default grid (5 per
        # knot span on 4 cells). The shadow functions have degree n.
        return max(16, 2 * self.degree)


def _uniform_bspline_blending(degree: int) -> np.ndarray:
    """Coefficients W (p+1, p+1): on one knot span the weight of P_{j-p+s} is
    sum_k W[s, k] tau^k, tau in [0, 1) (the cardinal B-spline N_p on piece p - s)."""
    from numpy.polynomial import Polynomial as Poly

    pieces = [Poly([1.0])]  # N_0 on [0, 1)
    for p in range(1, degree + 1):
        new = []
        for m in range(p + 1):  # piece m of N_p, u = m + tau
            piece = Poly([0.0])
            if m <= p - 1:
                piece = piece + Poly([m / p, 1.0 / p]) * pieces[m]
            if m >= 1:
                piece = piece + Poly([(p + 1 - m) / p, -1.0 / p]) * pieces[m - 1]
            new.append(piece)
        pieces = new
    w = np.zeros((degree + 1, degree + 1))
    for s in range(degree + 1):
        c = pieces[degree - s].coef
        w[s, : len(c)] = c
    return w


class BSplineCurve(AbstractCurve):
    """Periodic uniform B-spline of degree p >= 2 with n > p control points.

    With u = n t: x(t) = sum_i P_i sum_m N_p(u - i + m n), N_p the cardinal B-spline on
    [0, p + 1]. It is C^(p-1) everywhere; the knots t = j/n are its breakpoints.

    **Arguments:**

    - `control_points`: shape (n, 2), not repeated at the end (the curve is periodic).
    - `degree`: polynomial degree p (static), default 3.
    """

    control_points: Float[Array, "n 2"]
    degree: int = eqx.field(static=True)

    def __init__(self, control_points: Real[ArrayLike, "n 2"] | Sequence, degree: int = 3):
        if int(degree) != degree or degree < 2:
            raise ValueError(f"BSplineCurve degree must be an integer >= 2, got {degree}.")
        self.degree = int(degree)
        self.control_points = _as_points(
            control_points, "BSplineCurve control_points", max(self.degree + 1, 3)
        )

    def __check_init__(self):
        if is_concrete(self.control_points):
            _check_regular(self, "BSplineCurve")

    def bounds(self):
        return _point_bounds(self.control_points)

    def in_frame(self, origin, scale):
        return _points_in_frame(self, lambda c: c.control_points, origin, scale)

    def components(self, t):
        first, powers = self._span(t)
        local = [Vec.of(self.control_points[i]) for i in first]

        def combine(coef):
            # Explicit sums: XLA's CPU dot is slow for such small shapes.
            weights = [
                sum(float(coef[s, k]) * powers[k] for k in range(coef.shape[1]))
                for s in range(self.degree + 1)
            ]
            x, y = weights[0] * local[0].x, weights[0] * local[0].y
            for weight, point in zip(weights[1:], local[1:]):
                x = x + weight * point.x
                y = y + weight * point.y
            return Vec(x, y)

        return tuple(combine(w) for w in self._blending())

    def point_and_tangent(self, t):
        # One expression for the four rows, with row-wise blending coefficients
        # (p + 1, p + 1, 4): a stack of `components` would gather the control points and
        # build the powers in each row again.
        first, powers = self._span(t[None])  # (1, *shape) against the rows (4, 1, ..., 1)
        w, dw, _ = self._blending()
        dw = np.pad(dw, ((0, 0), (0, 1)))  # (to the degree of w)
        coefficients = _rows(np.stack([w, w, dw, dw], -1), t)
        of_x = _rows(np.array([True, False, True, False]), t)
        rows = 0.0
        for s, i in enumerate(first):
            weight = sum(coefficients[s, k] * powers[k] for k in range(self.degree + 1))
            local = Vec.of(self.control_points[i])
            rows = rows + weight * jnp.where(of_x, local.x, local.y)
        return rows

    def _span(self, t) -> tuple[list[Array], list[Array]]:
        """At u = n t: the indices of the p + 1 control points of its knot span, and the
        powers [1, tau, ..., tau^p] of tau = u - floor(u)."""
        n, deg = self.control_points.shape[0], self.degree
        u = t * n
        span = jnp.floor(u)
        first = span.astype(jnp.int32) - deg
        return [(first + s) % n for s in range(deg + 1)], _powers(u - span, deg)

    def _blending(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The blending coefficients of x, x' and x'' in t on a knot span (static)."""
        n, deg = self.control_points.shape[0], self.degree
        w = _uniform_bspline_blending(deg)
        dw = w[:, 1:] * np.arange(1, deg + 1) * n
        return w, dw, dw[:, 1:] * np.arange(1, deg) * n

    def panels(self):
        return self.control_points.shape[0]  # the knots t = j/n

    def grid_cells(self):
        return 4 * self.control_points.shape[0]  # four per knot span, aligned with knots


class UnitFrame(NamedTuple):
    """The affine map p -> M (p - c) that takes a conic onto the unit circle, and back:
    M (x(t) - c) = (cos 2 pi t, sin 2 pi t), x(t) = c + M^-1 (cos 2 pi t, sin 2 pi t)."""

    center: Float[Array, "*m 2"]
    to_unit: Float[Array, "*m 2 2"]  # M
    from_unit: Float[Array, "*m 2 2"]  # M^-1 (its singular values: the semi-axes)


class AbstractConic(AbstractCurve):
    """A curve that an affine map takes onto the unit circle, x(t) to (cos 2 pi t,
    sin 2 pi t): circles and ellipses. Tangency and line crossings are preserved by
    affine maps, so their events have closed forms (`_conics.py`)."""

    center: eqx.AbstractVar[Float[Array, "2"]]

    @abc.abstractmethod
    def unit_frame(self) -> UnitFrame:
        """The map onto the unit circle and its inverse."""

    @abc.abstractmethod
    def _lengths(self) -> Array:
        """The field of its lengths (radius, semi-axes), beside its `center`."""

    @abc.abstractmethod
    def as_ellipse(self) -> "Ellipse":
        """The same curve, with the same parameter, as an `Ellipse`: the scene evaluates
        all its conics as one stack of ellipses (`Scene`)."""

    def bounds(self):
        reach = jnp.max(jnp.abs(self._lengths()))  # (|.|: not checked under jit)
        return self.center - reach, self.center + reach

    def in_frame(self, origin, scale):
        return eqx.tree_at(
            lambda c: (c.center, c._lengths()),
            self,
            (to_frame(self.center, origin, scale), self._lengths() / scale),
        )


class Circle(AbstractConic):
    """x(t) = c + r (cos 2 pi t, sin 2 pi t), counter-clockwise."""

    center: Float[Array, "2"]
    radius: Float[Array, ""]

    def __init__(self, center: Real[ArrayLike, "2"] | Sequence, radius: Real[ArrayLike, ""]):
        center = jnp.asarray(center)  # (a list has no dtype to promote)
        self.center = jnp.asarray(center, jnp.result_type(center, float))
        self.radius = jnp.asarray(radius, self.center.dtype)

    def __check_init__(self):
        if self.center.shape != (2,) or self.radius.shape != ():
            raise ValueError("Circle needs center of shape (2,) and a scalar radius.")
        if is_concrete(self.center, self.radius):
            if not (np.all(np.isfinite(self.center)) and np.isfinite(self.radius)):
                raise ValueError("Circle center and radius must be finite.")
            if not self.radius > 0:
                raise ValueError(f"Circle radius must be positive, got {float(self.radius)}.")

    def components(self, t):
        angle = TWO_PI * t
        c, s = jnp.cos(angle), jnp.sin(angle)
        r = self.radius
        w = TWO_PI * r
        return (
            Vec(self.center[0] + r * c, self.center[1] + r * s),
            Vec(-w * s, w * c),
            Vec(-TWO_PI * w * c, -TWO_PI * w * s),
        )

    def unit_frame(self):
        identity = jnp.eye(2, dtype=self.center.dtype)
        return UnitFrame(self.center, identity / self.radius, identity * self.radius)

    def _lengths(self):
        return self.radius

    def as_ellipse(self):
        return Ellipse(self.center, jnp.stack([self.radius, self.radius]))


class Ellipse(AbstractConic):
    """x(t) = c + R(angle) (a cos 2 pi t, b sin 2 pi t), counter-clockwise."""

    center: Float[Array, "2"]
    semi_axes: Float[Array, "2"]
    angle: Float[Array, ""]

    def __init__(
        self,
        center: Real[ArrayLike, "2"] | Sequence,
        semi_axes: Real[ArrayLike, "2"] | Sequence,
        angle: Real[ArrayLike, ""] = 0.0,
    ):
        center = jnp.asarray(center)  # (a list has no dtype to promote)
        self.center = jnp.asarray(center, jnp.result_type(center, float))
        self.semi_axes = jnp.asarray(semi_axes, self.center.dtype)
        self.angle = jnp.asarray(angle, self.center.dtype)

    def __check_init__(self):
        if self.center.shape != (2,) or self.semi_axes.shape != (2,) or self.angle.shape:
            raise ValueError("Ellipse needs center (2,), semi_axes (2,) and a scalar angle.")
        if is_concrete(self.center, self.semi_axes, self.angle):
            leaves = np.concatenate([self.center, self.semi_axes, [self.angle]])
            if not np.all(np.isfinite(leaves)):
                raise ValueError("Ellipse parameters must be finite.")
            if not np.all(self.semi_axes > 0):
                raise ValueError(f"Ellipse semi_axes must be positive, got {self.semi_axes}.")

    def components(self, t):
        angle = TWO_PI * t
        c, s = jnp.cos(angle), jnp.sin(angle)
        a, b = self.semi_axes[0], self.semi_axes[1]
        cos, sin = jnp.cos(self.angle), jnp.sin(self.angle)

        def rotate(u, v):
            return Vec(cos * u - sin * v, sin * u + cos * v)

        local = rotate(a * c, b * s)
        return (
            add(Vec(self.center[0], self.center[1]), local),
            scale(TWO_PI, rotate(-a * s, b * c)),
            scale(-(TWO_PI**2), local),
        )

    def unit_frame(self):
        # M = diag(1/a, 1/b) R(-angle), M^-1 = R(angle) diag(a, b)
        cos, sin = jnp.cos(self.angle), jnp.sin(self.angle)
        rows = jnp.stack([jnp.stack([cos, sin]), jnp.stack([-sin, cos])])
        return UnitFrame(self.center, rows / self.semi_axes[:, None], rows.T * self.semi_axes[None])

    def _lengths(self):
        return self.semi_axes

    def as_ellipse(self):
        return self

    def panels(self):
        return 8


class PiecewiseCurve(AbstractCurve):
    """A closed path of n Bezier segments of one degree d (line segments: d = 1), joined
    end to start, with corners allowed at the joints: polygons, rounded rectangles, the
    closed paths of SVG files. Segment j is traced for t in [j/n, (j+1)/n):

        x(t) = sum_i B_{i,d}(s) P_{j,i},  s = n t - j,  x'(t) = n dx/ds,

    with P_{j,d} = P_{j+1,0}: each segment ends where the next starts (cyclically), so
    the path is closed for any parameter values (and differentiable in them).

    Every joint t = j/n counts as a corner (an event of every camera, a quadrature
    breakpoint, a grid node, and the source of a shadow ray where the line of sight
    leaves the object there); a joint that happens to be smooth only splits intervals.
    Build one with `PiecewiseCurve.polygon(vertices)`, `PiecewiseCurve.from_segments`,
    `PiecewiseCurve.rounded_rectangle`, or `ocp.load_svg`.

    **Arguments:**

    - `points`: shape (n, d, 2): segment j's control points P_{j,0..d-1} (its start
      and inner points; a polygon's vertices as shape (n, 1, 2)).
    """

    points: Float[Array, "n d 2"]

    def __init__(self, points: Real[ArrayLike, "n d 2"] | Sequence):
        points = jnp.asarray(points)
        if not jnp.issubdtype(points.dtype, jnp.floating):
            points = points.astype(jnp.result_type(float))
        if points.ndim != 3 or points.shape[2] != 2 or points.shape[1] < 1:
            raise ValueError(
                f"PiecewiseCurve points must have shape (segments, degree, 2), got {points.shape}."
            )
        if points.shape[0] * points.shape[1] < 3:
            raise ValueError(
                "A closed PiecewiseCurve needs at least 3 control points in all (3 segments "
                f"of lines), got {points.shape[0]} segments of degree {points.shape[1]}."
            )
        if is_concrete(points) and not np.all(np.isfinite(np.asarray(points))):
            raise ValueError("PiecewiseCurve contains NaN or inf; every coordinate must be finite.")
        self.points = points

    def __check_init__(self):
        if is_concrete(self.points):
            _check_regular(self, "PiecewiseCurve")

    def bounds(self):
        return _point_bounds(self.points)

    def in_frame(self, origin, scale):
        return _points_in_frame(self, lambda c: c.points, origin, scale)

    @property
    def control_points(self) -> Float[Array, "n d1 2"]:
        """Every segment's full control points P_{j,0..d}, shape (n, d + 1, 2)."""
        return jnp.concatenate([self.points, jnp.roll(self.points[:, :1], -1, axis=0)], 1)

    @property
    def degree(self) -> int:
        return self.points.shape[1]

    @property
    def segments(self) -> int:
        return self.points.shape[0]

    @classmethod
    def polygon(cls, vertices: Real[ArrayLike, "n 2"] | Sequence) -> "PiecewiseCurve":
        """The closed polygon through `vertices` (n >= 3, not repeated at the end), its
        edges split as in `from_segments`."""
        vertices = _as_points(vertices, "PiecewiseCurve.polygon vertices", 3)
        return cls.from_segments(
            [jnp.stack([v, w]) for v, w in zip(vertices, jnp.roll(vertices, -1, axis=0))]
        )

    @classmethod
    def from_segments(cls, segments) -> "PiecewiseCurve":
        """From a list of Bezier segments, arrays (d_j + 1, 2) of any degrees d_j >= 1
        (a line is [start, end]), each ending where the next starts (checked); all are
        raised to the highest degree, and the longest are split in half until their
        number is a power of two (both exact: the same curve). Power-of-two counts keep
        the scene's common grid, a multiple of every curve's segment count, small."""
        segments = [_as_points(seg, "PiecewiseCurve segment", 2) for seg in segments]
        if is_concrete(*segments):
            ends = np.stack([np.asarray(seg[-1]) for seg in segments])
            starts = np.roll(np.stack([np.asarray(seg[0]) for seg in segments]), -1, axis=0)
            scale = max(np.ptp(np.concatenate(segments), axis=0).max(), 1e-300)
            gap = np.abs(ends - starts).max(axis=1)
            if np.any(gap > 1e-9 * scale):
                j = int(np.argmax(gap))
                raise ValueError(
                    f"PiecewiseCurve is not closed: segment {j} ends at {ends[j].tolist()} "
                    f"but segment {(j + 1) % len(segments)} starts at {starts[j].tolist()}."
                )
        degree = max(seg.shape[0] - 1 for seg in segments)
        segments = _to_power_of_two([_elevate(seg, degree) for seg in segments])
        return cls(jnp.stack([seg[:-1] for seg in segments]))

    @classmethod
    def rounded_rectangle(
        cls,
        center: Real[ArrayLike, "2"] | Sequence,
        width: float,
        height: float,
        radius: float,
    ) -> "PiecewiseCurve":
        """An axis-aligned rectangle with corners rounded by quarter circles of `radius`
        (cubic Bezier arcs, kappa = 4 (sqrt 2 - 1) / 3; relative radius error 3e-4):
        eight segments, the joints between sides and arcs are smooth."""
        cx, cy = (float(v) for v in np.asarray(center, float))
        a, b, r = 0.5 * width, 0.5 * height, float(radius)
        if not 0 < r < min(a, b):
            raise ValueError(f"rounded_rectangle radius must lie in (0, {min(a, b)}), got {r}.")
        k = 4.0 * (math.sqrt(2.0) - 1.0) / 3.0 * r
        segments = []
        for angle in (0.0, 0.5 * math.pi, math.pi, 1.5 * math.pi):  # counter-clockwise
            c, s = round(math.cos(angle)), round(math.sin(angle))
            rot = np.array([[c, -s], [s, c]])
            side_a, side_b = (a, b) if c != 0 else (b, a)
            # The right side (in the rotated frame), then the arc into the top side.
            start = rot @ [side_a, -(side_b - r)]
            end = rot @ [side_a, side_b - r]
            segments.append(np.array([start, end]))
            arc_end = rot @ [side_a - r, side_b]
            segments.append(
                np.array([end, end + rot @ [0.0, k], arc_end + rot @ [k, 0.0], arc_end])
            )
        return cls.from_segments([seg + [cx, cy] for seg in segments])

    def components(self, t):
        return self._components(t, left=False)

    def components_left(self, t):
        return self._components(t, left=True)

    def _components(self, t, left: bool):
        points = self.control_points
        return _segment_components(lambda j: points[j], self.segments, self.degree, t, left)

    def corners(self):
        return np.arange(self.segments) / self.segments

    def bezier_pieces(self):
        return self.control_points

    def panels(self):
        # The foreshortened q on a line at distance a from the camera is the Lorentzian
        # a^2 / (a^2 + y^2): 16 Gauss-Legendre nodes on a panel of half-length h err by
        # about (a/h + sqrt(1 + (a/h)^2))^-32, 1e-19 at a = 2h, 1e-6 at a = h / 2.
        return self.segments * 4

    def grid_cells(self):
        return self.segments * (1 if self.degree == 1 else 4 * self.degree)


def _segment_components(points_of, n, degree: int, t, left: bool) -> tuple[Vec, Vec, Vec]:
    """x, x', x'' (or their left limits) of a closed path of n Bezier segments of one
    `degree`, segment j traced for t in [j/n, (j+1)/n) (`PiecewiseCurve`, `PieceTable`);
    `points_of(j)` gives the full control points of the segments j (an integer array),
    shape j.shape + (degree + 1, 2), and n may be traced."""
    d = degree
    u = t * n
    # A joint is where u is an integer up to rounding (t = j/n need not be exact).
    joint = jnp.round(u)
    at_joint = jnp.abs(u - joint) <= 8 * n * jnp.finfo(u.dtype).eps
    if left:
        segment = jnp.where(at_joint, joint - 1.0, jnp.ceil(u) - 1.0)
    else:
        segment = jnp.where(at_joint, joint, jnp.floor(u))
    segment = jnp.clip(segment, 0, n - 1)
    s = u - segment
    p = points_of(segment.astype(jnp.int32))  # t.shape + (d + 1, 2)
    d1 = (n * d) * (p[..., 1:, :] - p[..., :-1, :])
    sp, tp = _powers(1.0 - s, d), _powers(s, d)
    x = _bernstein_combination(tp, sp, d, p)
    dx = _bernstein_combination(tp, sp, d - 1, d1)
    if d == 1:
        zero = jnp.zeros_like(t)
        return x, dx, Vec(zero, zero)
    d2 = (n * (d - 1)) * (d1[..., 1:, :] - d1[..., :-1, :])
    return x, dx, _bernstein_combination(tp, sp, d - 2, d2)


class PieceTable(AbstractCurve):
    """Row `row` of a table of closed paths of Bezier segments of one degree d
    (`AbstractCurve.bezier_pieces`), each padded to the table's S segments: how the
    scene evaluates its polygons and other `PiecewiseCurve`s, so that curves of one degree
    compile to one evaluation, however many they are and whatever their numbers of
    segments.

    **Arguments:**

    - `table`: (m, S, d + 1, 2), path i's segments, the last repeated past its own.
    - `counts`: (m,), each path's number of segments n_i (segment j is traced for t in
      [j/n_i, (j+1)/n_i)).
    - `row`: which path this is (None: the first; a scene stores its tables so, with
      no integer leaf, which `jax.grad` over a scene would refuse).
    """

    table: Float[Array, "m s d1 2"]
    counts: Float[Array, " m"]
    row: Int[Array, ""] | None = None

    def _components(self, t, left: bool):
        degree = self.table.shape[-2] - 1
        n = self.counts[self._row]
        return _segment_components(lambda j: self.table[self._row, j], n, degree, t, left)

    @property
    def _row(self):
        return 0 if self.row is None else self.row

    def components(self, t):
        return self._components(t, left=False)

    def components_left(self, t):
        return self._components(t, left=True)

    def bounds(self):
        return _point_bounds(self.table[self._row])


def piece_table(pieces: list[Array], dtype) -> tuple[Array, Array]:
    """The `PieceTable` arrays of paths of one degree (their `bezier_pieces`)."""
    width = max(p.shape[0] for p in pieces)
    table = jnp.stack(
        [jnp.pad(p, ((0, width - p.shape[0]), (0, 0), (0, 0)), "edge") for p in pieces]
    )
    return table.astype(dtype), jnp.asarray([p.shape[0] for p in pieces], dtype)


def _elevate(points: Array, degree: int) -> Array:
    """The same Bezier segment with control points of a higher `degree`."""
    while points.shape[0] - 1 < degree:
        n = points.shape[0]  # degree n - 1 -> n
        i = np.arange(1, n)[:, None] / n
        inner = i * points[:-1] + (1.0 - i) * points[1:]
        points = jnp.concatenate([points[:1], inner, points[-1:]])
    return points


def _halve(points: Array) -> tuple[Array, Array]:
    """De Casteljau split of a Bezier segment at its middle (the same curve)."""
    rows = [points]
    while rows[-1].shape[0] > 1:
        rows.append(0.5 * (rows[-1][:-1] + rows[-1][1:]))
    return jnp.stack([r[0] for r in rows]), jnp.stack([r[-1] for r in rows[::-1]])


def _to_power_of_two(segments: list[Array]) -> list[Array]:
    """Split the longest segments in half until their number is a power of two, so that
    the scene's common grid (a multiple of every curve's segment count) stays small."""
    target = 1 << (len(segments) - 1).bit_length()
    segments = list(segments)
    concrete = is_concrete(*segments)
    for split in range(target - len(segments)):
        if concrete:  # the longest control polygon
            lengths = [
                np.linalg.norm(np.diff(np.asarray(s), axis=0), axis=1).sum() for s in segments
            ]
            j = int(np.argmax(lengths))
        else:  # traced points: every other segment from the start
            j = 2 * split
        segments[j : j + 1] = _halve(segments[j])
    return segments
