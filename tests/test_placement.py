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
    want = [
        [-50, -20],
        [50, -20],
        [50, 60],
        [-50, 60],
        [-50, -20],
        [0, -20],
        [50, 20],
        [0, 60],
        [-50, 20],
    ]
    np.testing.assert_allclose(RECT.cameras(jnp.asarray(s)[:, None]), want, atol=1e-12)
    # periodic in s
    np.testing.assert_allclose(
        RECT.cameras(jnp.array([[0.3], [1.3], [-0.7]])),
        RECT.cameras(jnp.array([[0.3]] * 3)),
        atol=1e-12,
    )


def test_rectangle_parametrisation_is_by_arc_length():
    """|dC/ds| = perimeter away from the corners, along the side's direction."""
    jac = jax.vmap(jax.jacfwd(lambda s: RECT.cameras(s[None, None])[0]))(
        jnp.array([0.1, 0.4, 0.6, 0.9])
    )
    np.testing.assert_allclose(np.linalg.norm(jac, axis=-1), PERIMETER, rtol=1e-12)
    np.testing.assert_allclose(
        jac, PERIMETER * np.array([[1, 0], [0, 1], [-1, 0], [0, -1]]), atol=1e-9
    )


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
    [
        (((0.0, 0.0), -1.0, 2.0), "width and height must be positive"),
        (((0.0, 0.0, 1.0), 1.0, 2.0), r"center must have shape \(2,\)"),
    ],
)
def test_rectangle_rejects_bad_input(args, match):
    with pytest.raises(ValueError, match=match):
        ocp.RectangleBoundary(*args)


ROOM = ocp.PolygonBoundary(jnp.array([[0.0, 0.0], [4.0, 0.0], [4.0, 3.0], [2.0, 5.0], [0.0, 3.0]]))


def test_polygon_boundary_walks_the_walls_by_arc_length():
    perimeter = 4 + 3 + 2 * np.sqrt(8) + 3
    s = np.array([0.0, 2.0, 4.0, 5.5, 7.0, 7.0 + np.sqrt(8), perimeter - 1.0]) / perimeter
    want = [[0, 0], [2, 0], [4, 0], [4, 1.5], [4, 3], [2, 5], [0, 1]]
    np.testing.assert_allclose(ROOM.cameras(jnp.asarray(s)[:, None]), want, atol=1e-12)
    assert float(ROOM.violation(ROOM.cameras(jnp.linspace(0, 1, 101)[:, None]))) < 1e-12
    assert float(ROOM.violation(jnp.array([[2.0, 1.0]]))) == pytest.approx(1.0)
    grid = ROOM.cameras(ROOM.candidates(8))
    assert grid.shape == (40, 2)  # 8 per wall, each corner once
    np.testing.assert_allclose(grid[8], [4.0, 0.0], atol=1e-12)


def test_rectangle_is_the_four_cornered_polygon():
    as_polygon = ocp.PolygonBoundary(RECT.vertices())
    s = jnp.linspace(-0.3, 1.7, 41)[:, None]
    np.testing.assert_allclose(as_polygon.cameras(s), RECT.cameras(s), atol=1e-12)


@pytest.mark.parametrize(
    "corners,match",
    [
        ([[0.0, 0.0], [1.0, 0.0]], r"shape \(n, 2\) with n >= 3"),
        ([[0.0, 0.0], [1.0, 0.0], [1.0, 0.0], [0.0, 1.0]], "zero-length edge"),
        ([[0.0, 0.0], [1.0, 0.0], [0.0, np.nan]], "NaN or inf"),
    ],
)
def test_polygon_rejects_bad_corners(corners, match):
    with pytest.raises(ValueError, match=match):
        ocp.PolygonBoundary(jnp.asarray(corners))


def test_region_map_sampling_and_candidates():
    triangle = jnp.array([[0.0, 0.0], [4.0, 0.0], [0.0, 4.0]])
    region = ocp.Region(jnp.array([0.0, 0.0]), jnp.array([4.0, 4.0]), polygon=triangle)
    # every parameter maps into the box; the box's corners are reached
    u = jnp.array([[-10.0, 3.0], [np.pi / 2, -np.pi / 2], [0.0, 0.0]])
    cams = np.asarray(region.cameras(u))
    assert np.all((cams >= 0) & (cams <= 4))
    np.testing.assert_allclose(cams[1:], [[4.0, 0.0], [2.0, 2.0]], atol=1e-12)
    starts = region.cameras(region.sample(jax.random.key(1), 3, 50).reshape(-1, 2))
    assert np.all(np.asarray(starts).sum(-1) <= 4.0)  # inside the triangle (16 tries each)
    grid = np.asarray(region.cameras(region.candidates(5)))
    assert len(grid) == 10 and np.all(
        grid.sum(-1) < 4.0 + 1e-12
    )  # the lower-left half, diagonal off


def test_region_constraints_measure_the_clearance_and_the_polygon():
    scene = ocp.Scene([ocp.Circle(jnp.array([0.0, 0.0]), 1.0)])
    square = jnp.array([[-3.0, -3.0], [3.0, -3.0], [3.0, 3.0], [-3.0, 3.0]])
    region = ocp.Region(jnp.array([-4.0, -4.0]), jnp.array([4.0, 4.0]), square, clearance=0.5)
    cams = jnp.array([[2.0, 0.0], [0.0, 0.3], [3.5, 0.0]])
    equal, at_least = region.constraints(cams, scene)
    assert equal.shape == (0,)
    # per camera: distance to the circle minus the clearance, then inside the square
    np.testing.assert_allclose(at_least, [0.5, -1.2, 2.0, 1.0, 2.7, -0.5], atol=1e-9)
    np.testing.assert_allclose(region.violations(cams, scene), [0.0, 1.2, 0.5], atol=1e-9)
    # the gradient of the clearance is the unit vector away from the nearest point
    grad = jax.grad(lambda c: region.constraints(c[None], scene).at_least[0])(jnp.array([1.2, 1.6]))
    np.testing.assert_allclose(grad, [0.6, 0.8], atol=1e-8)


def test_equality_constraint_starts_and_candidates_lie_on_the_set():
    ring = ocp.EqualityConstraint(
        lambda c: jnp.sum(c**2) - 4.0, jnp.array([-3.0, -3.0]), jnp.array([3.0, 3.0])
    )
    starts = ring.sample(jax.random.key(0), 2, 8)
    np.testing.assert_allclose(np.linalg.norm(starts, axis=-1), 2.0, atol=1e-10)
    grid = np.asarray(ring.candidates(9))
    np.testing.assert_allclose(np.linalg.norm(grid, axis=-1), 2.0, atol=1e-10)
    assert len(grid) >= 8 and len(np.unique(grid.round(6), axis=0)) == len(grid)
    cams = jnp.array([[2.0, 0.0], [0.0, 3.0]])
    np.testing.assert_allclose(ring.violations(cams, ocp.scenes.circle()), [0.0, 5.0], atol=1e-12)
    assert float(ring.violation(cams)) == 0.0  # constraints are checked only with a scene


def test_free_placement():
    free = ocp.FreePlacement(jnp.array([-1.0, 2.0]), jnp.array([1.0, 3.0]))
    starts = np.asarray(free.sample(jax.random.key(0), 2, 10))
    assert starts.shape == (10, 2, 2)
    assert np.all(
        (starts[..., 0] >= -1)
        & (starts[..., 0] <= 1)
        & (starts[..., 1] >= 2)
        & (starts[..., 1] <= 3)
    )
    np.testing.assert_array_equal(free.cameras(jnp.asarray(starts[0])), starts[0])
    assert free.candidates(3).shape == (9, 2)
    with pytest.raises(ValueError, match="upper > lower"):
        ocp.FreePlacement(jnp.array([0.0, 0.0]), jnp.array([1.0, 0.0]))


def test_arc_fraction_inverts_the_walk():
    s = jnp.array([0.0, 0.13, 0.5, 0.77, 0.999])
    np.testing.assert_allclose(ROOM.arc_fraction(ROOM.cameras(s[:, None])), s, atol=1e-12)
    np.testing.assert_allclose(RECT.arc_fraction(jnp.array([[0.0, -25.0]])), [50 / 360], atol=1e-12)


def test_coupled_equality_constraint():
    """g couples the cameras: both on the circle of radius 2 and opposite each other."""

    def g(c):
        return jnp.concatenate([jnp.linalg.norm(c, axis=1) - 2.0, c[0] + c[1]])

    pair = ocp.EqualityConstraint(
        g, jnp.array([-3.0, -3.0]), jnp.array([3.0, 3.0]), per_camera=False
    )
    starts = np.asarray(pair.sample(jax.random.key(2), 2, 6))
    np.testing.assert_allclose(np.linalg.norm(starts, axis=-1), 2.0, atol=1e-10)
    np.testing.assert_allclose(starts[:, 0], -starts[:, 1], atol=1e-10)
    np.testing.assert_allclose(
        pair.violations(jnp.array([[2.0, 0.0], [-1.0, 0.0]]), ocp.scenes.circle()), [1.0, 1.0]
    )
    with pytest.raises(ValueError, match="need a per-camera g"):
        pair.candidates(8)
