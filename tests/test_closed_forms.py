"""Q against closed forms: one circle, a small circle shadowing a big one, user
objectives and several cameras on one circle; strict rank promotion.
"""

import functools
import math

import helpers as H
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import FS, OPTIONS, TWO_CIRCLE_CASES, VL, grid_cells, rel, visible_length_of
from reference import eval_curve, reference_visibility
from scipy import integrate

import ocp_jax as ocp
from ocp_jax._geometry.vec import Vec
from ocp_jax._visibility import events as _events
from ocp_jax._visibility import roots as _roots


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
CIRCLE_CASES = {  # name: (centre, radius, camera)
    "unit circle from 3": ((0.0, 0.0), 1.0, (3.0, 0.0)),
    "very close": ((0.0, 0.0), 1.0, (1.05, 0.0)),
    "moved, from an angle": (
        (1.5, -0.7),
        2.0,
        (1.5 + 5.0 * math.cos(2.0), -0.7 + 5.0 * math.sin(2.0)),
    ),
    "small and far": (
        (-3.0, 4.0),
        0.3,
        (-3.0 + 40.0 * math.cos(-1.0), 4.0 + 40.0 * math.sin(-1.0)),
    ),
    "large, off axis": ((0.2, 0.1), 1.7, (2.1, -3.0)),
}


@functools.cache
def circle_results():
    scenes = [H.circle_scene(c, r) for c, r, _ in CIRCLE_CASES.values()]
    cams = np.array([[cam] for _, _, cam in CIRCLE_CASES.values()])
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
            [{"type": "circle", "center": np.zeros(2), "radius": r}],
            np.array([[d, 0.0]]),
            "foreshortened",
        )
        assert abs(H.circle_foreshortened(r, d) / ref - 1) < 1e-12
    # far-camera limit: the half circle seen with q = cos^2 gives r pi / 2 (+ O(r/d))
    assert abs(H.circle_foreshortened(1.0, 1e4) / (math.pi / 2) - 1) < 1e-3


@pytest.mark.parametrize("case", CIRCLE_CASES)
def test_circle_closed_forms(case):
    center, r, cam = CIRCLE_CASES[case]
    case = list(CIRCLE_CASES).index(case)  # its row of the batch
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


@pytest.mark.parametrize("case", CIRCLE_CASES)
def test_circle_gradients_closed_form(case):
    """dQ/d(camera, centre, radius) against the derivatives of the closed forms."""
    center, r, cam = CIRCLE_CASES[case]
    case = list(CIRCLE_CASES).index(case)  # its row of the batch
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

    want = jax.grad(closed, argnums=(0, 1, 2))(
        jnp.asarray(center), jnp.asarray(r), jnp.asarray(cam)
    )
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


@functools.cache
def two_circle_results():
    scenes = [H.two_circles(cb, R_, cs, r) for _, cb, R_, cs, r in TWO_CIRCLE_CASES.values()]
    cams = np.array([[C] for C, *_ in TWO_CIRCLE_CASES.values()])
    return H.batched("grads", scenes, cams)


@pytest.mark.parametrize("case", TWO_CIRCLE_CASES)
def test_two_circles_shadow_closed_form(case):
    C, cb, R_, cs, r = TWO_CIRCLE_CASES[case]
    case = list(TWO_CIRCLE_CASES).index(case)  # its row of the batch
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


@pytest.mark.parametrize("case", TWO_CIRCLE_CASES)
def test_two_circles_gradients_closed_form(case):
    """Shadow times move with the camera and both circles: dQ against autodiff of the
    closed form, for every parameter."""
    C, cb, R_, cs, r = (jnp.asarray(v, jnp.float64) for v in TWO_CIRCLE_CASES[case])
    case = list(TWO_CIRCLE_CASES).index(case)  # its row of the batch
    _, _, gvl, gfs = two_circle_results()
    for index, grads in ((0, gvl), (1, gfs)):

        def closed(C, cb, R_, cs, r):
            return two_circles_closed_form(C, cb, R_, cs, r, xp=jnp)[index]

        want = jax.grad(closed, argnums=(0, 1, 2, 3, 4))(C, cb, R_, cs, r)
        scene_g, cam_g = grads
        big, small = scene_g.curves
        got = (
            cam_g[case, 0],
            big.center[case],
            big.radius[case],
            small.center[case],
            small.radius[case],
        )
        flat_got = np.concatenate([np.ravel(g) for g in got])
        flat_want = np.concatenate([np.ravel(np.asarray(g)) for g in want])
        assert rel(flat_got, flat_want) < 1e-9, (index, flat_got, flat_want)


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
# two cameras beside one straight edge
# ===========================================================================
# Cameras (a, 1 + h) above the top edge y = 1, 0 <= x <= 2, of the rectangle [0, 2] x
# [0, 1] see only that edge, where q = h^2 / (h^2 + (x - a)^2), a peak of width h: the
# cameras' q cross where h_1^2 ((x - a_2)^2 + h_2^2) = h_2^2 ((x - a_1)^2 + h_1^2).
EDGE_CAMERA_CASES = {  # (a, h) of each camera, tolerance of Q
    # the near camera's peak inside the far one's: a pair of crossovers 0.24 apart inside
    # the edge's one grid cell, F < 0 at both its ends (as dev/fuzz_scenes.py seed 38)
    "a near camera's peak inside a far one's": ((0.8, 0.11), (1.0, 0.36), 1e-12),
    # close to the nearest-point check's limit, where Gauss-Legendre reaches 1e-9
    "a camera 0.1 from the edge": ((0.5, 0.1), (1.3, 0.2), 1e-9),
    "peaks apart, one crossover": ((0.4, 0.3), (1.6, 0.25), 1e-12),
}


def edge_foreshortened_closed_form(first, second, width=2.0):
    """Q = int_0^width max(q_1, q_2) dx, int q dx = h atan((x - a) / h) between the
    crossovers."""
    (a1, h1), (a2, h2) = first, second
    coefficients = [
        h1**2 - h2**2,
        -2.0 * (h1**2 * a2 - h2**2 * a1),
        h1**2 * (a2**2 + h2**2) - h2**2 * (a1**2 + h1**2),
    ]
    roots = [r.real for r in np.roots(coefficients) if abs(r.imag) < 1e-12 and 0 < r.real < width]
    cuts = [0.0, *sorted(roots), width]

    def q(x, a, h):
        return h * h / (h * h + (x - a) ** 2)

    def integral(x0, x1, a, h):
        return h * (math.atan((x1 - a) / h) - math.atan((x0 - a) / h))

    total = 0.0
    for x0, x1 in zip(cuts, cuts[1:]):
        mid = 0.5 * (x0 + x1)
        a, h = first if q(mid, *first) >= q(mid, *second) else second
        total += integral(x0, x1, a, h)
    return total


@pytest.mark.parametrize("case", EDGE_CAMERA_CASES)
def test_two_cameras_beside_an_edge_closed_form(case):
    """Foreshortened Q of two cameras beside one edge, under jit with default options,
    against the closed form (1e-12 relative, 1e-9 for a camera near the quadrature's
    limit), and its gradient against central
    differences of the closed form (1e-6)."""
    first, second, tolerance = EDGE_CAMERA_CASES[case]
    rectangle = ocp.PiecewiseCurve.polygon(
        jnp.array([[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [0.0, 1.0]])
    )
    scene = ocp.Scene([rectangle])
    cameras = np.array([[first[0], 1.0 + first[1]], [second[0], 1.0 + second[1]]])
    value, grad = jax.jit(jax.value_and_grad(lambda c: ocp.visibility(scene, c, FS)))(
        jnp.asarray(cameras)
    )

    def closed_form(c):
        return edge_foreshortened_closed_form(*((x, y - 1.0) for x, y in c))

    assert abs(float(value) / closed_form(cameras) - 1) <= tolerance
    want = H.central_differences(closed_form, cameras, 1e-7)
    assert np.max(np.abs(np.asarray(grad) - want)) <= 1e-6 * np.max(np.abs(want))
