"""Invalid input and exceeded budgets: clear errors, also under jit."""

import functools
import json
import math
import subprocess
import sys

import helpers as H
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import FS, TWO_CIRCLE_CASES, grid_cells, rel, scene_results
from reference import _bisect, eval_curve

import ocp_jax as ocp
from ocp_jax._visibility import events as _events
from ocp_jax._visibility import visibility as _visibility


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
        # (lists: an array of another shape than (k, 2) is outside the annotation)
        (np.zeros((2, 3)).tolist(), r"cameras must have shape \(k, 2\)"),
        (np.zeros((0, 2)), r"k >= 1"),
        (np.zeros((1, 2, 2)).tolist(), r"cameras must have shape \(k, 2\)"),
    ],
)
def test_cameras_with_wrong_shape_raise(cameras, match):
    with pytest.raises(ValueError, match=match):
        ocp.visibility(H.THREE, cameras)
    with pytest.raises(ValueError, match=match):
        ocp.visible_intervals(H.THREE, cameras)


# Arguments outside their annotations, which this suite's runtime type checker (jaxtyping
# with beartype) rejects before the library's own checks: a user's session has no such
# checker, so they run in a subprocess, all in one.
WRONG_TYPES = {
    "a float B-spline degree": (
        "ocp.BSplineCurve([[0, 0], [1, 0], [1, 1], [0, 1]], degree=2.5)",
        "ValueError: BSplineCurve degree must be an integer >= 2",
    ),
    "an array among a scene's curves": (
        "ocp.Scene([circle, np.zeros((4, 2))])",
        "TypeError: Scene curves must be ocp_jax curves",
    ),
    "a list of curves for a scene": (
        "ocp.visibility([circle], [[3.0, 0.0]])",
        "TypeError: scene must be an ocp_jax.Scene",
    ),
    "a curve for a scene": (
        "ocp.visible_intervals(circle, [[3.0, 0.0]])",
        "TypeError: scene must be an ocp_jax.Scene",
    ),
    "a number for an objective": (
        "ocp.visibility(ocp.Scene([circle]), [[3.0, 0.0]], 3.0)",
        "TypeError: objective must be a local objective",
    ),
    "a float grid": (
        "ocp.VisibilityOptions(grid=64.0)",
        "ValueError: VisibilityOptions.grid must be a positive int",
    ),
    "a float interval budget": (
        "ocp.VisibilityOptions(max_camera_intervals=1.5)",
        "ValueError: VisibilityOptions.max_camera_intervals must be a positive int",
    ),
    "no placement": (
        "ocp.place(ocp.Scene([circle]), ocp.VisibleLength(), None, 1)",
        "TypeError: ocp_jax.place: `placement` says where cameras may go",
    ),
    "a string for a solver": (
        "ocp.place(ocp.Scene([circle]), ocp.VisibleLength(), square, 1, solver='bfgs')",
        "TypeError: ocp_jax.place: `solver` is one of",
    ),
    "a float resolution": (
        "ocp.Greedy(resolution=2.5)",
        "ValueError: Greedy: resolution must be a positive int",
    ),
}


@pytest.fixture(scope="module")
def wrong_type_errors() -> dict[str, str]:
    """'Type: message' of each call of WRONG_TYPES, run without a type checker."""
    code = (
        "import json, numpy as np, ocp_jax as ocp\n"
        "circle = ocp.Circle([0.0, 0.0], 1.0)\n"
        "square = ocp.RectangleBoundary([0.0, 0.0], 4.0, 4.0)\n"
        "errors = {}\n"
        "for case, call in json.loads(input()).items():\n"
        "    try:\n"
        "        eval(call)\n"
        "        errors[case] = 'no error'\n"
        "    except Exception as e:\n"
        "        errors[case] = f'{type(e).__name__}: {e}'\n"
        "print(json.dumps(errors))\n"
    )
    calls = json.dumps({case: call for case, (call, _) in WRONG_TYPES.items()})
    done = subprocess.run(
        [sys.executable, "-c", code], input=calls, capture_output=True, text=True, check=True
    )
    return json.loads(done.stdout.splitlines()[-1])


@pytest.mark.parametrize("case", WRONG_TYPES)
def test_wrong_types_get_the_library_message(case, wrong_type_errors):
    assert wrong_type_errors[case].startswith(WRONG_TYPES[case][1]), wrong_type_errors[case]


def test_exceeded_shadow_budget_raises():
    """Small circle in front of a big one: its two silhouette rays meet the big circle
    beyond the small one, 2 shadow times (first crossings) > max_shadows = 1."""
    C, cb, R_, cs, r = TWO_CIRCLE_CASES["in line"]
    fn = jax.jit(lambda s, c: ocp.visibility(s, c, FS, ocp.VisibilityOptions(max_shadows=1)))
    with pytest.raises(
        Exception,
        match=r"more shadow times on one curve than the budget of 1.*max_shadows=.*ocp.fit_options",
    ):
        fn(H.two_circles(cb, R_, cs, r), jnp.asarray([C]))


def test_exceeded_budget_outside_jit_is_grown_with_a_warning():
    """Called outside any jit, the same overflow compiles again with the budgets that
    `fit_options` gives, says so, and returns the Q of those budgets."""
    C, cb, R_, cs, r = TWO_CIRCLE_CASES["in line"]
    scene, camera = H.two_circles(cb, R_, cs, r), jnp.asarray([C])
    tight = ocp.VisibilityOptions(max_shadows=1)
    with pytest.warns(
        UserWarning, match=r"compiled again with VisibilityOptions\(max_shadows=2[,)]"
    ):
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
    with pytest.raises(
        Exception, match=r"more tangency times on one curve than the budget of 1.*max_tangents="
    ):
        fn(H.BANANA, jnp.asarray([H.BANANA_CAMERAS[0]]))


def test_exceeded_interval_budget_raises():
    fn = jax.jit(lambda s, c: ocp.visibility(s, c, FS, ocp.VisibilityOptions(max_intervals=4)))
    with pytest.raises(
        Exception, match=r"more event intervals in the scene than the budget of 4.*max_intervals="
    ):
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
    from ocp_jax._visibility.quadrature import gauss_legendre

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
    np.testing.assert_allclose(
        np.array(jax.jacfwd(integral, argnums=(0, 1, 2))(a, b, w)), np.array(want), rtol=1e-13
    )
    for i in range(3):  # one argument at a time: the others' tangents are symbolic zeros
        alone = float(jax.grad(integral, argnums=i)(a, b, w))
        assert abs(alone - float(want[i])) <= 1e-13 * abs(float(want[i]))


def test_perturbed_jvp_holds_unperturbed_leaves_constant():
    """Leaves whose tangent is a symbolic zero are held constant (not traced as JVP
    inputs); the tangent comes from the perturbed leaves alone."""
    from jax.custom_derivatives import SymbolicZero

    from ocp_jax._visibility.jvp import perturbed_jvp

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
