"""Objectives of camera groups (Reconstruction, Coverage: Eq. 3.15 with l > 1) and the
smoothed visibility of Chapter 6 (Smoothed).

Values against the NumPy reference extended to camera groups and against closed forms;
gradients against central differences; the smoothed Q against the exact one as the width
shrinks.
"""

import functools
import math

import helpers as H
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from reference import reference_visibility

import ocp_jax as ocp

RECONSTRUCTION = ocp.Reconstruction(area=0.05, delta=0.05)  # q = 1/2 at d ~ 4.5 broadside
REFERENCE_RECONSTRUCTION = ("reconstruction", 0.05, 0.05)
GROUP_CASES = {  # name: scene, camera sets (the best pair varies along curves)
    "three objects, 3 cameras": ("three", H.CAMERAS["three"][3]),
    "mixed, 4 cameras": ("mixed", [[[1.0, 4.2], [3.0, -4.0], [-2.5, 3.0], [1.7, -0.2]]]),
}


@functools.cache
def group_values(case: str):
    name, cameras = GROUP_CASES[case]
    scene = H.SCENES[name]

    @jax.jit
    @jax.vmap
    def values(c):
        return ocp.visibility(scene, c, RECONSTRUCTION), ocp.visibility(scene, c, ocp.Coverage(2))

    return np.asarray(cameras), jax.tree.map(np.asarray, values(jnp.asarray(cameras)))


@pytest.mark.parametrize("case", GROUP_CASES)
def test_groups_match_reference(case):
    """Reconstruction (best pair) and Coverage(2) on non-convex scenes with occlusions,
    3 cameras (two sets) and 4 cameras (6 pairs, 15 crossover functions), against the
    NumPy reference's pairs."""
    name = GROUP_CASES[case][0]
    cameras, (reconstruction, coverage) = group_values(case)
    curves = H.to_reference(H.SCENES[name])
    for i, c in enumerate(cameras):
        want = reference_visibility(curves, c, REFERENCE_RECONSTRUCTION)
        assert abs(reconstruction[i] / want - 1) < 1e-9, (i, reconstruction[i], want)
        want = reference_visibility(curves, c, ("coverage", 2))
        assert abs(coverage[i] / want - 1) < 1e-9, (i, coverage[i], want)
        assert reconstruction[i] > 0.05  # the pairs see something together


def test_coverage_closed_forms():
    """Cameras at distance d from a unit circle see arcs of half-angle acos(1/d). Two,
    psi apart, both see 2 acos(1/d) - psi; Coverage(1) is the visible length. Three at
    d = 3, 120 degrees apart: each pair shares 2 acos(1/3) - 2 pi / 3, no point is seen
    by all three, and together they see the whole circle."""
    circle = H.circle_scene()
    d, psi = 3.0, 0.7
    half = math.acos(1 / d)
    pair = jnp.array([[d, 0.0], [d * math.cos(psi), d * math.sin(psi)]])
    assert abs(ocp.visibility(circle, pair, ocp.Coverage(2)) - (2 * half - psi)) < 1e-13
    single = ocp.visibility(circle, pair, ocp.VisibleLength())
    assert abs(ocp.visibility(circle, pair, ocp.Coverage(1)) - single) < 1e-14
    angles = 2 * math.pi * np.arange(3) / 3
    triple = jnp.asarray(d * np.stack([np.cos(angles), np.sin(angles)], 1))
    shared = 3 * (2 * half - 2 * math.pi / 3)
    assert abs(ocp.visibility(circle, triple, ocp.Coverage(2)) - shared) < 1e-13
    assert ocp.visibility(circle, triple, ocp.Coverage(3)) == 0.0
    assert abs(ocp.visibility(circle, triple, ocp.Coverage(1)) - 2 * math.pi) < 1e-13


def test_negative_q_is_maximised_with_the_unseen_groups_zero():
    """Eq. 3.15's max runs over chi q, which is 0 for a camera that does not see the
    point: for q = -1 and two cameras psi apart at distance d from a unit circle, Q is
    minus the arc that both see, 2 acos(1/d) - psi (where one sees, the other's 0 wins)."""
    circle = H.circle_scene()
    d, psi = 3.0, 0.7
    pair = jnp.array([[d, 0.0], [d * math.cos(psi), d * math.sin(psi)]])
    value = ocp.visibility(circle, pair, lambda point, tangent, camera: -jnp.ones(()))
    assert abs(value + (2 * math.acos(1 / d) - psi)) < 1e-13


def test_reconstruction_local_objective():
    """q = 1 / (1 + (A / area)^2) with the error region A = delta^2 d1 d2 / sin(theta) of
    two wedges of angle delta: against the quadrilateral cut out by the four rays, built
    by hand (small delta), and symmetric in the cameras; 0 for collinear cameras."""
    delta, area = 1e-4, 3e-8
    objective = ocp.Reconstruction(area=area, delta=delta)
    point = np.array([0.3, -0.2])
    for c1, c2 in (([4.0, 1.0], [-1.0, 3.5]), ([2.0, -3.0], [-3.0, -2.5]), ([0.3, 5], [5, -0.2])):
        c1, c2 = np.array(c1), np.array(c2)
        # Corners of the error quadrilateral: intersections of the edge rays of both wedges.
        corners = []
        for s1 in (-0.5, 0.5):
            for s2 in (-0.5, 0.5):
                u1 = rotate(point - c1, s1 * delta)
                u2 = rotate(point - c2, s2 * delta)
                t = np.linalg.solve(np.stack([u1, -u2], 1), c2 - c1)
                corners.append(c1 + t[0] * u1)
        quad = np.array(corners)[[0, 1, 3, 2]]
        shoelace = 0.5 * abs(
            np.dot(quad[:, 0], np.roll(quad[:, 1], 1)) - np.dot(quad[:, 1], np.roll(quad[:, 0], 1))
        )
        q = float(objective(jnp.asarray(point), jnp.zeros(2), jnp.asarray(c1), jnp.asarray(c2)))
        assert abs(q - 1 / (1 + (shoelace / area) ** 2)) < 1e-6
        q21 = float(objective(jnp.asarray(point), jnp.zeros(2), jnp.asarray(c2), jnp.asarray(c1)))
        assert q == q21
    collinear = objective(
        jnp.asarray(point), jnp.zeros(2), jnp.array([1.3, -0.2]), jnp.array([-4.0, -0.2])
    )
    assert float(collinear) == 0.0


def rotate(v, angle):
    c, s = math.cos(angle), math.sin(angle)
    return np.array([c * v[0] - s * v[1], s * v[0] + c * v[1]])


def assert_gradients_match_differences(scene, cameras, objective):
    """dQ/dcameras against central differences in every coordinate, and dQ/dscene along
    a random direction over every parameter, both to 1e-6 relative (one compiled value
    and one compiled gradient)."""
    cameras = np.asarray(cameras)
    value = jax.jit(lambda s, c: ocp.visibility(s, c, objective))
    grad_scene, grad_cameras = jax.jit(jax.grad(value, argnums=(0, 1)))(scene, jnp.asarray(cameras))
    fd = H.central_differences(lambda c: value(scene, c), cameras, 1e-6)
    assert np.max(np.abs(grad_cameras - fd)) <= 1e-6 * np.max(np.abs(fd)), (grad_cameras, fd)
    leaves, tree = jax.tree.flatten(scene)
    keys = jax.random.split(jax.random.key(0), len(leaves))
    v = jax.tree.unflatten(
        tree, [jax.random.normal(k, a.shape, a.dtype) for k, a in zip(keys, leaves)]
    )
    moved = lambda e: jax.tree.map(lambda a, b: a + e * b, scene, v)  # noqa: E731
    fd = (
        value(moved(1e-6), jnp.asarray(cameras)) - value(moved(-1e-6), jnp.asarray(cameras))
    ) / 2e-6
    ad = sum(jnp.vdot(a, b) for a, b in zip(jax.tree.leaves(grad_scene), jax.tree.leaves(v)))
    assert abs(fd / ad - 1) < 1e-6, (fd, ad)


@pytest.mark.parametrize(
    "objective", [RECONSTRUCTION, ocp.Coverage(2)], ids=["reconstruction", "coverage"]
)
def test_group_gradients_match_differences(objective):
    """dQ/dcameras and dQ/dscene (a random direction over every control point) against
    central differences, 3 cameras on the mixed scene (Bezier, circle, ellipse)."""
    assert_gradients_match_differences(H.MIXED, H.CAMERAS["mixed"][3][0], objective)


def test_group_objectives_need_enough_cameras():
    circle = H.circle_scene()
    with pytest.raises(ValueError, match="Reconstruction values groups of 2 cameras"):
        ocp.visibility(circle, jnp.array([[3.0, 0.0]]), RECONSTRUCTION)
    with pytest.raises(ValueError, match="Coverage values groups of 3 cameras"):
        ocp.visibility(circle, jnp.array([[3.0, 0.0], [0.0, 3.0]]), ocp.Coverage(3))
    with pytest.raises(ValueError, match="area must be positive"):
        ocp.Reconstruction(area=-1.0)
    with pytest.raises(ValueError, match="Coverage.m must be a positive int"):
        ocp.Coverage(0)
    with pytest.raises(ValueError, match="Reconstruction values groups of 2 cameras"):
        square = ocp.RectangleBoundary(jnp.zeros(2), 8.0, 8.0)
        ocp.place(circle, RECONSTRUCTION, square, 1, solver=ocp.Greedy())


# --- the smoothed visibility of Chapter 6 --------------------------------------------

SMOOTH_NODES = 1024
WIDTHS = (0.1, 0.05, 0.025, 0.0125)


@functools.cache
def smoothed_circle_errors():
    """(VisibleLength, Foreshortened) errors of the smoothed Q on a unit circle seen from
    (3, 0), for each width (one compilation: the width is an array)."""
    circle, camera = H.circle_scene(), jnp.array([[3.0, 0.0]])

    @jax.jit
    def values(width):
        return [
            ocp.visibility(circle, camera, ocp.Smoothed(q, width, nodes=SMOOTH_NODES))
            for q in (ocp.VisibleLength(), ocp.Foreshortened())
        ]

    exact = (H.circle_visible_length(1.0, 3.0), H.circle_foreshortened(1.0, 3.0))
    return np.array([[float(v) - e for v, e in zip(values(jnp.asarray(w)), exact)] for w in WIDTHS])


def test_smoothed_converges_on_a_convex_object():
    """Smoothed Q -> exact Q as the width w -> 0 (convex object, no occluders): the
    errors shrink with w; at w = 0.0125 visible length is within 2.5e-4 of 2 acos(1/3), the
    foreshortened Q within 1e-6 (it vanishes at the silhouettes, where the smoothing
    acts). Rates are in benchmarks/smoothed_vs_exact.py."""
    errors = np.abs(smoothed_circle_errors())
    assert np.all(np.diff(errors[:, 1]) < 0), errors  # foreshortened: strictly decreasing
    assert errors[-1, 0] < 2.5e-4 and errors[-1, 0] < errors[0, 0] / 100, errors
    assert errors[-1, 1] < 1e-6, errors


def test_smoothed_matches_exact_on_the_banana():
    """The banana's self-occlusion (non-convex) from a camera on the thesis's rectangle:
    the smoothed foreshortened Q at w = 0.01 agrees with the exact one to 1e-5."""
    camera = jnp.array([H.BANANA_CAMERAS[0]])
    exact = ocp.visibility(H.BANANA, camera)
    smoothed = ocp.visibility(H.BANANA, camera, ocp.Smoothed(ocp.Foreshortened(), 0.01, nodes=512))
    assert abs(smoothed / exact - 1) < 1e-5, (smoothed, exact)


@pytest.mark.parametrize("inner", [ocp.Foreshortened(), RECONSTRUCTION], ids=["fs", "pairs"])
def test_smoothed_gradients_match_differences(inner):
    """Gradients of the smoothed Q (cameras, and every control point along a random
    direction) against central differences, two cameras among three objects."""
    objective = ocp.Smoothed(inner, 0.05, nodes=64)
    assert_gradients_match_differences(H.THREE, H.CAMERAS["three"][2][1], objective)


def test_smoothed_bad_input():
    circle = H.circle_scene()
    with pytest.raises(ValueError, match="width must be positive"):
        ocp.Smoothed(ocp.Foreshortened(), 0.0)
    with pytest.raises(ValueError, match="nodes must be an int >= 8"):
        ocp.Smoothed(ocp.Foreshortened(), 0.1, nodes=4)
    with pytest.raises(TypeError, match="smooth a plain local objective once"):
        ocp.Smoothed(ocp.Smoothed(ocp.Foreshortened(), 0.1), 0.1)
    wedge = ocp.Camera(jnp.array([[3.0, 0.0]]), jnp.array([math.pi]), jnp.array([0.5]))
    with pytest.raises(ValueError, match="no view wedge or range"):
        ocp.visibility(circle, wedge, ocp.Smoothed(ocp.Foreshortened(), 0.1))
    with pytest.raises(Exception, match="inside an object"):
        ocp.visibility(circle, jnp.array([[0.2, 0.0]]), ocp.Smoothed(ocp.Foreshortened(), 0.1))


# --- the optimiser, the baselines and the plots take the new objectives ---------------

SQUARE = ocp.RectangleBoundary(jnp.zeros(2), 8.0, 8.0)


def test_optimize_coverage_finds_the_closed_form():
    """Length seen by both of two cameras on the square |x|, |y| = 4 around the unit
    circle: the arc both see is longest with both cameras together at a corner, where it
    is 2 acos(1 / (4 sqrt 2)); greedy's first stage is the best pair of the 16
    candidates (two distinct ones: less)."""
    want = 2 * math.acos(1 / (4 * math.sqrt(2)))
    solver = ocp.MultiStart(n_starts=4, max_steps=60)
    result = ocp.place(H.circle_scene(), ocp.Coverage(2), SQUARE, 2, solver=solver)
    assert abs(float(result.value) - want) < 1e-6, result.value
    baseline = ocp.place(H.circle_scene(), ocp.Coverage(2), SQUARE, 2, solver=ocp.Greedy(4))
    assert baseline.num_evaluations == math.comb(16, 2)
    assert abs(float(np.max(baseline.stage_values[0])) - float(baseline.value)) < 1e-12
    assert float(baseline.value) < want


def test_optimize_refines_greedy_reconstruction():
    """Two cameras for triangulation on the square around two circles. The landscape
    has many local optima (16 random starts end at 1.765 at best); greedy's best pair
    of the 32 candidates (1.880) is in a better basin, and BFGS started there improves
    it to a stationary point."""
    scene = ocp.Scene(
        [ocp.Circle(jnp.array([-1.5, 0.0]), 1.0), ocp.Circle(jnp.array([1.8, 0.6]), 0.7)]
    )
    objective = ocp.Reconstruction(area=0.05, delta=0.05)
    baseline = ocp.place(scene, objective, SQUARE, 2, solver=ocp.Greedy(8))
    starts = SQUARE.arc_fraction(baseline.cameras)[None, :, None]
    solver = ocp.MultiStart(starts=starts, max_steps=100)
    result = ocp.place(scene, objective, SQUARE, 2, solver=solver)
    assert result.result == ocp.RESULTS.successful
    assert float(result.value) > float(baseline.value) * (1 + 1e-3) > 1.8, (
        result.value,
        baseline.value,
    )


def test_optimize_smoothed_objective():
    """The optimiser takes a Smoothed objective: one camera on the square around the
    unit circle, smoothed foreshortened Q at w = 0.02, ends at a corner, where the exact
    Q is largest (within the optimum's flatness)."""
    objective = ocp.Smoothed(ocp.Foreshortened(), 0.02, nodes=256)
    solver = ocp.MultiStart(n_starts=4, max_steps=60)
    result = ocp.place(H.circle_scene(), objective, SQUARE, 1, solver=solver)
    corner = np.abs(np.asarray(result.cameras[0]))
    assert np.allclose(corner, 4.0, atol=0.05), result.cameras
    exact = ocp.visibility(H.circle_scene(), jnp.full((1, 2), 4.0))
    assert abs(float(result.value) / float(exact) - 1) < 1e-3


def test_plots_take_group_objectives():
    import matplotlib

    matplotlib.use("Agg")
    from ocp_jax import plot

    cameras = jnp.array([[4.0, 1.0], [-1.0, 4.0]])
    ax = plot.plot_landscape(H.circle_scene(), SQUARE, cameras, 1, ocp.Coverage(2), resolution=64)
    values = ax.lines[0].get_ydata()
    # camera 1 sees an arc shared with camera 0 only from part of the square
    assert values.max() > 1.0 and values.min() == 0.0
    matplotlib.pyplot.close(ax.figure)
