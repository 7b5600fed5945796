"""The visibility objective Q, its events and its derivatives.

Checked against closed forms (circles, a shadowing pair of circles), the independent
NumPy reference (tests/reference.py), finite differences, and the thesis's closed-form
event derivatives (Eqs. 5.17, 5.28, 5.32).

Compile time: every visibility evaluation goes through a few batched, jitted functions in
helpers.py (one compilation per scene structure and number of cameras); the other
compiled functions of this module are module-level caches used by several tests.
"""

import functools
import math
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.flatten_util import ravel_pytree
from reference import _bisect, eval_curve, reference_visibility, reference_visible_intervals
from scipy import integrate

import helpers as H
import ocp_jax as ocp
from helpers import FS, VL
from ocp_jax import _conics, _events, _occlusion, _roots, _visibility
from ocp_jax._materialize import computed_on_one_thread, materialize
from ocp_jax._vec import Vec

J = np.array([[0.0, -1.0], [1.0, 0.0]])  # n = J x' (the library's Eq. 2.3)
R = np.array([[0.0, 1.0], [-1.0, 0.0]])  # the thesis's matrix in Eqs. 5.14-5.20, 5.29-5.32


def rel(a, b):
    return H.relative_error(a, b)


OPTIONS = ocp.VisibilityOptions()


def grid_cells(scene):
    """The number of grid cells the library uses for `scene` by default."""
    return OPTIONS.grid or scene.grid_cells()


# ===========================================================================
# strict rank promotion (conftest sets jax_numpy_rank_promotion="raise")
# ===========================================================================
def test_grid_brackets_under_rank_promotion_raise():
    t = jnp.linspace(0.0, 1.0, 9)
    values = (t - 0.3)[None]
    brackets = _roots.grid_brackets(t, values, jnp.ones_like(values), 2)
    assert int(brackets.count) == 1


def test_a_sign_change_across_a_cell_is_never_split_away():
    """F = -1 + 2 (1 + 33 t) exp(-30 t) on one cell: F(0) = 1, F'(0) = 6, F(1) = -1,
    F'(1) = -1.8e-10, one root near t = 0.06. The Hermite interpolant's extremum lies at
    s = 0.2 with the value 1.56 (F there is -0.96): split there, the sign change fell in
    [0.2, 1], where F has none, and the root was lost (valid False)."""

    def fn(t, _):
        decay = jnp.exp(-30.0 * t)
        return -1.0 + 2.0 * (1.0 + 33.0 * t) * decay, 2.0 * (3.0 - 990.0 * t) * decay, 1.0

    nodes = jnp.array([0.0, 1.0])
    values, slopes, _ = fn(nodes, None)
    brackets = _roots.grid_brackets(nodes, values[None], slopes[None], 2)
    t, valid, settled = _roots.solve_roots(
        fn, None, brackets, OPTIONS.newton_iterations, 1.0, False
    )
    assert int(brackets.count) == 1 and bool(valid[0]) and bool(settled)
    assert abs(float(fn(t[0], None)[0])) < 1e-14 and 0.05 < float(t[0]) < 0.07


def test_a_pair_the_cubic_predicts_but_f_lacks_holds_no_root():
    """On one cell, F = 1 + (t - 1/2)^2 / 10 > 0 with node slopes -6 and 6 (as where F is
    sampled more coarsely than it bends): the Hermite cubic 1.025 - 6 s + 6 s^2 dips to
    -0.475 at s = 1/2 and predicts a pair of roots there. F has none: neither slot holds
    a root, and the search is done. (The second slot had been confirmed by iterates of
    F's sign, the sign of its grid node: a root reported where F = 1.)"""

    def fn(t, _):
        return 1.0 + 0.1 * (t - 0.5) ** 2, 0.2 * (t - 0.5), jnp.ones_like(t)

    nodes = jnp.array([0.0, 1.0])
    values = fn(nodes, None)[0]
    brackets = _roots.grid_brackets(nodes, values[None], jnp.array([[-6.0, 6.0]]), 2)
    _, valid, settled = _roots.solve_roots(
        fn, None, brackets, OPTIONS.newton_iterations, 1.0, False
    )
    assert int(brackets.count) == 2 and bool(jnp.all(brackets.turning & brackets.candidate))
    assert not bool(jnp.any(valid)) and bool(settled)


# ===========================================================================
# closed forms: one circle
# ===========================================================================
# (center, radius, camera)
CIRCLE_CASES = [
    ((0.0, 0.0), 1.0, (3.0, 0.0)),
    ((0.0, 0.0), 1.0, (1.05, 0.0)),  # very close
    ((1.5, -0.7), 2.0, (1.5 + 5.0 * math.cos(2.0), -0.7 + 5.0 * math.sin(2.0))),
    ((-3.0, 4.0), 0.3, (-3.0 + 40.0 * math.cos(-1.0), 4.0 + 40.0 * math.sin(-1.0))),  # far
    ((0.2, 0.1), 1.7, (2.1, -3.0)),
]


@functools.cache
def circle_results():
    scenes = [H.circle_scene(c, r) for c, r, _ in CIRCLE_CASES]
    cams = np.array([[cam] for _, _, cam in CIRCLE_CASES])
    return H.batched("grads", scenes, cams)


def test_foreshortened_closed_form_is_right():
    """The closed form itself (derived in helpers.foreshortened_antiderivative) against
    adaptive quadrature of r q(phi) and against the NumPy reference."""
    for r, d in ((1.0, 3.0), (2.0, 2.3), (0.3, 40.0), (1.0, 1.05)):
        alpha = math.acos(r / d)

        def integrand(phi):
            return r * (r - d * math.cos(phi)) ** 2 / (r * r + d * d - 2 * r * d * math.cos(phi))

        quad = integrate.quad(integrand, -alpha, alpha, epsabs=0, epsrel=1e-13, limit=200)[0]
        assert abs(H.circle_foreshortened(r, d) / quad - 1) < 1e-12
        ref = reference_visibility(
            [{"type": "circle", "center": np.zeros(2), "radius": r}], np.array([[d, 0.0]]),
            "foreshortened",
        )
        assert abs(H.circle_foreshortened(r, d) / ref - 1) < 1e-12
    # far-camera limit: the half circle seen with q = cos^2 gives r pi / 2 (+ O(r/d))
    assert abs(H.circle_foreshortened(1.0, 1e4) / (math.pi / 2) - 1) < 1e-3


@pytest.mark.parametrize("case", range(len(CIRCLE_CASES)))
def test_circle_closed_forms(case):
    center, r, cam = CIRCLE_CASES[case]
    d = math.dist(center, cam)
    vl, fs, _, _ = circle_results()
    assert abs(vl[case] / H.circle_visible_length(r, d) - 1) <= 1e-12
    assert abs(fs[case] / H.circle_foreshortened(r, d) - 1) <= 1e-7


def test_camera_too_close_for_the_quadrature_raises():
    """At 0.5% of the radius q = cos^2 is too nearly singular for 16 nodes per interval
    (Q would be off by ~1e-4): an error says so; VisibleLength (q = 1) is unaffected."""
    cam = jnp.array([[1.005, 0.0]])
    with pytest.raises(Exception, match="closer to a curve than 0.024 of its radius.*quadrature="):
        ocp.visibility(H.circle_scene(), cam, FS)
    q = ocp.visibility(H.circle_scene(), cam, VL)
    assert abs(float(q) / H.circle_visible_length(1.0, 1.005) - 1) < 1e-12


def test_foreshortened_quadrature_for_a_close_camera():
    """A camera close to a curve makes q = cos^2 nearly singular (poles (d - r) / r from
    the real axis): 16 nodes per panel keep the issue's 1e-7 down to d = 1.05 r
    (test_circle_closed_forms), and `VisibilityOptions(quadrature=...)` buys the rest."""
    opts = ocp.VisibilityOptions(quadrature=32)
    fn = jax.jit(lambda s, c: ocp.visibility(s, c, FS, opts))
    for d, tol in ((1.05, 1e-13), (1.01, 1e-9)):
        q = fn(H.circle_scene(), jnp.array([[d, 0.0]]))
        assert abs(float(q) / H.circle_foreshortened(1.0, d) - 1) <= tol


def test_close_camera_anywhere_along_a_circle():
    """A camera-dependent q is nearly singular at the point nearest to a close camera:
    Q's intervals are cut there, so the calibration of the too-close threshold (~1e-7 at
    (2.5 / 16)^2 of the radius) holds wherever that point lies, not only at a panel
    breakpoint (at 1.3 r, t = 0.09, the uncut quadrature was off by 7e-6)."""
    fn = jax.jit(lambda c: ocp.visibility(H.circle_scene(), c, FS))
    for d, tol in ((1.03, 1e-7), (1.05, 3e-8), (1.1, 1e-9), (1.3, 1e-12)):
        for t in (0.0, 0.02, 0.04, 0.09, 0.61):
            cam = d * np.array([[math.cos(2 * math.pi * t), math.sin(2 * math.pi * t)]])
            assert abs(float(fn(jnp.asarray(cam))) / H.circle_foreshortened(1.0, d) - 1) <= tol


def test_close_camera_in_the_middle_of_a_panel_of_the_banana():
    """The same for the banana's Bezier (nearest points by Newton from the grid): a camera
    at 4% of the banana's radius from the middle of one of its 18 panels, against the
    NumPy reference (1e-8)."""
    banana = H.BANANA.curves[0]
    dense = np.asarray(banana(np.linspace(0, 1, 4001)))
    area = np.sum(dense[:-1, 0] * dense[1:, 1] - dense[:-1, 1] * dense[1:, 0])
    radius = np.linalg.norm(dense - dense.mean(0), axis=1).max()
    t = 6.5 / 18
    x, dx = (np.asarray(a) for a in banana.derivatives(t)[:2])
    outward = np.sign(area) * np.array([dx[1], -dx[0]]) / np.linalg.norm(dx)
    cam = (x + 0.04 * radius * outward)[None]
    q = jax.jit(lambda c: ocp.visibility(H.BANANA, c, FS))(jnp.asarray(cam))
    ref = reference_visibility(H.to_reference(H.BANANA), cam, "foreshortened")
    assert rel(q, ref) < 1e-8


@functools.cache
def visible_length_of(name):
    """VisibleLength of `name`'s scene for a batch of single cameras, jitted once."""
    return jax.jit(jax.vmap(lambda c: ocp.visibility(H.SCENES[name], c[None], VL)))


def test_a_camera_beside_the_banana_sees_the_arc_in_front_of_it():
    """A camera close to a curve sees a short arc between two tangency times, closer
    together than the grid resolves: the camera's nearest point, where F = cross(x', x -
    C) has the sign opposite to both ends of its cell, is an extra node of the tangency
    search. Before it, cameras 1e-5 to 1e-3 (2e-7 to 2e-5 of the banana's length) from
    these convex arcs saw nothing (VisibleLength 0, the reference 0.015 to 0.45); with it
    and 8 Newton steps (the default until then), those at 1e-5 were off by up to 1.4e-5:
    their roots beside the extra node are reached by bisection. The last camera, 2 along
    a tangent line near an inflection, lies 1.9e-4 from the curve, which has three
    tangency times in one cell: beyond the extra node F first rises, then dips past a
    pair of them, and the cell's interpolant has two extrema; only one taken into
    account, the pair was missed (Q 7% too large)."""
    spec = H.to_reference(H.BANANA)[0]
    beside = H.cameras_beside(spec, np.array([0.0165, 0.2698, 0.9808]), (1e-3, 3e-4, 1e-4, 1e-5))
    x, dx, _ = eval_curve(spec, 15 / 36 - 1e-5)
    cams = [*beside, x - 2.0 * dx / np.linalg.norm(dx)]
    q = visible_length_of("banana")(jnp.asarray(cams))
    ref = [reference_visibility([spec], c[None], "visible_length") for c in cams]
    assert min(ref) > 0.01
    assert np.max(np.abs(np.asarray(q) / np.array(ref) - 1)) < 1e-9


def test_a_camera_beside_the_kidney_sees_past_the_bend_behind_it():
    """Cameras 1e-2 to 1e-6 from the concave side of the kidney (three_objects): a line
    of sight to a point of the kidney crosses it again just behind the camera, where the
    curve passes close by it. Interpolated linearly across the grid cell there, that
    crossing's depth (x - C) . d came out positive, in front of the camera (on the hand
    case, +1.3e-4 for -1.2e-5), and the point was taken for hidden: of cameras beside
    400 points of the kidney, 5 at 1e-2, 72 at 1e-3 and 81 at 1e-5 (all on the arc t in
    [0.63, 0.85]) were off by 36% to all of it (VisibleLength 0). The camera's nearest
    point is now a node of the occlusion test too: beside it, a cell's interpolation
    errs by O(the camera's distance)."""
    specs = H.to_reference(H.THREE)
    t = np.array([0.6375, 0.6525, 0.7025, 0.71, 0.7325, 0.76, 0.79, 0.8125, 0.8275, 0.845])
    cams = H.cameras_beside(specs[0], t, (1e-2, 1e-3, 1e-5, 1e-6))
    q = visible_length_of("three")(jnp.asarray(cams))
    ref = [reference_visibility(specs, c[None], "visible_length") for c in cams]
    assert min(ref) > 1.0
    assert np.max(np.abs(np.asarray(q) / np.array(ref) - 1)) < 1e-9


def test_a_nearest_point_one_ulp_before_a_corner_counts_as_the_corner():
    """The camera's nearest point on a polygon is often a corner, which the nearest-point
    search may reach from the piece before it: t* = 0.75 - 1 ulp on the unit square. A
    polygon evaluated there gives the next edge's x' (as at the corner), so as an extra
    node of the camera's grid its F = cross(x', x - C) had the next edge's sign, the
    cell before it a sign change of F (constant on an edge) and the tangency search a
    root at 0.75 - 1e-12 that is none (its Newton steps never settled). t* within 1e4
    eps of a node counts as the node: the extra node is the midpoint of its cell."""
    square = ocp.PiecewiseCurve.polygon(jnp.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]))
    scene = ocp.Scene([square])
    samples = _events.sample(scene, grid_cells(scene))
    camera = Vec(jnp.array(1.0), jnp.array(2.0))  # the corner (0, 1) a silhouette corner
    cells = samples.t.shape[0] - 1
    grid = _events.with_nearest_node(scene, samples, jnp.array([np.nextafter(0.75, 0.0)]))
    assert float(grid.t[0, round(0.75 * cells)]) == 0.75 - 0.5 / cells
    tangents = _events.tangency_times(
        scene, camera, grid, OPTIONS.max_tangents, OPTIONS.newton_iterations
    )
    assert not np.any(tangents.valid)


def test_gradient_where_a_tangency_time_meets_a_panel_breakpoint():
    """A camera on an axis-aligned tangent line of a circle touches it at a panel
    breakpoint (t = 0, 1/2, 3/4). The zero-length interval between the tie's two pieces is
    looked up on the tangency's near side, so dQ/dC equals central differences (before,
    VisibleLength's was (0.2, 0.267) at (3, -1) against (0.2, -0.067))."""
    value_and_grad = jax.value_and_grad(lambda c, s: ocp.visibility(H.circle_scene(), c, s))
    fn = jax.jit(value_and_grad, static_argnums=1)
    for objective in (VL, FS):
        for cam in ([3.0, -1.0], [1.0, 3.0], [-1.0, -2.0]):
            cam = jnp.asarray([cam])
            grad = fn(cam, objective)[1]
            fd = H.central_differences(lambda c: fn(c, objective)[0], cam, 1e-6)
            assert rel(grad, fd) < 1e-7


@pytest.mark.parametrize("case", range(len(CIRCLE_CASES)))
def test_circle_gradients_closed_form(case):
    """dQ/d(camera, centre, radius) against the derivatives of the closed forms."""
    center, r, cam = CIRCLE_CASES[case]
    _, _, gvl, gfs = circle_results()
    center, cam = np.asarray(center), np.asarray(cam)
    d = np.linalg.norm(cam - center)
    e = (cam - center) / d
    # visible length 2 r acos(r/d): d/dd = 2 r^2 / (d sqrt(d^2 - r^2)),
    # d/dr = 2 acos(r/d) - 2 r / sqrt(d^2 - r^2)
    dd = 2 * r * r / (d * math.sqrt(d * d - r * r))
    dr = 2 * math.acos(r / d) - 2 * r / math.sqrt(d * d - r * r)
    (scene_g, cam_g) = gvl
    assert rel(cam_g[case, 0], dd * e) < 1e-10
    assert rel(scene_g.curves[0].center[case], -dd * e) < 1e-10
    assert abs(scene_g.curves[0].radius[case] - dr) < 1e-10 * max(1.0, abs(dr))

    # foreshortened: autodiff of the closed form (independent of the library)
    def closed(c, radius, camera):
        return H.circle_foreshortened(radius, jnp.linalg.norm(camera - c), xp=jnp)

    want = jax.grad(closed, argnums=(0, 1, 2))(jnp.asarray(center), jnp.asarray(r), jnp.asarray(cam))
    # (1e-6: the quadrature error of Q at d = 1.05 r carries over to dQ)
    (scene_g, cam_g) = gfs
    assert rel(cam_g[case, 0], want[2]) < 1e-6
    assert rel(scene_g.curves[0].center[case], want[0]) < 1e-6
    assert abs(scene_g.curves[0].radius[case] - want[1]) < 1e-6 * max(1.0, abs(float(want[1])))


# ===========================================================================
# closed forms: a small circle shadowing a big one
# ===========================================================================
def two_circles_closed_form(C, cb, R_, cs, r, xp=np):
    """(visible length, foreshortened Q) of a big circle (cb, R_) partly shadowed by a
    small circle (cs, r) in front of it, seen from C. The shadow is the arc of the big
    circle between the first hits of the two rays from C tangent to the small circle."""
    C, cb, cs = (xp.asarray(v) for v in (C, cb, cs))

    def norm(v):
        return xp.sqrt(v[0] * v[0] + v[1] * v[1])

    ds = norm(C - cs)
    v = C - cb
    db = norm(v)
    alpha = xp.arccos(R_ / db)  # the big circle's visible half-angle
    base = xp.arctan2(v[1], v[0])
    w = cs - C
    psi0, beta = xp.arctan2(w[1], w[0]), xp.arcsin(r / ds)
    phis, checks = [], []
    for psi in (psi0 - beta, psi0 + beta):
        u0, u1 = xp.cos(psi), xp.sin(psi)
        b = u0 * v[0] + u1 * v[1]
        disc = b * b - (db * db - R_ * R_)
        lam = -b - xp.sqrt(disc)  # first hit of C + lam u on the big circle
        y0, y1 = v[0] + lam * u0, v[1] + lam * u1
        phi = xp.arctan2(y1, y0) - base
        phis.append((phi + math.pi) % (2 * math.pi) - math.pi)
        checks.append((disc, lam))
    p1, p2 = xp.minimum(phis[0], phis[1]), xp.maximum(phis[0], phis[1])
    G = H.foreshortened_antiderivative
    vl = R_ * (2 * alpha - (p2 - p1)) + 2 * r * xp.arccos(r / ds)
    fs = (G(p1, R_, db, xp) - G(-alpha, R_, db, xp)) + (G(alpha, R_, db, xp) - G(p2, R_, db, xp))
    fs = fs + H.circle_foreshortened(r, ds, xp)
    return vl, fs, (p1, p2, alpha, checks)


# (camera, big centre, big radius, small centre, small radius)
TWO_CIRCLE_CASES = [
    ((7.0, 0.3), (0.0, 0.0), 2.0, (4.0, 0.0), 0.6),
    ((-3.0, 5.0), (1.0, -1.0), 1.5, (-0.9, 1.8), 0.35),
    ((2.0, 6.0), (0.5, 0.0), 1.2, (1.5, 3.0), 0.3),
]


@functools.cache
def two_circle_results():
    scenes = [H.two_circles(cb, R_, cs, r) for _, cb, R_, cs, r in TWO_CIRCLE_CASES]
    cams = np.array([[C] for C, *_ in TWO_CIRCLE_CASES])
    return H.batched("grads", scenes, cams)


@pytest.mark.parametrize("case", range(len(TWO_CIRCLE_CASES)))
def test_two_circles_shadow_closed_form(case):
    C, cb, R_, cs, r = TWO_CIRCLE_CASES[case]
    vl_want, fs_want, (p1, p2, alpha, checks) = two_circles_closed_form(C, cb, R_, cs, r)
    # preconditions of the closed form: both tangent rays hit the big circle in front of
    # the camera, and the whole shadow lies inside its visible arc
    assert all(disc > 0 and lam > 0 for disc, lam in checks)
    assert -alpha < p1 < p2 < alpha
    vl, fs, _, _ = two_circle_results()
    assert abs(vl[case] / vl_want - 1) <= 1e-12
    assert abs(fs[case] / fs_want - 1) <= 1e-11
    # and the reference agrees with the hand computation
    spec = H.to_reference(H.two_circles(cb, R_, cs, r))
    assert abs(reference_visibility(spec, np.array([C]), "visible_length") / vl_want - 1) < 1e-12
    assert abs(reference_visibility(spec, np.array([C]), "foreshortened") / fs_want - 1) < 1e-12


@pytest.mark.parametrize("case", range(len(TWO_CIRCLE_CASES)))
def test_two_circles_gradients_closed_form(case):
    """Shadow times move with the camera and both circles: dQ against autodiff of the
    closed form, for every parameter."""
    C, cb, R_, cs, r = (jnp.asarray(v, jnp.float64) for v in TWO_CIRCLE_CASES[case])
    _, _, gvl, gfs = two_circle_results()
    for index, grads in ((0, gvl), (1, gfs)):

        def closed(C, cb, R_, cs, r):
            return two_circles_closed_form(C, cb, R_, cs, r, xp=jnp)[index]

        want = jax.grad(closed, argnums=(0, 1, 2, 3, 4))(C, cb, R_, cs, r)
        scene_g, cam_g = grads
        big, small = scene_g.curves
        got = (cam_g[case, 0], big.center[case], big.radius[case], small.center[case],
               small.radius[case])
        flat_got = np.concatenate([np.ravel(g) for g in got])
        flat_want = np.concatenate([np.ravel(np.asarray(g)) for g in want])
        assert rel(flat_got, flat_want) < 1e-9, (index, flat_got, flat_want)


# ===========================================================================
# the NumPy reference on non-convex scenes with several objects
# ===========================================================================
# scenes whose (k) batch also yields gradients (used by the finite-difference tests)
GRAD_SETS = {("three", 2), ("mixed", 1)}
# Cameras nearly on an inflection tangent line (helpers.near_double_camera arguments:
# scene, curve, inflection, distance along the line, side, separation of the two roots).
# Of three_objects' kidney B-spline:
KIDNEY_NEAR_DOUBLE = [("three", 0, 1, 4.0, 1, 0.004), ("three", 0, 1, 4.0, 1, 0.001)]
# of the banana's two inflections (cameras inside the thesis's rectangle):
BANANA_NEAR_DOUBLE = [
    ("banana", 0, 0, -30.0, 1, 0.004),
    ("banana", 0, 1, 30.0, 1, 0.004),
    ("banana", 0, 0, -30.0, 1, 0.002),
    ("banana", 0, 0, -30.0, 1, 0.001),
]


def camera_sets(name, k):
    sets = np.asarray(H.CAMERAS[name][k], float).reshape(-1, k, 2)
    if (name, k) == ("three", 1):
        extra = [H.near_double_camera(*args)[0] for args in KIDNEY_NEAR_DOUBLE]
        sets = np.concatenate([sets, np.asarray(extra)[:, None]])
    return sets


@functools.cache
def scene_results(name, k):
    """(camera sets, outputs) of the shared batched function for this scene and k."""
    if name == "banana":
        extra = [H.near_double_camera(*args)[0] for args in BANANA_NEAR_DOUBLE]
        cams = np.concatenate([np.asarray(H.BANANA_CAMERAS), extra])[:, None]
    else:
        cams = camera_sets(name, k)
    kind = "grad" if (name, k) in GRAD_SETS else "values"
    return cams, H.batched(kind, H.SCENES[name], cams)


@functools.cache
def reference_values(name, k, i):
    cams, _ = scene_results(name, k)
    spec = H.to_reference(H.SCENES[name])
    return (reference_visibility(spec, cams[i], "visible_length"),
            reference_visibility(spec, cams[i], "foreshortened"))


REFERENCE_CASES = [
    (name, k, i)
    for name in ("three", "blobs3", "mixed")
    for k in (1, 2, 3)
    for i in range(len(H.CAMERAS[name][k]))
]


def _inside_or_near(spec_list, point, margin):
    """True if `point` is inside a curve (winding number of a dense polygon) or closer
    than `margin` to it."""
    t = np.linspace(0, 1, 4001)
    for spec in spec_list:
        x = eval_curve(spec, t)[0] - point
        ang = np.arctan2(x[1:, 1] * x[:-1, 0] - x[1:, 0] * x[:-1, 1], (x[1:] * x[:-1]).sum(-1))
        if abs(ang.sum()) > np.pi or np.linalg.norm(x, axis=-1).min() < margin:
            return True
    return False


def test_test_cameras_are_outside_every_object(reference_specs):
    for name in ("three", "blobs3", "mixed", "banana"):
        spec = reference_specs[name]
        cams = [scene_results(name, 1)[0].reshape(-1, 2)] if name == "banana" else [
            camera_sets(name, k).reshape(-1, 2) for k in (1, 2, 3)
        ]
        for cam in np.concatenate(cams):
            assert not _inside_or_near(spec, cam, 0.1), (name, cam)


@pytest.mark.parametrize("name,k,i", REFERENCE_CASES, ids=[f"{n}-k{k}-{i}" for n, k, i in REFERENCE_CASES])
def test_matches_reference(name, k, i):
    cams, out = scene_results(name, k)
    vl, fs = out[0][i], out[1][i]
    ref_vl, ref_fs = reference_values(name, k, i)
    assert abs(vl / ref_vl - 1) <= 1e-7, (vl, ref_vl)
    assert abs(fs / ref_fs - 1) <= 1e-7, (fs, ref_fs)


# the cameras on the rectangle (the near-double ones: test_near_double_roots_banana)
BANANA_Q_CASES = range(len(H.BANANA_CAMERAS))


def test_banana_cameras_on_the_thesis_rectangle():
    (cx, cy), w, h = ocp.scenes.BANANA_RECTANGLE
    for x, y in H.BANANA_CAMERAS:
        assert (abs(abs(x - cx) - w / 2) < 1e-12 and abs(y - cy) <= h / 2) or (
            abs(abs(y - cy) - h / 2) < 1e-12 and abs(x - cx) <= w / 2
        )


@pytest.mark.parametrize("i", BANANA_Q_CASES)
def test_banana_matches_reference(i):
    cams, (vl, fs) = scene_results("banana", 1)
    ref_vl, ref_fs = reference_values("banana", 1, i)
    assert abs(vl[i] / ref_vl - 1) <= 1e-7, (vl[i], ref_vl)
    assert abs(fs[i] / ref_fs - 1) <= 1e-7, (fs[i], ref_fs)


def test_multi_camera_bounds():
    """Q of a camera set lies between the best single camera and the sum of all (for
    both objectives: the integrand is a max over the cameras)."""
    for name in ("three", "blobs3", "mixed"):
        cams1, out1 = scene_results(name, 1)
        singles = {tuple(c[0]): (out1[0][i], out1[1][i]) for i, c in enumerate(cams1)}
        checked = 0
        for k in (2, 3):
            cams, out = scene_results(name, k)
            for i, cam_set in enumerate(cams):
                if not all(tuple(c) in singles for c in cam_set):
                    continue
                checked += 1
                for obj in (0, 1):
                    parts = [singles[tuple(c)][obj] for c in cam_set]
                    assert max(parts) * (1 - 1e-12) <= out[obj][i] <= sum(parts) * (1 + 1e-12)
                    # several cameras see more than the best one of them here
                    assert out[obj][i] > max(parts) * (1 + 1e-6)
        assert checked >= 2, name


def test_duplicated_cameras_count_once():
    """Two cameras at the same place see what one sees (q_a - q_b vanishes identically:
    no spurious crossover events, no exceeded budget)."""
    cams, out = scene_results("three", 1)
    dup = np.repeat(cams[:2], 2, axis=1)  # (2, 2, 2): [[A, A], [B, B]]
    vl, fs, _ = H.batched("grad", H.THREE, dup)
    np.testing.assert_allclose(vl, out[0][:2], rtol=1e-12)
    np.testing.assert_allclose(fs, out[1][:2], rtol=1e-12)


# ===========================================================================
# visible intervals
# ===========================================================================
@functools.cache
def intervals_of(name):
    if name == "banana":
        cams, _ = scene_results("banana", 1)
    else:
        cams = camera_sets(name, 1)
    fn = jax.jit(jax.vmap(ocp.visible_intervals, in_axes=(None, 0)))
    out = fn(H.SCENES[name], jnp.asarray(cams))
    return cams, [H.unstack_tree(out, i) for i in range(cams.shape[0])]


def _compare_intervals(name, i, atol=1e-9):
    cams, ivs = intervals_of(name)
    spec = H.to_reference(H.SCENES[name])
    ref = reference_visible_intervals(spec, cams[i, 0])
    for curve, want in enumerate(ref):
        got = ivs[i].to_list(0, curve)
        assert len(got) == len(want), (curve, got, want)
        if want:
            np.testing.assert_allclose(np.array(got), np.array(want), rtol=0, atol=atol)
    return ivs[i], ref


@pytest.mark.parametrize("i", range(len(H.CAMERAS["three"][1])))
def test_visible_intervals_match_reference(i):
    iv, ref = _compare_intervals("three", i)
    assert iv.start.shape == iv.end.shape == iv.visible.shape
    assert iv.start.shape[:2] == (1, 3)
    assert np.all(np.asarray(iv.tangents.count) >= 2)  # every closed curve has silhouettes


@pytest.mark.parametrize(
    "name",
    ["three", "banana"],
)
def test_visible_intervals_partition_and_agree_with_q(name, reference_specs):
    """The intervals tile [0, 1] per curve, and integrating |x'| over the visible ones
    (adaptive quadrature) gives the visible length Q."""
    cams, ivs = intervals_of(name)
    _, (vl, _) = scene_results(name, 1)
    for i, iv in enumerate(ivs):
        start, end = np.asarray(iv.start[0]), np.asarray(iv.end[0])
        np.testing.assert_array_equal(start[:, 1:], end[:, :-1])
        assert np.all(start[:, 0] == 0.0) and np.all(end[:, -1] == 1.0)
        assert np.all(end >= start)
        total = 0.0
        for curve, spec in enumerate(reference_specs[name]):
            for a, b in iv.to_list(0, curve):
                total += integrate.quad(
                    lambda t: np.linalg.norm(eval_curve(spec, np.array(t))[1]), a, b,
                    epsabs=1e-13, epsrel=1e-13, limit=200,
                )[0]
        assert abs(vl[i] / total - 1) < 1e-9, (i, vl[i], total)


# ===========================================================================
# near-double roots
# ===========================================================================
def _assert_near_double(args):
    camera, (t1, t2) = H.near_double_camera(*args)
    # precondition: two tangency roots inside one cell of the library's default grid
    cells = grid_cells(H.SCENES[args[0]])
    assert 0 < t2 - t1 < 1 / cells and math.floor(cells * t1) == math.floor(cells * t2)
    # ...and one of them is an end of a visible arc, so missing the pair changes Q
    spec = H.to_reference(H.SCENES[args[0]])
    ends = np.array([v for iv in reference_visible_intervals(spec, camera)[args[1]] for v in iv])
    assert min(np.abs(ends - t1).min(), np.abs(ends - t2).min()) < 1e-9
    return camera, (t1, t2)


@pytest.mark.parametrize("j", range(len(KIDNEY_NEAR_DOUBLE)))
def test_near_double_roots_kidney_bspline(j):
    _assert_near_double(KIDNEY_NEAR_DOUBLE[j])
    cams, (vl, fs) = scene_results("three", 1)
    i = len(H.CAMERAS["three"][1]) + j
    ref_vl, ref_fs = reference_values("three", 1, i)
    assert abs(vl[i] / ref_vl - 1) <= 1e-7
    assert abs(fs[i] / ref_fs - 1) <= 1e-7
    _compare_intervals("three", i)


@pytest.mark.parametrize("j", range(len(BANANA_NEAR_DOUBLE)))
def test_near_double_roots_banana(j):
    _assert_near_double(BANANA_NEAR_DOUBLE[j])
    _compare_intervals("banana", len(H.BANANA_CAMERAS) + j)


def test_banana_visible_intervals_match_reference():
    for i in range(len(H.BANANA_CAMERAS)):
        _compare_intervals("banana", i)


# ===========================================================================
# gradients against finite differences
# ===========================================================================
def fd_gradient(name, k, i, step=1e-4):
    """Fourth-order central differences of (VisibleLength, Foreshortened) in every scene
    parameter and camera coordinate, evaluated as batch members of the shared function."""
    scene = H.SCENES[name]
    cams = camera_sets(name, k)[i]
    flat, unravel = ravel_pytree((scene, jnp.asarray(cams)))
    flat = np.asarray(flat)
    h = step * np.maximum(1.0, np.abs(flat))
    points = []
    for j in range(flat.size):
        for m in (1, -1, 2, -2):
            p = flat.copy()
            p[j] += m * h[j]
            points.append(unravel(jnp.asarray(p)))
    scenes = [p[0] for p in points]
    cam_sets = np.stack([np.asarray(p[1]) for p in points])
    vl, fs, _ = H.batched("grad", scenes, cam_sets)
    out = []
    for values in (vl, fs):
        v = values.reshape(flat.size, 4)
        out.append((8 * (v[:, 0] - v[:, 1]) - (v[:, 2] - v[:, 3])) / (12 * h))
    return flat.size, out[1]


@pytest.mark.parametrize("name,k,i", [("three", 2, 0), ("three", 2, 1), ("mixed", 1, 0), ("mixed", 1, 1)])
def test_gradient_matches_finite_differences(name, k, i):
    cams, (vl, fs, grads) = scene_results(name, k)
    grad = H.unstack_tree(grads, i)
    flat_grad, _ = ravel_pytree((grad[0], jnp.asarray(grad[1])))
    flat_grad = np.asarray(flat_grad)
    n, fd = fd_gradient(name, k, i)
    n_cam = 2 * k
    assert rel(flat_grad, fd) < 1e-6
    assert rel(flat_grad[-n_cam:], fd[-n_cam:]) < 1e-6  # the cameras alone
    assert rel(flat_grad[:-n_cam], fd[:-n_cam]) < 1e-6  # the scene alone
    assert np.linalg.norm(flat_grad[-n_cam:]) > 1e-3 and np.linalg.norm(flat_grad[:-n_cam]) > 1e-3


# ===========================================================================
# transformations: jit, vmap, grad, jacfwd, float32
# ===========================================================================
def _single(scene, cameras):
    """Q, reverse-mode and forward-mode derivatives of one (unbatched) evaluation."""

    def q(s, c):
        return ocp.visibility(s, c, FS)

    value, grad = jax.value_and_grad(q, (0, 1))(scene, cameras)
    return value, grad, jax.jacfwd(q, (0, 1))(scene, cameras)


single = jax.jit(_single)


def test_vmap_equals_loop_of_single_evaluations():
    """Values and gradients of the vmapped batch equal one jitted evaluation per camera
    set (grad under vmap included)."""
    cams, (vl, fs, grads) = scene_results("three", 2)
    for i, cam_set in enumerate(cams):
        value, grad, _ = single(H.THREE, jnp.asarray(cam_set))
        assert abs(float(value) / fs[i] - 1) < 1e-13
        assert rel(ravel_pytree(grad)[0], ravel_pytree(H.unstack_tree(grads, i))[0]) < 1e-12


def test_jacfwd_equals_grad():
    cams, _ = scene_results("three", 2)
    for cam_set in cams:
        _, grad, jac = single(H.THREE, jnp.asarray(cam_set))
        assert rel(ravel_pytree(jac)[0], ravel_pytree(grad)[0]) < 1e-12


def test_float32():
    scene32 = H.to_float32(H.THREE)
    assert scene32.dtype == jnp.float32
    cams, (vl64, fs64) = scene_results("three", 1)
    n = len(H.CAMERAS["three"][1])
    vl, fs = H.batched("values", scene32, np.asarray(cams[:n], np.float32))
    assert vl.dtype == np.float32 and fs.dtype == np.float32
    np.testing.assert_allclose(vl, vl64[:n], rtol=1e-4)
    np.testing.assert_allclose(fs, fs64[:n], rtol=1e-4)


# ===========================================================================
# the scene's frame: units and place do not matter (`_frame.py`)
# ===========================================================================
# `THREE` with a triangle (a polygon's corners and straight edges), two cameras
TRIANGLE = ocp.PiecewiseCurve.polygon(jnp.array([[2.0, -2.5], [3.5, -1.5], [2.2, -1.0]]))
FRAME_SCENE = ocp.Scene([*H.THREE.curves, TRIANGLE])
FRAME_CAMERAS = np.array([[5.0, 4.0], [-1.4, 2.2]])


@jax.jit
def _frame_values(scene, cams):
    """Visible length, foreshortened Q and its gradient in the cameras."""
    foreshortened, grad = jax.value_and_grad(lambda c: ocp.visibility(scene, c, FS))(cams)
    return ocp.visibility(scene, cams, VL), foreshortened, grad


def _scaled(factor, dtype):
    """FRAME_SCENE and FRAME_CAMERAS scaled by `factor` about the origin, in `dtype`."""
    scene = jax.tree.map(lambda a: jnp.asarray(a, dtype), FRAME_SCENE)
    scene = scene.in_frame(jnp.zeros(2, dtype), jnp.asarray(1.0 / factor, dtype))
    return scene, jnp.asarray(FRAME_CAMERAS * factor, dtype)


@pytest.mark.parametrize("power", [-24, 24])
def test_a_scene_scaled_by_a_power_of_two_gives_bitwise_the_same_q_in_float32(power):
    """In the scene's frame a scene scaled by 2^j is bitwise the scene: Q scales by 2^j,
    its gradient in the cameras not at all. Computed in the user's units, float32 lost
    the products of lengths to underflow and overflow (benchmarks/scene_scale.py, before:
    at 2^-30 Q 52% short and its gradient NaN; at 2^30 VisibleLength 0.1% off and
    Foreshortened NaN). Both parameters fail on the code before."""
    unit = _frame_values(*_scaled(1.0, jnp.float32))
    scaled = _frame_values(*_scaled(2.0**power, jnp.float32))
    assert unit[0] > 0.5 and unit[1] > 0.3  # (the scene is seen)
    assert float(scaled[0]) == float(unit[0]) * 2.0**power
    assert float(scaled[1]) == float(unit[1]) * 2.0**power
    np.testing.assert_array_equal(scaled[2], unit[2])


@pytest.mark.parametrize("factor", [1e-6, 1e6])
def test_float32_q_of_tiny_and_huge_scenes_matches_float64(factor):
    """Not a power of two: float32 rounds the scaled scene, and Q stays within float32's
    accuracy of the float64 Q of the unscaled scene."""
    value64 = _frame_values(*_scaled(1.0, jnp.float64))
    value32 = _frame_values(*_scaled(factor, jnp.float32))
    for i in (0, 1):
        assert abs(float(value32[i]) / factor / float(value64[i]) - 1) < 2e-6
    assert rel(np.asarray(value32[2], np.float64), value64[2]) < 1e-5


def test_lengths_of_objectives_and_cameras_scale_with_the_scene():
    """Reconstruction's area (a length squared), a camera's range and the signed
    distances scale with the scene: scaled by 2^-20 with them, Q and the distances
    scale by 2^-20 exactly (in the frame both are the unscaled problem)."""
    factor = 2.0**-20

    def problem(c):
        scene, cams = _scaled(c, jnp.float64)
        return scene, ocp.Camera(cams, range=5.0 * c), ocp.Reconstruction(area=0.01 * c * c)

    values = [
        (
            float(ocp.visibility(*problem(c))),
            np.asarray(_visibility.signed_distances(problem(c)[0], jnp.asarray(FRAME_CAMERAS * c))),
        )
        for c in (1.0, factor)
    ]
    assert 0.5 < values[0][0] < 0.9  # (the range cuts: 0.96 unlimited)
    assert values[1][0] == values[0][0] * factor
    np.testing.assert_array_equal(values[1][1], values[0][1] * factor)


class _UserCircle(ocp.AbstractCurve):
    """A circle defined the way a user would add a curve type: `components` only."""

    center: jax.Array
    radius: jax.Array

    def components(self, t):
        angle = 2 * jnp.pi * t
        c, s = jnp.cos(angle), jnp.sin(angle)
        w = 2 * jnp.pi * self.radius
        return (
            Vec(self.center[0] + self.radius * c, self.center[1] + self.radius * s),
            Vec(-w * s, w * c),
            Vec(-2 * jnp.pi * w * c, -2 * jnp.pi * w * s),
        )


def test_a_user_curve_type_gets_the_default_frame():
    """A curve type without `bounds` and `in_frame` of its own is moved into the frame by
    mapping its points: Q equals that of the built-in Circle (off the origin, and with a
    radius far from 1)."""
    center, radius = jnp.array([40.0, -25.0]), 0.02
    cams = jnp.array([[40.05, -25.03], [39.9, -24.96]])
    user = ocp.visibility(ocp.Scene([_UserCircle(center, jnp.asarray(radius))]), cams, FS)
    built_in = ocp.visibility(ocp.Scene([ocp.Circle(center, radius)]), cams, FS)
    assert abs(float(user) / float(built_in) - 1) < 1e-12


def test_a_user_objective_sees_points_and_cameras_in_the_users_coordinates():
    """The engine works in the scene's frame (moved and scaled); a q that depends on
    where the point is, q = 1 + x^2, gets the user's x. A circle of radius r centred at
    (5, -3), seen from distance d along +x: Q = int (1 + (5 + r cos phi)^2) r dphi over
    |phi| <= acos(r / d)."""
    r, d = 1.5, 4.0
    scene = ocp.Scene([ocp.Circle(jnp.array([5.0, -3.0]), r)])
    objective = ocp.LocalObjective(lambda x, dx, c: 1.0 + x[0] ** 2)
    value = ocp.visibility(scene, jnp.array([[5.0 + d, -3.0]]), objective)
    alpha = math.acos(r / d)
    want = integrate.quad(lambda phi: (1 + (5 + r * math.cos(phi)) ** 2) * r, -alpha, alpha)[0]
    assert abs(float(value) / want - 1) < 1e-12


# ===========================================================================
# user objectives and several cameras on one circle (closed forms)
# ===========================================================================
def foreshortened_formula(x, dx, c):
    n = jnp.stack([-dx[1], dx[0]])
    d = x - c
    return jnp.dot(n, d) ** 2 / (jnp.dot(n, n) * jnp.dot(d, d))


def inverse_distance(x, dx, c):
    return 1.0 / jnp.linalg.norm(x - c)


USER_FS = ocp.LocalObjective(foreshortened_formula)
USER_ONE = ocp.LocalObjective(lambda x, dx, c: jnp.ones((), x.dtype))
USER_INV = ocp.LocalObjective(inverse_distance)


def _user_objectives(scene, cams):
    def q(objective):
        return ocp.visibility(scene, cams, objective)

    values = {
        "fs": q(FS),
        "user_fs": q(USER_FS),
        "plain_fs": q(lambda x, dx, c: foreshortened_formula(x, dx, c)),  # a bare function
        "one": q(USER_ONE),
        "vl": q(VL),
        "inv": q(USER_INV),
    }
    grads = {
        "fs": jax.grad(lambda c: ocp.visibility(scene, c, FS))(cams),
        "user_fs": jax.grad(lambda c: ocp.visibility(scene, c, USER_FS))(cams),
    }
    return values, grads


# unit circle; cameras at distance 3 at right angles (by symmetry the best camera
# switches at 45 degrees), and a generic pair
USER_CAMERAS = np.array([[[3.0, 0.0], [0.0, 3.0]], [[2.5, 1.0], [-1.2, 2.2]]])


@functools.cache
def user_objective_results():
    fn = jax.jit(jax.vmap(_user_objectives, in_axes=(None, 0)))
    out = fn(H.circle_scene(), jnp.asarray(USER_CAMERAS))
    return jax.tree.map(np.asarray, out)


def test_user_objective_equals_foreshortened():
    values, grads = user_objective_results()
    np.testing.assert_allclose(values["user_fs"], values["fs"], rtol=1e-13)
    np.testing.assert_allclose(values["plain_fs"], values["fs"], rtol=1e-13)
    assert rel(grads["user_fs"], grads["fs"]) < 1e-12
    # a camera-independent q = 1 is the visible length
    np.testing.assert_allclose(values["one"], values["vl"], rtol=1e-13)


def test_two_cameras_on_a_circle_closed_forms():
    """Crossovers: with cameras at (3, 0) and (0, 3) the better camera switches at 45
    degrees, so Q = 2 int_{-alpha}^{pi/4} q r dphi for any q decreasing in the angle."""
    values, grads = user_objective_results()
    r, d = 1.0, 3.0
    alpha = math.acos(r / d)
    G = H.foreshortened_antiderivative
    assert abs(values["vl"][0] / (r * (math.pi / 2 + 2 * alpha)) - 1) < 1e-12
    assert abs(values["fs"][0] / (2 * (G(math.pi / 4, r, d) - G(-alpha, r, d))) - 1) < 1e-11

    def inv(phi):
        return r / math.sqrt(r * r + d * d - 2 * r * d * math.cos(phi))

    want = 2 * integrate.quad(inv, -alpha, math.pi / 4, epsabs=0, epsrel=1e-13)[0]
    assert abs(values["inv"][0] / want - 1) < 1e-11
    # the reflection (x, y) -> (y, x) swaps the cameras, so it maps one gradient onto
    # the other
    g = grads["fs"][0]
    assert rel(g[1], g[0, ::-1]) < 1e-10 and np.linalg.norm(g[0]) > 1e-3
    # the generic pair against the reference
    spec = H.to_reference(H.circle_scene())
    for obj, key in (("visible_length", "vl"), ("foreshortened", "fs")):
        ref = reference_visibility(spec, USER_CAMERAS[1], obj)
        assert abs(values[key][1] / ref - 1) < 1e-10


# ===========================================================================
# events: the implicit-function derivatives against the thesis's closed forms
# ===========================================================================
def camera_grid(scene, camera: Vec, samples):
    """The camera's grid, as visibility builds it (its nearest point on each curve an
    extra node)."""
    frozen = jax.lax.stop_gradient(scene)
    sense = _visibility._sense(frozen, samples)
    cameras = camera.map(lambda a: jnp.reshape(a, (1,)))
    nearest = _visibility._nearest_points(frozen, cameras, samples, sense).t[:, 0]
    return _events.with_nearest_node(scene, samples, nearest)


def tangency_times(scene, camera: Vec, samples):
    """The camera's tangency times, as visibility computes them (on its grid)."""
    grid = camera_grid(scene, camera, samples)
    return _events.tangency_times(
        scene, camera, grid, OPTIONS.max_tangents, OPTIONS.newton_iterations
    )


def camera_events(scene, camera):
    """One camera's tangency times, ray sources (tangency points, silhouette corners)
    and shadow times, as visibility computes them."""
    samples = _events.sample(jax.lax.stop_gradient(scene), grid_cells(scene))
    cam = Vec(camera[0], camera[1])
    tangents = tangency_times(scene, cam, samples)
    points = _events.tangency_points(scene, tangents)
    sources = _events.tangency_sources(scene, points)
    if scene.has_corners:
        sources = _events.join_sources(sources, _events.silhouette_corners(scene, cam, samples))
    probes = _events.grazing_probes(cam, samples, tangents, points)
    shadows = _events.shadow_times(
        scene, cam, samples, sources, probes, OPTIONS.max_shadows, OPTIONS.newton_iterations
    )
    return tangents, sources, shadows


def _events_fn(scene, camera):
    """The tangency and shadow times of one camera, as visibility computes them."""
    tan, _, sh = camera_events(scene, camera)
    return tan.t, tan.valid, sh.t, sh.valid


def _events_and_jacobian(scene, camera):
    tan_t, tan_valid, sh_t, sh_valid = _events_fn(scene, camera)

    def times(s, c):
        out = _events_fn(s, c)
        return out[0], out[2]

    jac = jax.jacfwd(times, argnums=(0, 1))(scene, camera)
    return (tan_t, tan_valid, sh_t, sh_valid), jac


@functools.cache
def events_and_jacobian():
    return jax.jit(_events_and_jacobian)


EVENT_CAMERAS = [(5.0, 4.0), (3.1, 0.2), (-4.5, 2.5)]


@functools.cache
def event_data(ci):
    camera = jnp.asarray(EVENT_CAMERAS[ci])
    (tan_t, tan_valid, sh_t, sh_valid), jac = events_and_jacobian()(H.THREE, camera)
    return jax.tree.map(np.asarray, (tan_t, tan_valid, sh_t, sh_valid, jac))


def _fd_roots(scene, camera, h=1e-6):
    """Central differences of the event times (tangency, shadow) in the camera."""
    fn = events_and_jacobian()
    cols_t, cols_s = [], []
    for e in np.eye(2):
        (tp, _, sp, _), _ = fn(scene, jnp.asarray(camera + h * e))
        (tm, _, sm, _), _ = fn(scene, jnp.asarray(camera - h * e))
        cols_t.append((np.asarray(tp) - np.asarray(tm)) / (2 * h))
        cols_s.append((np.asarray(sp) - np.asarray(sm)) / (2 * h))
    return np.stack(cols_t, -1), np.stack(cols_s, -1)


@pytest.mark.parametrize("ci", range(len(EVENT_CAMERAS)))
def test_tangency_time_derivative_matches_eqs_5_28_and_5_32(ci, reference_specs):
    C = np.asarray(EVENT_CAMERAS[ci])
    tan_t, tan_valid, _, _, jac = event_data(ci)
    dT_dC = jac[0][1]  # (m, r, 2)
    fd_t, _ = _fd_roots(H.THREE, C)
    specs = reference_specs["three"]
    signs = []
    for i, spec in enumerate(specs):
        roots = tan_t[i][tan_valid[i]]
        assert roots.size >= 2
        for slot in np.nonzero(tan_valid[i])[0]:
            T = tan_t[i, slot]
            x, dx, ddx = eval_curve(spec, np.array(T))
            n, n_dot = J @ dx, J @ ddx
            got = dT_dC[i, slot]
            # Eq. 5.28: dT/dC = n(T)^T / (n'(T)^T (x(T) - C))
            assert rel(got, n / (n_dot @ (x - C))) < 1e-9
            # Eq. 5.32 (n = R x', x - C replaced by |x - C| x'/|x'|) holds up to the sign
            # sigma of x'.(x - C): the substitution 5.31 assumes x' points away from C
            sigma = np.sign(dx @ (x - C))
            eq532 = (np.linalg.norm(dx) / np.linalg.norm(x - C)) * (dx @ R) / (ddx @ R @ dx)
            assert rel(got, sigma * eq532) < 1e-9
            signs.append(sigma)
            # and the root itself moves that way
            assert rel(got, fd_t[i, slot]) < 1e-6
    assert {1.0, -1.0} <= set(signs)  # both signs occur, so the sign is really tested


@pytest.mark.parametrize("ci", range(len(EVENT_CAMERAS)))
def test_shadow_time_derivative_matches_eq_5_17(ci, reference_specs):
    """dS/dC for a shadow time S of the tangency point P = x(T): from Eq. 5.16,
    dS/dC = (x(S) - P)^T R^T / (x'(S)^T R (C - P)). Eq. 5.17 as printed has R instead of
    R^T in the numerator, i.e. the opposite sign; finite differences decide."""
    C = np.asarray(EVENT_CAMERAS[ci])
    tan_t, tan_valid, sh_t, sh_valid, jac = event_data(ci)
    dS_dC = jac[1][1]
    _, fd_s = _fd_roots(H.THREE, C)
    specs = reference_specs["three"]
    points = np.concatenate(
        [eval_curve(spec, tan_t[i][tan_valid[i]])[0] for i, spec in enumerate(specs)]
    )
    checked = 0
    for i, spec in enumerate(specs):
        for slot in np.nonzero(sh_valid[i])[0]:
            S = sh_t[i, slot]
            X, dX, _ = eval_curve(spec, np.array(S))
            # the tangency point whose ray through C hits x_i(S) beyond it
            ray = points - C
            line = np.abs(ray[:, 0] * (X - C)[1] - ray[:, 1] * (X - C)[0])
            beyond = (ray @ (X - C)) > (ray * ray).sum(-1)
            p = np.argmin(np.where(beyond, line / np.linalg.norm(ray, axis=-1), np.inf))
            P = points[p]
            assert line[p] <= 1e-9 * np.linalg.norm(ray[p]) * np.linalg.norm(X - C)
            got = dS_dC[i, slot]
            correct = ((X - P) @ R.T) / (dX @ R @ (C - P))
            printed = ((X - P) @ R) / (dX @ R @ (C - P))
            assert rel(got, correct) < 1e-9
            assert rel(got, -printed) < 1e-9
            assert rel(got, fd_s[i, slot]) < 1e-6
            checked += 1
    assert checked == [1, 2, 2][ci]  # every ray's first hit (`test_each_ray_casts_...`)


def _first_crossings(specs, camera, points):
    """Each ray from `camera` through `points` (l, 2): where it first crosses a curve
    beyond its point (at more than 1 + 1e-4 times the point's depth), from the NumPy
    reference's curves as polylines of 4000 chords, as (curve, point) or None."""
    lines = [eval_curve(spec, np.linspace(0.0, 1.0, 4001))[0] for spec in specs]
    hits = []
    for d in points - camera:
        best = (np.inf, None, None)
        for i, x in enumerate(lines):
            a, e = x[:-1] - camera, np.diff(x, axis=0)
            det = d[0] * -e[:, 1] + d[1] * e[:, 0]
            with np.errstate(divide="ignore", invalid="ignore"):
                s = (a[:, 0] * -e[:, 1] + a[:, 1] * e[:, 0]) / det
                u = (d[0] * a[:, 1] - d[1] * a[:, 0]) / det
            s = np.where((u >= 0) & (u <= 1) & (s > 1 + 1e-4), s, np.inf)
            j = int(np.argmin(s))
            if s[j] < best[0]:
                best = (s[j], i, camera + s[j] * d)
        hits.append(None if best[1] is None else best[1:])
    return hits


FIRST_HIT_CASES = {
    **{f"three, camera {c}": ("three", c) for c in range(len(EVENT_CAMERAS))},
    "floor with a room": ("floor", 0),
}


@pytest.mark.parametrize("case", FIRST_HIT_CASES)
def test_each_ray_casts_one_shadow_at_its_first_crossing(case, reference_specs):
    """The shadow times are exactly the first crossings beyond their sources of the rays
    through every tangency point and silhouette corner (later crossings lie behind
    the curve the ray crossed first): one per ray, against the NumPy reference's
    polylines (1e-6 of the scene's size). In the floor, the room is met by every ray."""
    name, c = FIRST_HIT_CASES[case]
    if name == "three":
        scene, camera = H.THREE, np.asarray(EVENT_CAMERAS[c])
        specs = reference_specs["three"]
    else:
        scene = ocp.scenes.floor(seed=5, cells=8, objects=4, kinds=("rectangle", "circle", "blob"))
        camera = np.asarray(ocp.scenes.free_points(scene, 1, seed=5)[0])
        specs = H.to_reference(scene)
    _, sources, shadows = jax.tree.map(
        np.asarray, jax.jit(camera_events)(scene, jnp.asarray(camera))
    )
    rays = np.asarray(sources.point.stack())[sources.valid]
    want = [hit for hit in _first_crossings(specs, camera, rays) if hit is not None]
    got = [
        (i, eval_curve(specs[i], t)[0])
        for i in range(len(specs))
        for t in np.asarray(shadows.t[i])[np.asarray(shadows.valid[i])]
    ]
    assert len(got) == len(want) >= (8 if name == "floor" else 1)
    size = np.ptp(np.concatenate([eval_curve(spec, np.linspace(0, 1, 99))[0] for spec in specs]))
    for curve, point in want:
        assert min(np.linalg.norm(x - point) for i, x in got if i == curve) <= 1e-6 * size


INSCRIBED_CASES = {
    # The grid polygon's nearest chord r cos(pi / N), less the longest step 2 r sin(pi / N).
    "circle": (ocp.Circle([1.0, -1.0], 2.0), 2.0 * (math.cos(math.pi / 64) - 2 * math.sin(math.pi / 64))),
    # The mean of the grid points, (1.5, 1.75), lies in the U's notch: no disc.
    "U shape": (
        ocp.PiecewiseCurve.polygon([(0, 0), (3, 0), (3, 3), (2, 3), (2, 1), (1, 1), (1, 3), (0, 3)]),
        0.0,
    ),
}


@pytest.mark.parametrize("case", INSCRIBED_CASES)
def test_inscribed_discs(case):
    """A disc inside each curve (it culls the rays that certainly stop at a curve from
    the search of the curves behind it): the closed form for a circle's grid, and none
    where the centre lies outside the curve."""
    curve, want = INSCRIBED_CASES[case]
    scene = ocp.Scene([curve])
    samples = _events.sample(scene, 64)
    centre, _ = _events.bounding_discs(samples)
    radius = float(_events.inscribed_radii(samples, centre, scene.straight())[0])
    assert radius == pytest.approx(want, abs=1e-12)


BLOCKS = {
    # a polygon stops a ray where it crosses an edge, a curve inside its inscribed disc;
    # the counts of the curved objects' searches (a polygon's crossings are closed forms)
    "square block": (
        ocp.PiecewiseCurve.polygon([(2.0, -1.0), (4.0, -1.0), (4.0, 1.0), (2.0, 1.0)]),
        [0, 0, 2],
    ),
    "round block": (ocp.Circle([3.0, 0.0], 1.0), [0, 4, 2]),
}


@pytest.mark.parametrize("block", BLOCKS)
def test_rays_stopped_by_a_nearer_object_are_not_searched_behind_it(block):
    """From the origin, a small square's silhouette rays (at +-3.2 degrees) cross the
    block around (3, 0) and then pass the bounding disc of the circle at x in [8, 9]
    behind it. They stop at the block, so the far circle's search holds only its own
    two tangency points' rays (each object's own rays pass its disc; a round block's
    also holds the small square's)."""
    square = ocp.PiecewiseCurve.polygon([(0.9, -0.05), (1.0, -0.05), (1.0, 0.05), (0.9, 0.05)])
    far = ocp.Circle([8.5, 0.0], 0.5)
    curve, counts = BLOCKS[block]
    scene = ocp.Scene([square, curve, far])
    _, sources, shadows = jax.jit(camera_events)(scene, jnp.zeros(2))
    assert int(jnp.sum(sources.valid & (sources.curve == 2))) == 2
    np.testing.assert_array_equal(np.asarray(shadows.count), counts)


def test_polygon_crossings_are_the_first_crossings_of_a_polygon_floor():
    """The closed-form crossings of rays with a floor's walls and polygon furniture are
    each ray's first crossing beyond its source, as the NumPy reference's polylines give
    it (rays that only touch a vertex are not stopped by it), and the shadow times on
    their edges are the points crossed, on the curves crossed."""
    scene = ocp.scenes.floor(seed=11, cells=10, objects=5, kinds=("rectangle", "l_shape", "triangle"))
    camera = np.asarray(ocp.scenes.free_points(scene, 1, seed=11)[0])
    _, sources, _ = jax.jit(camera_events)(scene, jnp.asarray(camera))
    samples = _events.sample(scene, grid_cells(scene))
    ray = Vec(sources.point.x - camera[0], sources.point.y - camera[1])
    edges = _events.polygon_edges(scene, samples)
    crossings = _events.polygon_crossings(edges, Vec(*camera), ray, sources.depth)
    got = np.asarray(crossings.depth)
    valid = np.asarray(sources.valid)
    rays = np.asarray(sources.point.stack())[valid] - camera
    hits = _first_crossings(H.to_reference(scene), camera, rays + camera)
    want = [np.inf if hit is None else (hit[1] - camera) @ d / (d @ d) for hit, d in zip(hits, rays)]
    assert np.isfinite(got[valid]).sum() >= 10
    np.testing.assert_allclose(got[valid], want, rtol=1e-9)

    t = _events.polygon_shadow_times(scene, edges, Vec(*camera), sources.point, crossings)
    curve = edges.curve[np.asarray(crossings.edge)][valid]
    found = np.isfinite(got[valid])
    x = np.asarray(scene.components_at(jnp.asarray(curve), t[valid])[0].stack())
    np.testing.assert_array_equal(curve[found], [hit[0] for hit in hits if hit is not None])
    np.testing.assert_allclose(x[found], [hit[1] for hit in hits if hit is not None], atol=1e-9)
    assert np.all(np.asarray(t)[valid][~found] == 1.0)


def test_edges_cross_lines_of_sight_as_segments_do():
    """A polygon's edge tested whole (`_crosses_edges`) blocks a line of sight exactly
    where the two segments intersect (orientation tests in NumPy), on random edges and
    query points around a camera."""
    rng = np.random.default_rng(0)
    camera = np.array([0.3, -0.2])
    start, end = rng.normal(size=(2, 300, 2)) * 3
    query = rng.normal(size=(200, 2)) * 3

    def side(p, q, r):  # orientation of r about the line p -> q
        return np.sign((q[..., 0] - p[..., 0]) * (r[..., 1] - p[..., 1])
                       - (q[..., 1] - p[..., 1]) * (r[..., 0] - p[..., 0]))

    c, m = camera[None, None], query[:, None]
    a, b = start[None], end[None]
    want = (side(c, m, a) != side(c, m, b)) & (side(a, b, c) != side(a, b, m))
    d = query - camera
    got = _occlusion._crosses_edges(
        Vec(*jnp.asarray(d).T), jnp.asarray(np.sum(d * d, -1)),
        Vec(*jnp.asarray(start - camera).T), Vec(*jnp.asarray(end - camera).T),
    )
    assert 0.05 < want.mean() < 0.95
    np.testing.assert_array_equal(np.asarray(got), want)


def test_event_time_derivatives_wrt_scene_match_finite_differences():
    C = np.asarray(EVENT_CAMERAS[1])
    tan_t, tan_valid, sh_t, sh_valid, jac = event_data(1)
    flat, unravel = ravel_pytree(H.THREE)
    # d(times)/d(scene leaves): flatten the Scene-shaped jacobians leaf by leaf
    leaves_t = [np.asarray(a).reshape(*tan_t.shape, -1) for a in jax.tree.leaves(jac[0][0])]
    leaves_s = [np.asarray(a).reshape(*sh_t.shape, -1) for a in jax.tree.leaves(jac[1][0])]
    jt, js = np.concatenate(leaves_t, -1), np.concatenate(leaves_s, -1)
    fn = events_and_jacobian()
    h = 1e-6
    flat = np.asarray(flat)
    for j in range(flat.size):
        e = np.zeros_like(flat)
        e[j] = h
        (tp, vp, sp, svp), _ = fn(unravel(jnp.asarray(flat + e)), jnp.asarray(C))
        (tm, vm, sm, svm), _ = fn(unravel(jnp.asarray(flat - e)), jnp.asarray(C))
        np.testing.assert_array_equal(np.asarray(vp), tan_valid)
        np.testing.assert_array_equal(np.asarray(svm), sh_valid)
        fd_t = (np.asarray(tp) - np.asarray(tm)) / (2 * h)
        fd_s = (np.asarray(sp) - np.asarray(sm)) / (2 * h)
        np.testing.assert_allclose(jt[..., j][tan_valid], fd_t[tan_valid], rtol=1e-5, atol=1e-7)
        np.testing.assert_allclose(js[..., j][sh_valid], fd_s[sh_valid], rtol=1e-5, atol=1e-7)
    # invalid (padded) slots carry zero, finite derivatives
    assert np.all(jt[~tan_valid] == 0) and np.all(js[~sh_valid] == 0)


# ---------------------------------------------------------------------------
# scenes of conics: closed-form events (_conics.py) against the root solves
# ---------------------------------------------------------------------------
CONICS = ocp.Scene(
    [
        ocp.Circle(jnp.array([0.0, 0.0]), 1.0),
        ocp.Ellipse(jnp.array([2.5, 1.3]), jnp.array([0.6, 0.3]), 0.6),
        ocp.Circle(jnp.array([-1.6, 2.1]), 0.5),
    ],
    room=ocp.Circle(jnp.array([0.4, 0.6]), 6.0),
)
CONIC_CAMERAS = [(4.4, 2.2), (-3.5, 3.8), (3.2, -1.2)]
WEDGE = Vec(jnp.cos(jnp.array([2.5, 3.5])), jnp.sin(jnp.array([2.5, 3.5])))  # edge directions


def _conic_events(flat, camera, closed: bool):
    """Tangency and shadow times (of the tangency points and of two wedge edges) on
    CONICS (its parameters flattened), in closed form or by the root solves."""
    scene = ravel_pytree(CONICS)[1](flat)
    cam = Vec(camera[0], camera[1])
    iters = OPTIONS.newton_iterations
    samples = _events.sample(jax.lax.stop_gradient(scene), grid_cells(scene))
    if closed:
        tan = _conics.conic_tangency_times(scene.conic_frames(), cam)
    else:
        tan = tangency_times(scene, cam, samples)
    points = _events.tangency_points(scene, tan)
    sources = _events.join_sources(points, _events.wedge_edges(cam, WEDGE))
    if closed:
        sh = _conics.conic_shadow_times(scene.conic_frames(), cam, sources, 64)
    else:
        probes = _events.grazing_probes(cam, samples, tan, points)
        sh = _events.shadow_times(
            scene, cam, samples, sources, probes, OPTIONS.max_shadows, iters
        )
    return (tan.t, sh.t), (tan.valid, sh.valid, sh.count)


@functools.cache
def conic_events(closed: bool):
    """Jitted: the event times, their validity and count, and their Jacobians in the
    scene's parameters and the camera."""

    def fn(flat, camera):
        jac = jax.jacfwd(lambda f, c: _conic_events(f, c, closed)[0], argnums=(0, 1))
        return _conic_events(flat, camera, closed), jac(flat, camera)

    return jax.jit(fn)


def _by_curve(times, valid, jacobians):
    """Per curve: the valid times, sorted, and their Jacobian rows in that order."""
    out = []
    for i in range(times.shape[0]):
        keep = np.nonzero(valid[i])[0]
        order = keep[np.argsort(times[i, keep])]
        out.append((times[i, order], np.concatenate([j[i, order] for j in jacobians], -1)))
    return out


@pytest.mark.parametrize("ci", range(len(CONIC_CAMERAS)))
def test_conic_events_in_closed_form_match_the_root_solves(ci):
    """The closed forms of the tangency and shadow times of circles and ellipses (a room
    circle around them) against the grid + Newton root solves with implicit-function
    derivatives, which every other curve uses: the same times (to 1e-12) with the same
    derivatives in every parameter of the scene and the camera (to 1e-8 relative).

    Both keep each ray's first crossing beyond its source over the whole scene (behind
    it, the curve it crossed hides both sides of the ray): one shadow time per ray."""
    flat, camera = ravel_pytree(CONICS)[0], jnp.asarray(CONIC_CAMERAS[ci])
    assert CONICS.conics_only and not H.THREE.conics_only
    results = [
        jax.tree.map(np.asarray, conic_events(closed)(flat, camera)) for closed in (True, False)
    ]
    for kind in range(2):  # tangency, shadow times
        closed, solved = [
            _by_curve(times[kind], flags[kind], [jac[kind][0], jac[kind][1]])
            for (times, flags), jac in results
        ]
        for (t_closed, j_closed), (t_solved, j_solved) in zip(closed, solved):
            assert t_closed.size == t_solved.size
            np.testing.assert_allclose(t_closed, t_solved, rtol=0, atol=1e-12)
            np.testing.assert_allclose(j_closed, j_solved, rtol=1e-8, atol=1e-10)
    (_, (tan_valid, sh_valid, count)), _ = results[0]
    assert np.all(tan_valid.sum(1) == [2, 2, 2, 0])  # two per object, none on the room
    assert np.all(sh_valid.sum(1) == count)
    assert count.sum() == 8  # every ray (6 tangent, 2 wedge edges) first meets one curve
    assert count[:3].sum() >= 1  # objects shadow others


@functools.cache
def conic_value_and_grad():
    """Jitted: Q (Foreshortened) of CONICS from two cameras (parameters flattened) and its
    gradient in both."""

    def fn(flat, cameras):
        return ocp.visibility(ravel_pytree(CONICS)[1](flat), cameras, FS)

    return jax.jit(jax.value_and_grad(fn, argnums=(0, 1)))


def test_conics_q_and_gradient_match_the_reference_and_finite_differences():
    """End to end through the closed-form events: Q of circles and an ellipse in a room
    circle from two cameras against the NumPy reference (1e-9), and its gradient in the
    cameras and in every parameter of the scene against central differences (1e-6)."""
    flat, cameras = ravel_pytree(CONICS)[0], jnp.asarray(CONIC_CAMERAS[:2])
    fn = conic_value_and_grad()
    value, (g_scene, g_cameras) = fn(flat, cameras)
    spec = H.to_reference(CONICS)
    ref = reference_visibility(spec, np.asarray(cameras), "foreshortened", observed=[1, 1, 1, 0])
    assert rel(value, ref) < 1e-9
    fd_cameras = H.central_differences(lambda c: fn(flat, c)[0], cameras, 1e-6)
    fd_scene = H.central_differences(lambda f: fn(f, cameras)[0], flat, 1e-6)
    assert rel(g_cameras, fd_cameras) < 1e-6 and np.linalg.norm(g_cameras) > 0.1
    assert rel(g_scene, fd_scene) < 1e-6 and np.linalg.norm(g_scene) > 0.1


def test_conics_seen_through_wedges_and_ranges_match_the_reference():
    """Cameras with a view wedge and a range on the scene of conics: the wedges' edges
    join the closed-form shadow rays (after the tangency points of every conic), the
    range crossings are root solves, and the 8 shadow slots of a conic are packed into
    max_shadows = 5 (5 rays first meet the room). Q against the NumPy reference (1e-9), and
    in float32 (1e-4)."""
    cams = np.array(CONIC_CAMERAS[:2])
    heading = np.arctan2(-cams[:, 1], -cams[:, 0]) + np.array([0.15, -0.2])
    fov, reach = np.array([0.45, 0.6]), np.array([5.5, 6.5])
    camera = ocp.Camera(*(jnp.asarray(a) for a in (cams, heading, fov, reach)))
    options = ocp.VisibilityOptions(max_shadows=5)
    shadows = ocp.visible_intervals(CONICS, camera, options).shadows
    assert shadows.t.shape == (2, 4, 5) and np.asarray(shadows.count).max() == 5
    poses = [{"heading": heading[c], "half_fov": fov[c], "range": reach[c]} for c in range(2)]
    spec = H.to_reference(CONICS)
    ref = reference_visibility(spec, cams, "foreshortened", poses=poses, observed=[1, 1, 1, 0])
    fn = jax.jit(lambda s, c: ocp.visibility(s, c, FS, options))
    assert rel(fn(CONICS, camera), ref) < 1e-9
    value32 = fn(*H.to_float32((CONICS, camera)))
    assert value32.dtype == jnp.float32 and rel(value32, ref) < 1e-4
    # the wedges and ranges matter: less is seen than without them
    assert ref < reference_visibility(spec, cams, "foreshortened", observed=[1, 1, 1, 0]) - 1.0


def occlusion_test(scene, camera, samples, t):
    """`visible_points` of the points t (m, q) as visibility runs it for every scene but
    conics: on the camera's grid, the grazing probes from its tangency times."""
    grid = camera_grid(scene, camera, samples)
    tangents = _events.tangency_times(
        scene, camera, grid, OPTIONS.max_tangents, OPTIONS.newton_iterations
    )
    points = _events.tangency_points(scene, tangents)
    probes = _events.grazing_probes(camera, grid, tangents, points)
    sense = _occlusion.orientation(samples) * scene.sides()
    x, dx, _ = jax.tree.map(jnp.ravel, scene.components(t))
    curve = jnp.repeat(jnp.arange(t.shape[0]), t.shape[1])
    seen = _occlusion.visible_points(camera, grid, sense, curve, t.ravel(), x, dx, probes)
    return seen.reshape(t.shape)


@functools.cache
def conic_decisions():
    """Jitted, on a scene of conics: the camera checks' (distance, outward) and the
    occlusion test of query points, in closed form and from the grid of samples (what
    every other scene uses), with the size, radii and orientation both ways."""

    def fn(scene, cameras, camera, t):
        frozen = jax.lax.stop_gradient(scene)
        samples = _events.sample(frozen, grid_cells(scene))
        sense = _occlusion.orientation(samples) * scene.sides()
        cams, cam = Vec.of(cameras), Vec.of(camera)
        frames = scene.conic_frames()
        x, dx, _ = scene.components(t)
        grid = (
            _visibility._closest_points(frozen, cams, samples, sense),
            (jnp.max(jnp.abs(samples.x.x)) + jnp.max(jnp.abs(samples.x.y)), sense),
            occlusion_test(frozen, cam, samples, t),
        )
        closed = (
            _conics.conic_distances(frames, scene.sides(), cams),
            (_conics.conic_extent(frames)[0], _conics.conic_orientation(frames) * scene.sides()),
            _occlusion.facing(cam, sense[:, None], x, dx)
            & ~_conics.conic_occluded(
                _conics.conic_occluders(scene),
                cam,
                x.map(jnp.ravel),
                jnp.repeat(jnp.arange(t.shape[0]), t.shape[1]),
            ).reshape(t.shape),
        )
        return closed, grid, _conics.conic_extent(frames)[1]

    return jax.jit(fn)


def test_conic_camera_checks_in_closed_form_match_the_grid():
    """The camera checks of a scene of conics in closed form (no samples) against the
    grid + Newton closest points: the same sides of every conic, distances equal on
    circles (1e-12, and the same nearest points) and to first order on the ellipse (error
    below d^2 / b, b its smaller semi-axis), at cameras far, near (1% and 1e-9 of a
    radius) and inside; the scene's size and the radii (largest semi-axes) against dense
    samples."""
    circle, ellipse = CONICS.curves[0], CONICS.curves[1]
    near = []
    for curve, t in ((circle, 0.3), (ellipse, 0.1), (ellipse, 0.55)):
        x, dx = (np.asarray(a) for a in curve.derivatives(t)[:2])
        outward = np.array([dx[1], -dx[0]]) / np.linalg.norm(dx)  # counter-clockwise
        near += [x + s * outward for s in (1e-2, 1e-9, -1e-2)]
    cameras = np.array(CONIC_CAMERAS + near + [(2.5, 1.3), (5.9, 5.9), (0.4, 0.6)])
    (closed, (size, sense), _), (grid, (grid_size, grid_sense), _), radius = jax.tree.map(
        np.asarray, conic_decisions()(CONICS, jnp.asarray(cameras), cameras[0], jnp.zeros((4, 1)))
    )
    (distance, outward, t), (true_distance, true_outward, true_t) = closed, grid
    np.testing.assert_array_equal(np.sign(outward), np.sign(true_outward))
    assert np.sum(outward < 0) == 6  # 3 near points, 2 centres inside objects, 1 out of the room
    circles = [0, 2, 3]
    np.testing.assert_allclose(distance[circles], true_distance[circles], rtol=1e-12, atol=1e-15)
    turn = t[circles] - true_t[circles]  # the nearest points on circles: the same
    turn[2, -1] = 0.0  # (but for the camera at the room's centre: every point is nearest)
    assert np.abs(turn - np.round(turn)).max() < 1e-9
    b = 0.3  # the ellipse's smaller semi-axis
    assert np.all(np.abs(distance[1] - true_distance[1]) <= true_distance[1] ** 2 / b + 1e-15)
    assert np.abs(distance[1] - true_distance[1]).max() > 1e-6  # (first order, not exact)
    np.testing.assert_array_equal(sense, grid_sense)
    dense = np.concatenate([np.asarray(c(np.linspace(0, 1, 20001))) for c in CONICS.curves])
    assert abs(size - (np.abs(dense[:, 0]).max() + np.abs(dense[:, 1]).max())) < 1e-8
    assert size >= grid_size
    np.testing.assert_allclose(radius, [1.0, 0.6, 0.5, 6.0], rtol=1e-15)


@pytest.mark.parametrize("ci", range(len(CONIC_CAMERAS)))
def test_conic_occlusion_in_closed_form_matches_the_grid(ci):
    """Which of 400 points on every conic of CONICS a camera sees: the closed-form
    segment crossings (with the facing test) against the grid's occlusion test, equal
    wherever a point is farther than 1e-6 from every event of the camera."""
    camera = np.asarray(CONIC_CAMERAS[ci])
    t = np.random.default_rng(ci).uniform(0, 1, (4, 400))
    (_, _, closed), (_, _, grid), _ = jax.tree.map(
        np.asarray, conic_decisions()(CONICS, jnp.asarray([camera]), camera, jnp.asarray(t))
    )
    (tangents, shadows), (valid, shadow_valid, _) = jax.tree.map(
        np.asarray, _conic_events(ravel_pytree(CONICS)[0], jnp.asarray(camera), True)
    )
    assert 0.2 < closed.mean() < 0.8
    for i in range(4):
        events = np.concatenate([tangents[i][valid[i]], shadows[i][shadow_valid[i]]])
        clear = np.abs(t[i][:, None] - events[None]).min(1, initial=1.0) > 1e-6
        np.testing.assert_array_equal(closed[i][clear], grid[i][clear])


@functools.cache
def point_decisions(name, dtype=jnp.float64):
    """Jitted: the occlusion test (`visible_points`) of query points t (m, q) on `name`'s
    scene (its arrays in `dtype`) from one camera, on the library's default grid."""
    scene = jax.tree.map(lambda a: jnp.asarray(a, dtype), H.SCENES[name])

    def fn(camera, t):
        samples = _events.sample(scene, grid_cells(scene))
        return occlusion_test(scene, Vec.of(camera), samples, t)

    return jax.jit(fn)


@pytest.mark.parametrize("name", ["three", "blobs3", "mixed", "banana"])
def test_points_next_to_events_are_decided_as_the_reference(name):
    """Query points 1e-3, 1e-4 and 1e-5 in t on either side of every end of the
    reference's visible intervals, from every single camera of the scene, decided as the
    reference's intervals say. Until the own curve's depth was deflated, 66 of these 660
    points were taken for hidden: on the visible side of a tangency the line of sight
    meets the curve again just beyond the point, and the depth there, interpolated
    linearly over a grid cell, came out in front of it (down to 3e-4 from the tangency);
    an interval that short next to a tangency (an event of another curve beside it) was
    then lost from Q."""
    spec = H.to_reference(H.SCENES[name])
    cameras = H.BANANA_CAMERAS if name == "banana" else H.CAMERAS[name][1]
    steps = np.array([1e-3, 1e-4, 1e-5])
    for camera in cameras:
        intervals = reference_visible_intervals(spec, camera)
        t = np.full((len(intervals), 96), 0.5)  # (one compiled shape per scene)
        for i, curve in enumerate(intervals):
            ends = np.array(sorted({e for iv in curve for e in iv} - {0.0, 1.0}))
            points = (ends[:, None, None] + np.array([-1, 1])[:, None] * steps).ravel()
            t[i, : points.size] = np.mod(points, 1.0)
        seen = np.asarray(point_decisions(name)(jnp.asarray(camera), jnp.asarray(t)))
        expected = [
            [any(a < s < b for a, b in curve) for s in row] for curve, row in zip(intervals, t)
        ]
        np.testing.assert_array_equal(seen, expected, err_msg=f"camera {camera}")


def test_points_between_the_seam_and_a_tangency_beside_it_are_decided_in_float32():
    """Cameras on the banana's tangent lines at t = -+1e-4 and -+3e-5, 2 units from the
    curve: the visible sliver between the seam t = 0 and the tangency, in float32, at a
    quarter, half and three quarters of its length, decided as the reference's intervals
    say. The own curve's line of sight has a root at the query point's periodic image
    t_m -+ 1 too, next to the grid's end; until it was deflated with the trivial root,
    rounding put it on either side of the end, and 6 of these 24 points were taken for
    hidden (Q lost up to 4e-3 of itself)."""
    spec = H.to_reference(H.BANANA)
    decide = point_decisions("banana", jnp.float32)
    seen, expected = [], []
    for tangency in (-1e-4, -3e-5, 3e-5, 1e-4):
        x, dx, _ = eval_curve(spec[0], tangency)
        for along in (2.0, -2.0):
            camera = x + along * dx / np.linalg.norm(dx)
            t = np.mod(tangency * np.array([[0.25, 0.5, 0.75]]), 1.0)
            seen += list(np.asarray(decide(jnp.float32(camera), jnp.float32(t)))[0])
            intervals = reference_visible_intervals(spec, camera)[0]
            expected += [any(a < s < b for a, b in intervals) for s in t[0]]
    np.testing.assert_array_equal(seen, expected)
    assert sum(expected) >= 12  # (the sliver is seen from at least one side of each)


@functools.cache
def grazed_circle_values():
    """Jitted VisibleLength Q of a two-curve scene (the banana and a circle)."""
    return jax.jit(lambda scene, cameras: ocp.visibility(scene, cameras, VL))


@pytest.mark.parametrize("depth", [1e-4, 1e-7])
def test_a_silhouette_ray_grazing_another_curve(depth):
    """From (50, 0) the banana's silhouette ray at its tangency point t = 0.328 grazes a
    circle of radius 2, 20 units beyond the point, cutting `depth` into it from either
    side: its shadow on the circle is a pair of roots 2 sqrt(2 r depth) / (2 pi r) apart
    in t (3e-3 and 1e-4, a tenth and a 280th of a grid cell), and the lines of sight to
    the arc between them graze the banana. Q as the NumPy reference (on a grid of
    32768 cells, which separates the pair). Until the camera's tangency points became
    probes (`_events.grazing_probes`), the default grid missed the crossings of those
    lines of sight with the banana (Q 2.6e-4 off at depth 1e-4) and at 1e-7 the pair
    of shadow roots too (8e-6)."""
    banana = H.to_reference(H.BANANA)
    camera = np.array([50.0, 0.0])
    (tangency,) = H.tangency_roots_near(banana[0], camera, 0.328)
    point = eval_curve(banana[0], tangency)[0]
    along = (point - camera) / np.linalg.norm(point - camera)
    normal = np.array([-along[1], along[0]])
    for side in (1.0, -1.0):
        centre = point + 20.0 * along + side * (2.0 - depth) * normal
        scene = ocp.Scene([H.BANANA.curves[0], ocp.Circle(jnp.asarray(centre), 2.0)])
        value = grazed_circle_values()(scene, jnp.asarray([camera]))
        spec = H.to_reference(scene)
        ref = reference_visibility(spec, camera[None], "visible_length", n_grid=32768)
        assert rel(value, ref) < 1e-10, (side, float(value), ref)


@pytest.mark.parametrize("j", range(len(KIDNEY_NEAR_DOUBLE)))
def test_near_double_tangency_roots_are_both_found(j):
    """Both roots of the pair, also the one hidden behind the curve (harmless to Q here,
    not in general)."""
    camera, (t1, t2) = H.near_double_camera(*KIDNEY_NEAR_DOUBLE[j])
    (tan_t, tan_valid, _, _), _ = events_and_jacobian()(H.THREE, jnp.asarray(camera))
    found = np.asarray(tan_t)[0][np.asarray(tan_valid)[0]]
    for t in (t1, t2):
        assert np.abs(found - t).min() < 1e-12


# ===========================================================================
# the root finder
# ===========================================================================
def test_hermite_extremum_is_exact_for_cubics():
    # p(t) = (t - 0.2)(t - 0.9)(t + 1.5) on the cell [0, h]: its Hermite interpolant is p
    h = 1.0
    p = np.polynomial.Polynomial.fromroots([0.2, 0.9, -1.5])
    dp = p.deriv()
    s, value, turning = _roots.hermite_extremum(
        jnp.asarray(p(0.0)), jnp.asarray(p(h)), jnp.asarray(dp(0.0)), jnp.asarray(dp(h)), h
    )
    crit = [c.real for c in dp.roots() if 0 < c.real < h]
    assert len(crit) == 1 and bool(turning)
    assert abs(float(s) * h - crit[0]) < 1e-14
    assert abs(float(value) - p(crit[0])) < 1e-14
    # monotone on the cell: no split, the value is the right end
    s, value, turning = _roots.hermite_extremum(
        jnp.asarray(0.0), jnp.asarray(1.0), jnp.asarray(0.5), jnp.asarray(2.0), 1.0
    )
    assert not bool(turning) and float(s) == 1.0 and float(value) == 1.0


def _pair_function(t, a):
    """F(t) = (t - a)(t - a - 0.002) - 1e-7 t: two roots 0.002 apart (inside one cell)."""
    value = (t - a) * (t - a - 0.002) - 1e-7 * t
    slope = 2 * t - 2 * a - 0.002 - 1e-7
    return value, slope, jnp.ones_like(t)


@functools.partial(jax.jit, static_argnums=1)
def _pair_roots(a, budget):
    t = jnp.linspace(0.0, 1.0, 9)  # cells of 1/8
    values, slopes, _ = _pair_function(t, a)
    brackets = _roots.grid_brackets(t, values[None], slopes[None], budget)
    roots, valid, _ = _roots.solve_roots(_pair_function, a, brackets, 30, 1.0, False)
    return brackets, roots, valid


def test_grid_brackets_split_near_double_roots_and_count_them():
    brackets, roots, valid = _pair_roots(jnp.asarray(0.4), 4)
    assert int(brackets.count) == 2  # no sign change on the grid, yet two roots
    exact = np.sort(np.polynomial.Polynomial([0.4 * 0.402, -(0.802 + 1e-7), 1.0]).roots().real)
    got = np.sort(np.asarray(roots)[np.asarray(valid)])
    # (the roots are 0.002 apart: F' = +-0.002 there, so F's rounding moves them ~1e-14)
    np.testing.assert_allclose(got, exact, rtol=0, atol=1e-13)
    # a budget too small for the roots reports the true count
    small, _, _ = _pair_roots(jnp.asarray(0.4), 1)
    assert int(small.count) == 2 and np.asarray(small.candidate).sum() == 1


def test_materialize_is_the_identity_with_an_identity_derivative():
    tree = {
        "a": Vec(jnp.arange(3.0), jnp.arange(3.0) + 10),
        "b": jnp.ones((2, 3)),
        "c": jnp.arange(4),
        "d": Vec(jnp.arange(3.0) + 20, jnp.arange(3.0) + 30),
    }
    out = jax.jit(materialize)(tree, tree)
    for want, got in zip(jax.tree.leaves(tree), jax.tree.leaves(out)):
        assert got.dtype == want.dtype
        np.testing.assert_array_equal(got, want)
    x = jnp.array([0.5, -2.0])
    fn = lambda x: materialize(Vec(jnp.sin(x), x**2), x).y  # noqa: E731
    np.testing.assert_allclose(jax.jacfwd(fn)(x), np.diag(2 * np.asarray(x)), rtol=1e-15)
    np.testing.assert_allclose(jax.jacrev(fn)(x), np.diag(2 * np.asarray(x)), rtol=1e-15)


def test_computed_on_one_thread_is_fn_with_the_derivatives_of_fn():
    def fn(a, b):
        return Vec(jnp.sin(a) * b, a**2), a > b, jnp.arange(3) * 2

    a, b = jnp.array([0.5, -2.0, 1.0]), jnp.array(0.7)
    out = jax.jit(lambda a, b: computed_on_one_thread(fn, (a, b), a))(a, b)
    for want, got in zip(jax.tree.leaves(fn(a, b)), jax.tree.leaves(out)):
        assert got.dtype == want.dtype
        np.testing.assert_array_equal(got, want)
    once = lambda a, b: computed_on_one_thread(fn, (a, b), a)[0].x
    plain = lambda a, b: fn(a, b)[0].x
    for argnums in (0, 1, (0, 1)):
        for jac in (jax.jacfwd, jax.jacrev):
            for got, want in zip(
                jax.tree.leaves(jac(once, argnums)(a, b)),
                jax.tree.leaves(jac(plain, argnums)(a, b)),
            ):
                np.testing.assert_allclose(got, want, rtol=1e-15)
    # a tangent along b only: a is held (its tangent a symbolic zero), so y = a^2 has none
    _, dy = jax.jvp(lambda b: computed_on_one_thread(fn, (a, b), a)[0].y, (b,), (1.0,))
    np.testing.assert_array_equal(dy, 0.0)
    for batch in (a[None], jnp.stack([a, a + 1])):  # in place, and stored (a batch)
        np.testing.assert_array_equal(
            jax.vmap(lambda a: once(a, b))(batch), jax.vmap(lambda a: plain(a, b))(batch)
        )
        np.testing.assert_allclose(
            jax.vmap(jax.grad(lambda a: once(a, b).sum()))(batch),
            jax.vmap(jax.grad(lambda a: plain(a, b).sum()))(batch),
            rtol=1e-15,
        )
    # a NaN key skips the loop: NaN floats (not values computed from other inputs)
    key = a.at[0].set(jnp.nan)
    assert np.isnan(computed_on_one_thread(fn, (a, b), key)[0].x).all()


@pytest.mark.parametrize("size", [1, 5, 40])
def test_first_true_equals_numpy_nonzero(size):
    mask = np.random.default_rng(size).uniform(size=(3, 2, 40)) < [[[0.0]], [[0.1]], [[0.6]]]
    index, filled, count = _roots.first_true(jnp.asarray(mask), size)
    assert index.shape == filled.shape == (3, 2, size)
    rows = zip(mask.reshape(-1, 40), index.reshape(-1, size), filled.reshape(-1, size), count.ravel())
    for row, got, got_filled, n in rows:
        want = np.nonzero(row)[0][:size]
        assert int(n) == row.sum()
        np.testing.assert_array_equal(got, np.pad(want, (0, size - want.size)))
        np.testing.assert_array_equal(got_filled, np.arange(size) < want.size)


def test_newton_in_brackets_takes_no_step_without_candidates():
    """F(t) = t - 0.3: one Newton step from any guess lands on the root. Slots move only
    where some slot of the batch element holds a candidate."""
    fn = lambda t, _: (t - 0.3, jnp.ones_like(t), jnp.ones_like(t))  # noqa: E731
    shape = (2, 3)
    candidate = jnp.array([[False, False, False], [False, True, False]])
    brackets = _roots.Brackets(
        lo=jnp.zeros(shape),
        hi=jnp.ones(shape),
        guess=jnp.full(shape, 0.5),
        sign_lo=-jnp.ones(shape),
        turning=jnp.zeros(shape, bool),
        curvature=jnp.ones(shape),
        candidate=candidate,
        source=jnp.zeros(shape, int),
        count=candidate.sum(1),
    )
    solve = jax.jit(jax.vmap(lambda b: _roots.newton_in_brackets(fn, None, b, 8)))
    t, valid, settled = solve(brackets)
    np.testing.assert_array_equal(settled, True)
    np.testing.assert_array_equal(t[0], 0.5)  # no candidate: no step
    np.testing.assert_allclose(t[1], 0.3, rtol=0, atol=1e-16)
    np.testing.assert_array_equal(valid, candidate)


def test_newton_in_brackets_stops_once_newtons_error_is_below_eps():
    """F(t) = exp(t) - 1.7 on cells of 1/8: the guess from the Hermite cubic is ~1e-7
    off, Newton's first step leaves ~1e-14, its second ~1e-27. After the second the
    predicted error (curvature d^2, curvature >= 8 here) is far below eps, so the root is
    final: F is evaluated in two steps and once for the validity check, with no third
    step only to see that the root no longer moves."""
    calls = []

    def fn(t, _):
        jax.debug.callback(calls.append, t)
        return jnp.exp(t) - 1.7, jnp.exp(t), jnp.exp(t) + 1.7

    t = jnp.linspace(0.0, 1.0, 9)
    brackets = _roots.grid_brackets(t, (jnp.exp(t) - 1.7)[None], jnp.exp(t)[None], 2)
    assert abs(float(brackets.guess[0]) - math.log(1.7)) > 1e-9  # Newton has work to do
    roots, valid, _ = jax.jit(lambda b: _roots.newton_in_brackets(fn, None, b, 8))(brackets)
    jax.effects_barrier()
    assert len(calls) == 3
    assert bool(valid[0]) and abs(float(roots[0]) - math.log(1.7)) <= 2e-16


def test_newton_in_brackets_stores_f_once_per_step():
    """XLA's CPU backend computes an elementwise producer in every consumer fusion, so a
    Newton step whose F updates four carried arrays compiles F four times (for a
    degree-18 Bezier, hundreds of instructions each). With `store`, each step and the
    validity check after the loop compute F in one kernel (`materialize`, whose loop
    condition reads its key, no copy of F): F = sin t - 0.4 and F' = cos t are one stack
    per step, plus one sine for the check. Without it: four in the step (the bracket's
    ends, the iterate, the confirmed sign) and the check's F in each of its two consumers
    (the roots' validity and the search's done flag)."""
    fn = lambda t, _: (jnp.sin(t) - 0.4, jnp.cos(t), jnp.ones_like(t))  # noqa: E731
    t = jnp.linspace(0.0, 1.0, 9)
    brackets = _roots.grid_brackets(t, (jnp.sin(t) - 0.4)[None], jnp.cos(t)[None], 2)
    for store, sines in ((True, 2), (False, 6)):
        solve = jax.jit(lambda b, s=store: _roots.newton_in_brackets(fn, None, b, 8, s))
        hlo = solve.lower(brackets).compile().as_text()
        assert len(re.findall(r" sine\(", hlo)) == sines, store
        roots, valid, _ = solve(brackets)
        assert bool(valid[0]) and abs(float(roots[0]) - math.asin(0.4)) <= 2e-16


def test_newton_in_brackets_says_whether_every_root_was_final_within_its_steps():
    """F(t) = t^2 - 1e-8 from the guess 1 in [0, 1]: Newton halves the distance to the
    root 1e-4 per step until it is close (Heron's square root), about 13 steps, then
    converges in four more. Within 8 steps the search is not done (and visibility reports
    that, `test_a_root_search_not_done_in_its_newton_steps_is_reported`); within 32 it is."""
    fn = lambda t, _: (t * t - 1e-8, 2.0 * t, t * t + 1e-8)  # noqa: E731
    brackets = _roots.Brackets(
        lo=jnp.zeros(1),
        hi=jnp.ones(1),
        guess=jnp.ones(1),
        sign_lo=-jnp.ones(1),
        turning=jnp.zeros(1, bool),
        curvature=jnp.ones(1),
        candidate=jnp.ones(1, bool),
        source=jnp.zeros(1, int),
        count=jnp.array(1),
    )
    for steps, done in ((8, False), (32, True)):
        roots, valid, settled = _roots.newton_in_brackets(fn, None, brackets, steps)
        assert bool(settled) == done and bool(valid[0])
    assert abs(float(roots[0]) - 1e-4) < 1e-15  # final: a step of at most 4 eps


def test_a_root_search_not_done_in_its_newton_steps_is_reported():
    """A camera 1e-6 from the banana (1.7e-8 of its size): a tangency time beside its
    nearest point takes more than 8 Newton steps. With 8 the call raises an error that
    says what to pass (before, it returned a root short of its final value); with the
    default (32) VisibleLength equals the reference to 1e-8 (the arc seen is 0.005 long;
    `benchmarks/beside_curves.py` finds up to 9e-9 at this distance)."""
    spec = H.to_reference(H.BANANA)[0]
    camera = jnp.asarray(H.cameras_beside(spec, np.array([0.2698]), (1e-6,)))
    few = ocp.VisibilityOptions(newton_iterations=8)
    with pytest.raises(Exception, match=r"not done in 8 Newton steps.*newton_iterations=\.\.\."):
        jax.block_until_ready(ocp.visibility(H.BANANA, camera, VL, few))
    q = visible_length_of("banana")(camera)
    ref = reference_visibility([spec], np.asarray(camera), "visible_length")
    assert abs(float(q[0]) / ref - 1) < 1e-8


def test_implicit_root_derivative():
    """d t*/da for t*(a) = the larger root of (t - a)(t - a - 0.002) = 1e-7 t."""

    def larger_root(a):
        _, roots, valid = _pair_roots(a, 4)
        return jnp.max(jnp.where(valid, roots, -1.0))

    a = 0.4
    B = 2 * a + 0.002 + 1e-7
    # root = (B + sqrt(B^2 - 4 a (a + 0.002))) / 2
    disc = B * B - 4 * a * (a + 0.002)
    want = (2 + (2 * B * 2 - 4 * (2 * a + 0.002)) / (2 * math.sqrt(disc))) / 2
    got = float(jax.jit(jax.grad(larger_root))(jnp.asarray(a)))
    assert abs(got / want - 1) < 1e-9
    got_fwd = float(jax.jit(jax.jacfwd(larger_root))(jnp.asarray(a)))
    assert abs(got_fwd / want - 1) < 1e-9


# ===========================================================================
# invalid input and exceeded budgets
# ===========================================================================
def _three_k1(cameras):
    return H.batched("values", H.THREE, np.asarray(cameras, float).reshape(-1, 1, 2))


def test_camera_inside_an_object_raises():
    with pytest.raises(Exception, match="a camera lies inside an object"):
        _three_k1([[3.8, 1.6]])  # the circle's centre
    with pytest.raises(Exception, match="a camera lies inside an object"):
        _three_k1([[5.0, 4.0], [-1.6, -0.6]])  # one good camera, one in the ellipse


def test_nan_camera_raises():
    with pytest.raises(Exception, match="a camera position is NaN or inf"):
        _three_k1([[np.nan, 1.0]])
    with pytest.raises(Exception, match="a camera position is NaN or inf"):
        _three_k1([[5.0, np.inf]])


def test_nan_scene_raises():
    scene = jax.tree.map(lambda a: a.at[..., 0].set(jnp.nan) if a.ndim else a, H.circle_scene())
    with pytest.raises(Exception, match="the scene contains NaN or inf control points"):
        H.batched("grads", scene, np.array([[[3.0, 0.0]]]))


def test_camera_on_a_grid_vertex_of_a_curve_raises():
    # x(1/4) of the circle (3.8, 1.6), r = 0.5 is a node of the grid
    assert grid_cells(H.THREE) % 4 == 0
    with pytest.raises(Exception, match="(on a curve|inside an object)"):
        _three_k1([[3.8, 2.1]])


def test_camera_on_a_grid_vertex_says_on_a_curve():
    with pytest.raises(Exception, match="a camera lies on a curve"):
        _three_k1([[3.8, 2.1]])


def test_camera_on_a_curve_between_grid_vertices_raises():
    # x(t) of the circle for t = 0.3 cells, between two grid nodes
    a = 2 * math.pi * 0.3 / grid_cells(H.THREE)
    with pytest.raises(Exception, match="a camera lies on a curve"):
        _three_k1([[3.8 + 0.5 * math.cos(a), 1.6 + 0.5 * math.sin(a)]])


def test_camera_just_inside_a_curve_raises():
    a = 2 * math.pi * 0.5 / grid_cells(H.THREE)
    rho = 0.5 * (1 - 2e-4)
    with pytest.raises(Exception, match="inside an object|on a curve"):
        _three_k1([[3.8 + rho * math.cos(a), 1.6 + rho * math.sin(a)]])


@pytest.mark.parametrize(
    "cameras,match",
    [
        (np.zeros((2, 3)), r"cameras must have shape \(k, 2\)"),
        (np.zeros((0, 2)), r"k >= 1"),
        (np.zeros((1, 2, 2)), r"cameras must have shape \(k, 2\)"),
    ],
)
def test_cameras_with_wrong_shape_raise(cameras, match):
    with pytest.raises(ValueError, match=match):
        ocp.visibility(H.THREE, jnp.asarray(cameras))
    with pytest.raises(ValueError, match=match):
        ocp.visible_intervals(H.THREE, jnp.asarray(cameras))


def test_not_a_scene_raises():
    cams = jnp.array([[5.0, 4.0]])
    for bad in (list(H.THREE.curves), H.THREE.curves[1], np.zeros((4, 2))):
        with pytest.raises(TypeError, match="scene must be an ocp_jax.Scene"):
            ocp.visibility(bad, cams)
        with pytest.raises(TypeError, match="scene must be an ocp_jax.Scene"):
            ocp.visible_intervals(bad, cams)


def test_bad_objective_raises():
    with pytest.raises(TypeError, match="objective must be a local objective"):
        ocp.visibility(H.THREE, jnp.array([[5.0, 4.0]]), 3.0)


def test_exceeded_shadow_budget_raises():
    """Small circle in front of a big one: its two silhouette rays meet the big circle
    beyond the small one, 2 shadow times (first crossings) > max_shadows = 1."""
    C, cb, R_, cs, r = TWO_CIRCLE_CASES[0]
    fn = jax.jit(lambda s, c: ocp.visibility(s, c, FS, ocp.VisibilityOptions(max_shadows=1)))
    with pytest.raises(
        Exception,
        match=r"more shadow times on one curve than the budget of 1.*max_shadows=.*ocp.fit_options",
    ):
        fn(H.two_circles(cb, R_, cs, r), jnp.asarray([C]))


def test_exceeded_budget_outside_jit_is_grown_with_a_warning():
    """Called outside any jit, the same overflow compiles again with the budgets that
    `fit_options` gives, says so, and returns the Q of those budgets."""
    C, cb, R_, cs, r = TWO_CIRCLE_CASES[0]
    scene, camera = H.two_circles(cb, R_, cs, r), jnp.asarray([C])
    tight = ocp.VisibilityOptions(max_shadows=1)
    with pytest.warns(UserWarning, match=r"compiled again with VisibilityOptions\(max_shadows=2[,)]"):
        grown = ocp.visibility(scene, camera, FS, tight)
    fitted = ocp.fit_options(scene, camera, FS, tight)
    assert fitted.max_shadows == 2
    # (the interval budgets left to the scene are fitted to what the camera needs)
    assert fitted.max_camera_intervals is not None and fitted.max_intervals is not None
    assert float(grown) == float(ocp.visibility(scene, camera, FS, fitted))
    # (budgets only size padding: the default ones, 16 shadow slots, give the same Q)
    default = float(ocp.visibility(scene, camera, FS))
    assert abs(float(grown) / default - 1) <= 1e-14


def test_exceeded_tangency_budget_raises():
    fn = jax.jit(lambda s, c: ocp.visibility(s, c, FS, ocp.VisibilityOptions(max_tangents=1)))
    with pytest.raises(Exception, match=r"more tangency times on one curve than the budget of 1.*max_tangents="):
        fn(H.BANANA, jnp.asarray([H.BANANA_CAMERAS[0]]))


def test_exceeded_interval_budget_raises():
    fn = jax.jit(lambda s, c: ocp.visibility(s, c, FS, ocp.VisibilityOptions(max_intervals=4)))
    with pytest.raises(Exception, match=r"more event intervals in the scene than the budget of 4.*max_intervals="):
        fn(H.BANANA, jnp.asarray([H.BANANA_CAMERAS[0]]))


def test_exceeded_camera_interval_budget_raises():
    options = ocp.VisibilityOptions(max_camera_intervals=2)
    fn = jax.jit(lambda s, c: ocp.visibility(s, c, FS, options))
    with pytest.raises(
        Exception,
        match=r"more event intervals of one camera in the scene than the budget of 2.*"
        r"max_camera_intervals=",
    ):
        fn(H.BANANA, jnp.asarray([H.BANANA_CAMERAS[0]]))


def test_interval_budget_does_not_change_q():
    """The default max_intervals and max_camera_intervals drop only padding: Q equals, to
    rounding, Q with every event slot kept and tested."""
    everything = ocp.VisibilityOptions(max_intervals=10_000, max_camera_intervals=10_000)
    fn = jax.jit(lambda c: ocp.visibility(H.THREE, c, FS, everything))
    cams, (_, fs, *_) = scene_results("three", 2)
    assert abs(float(fn(jnp.asarray(cams[0]))) / fs[0] - 1) < 1e-14


def test_gauss_legendre_leibniz_rule():
    """d/d(a, b, w) int_a^b sin(w t) dt by the Leibniz rule equals the closed form."""
    from ocp_jax._quadrature import gauss_legendre

    def integral(a, b, w):
        return gauss_legendre(lambda t, w: jnp.sin(w * t), a, b, w, 16)

    a, b, w = jnp.array(0.3), jnp.array(1.7), jnp.array(2.5)
    exact = (jnp.cos(w * a) - jnp.cos(w * b)) / w
    assert abs(float(integral(a, b, w)) - float(exact)) < 1e-14
    grads = jax.grad(integral, argnums=(0, 1, 2))(a, b, w)
    want = (
        -jnp.sin(w * a),
        jnp.sin(w * b),
        (b * jnp.sin(w * b) - a * jnp.sin(w * a)) / w - (jnp.cos(w * a) - jnp.cos(w * b)) / w**2,
    )
    np.testing.assert_allclose(np.array(grads), np.array(want), rtol=1e-13)
    np.testing.assert_allclose(np.array(jax.jacfwd(integral, argnums=(0, 1, 2))(a, b, w)), np.array(want), rtol=1e-13)
    for i in range(3):  # one argument at a time: the others' tangents are symbolic zeros
        alone = float(jax.grad(integral, argnums=i)(a, b, w))
        assert abs(alone - float(want[i])) <= 1e-13 * abs(float(want[i]))


def test_perturbed_jvp_holds_unperturbed_leaves_constant():
    """Leaves whose tangent is a symbolic zero are held constant (not traced as JVP
    inputs); the tangent comes from the perturbed leaves alone."""
    from jax.custom_derivatives import SymbolicZero

    from ocp_jax._jvp import perturbed_jvp

    traced = []

    def fn(args):
        a, b = args
        traced.append(isinstance(b, jax.core.Tracer))
        return a * jnp.sin(b)

    a, b = jnp.array(2.0), jnp.array(0.5)
    value, tangent = perturbed_jvp(fn, (a, b), (jnp.array(3.0), SymbolicZero.from_primal_value(b)))
    assert traced == [False]
    assert float(value) == float(a * jnp.sin(b))
    assert abs(float(tangent) - 3.0 * math.sin(0.5)) < 1e-15


def test_curve_points_derivative_is_the_tangent_and_the_control_point_jvp():
    """curve_points' rule: d x(t) = x'(t) dt + dx/dP dP, against central differences in
    t and in the control points, in forward and reverse mode; x'' is the curve's, held
    constant."""
    scene = ocp.scenes.banana()
    t = jnp.array([[0.1, 0.37, 0.5, 0.93]])
    dt = jnp.array([[1.0, -0.5, 2.0, 0.3]])
    dscene = jax.tree.map(lambda a: jnp.cos(jnp.arange(a.size).reshape(a.shape)), scene)
    (_, ddx), (_, dddx) = jax.jvp(_events.curve_points, (scene, t), (dscene, dt))
    np.testing.assert_array_equal(ddx.stack(), scene.components(t)[2].stack())
    np.testing.assert_array_equal(dddx.stack(), 0.0)

    def stacked(s, tt):
        return _events.curve_points(s, tt)[0].stack()

    def moved(eps):
        s = jax.tree.map(lambda a, d: a + eps * d, scene, dscene)
        return stacked(s, t + eps * dt)

    h = 1e-6
    want = (moved(h) - moved(-h)) / (2 * h)
    _, got = jax.jvp(stacked, (scene, t), (dscene, dt))
    assert rel(got, want) < 1e-8
    # Reverse mode: <v, J u> from the gradient of a projection.
    v = jnp.sin(jnp.arange(want.size)).reshape(want.shape)
    g_scene, g_t = jax.grad(lambda s, tt: jnp.sum(v * stacked(s, tt)), argnums=(0, 1))(scene, t)
    pairs = zip(jax.tree.leaves(g_scene), jax.tree.leaves(dscene))
    dual = jnp.sum(g_t * dt) + sum(jnp.sum(a * b) for a, b in pairs)
    assert abs(float(dual) - float(jnp.sum(v * want))) < 1e-8 * float(jnp.sum(jnp.abs(v * want)))


@pytest.mark.parametrize(
    "kwargs,match",
    [
        ({"grid": 3}, "grid must be >= 8"),
        ({"max_intervals": 0}, "max_intervals must be a positive int"),
        ({"max_camera_intervals": 1.5}, "max_camera_intervals must be a positive int"),
        ({"grid": 64.0}, "grid must be a positive int"),
        ({"max_tangents": 0}, "max_tangents must be a positive int"),
        ({"max_shadows": -2}, "max_shadows must be a positive int"),
        ({"quadrature": 0}, "quadrature must be a positive int"),
    ],
)
def test_invalid_options_raise(kwargs, match):
    with pytest.raises(ValueError, match=match):
        ocp.VisibilityOptions(**kwargs)


def _reference_nearest(curve: dict, cameras, samples: int = 20000):
    """The points of a reference curve nearest to `cameras` (k, 2), in NumPy: the nearest
    of `samples` equally spaced points, then bisection (`reference._bisect`) of
    g(t) = (x(t) - C) . x'(t), negative before the nearest point and positive after, in
    the two cells around it. Returns the distances, negative where a camera lies on the
    inward side, and the parameters t, arrays (k,)."""
    x = eval_curve(curve, np.arange(samples) / samples)[0]
    nearest = np.argmin(np.sum((x[None] - cameras[:, None]) ** 2, -1), axis=1)
    lo, hi = (nearest - 1.0) / samples, (nearest + 1.0) / samples

    def g(rows, s):
        x, dx, _ = eval_curve(curve, s)
        return np.sum((x - cameras[rows]) * dx, -1)

    rows = np.arange(len(cameras))
    assert np.all(g(rows, lo) < 0) and np.all(g(rows, hi) > 0)
    t = np.mod(_bisect(g, rows, lo, hi, g(rows, lo)), 1.0)
    offset = cameras - eval_curve(curve, t)[0]
    side = np.sign(np.sum(offset * H.outward_normals(curve, t), -1))
    return side * np.linalg.norm(offset, axis=-1), t


@pytest.mark.parametrize("name", ["mixed", "banana"])
def test_signed_distances_match_a_dense_numpy_search(name):
    """Distances from cameras to every curve (the camera checks and a `Region`'s
    clearance), from the nearest grid node and six Newton steps, against a dense
    search and bisection in NumPy: far cameras, and cameras 1e-3 outside, 1e-3 inside and
    1e-9 outside each curve (a B-spline, a Bezier, a circle and an ellipse on the mixed
    scene's 32 cells, the banana's degree 18 on 36); their gradient is the signed unit
    vector from the nearest point."""
    scene = H.SCENES[name]
    specs = H.to_reference(scene)
    far = H.BANANA_CAMERAS if name == "banana" else H.CAMERAS[name][1]
    t = np.array([0.13, 0.61])
    near = [
        eval_curve(spec, t)[0] + offset * H.outward_normals(spec, t)
        for spec in specs
        for offset in (1e-3, -1e-3, 1e-9)
    ]
    cameras = np.concatenate([np.asarray(far, float), *near])
    distance, t_nearest = np.stack([_reference_nearest(s, cameras) for s in specs], -1)  # (k, m)
    got = np.asarray(_signed_distances()(scene, jnp.asarray(cameras)))
    # (to rounding: 10 ulps of the scene's largest coordinate)
    size = max(np.abs(eval_curve(s, np.linspace(0, 1, 1001))[0]).max() for s in specs)
    atol = 10 * np.finfo(float).eps * size
    np.testing.assert_allclose(got, distance, rtol=1e-12, atol=atol)
    # The gradient in each far camera: the unit vector from its nearest point, signed.
    k = len(far)
    gradient = np.asarray(_signed_distances_gradients()(scene, jnp.asarray(cameras[:k])))
    for i, spec in enumerate(specs):
        offset = cameras[:k] - eval_curve(spec, t_nearest[:k, i])[0]
        unit = offset / np.linalg.norm(offset, axis=-1)[:, None] * np.sign(distance[:k, i, None])
        np.testing.assert_allclose(gradient[:, i], unit, atol=1e-9)


@functools.cache
def _signed_distances():
    return jax.jit(_visibility.signed_distances)


@functools.cache
def _signed_distances_gradients():
    """d(distance of camera c to curve i) / d(camera c), shape (k, m, 2)."""

    def per_camera(scene, camera):
        return jax.jacobian(lambda c: _visibility.signed_distances(scene, c[None])[0])(camera)

    return jax.jit(jax.vmap(per_camera, in_axes=(None, 0)))
