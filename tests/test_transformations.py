"""Gradients against finite differences; jit, vmap, grad, jacfwd and float32; the
scene's frame (units and place do not matter).
"""

import math

import helpers as H
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import FS, VL, camera_sets, rel, scene_results
from jax.flatten_util import ravel_pytree
from scipy import integrate

import ocp_jax as ocp
from ocp_jax._geometry.vec import Vec
from ocp_jax._visibility import visibility as _visibility


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


@pytest.mark.parametrize(
    "name,k,i", [("three", 2, 0), ("three", 2, 1), ("mixed", 1, 0), ("mixed", 1, 1)]
)
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
    the products of lengths to underflow and overflow (before:
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
