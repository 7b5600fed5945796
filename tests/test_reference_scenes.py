"""Q, its visible intervals and near-double roots on non-convex scenes of several
objects, against the independent NumPy reference (tests/reference.py).
"""

import functools
import math

import helpers as H
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import BANANA_NEAR_DOUBLE, KIDNEY_NEAR_DOUBLE, camera_sets, grid_cells, scene_results
from reference import eval_curve, reference_visibility, reference_visible_intervals
from scipy import integrate

import ocp_jax as ocp


@functools.cache
def reference_values(name, k, i):
    cams, _ = scene_results(name, k)
    spec = H.to_reference(H.SCENES[name])
    return (
        reference_visibility(spec, cams[i], "visible_length"),
        reference_visibility(spec, cams[i], "foreshortened"),
    )


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
        cams = (
            [scene_results(name, 1)[0].reshape(-1, 2)]
            if name == "banana"
            else [camera_sets(name, k).reshape(-1, 2) for k in (1, 2, 3)]
        )
        for cam in np.concatenate(cams):
            assert not _inside_or_near(spec, cam, 0.1), (name, cam)


@pytest.mark.parametrize(
    "name,k,i", REFERENCE_CASES, ids=[f"{n}-k{k}-{i}" for n, k, i in REFERENCE_CASES]
)
def test_matches_reference(name, k, i):
    cams, out = scene_results(name, k)
    vl, fs = out[0][i], out[1][i]
    ref_vl, ref_fs = reference_values(name, k, i)
    assert abs(vl / ref_vl - 1) <= 1e-7, (vl, ref_vl)
    assert abs(fs / ref_fs - 1) <= 1e-7, (fs, ref_fs)


def test_banana_cameras_on_the_thesis_rectangle():
    (cx, cy), w, h = ocp.scenes.BANANA_RECTANGLE
    for x, y in H.BANANA_CAMERAS:
        assert (abs(abs(x - cx) - w / 2) < 1e-12 and abs(y - cy) <= h / 2) or (
            abs(abs(y - cy) - h / 2) < 1e-12 and abs(x - cx) <= w / 2
        )


@pytest.mark.parametrize("camera", H.BANANA_CAMERAS, ids=str)
def test_banana_matches_reference(camera):
    """The cameras on the rectangle (the near-double ones: test_near_double_roots_banana)."""
    i = H.BANANA_CAMERAS.index(camera)  # its row of the batch
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


@pytest.mark.parametrize("case", H.CAMERAS["three"][1], ids=str)
def test_visible_intervals_match_reference(case):
    i = H.CAMERAS["three"][1].index(case)  # its row of the batch
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
                    lambda t: np.linalg.norm(eval_curve(spec, np.array(t))[1]),
                    a,
                    b,
                    epsabs=1e-13,
                    epsrel=1e-13,
                    limit=200,
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


@pytest.mark.parametrize("case", KIDNEY_NEAR_DOUBLE, ids=str)
def test_near_double_roots_kidney_bspline(case):
    j = KIDNEY_NEAR_DOUBLE.index(case)  # its row after the plain cameras
    _assert_near_double(case)
    cams, (vl, fs) = scene_results("three", 1)
    i = len(H.CAMERAS["three"][1]) + j
    ref_vl, ref_fs = reference_values("three", 1, i)
    assert abs(vl[i] / ref_vl - 1) <= 1e-7
    assert abs(fs[i] / ref_fs - 1) <= 1e-7
    _compare_intervals("three", i)


@pytest.mark.parametrize("case", BANANA_NEAR_DOUBLE, ids=str)
def test_near_double_roots_banana(case):
    j = BANANA_NEAR_DOUBLE.index(case)  # its row after the plain cameras
    _assert_near_double(case)
    _compare_intervals("banana", len(H.BANANA_CAMERAS) + j)


def test_banana_visible_intervals_match_reference():
    for i in range(len(H.BANANA_CAMERAS)):
        _compare_intervals("banana", i)
