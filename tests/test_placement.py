"""Placement sets: parametrisation, sampling, candidate grids, constraint violation."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ocp_jax as ocp

RECT = ocp.RectangleBoundary(jnp.array([0.0, 20.0]), 100.0, 80.0)  # the thesis's rectangle
PERIMETER = 360.0


def test_rectangle_corners_and_sides():
    s = np.array([0.0, 100, 180, 280, 360, 50, 140, 230, 320]) / PERIMETER
    want = [[-50, -20], [50, -20], [50, 60], [-50, 60], [-50, -20],
            [0, -20], [50, 20], [0, 60], [-50, 20]]
    np.testing.assert_allclose(RECT.cameras(jnp.asarray(s)[:, None]), want, atol=1e-12)
    # periodic in s
    np.testing.assert_allclose(RECT.cameras(jnp.array([[0.3], [1.3], [-0.7]])), RECT.cameras(jnp.array([[0.3]] * 3)), atol=1e-12)


def test_rectangle_parametrisation_is_by_arc_length():
    """|dC/ds| = perimeter away from the corners, along the side's direction."""
    jac = jax.vmap(jax.jacfwd(lambda s: RECT.cameras(s[None, None])[0]))(jnp.array([0.1, 0.4, 0.6, 0.9]))
    np.testing.assert_allclose(np.linalg.norm(jac, axis=-1), PERIMETER, rtol=1e-12)
    np.testing.assert_allclose(jac, PERIMETER * np.array([[1, 0], [0, 1], [-1, 0], [0, -1]]), atol=1e-9)


def test_rectangle_violation():
    on = RECT.cameras(jnp.linspace(0, 1, 37)[:, None])
    assert float(RECT.violation(on)) < 1e-12
    assert abs(float(RECT.violation(jnp.array([[0.0, 20.0]]))) - 40.0) < 1e-12  # centre
    assert abs(float(RECT.violation(jnp.array([[53.0, 64.0]]))) - 5.0) < 1e-12  # beyond a corner
    assert abs(float(RECT.violation(jnp.array([[10.0, -22.0], [0.0, -20.0]]))) - 2.0) < 1e-12


def test_rectangle_sample_and_candidates():
    starts = RECT.sample(jax.random.key(0), 2, 5)
    assert starts.shape == (5, 2, 1)
    assert float(RECT.violation(RECT.cameras(starts.reshape(-1, 1)))) < 1e-12
    grid = RECT.candidates(128)
    assert grid.shape == (512, 1)
    cams = np.asarray(RECT.cameras(grid))
    assert len(np.unique(cams.round(9), axis=0)) == 512  # corners once, no duplicates
    assert float(RECT.violation(cams)) < 1e-12
    # 128 per side: spacing width/128 on the horizontal sides
    np.testing.assert_allclose(np.diff(cams[:128, 0]), 100 / 128, rtol=1e-9)


@pytest.mark.parametrize(
    "args,match",
    [(((0.0, 0.0), -1.0, 2.0), "width and height must be positive"),
     (((0.0, 0.0, 1.0), 1.0, 2.0), r"center must have shape \(2,\)")],
)
def test_rectangle_rejects_bad_input(args, match):
    with pytest.raises(ValueError, match=match):
        ocp.RectangleBoundary(*args)
