"""The occlusion events and their implicit-function derivatives against the thesis's
closed forms (Eqs. 5.17, 5.28, 5.32).
"""

import functools
import math

import helpers as H
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import J, R, camera_events, events_and_jacobian, grid_cells, rel
from jax.flatten_util import ravel_pytree
from reference import eval_curve

import ocp_jax as ocp
from ocp_jax._geometry.vec import Vec
from ocp_jax._visibility import events as _events
from ocp_jax._visibility import occlusion as _occlusion

# ===========================================================================
# events: the implicit-function derivatives against the thesis's closed forms
# ===========================================================================


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


@pytest.mark.parametrize("case", EVENT_CAMERAS, ids=str)
def test_tangency_time_derivative_matches_eqs_5_28_and_5_32(case, reference_specs):
    ci = EVENT_CAMERAS.index(case)  # its row of the batch
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


@pytest.mark.parametrize("case", EVENT_CAMERAS, ids=str)
def test_shadow_time_derivative_matches_eq_5_17(case, reference_specs):
    """dS/dC for a shadow time S of the tangency point P = x(T): from Eq. 5.16,
    dS/dC = (x(S) - P)^T R^T / (x'(S)^T R (C - P)). Eq. 5.17 as printed has R instead of
    R^T in the numerator, i.e. the opposite sign; finite differences decide."""
    ci = EVENT_CAMERAS.index(case)  # its row of the batch
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
    **{f"three, camera {camera}": ("three", c) for c, camera in enumerate(EVENT_CAMERAS)},
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
    "circle": (
        ocp.Circle([1.0, -1.0], 2.0),
        2.0 * (math.cos(math.pi / 64) - 2 * math.sin(math.pi / 64)),
    ),
    # The mean of the grid points, (1.5, 1.75), lies in the U's notch: no disc.
    "U shape": (
        ocp.PiecewiseCurve.polygon(
            [(0, 0), (3, 0), (3, 3), (2, 3), (2, 1), (1, 1), (1, 3), (0, 3)]
        ),
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
    scene = ocp.scenes.floor(
        seed=11, cells=10, objects=5, kinds=("rectangle", "l_shape", "triangle")
    )
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
    want = [
        np.inf if hit is None else (hit[1] - camera) @ d / (d @ d) for hit, d in zip(hits, rays)
    ]
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
        return np.sign(
            (q[..., 0] - p[..., 0]) * (r[..., 1] - p[..., 1])
            - (q[..., 1] - p[..., 1]) * (r[..., 0] - p[..., 0])
        )

    c, m = camera[None, None], query[:, None]
    a, b = start[None], end[None]
    want = (side(c, m, a) != side(c, m, b)) & (side(a, b, c) != side(a, b, m))
    d = query - camera
    got = _occlusion._crosses_edges(
        Vec(*jnp.moveaxis(jnp.asarray(d[:, None]), -1, 0)),
        jnp.asarray(np.sum(d * d, -1))[:, None],
        Vec(*jnp.moveaxis(jnp.asarray(start[None] - camera), -1, 0)),
        Vec(*jnp.moveaxis(jnp.asarray(end[None] - camera), -1, 0)),
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
