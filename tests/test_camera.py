"""Camera poses (heading, view wedge, range): closed forms on a circle, the NumPy
reference on a scene with occlusions, finite differences of every pose parameter, and
bad input."""

import functools
import math

import helpers as H
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from reference import reference_visibility

import ocp_jax as ocp

rel = H.relative_error
G = H.foreshortened_antiderivative
CIRCLE = H.circle_scene()


def _values(scene, camera):
    return ocp.visibility(scene, camera, H.VL), ocp.visibility(scene, camera, H.FS)


@functools.cache
def _batched_values():
    return jax.jit(jax.vmap(_values, in_axes=(None, 0)))


def _values_and_grad(scene, camera):
    fs, grad = jax.value_and_grad(ocp.visibility, argnums=1)(scene, camera, H.FS)
    return ocp.visibility(scene, camera, H.VL), fs, grad


@functools.cache
def _batched_values_and_grad():
    return jax.jit(jax.vmap(_values_and_grad, in_axes=(None, 0)))


def _poses(position, heading, half_fov, range_):
    """A batch of `Camera`s (leading axis n) from arrays (n, k, 2) and (n, k)."""
    return ocp.Camera(
        jnp.asarray(position, float),
        jnp.asarray(heading, float),
        jnp.asarray(half_fov, float),
        jnp.asarray(range_, float),
    )


def _hit_angle(camera, direction):
    """Angle (at the centre) of the first point where the ray from `camera` at angle
    `direction` meets the unit circle."""
    c, u = np.asarray(camera, float), np.array([math.cos(direction), math.sin(direction)])
    b = c @ u
    s = -b - math.sqrt(b * b - c @ c + 1.0)
    p = c + s * u
    return math.atan2(p[1], p[0])


# ===========================================================================
# position-only cameras are the 360-degree, unlimited-range case
# ===========================================================================
def test_position_only_camera_equals_positions_exactly():
    cameras = jnp.asarray(H.CAMERAS["three"][2][0])
    plain = ocp.visibility(H.THREE, cameras, H.FS)
    posed = ocp.visibility(H.THREE, ocp.Camera(cameras, heading=0.7), H.FS)
    assert float(posed) == float(plain)


def test_full_wedge_and_far_range_equal_positions():
    """half_fov = pi and a range beyond the scene: the wedge's edge rays and nothing else
    are new events, which only split intervals."""
    cameras = np.asarray(H.CAMERAS["three"][2])
    n = len(cameras)
    poses = _poses(cameras, np.full((n, 2), 0.4), np.full((n, 2), np.pi), np.full((n, 2), 50.0))
    vl, fs = _batched_values()(H.THREE, poses)
    plain = H.batched("values", H.THREE, cameras)
    assert rel(vl, plain[0]) < 1e-13 and rel(fs, plain[1]) < 1e-13


# ===========================================================================
# closed forms on the unit circle, camera at (3, 0)
# ===========================================================================
D = 3.0
CAMERA = [D, 0.0]
TANGENT = math.acos(1.0 / D)  # half-angle of the arc seen without limits


def _circle_cases():
    """(heading, half_fov, range, (phi_lo, phi_hi)): the arc seen, as angles at the
    centre."""
    cases = []
    # A narrow wedge centred on the circle: both edges hit it.
    a = 0.2
    cases.append(
        (math.pi, a, 50.0, (_hit_angle(CAMERA, math.pi + a), _hit_angle(CAMERA, math.pi - a)))
    )
    # Off centre: edges at pi + 0.25 and pi - 0.05.
    h, a = math.pi + 0.1, 0.15
    cases.append((h, a, 50.0, (_hit_angle(CAMERA, h + a), _hit_angle(CAMERA, h - a))))
    # One edge misses the circle: the arc runs from the other edge's hit to the tangency.
    h, a = math.pi + 0.3, 0.2
    cases.append((h, a, 50.0, (-TANGENT, _hit_angle(CAMERA, h - a))))
    # A wide wedge: the whole arc.
    cases.append((math.pi, 1.0, 50.0, (-TANGENT, TANGENT)))
    # A range circle of radius R cuts the arc at |x - C| = R.
    for r in (2.5, 2.2):
        cut = math.acos((1.0 + D * D - r * r) / (2.0 * D))
        cases.append((0.0, math.pi, r, (-cut, cut)))
    # Wedge and range: edges at pi +- 0.2 hit at distance ~2.08; a range of 2.05 cuts.
    r = 2.05
    cut = math.acos((1.0 + D * D - r * r) / (2.0 * D))
    cases.append((math.pi, 0.2, r, (-cut, cut)))
    return cases


def test_circle_closed_forms():
    cases = _circle_cases()
    heading, fov, reach, arcs = (np.array(v) for v in zip(*cases))
    n = len(cases)
    poses = _poses(np.tile(CAMERA, (n, 1, 1)), heading[:, None], fov[:, None], reach[:, None])
    vl, fs = _batched_values()(CIRCLE, poses)
    lo, hi = arcs[:, 0], arcs[:, 1]
    assert np.all(hi > lo)
    np.testing.assert_allclose(vl, hi - lo, rtol=1e-12)
    np.testing.assert_allclose(fs, G(hi, 1.0, D) - G(lo, 1.0, D), rtol=1e-11)
    # The last case really is cut by the range (not by the wedge).
    assert abs(_hit_angle(CAMERA, math.pi - 0.2)) > hi[-1] + 0.01


def test_visible_intervals_of_a_wedge():
    a = 0.2
    phi_lo = _hit_angle(CAMERA, math.pi + a)
    phi_hi = _hit_angle(CAMERA, math.pi - a)
    seen = ocp.visible_intervals(CIRCLE, ocp.Camera(jnp.array([CAMERA]), math.pi, a))
    intervals = seen.to_list(0, 0)
    two_pi = 2.0 * math.pi
    np.testing.assert_allclose(
        intervals, [(0.0, phi_hi / two_pi), (1.0 + phi_lo / two_pi, 1.0)], atol=1e-14
    )


# ===========================================================================
# three objects: the NumPy reference, finite differences
# ===========================================================================
CENTRE = np.array([1.0, 0.7])
# (cameras, heading offset from the scene centre, half_fov, range), k = 2 each.
THREE_POSES = {  # name: positions, heading offsets, half fields of view, ranges
    "narrow wedges": ([[5.0, 4.0], [-4.5, 2.5]], [0.1, -0.15], [0.35, 0.5], [4.6, 5.0]),
    "short ranges": ([[3.1, 0.2], [-3.0, -2.8]], [0.5, 0.0], [1.2, 0.3], [2.35, 4.35]),
    "one wide wedge": ([[1.2, -4.0], [0.2, 4.5]], [-0.2, 0.25], [0.6, 2.5], [5.5, 4.5]),
    "turned away": ([[-1.4, 2.2], [4.0, -2.0]], [0.9, 0.1], [0.8, 0.45], [1.7, 2.7]),
}


def _three_poses():
    cams = np.array([p[0] for p in THREE_POSES.values()], float)
    to_centre = CENTRE - cams
    heading = np.arctan2(to_centre[..., 1], to_centre[..., 0]) + np.array(
        [p[1] for p in THREE_POSES.values()]
    )
    fov = np.array([p[2] for p in THREE_POSES.values()], float)
    reach = np.array([p[3] for p in THREE_POSES.values()], float)
    return cams, heading, fov, reach


@functools.cache
def three_results():
    cams, heading, fov, reach = _three_poses()
    out = _batched_values_and_grad()(H.THREE, _poses(cams, heading, fov, reach))
    return jax.tree.map(np.asarray, out)


@pytest.mark.parametrize("case", THREE_POSES)
def test_three_objects_match_reference(case):
    i = list(THREE_POSES).index(case)  # its row of the batch
    cams, heading, fov, reach = _three_poses()
    poses = [
        {"heading": heading[i, c], "half_fov": fov[i, c], "range": reach[i, c]} for c in range(2)
    ]
    curves = H.to_reference(H.THREE)
    vl, fs, _ = three_results()
    ref_vl = reference_visibility(curves, cams[i], "visible_length", poses=poses)
    ref_fs = reference_visibility(curves, cams[i], "foreshortened", poses=poses)
    assert abs(vl[i] / ref_vl - 1) < 1e-9
    assert abs(fs[i] / ref_fs - 1) < 1e-7
    # The wedges and ranges matter here: less is seen than without them.
    full = reference_visibility(curves, cams[i], "visible_length")
    assert vl[i] < full - 0.05


def test_pose_gradients_match_finite_differences():
    """d Q / d(position, heading, half_fov, range) vs 4th-order central differences."""
    cams, heading, fov, reach = _three_poses()
    _, _, grads = three_results()
    h = 1e-5
    for i in range(2):
        flat = np.concatenate([cams[i].ravel(), heading[i], fov[i], reach[i]])
        perturbed = []
        for j in range(flat.size):
            for m in (1, -1, 2, -2):
                p = flat.copy()
                p[j] += m * h
                perturbed.append(p)
        p = np.array(perturbed)
        poses = _poses(p[:, :4].reshape(-1, 2, 2), p[:, 4:6], p[:, 6:8], p[:, 8:10])
        _, fs = _batched_values()(H.THREE, poses)
        v = np.asarray(fs).reshape(flat.size, 4)
        fd = (8 * (v[:, 0] - v[:, 1]) - (v[:, 2] - v[:, 3])) / (12 * h)
        g = grads
        grad = np.concatenate([g.position[i].ravel(), g.heading[i], g.half_fov[i], g.range[i]])
        assert rel(grad, fd) < 1e-6
        for part in (slice(0, 4), slice(4, 6), slice(6, 8)):  # position, heading, fov
            assert rel(grad[part], fd[part]) < 1e-6 and np.linalg.norm(fd[part]) > 1e-3


def test_range_gradient_is_exercised():
    """In every case above a range circle cuts a visible arc (a non-zero derivative in
    the range; the first two cases are checked by finite differences)."""
    _, _, grads = three_results()
    assert np.all(np.max(np.abs(grads.range), axis=1) > 1e-3)


# ===========================================================================
# bad input
# ===========================================================================
@pytest.mark.parametrize(
    "kwargs,match",
    [
        ({"half_fov": 4.0}, "half_fov must lie in"),
        ({"half_fov": 0.0}, "half_fov must lie in"),
        ({"range": -1.0}, "range must be positive"),
        ({"heading": [0.0, 1.0, 2.0]}, "batch shape"),
    ],
)
def test_bad_poses_raise(kwargs, match):
    with pytest.raises(ValueError, match=match):
        ocp.Camera(jnp.array([[3.0, 0.0], [0.0, 3.0]]), **kwargs)


def test_nan_heading_raises():
    poses = _poses([[CAMERA]], [[jnp.nan]], [[0.3]], [[5.0]])
    with pytest.raises(Exception, match="heading, half_fov or range is NaN"):
        jax.block_until_ready(_batched_values()(CIRCLE, poses))
