"""`ocp.place` with each solver: the multi-start optimiser, SLSQP and the discrete baselines.

Small scenes (one ellipse or circle, a few starts) keep compilation short; each problem
shape is optimised once per module (functools.cache) and shared by the tests.
"""

import functools
import itertools
import math
import os
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ocp_jax as ocp

ELLIPSE = ocp.Scene([ocp.Ellipse(jnp.zeros(2), jnp.array([2.0, 1.0]))])
RING_RADIUS = 6.0
RING = ocp.EqualityConstraint(
    lambda c: jnp.linalg.norm(c) - RING_RADIUS, jnp.array([-7.0, -7.0]), jnp.array([7.0, 7.0])
)
CIRCLE = ocp.Scene([ocp.Circle(jnp.array([0.0, 0.0]), 1.0)])
BOX = ocp.Region(jnp.array([-3.0, -3.0]), jnp.array([3.0, 3.0]), clearance=0.5)
SQUARE = ocp.RectangleBoundary(jnp.array([0.5, 0.0]), 10.0, 8.0)
TWO_CIRCLES = ocp.Scene(
    [ocp.Circle(jnp.array([-1.5, 0.0]), 1.0), ocp.Circle(jnp.array([1.8, 0.6]), 0.7)]
)
TRIANGLE = ocp.PolygonBoundary(jnp.array([[-6.0, -4.0], [6.0, -4.0], [0.0, 6.0]]))


@functools.cache
def ring_result():
    """Foreshortened ellipse (semi-axes 2, 1), one camera on the circle |C| = 6 (an
    equality constraint, augmented Lagrangian): by symmetry the optimum is broadside,
    C = (0, +-6)."""
    return ocp.place(
        ELLIPSE, ocp.Foreshortened(), RING, 1, solver=ocp.MultiStart(n_starts=4, max_steps=60)
    )


@functools.cache
def box_result():
    """Visible length of a unit circle, one camera in a 6 x 6 box (smooth sin map) kept
    0.5 away from it: 2 acos(1/d) grows with d, so the optimum is a corner."""
    return ocp.place(
        CIRCLE, ocp.VisibleLength(), BOX, 1, solver=ocp.MultiStart(n_starts=4, max_steps=60)
    )


@functools.cache
def square_starts():
    return SQUARE.sample(jax.random.key(3), 2, 4)


@functools.cache
def square_result():
    """Two cameras on a rectangle around two circles (a parametrised boundary)."""
    solver = ocp.MultiStart(starts=square_starts(), max_steps=60)
    return ocp.place(TWO_CIRCLES, ocp.Foreshortened(), SQUARE, 2, solver=solver)


def test_equality_constraint_known_optimum():
    result = ring_result()
    camera = np.asarray(result.cameras[0])
    np.testing.assert_allclose(np.abs(camera), [0.0, RING_RADIUS], atol=1e-6)
    assert result.violation <= 1e-6
    assert abs(np.linalg.norm(camera) - RING_RADIUS) <= 1e-6
    broadside = ocp.visibility(ELLIPSE, jnp.array([[0.0, RING_RADIUS]]), ocp.Foreshortened())
    assert float(result.value) == pytest.approx(float(broadside), rel=1e-9)
    # and no point of the ring does better (a scan every degree)
    angles = np.linspace(0, np.pi, 181)
    ring = RING_RADIUS * np.stack([np.cos(angles), np.sin(angles)], 1)
    scan = jax.jit(jax.vmap(lambda c: ocp.visibility(ELLIPSE, c[None], ocp.Foreshortened())))
    assert float(result.value) >= float(jnp.max(scan(jnp.asarray(ring)))) - 1e-9


def test_region_known_optimum_at_a_corner():
    result = box_result()
    np.testing.assert_allclose(np.abs(np.asarray(result.cameras[0])), [3.0, 3.0], atol=1e-6)
    assert float(result.value) == pytest.approx(2 * math.acos(1 / (3 * math.sqrt(2))), rel=1e-9)
    assert result.violation <= 1e-8


def test_region_keeps_the_clearance():
    """Starts inside the clearance zone (or the object) end outside it."""
    starts = BOX._params(jnp.array([[[0.2, 0.1]], [[1.2, 0.0]], [[-2.0, 2.5]], [[0.0, -1.3]]]))
    solver = ocp.MultiStart(starts=starts, max_steps=60)
    result = ocp.place(CIRCLE, ocp.VisibleLength(), BOX, 1, solver=solver)
    infeasible = np.asarray(result.start_results == ocp.RESULTS.infeasible_start)
    np.testing.assert_array_equal(infeasible, [True, False, False, False])  # inside the circle
    distances = np.linalg.norm(np.asarray(result.start_cameras[1:, 0]), axis=-1)
    assert np.all(distances >= 1.5 - 1e-6)
    assert float(BOX.violation(result.cameras, CIRCLE)) <= 1e-6


@pytest.mark.parametrize(
    "solve,scene,objective",
    [
        (ring_result, ELLIPSE, ocp.Foreshortened()),
        (box_result, CIRCLE, ocp.VisibleLength()),
        (square_result, TWO_CIRCLES, ocp.Foreshortened()),
    ],
)
def test_returned_value_and_bookkeeping(solve, scene, objective):
    result = solve()
    assert float(result.value) == float(ocp.visibility(scene, result.cameras, objective))
    assert float(result.value) == float(jnp.max(result.start_values))
    assert result.num_evaluations == int(jnp.sum(result.num_steps))
    assert result.history.shape[1] == 3
    assert float(result.history[-1, 2]) <= float(result.value) + 1e-6


def test_boundary_results_lie_on_it():
    square = square_result()
    assert float(SQUARE.violation(square.start_cameras.reshape(-1, 2))) <= 1e-8
    ended = square.start_results
    assert bool(
        jnp.all((ended == ocp.RESULTS.successful) | (ended == ocp.RESULTS.max_steps_reached))
    )


def test_vmapped_starts_equal_single_solves():
    batch = square_result()
    for index in (0, 2):
        solver = ocp.MultiStart(starts=square_starts()[index : index + 1], max_steps=60)
        single = ocp.place(TWO_CIRCLES, ocp.Foreshortened(), SQUARE, 2, solver=solver)
        np.testing.assert_allclose(single.cameras, batch.start_cameras[index], atol=1e-9)
        assert int(single.num_steps[0]) == int(batch.num_steps[index])


def test_multistart_beats_greedy_on_two_circles():
    greedy = ocp.place(TWO_CIRCLES, ocp.Foreshortened(), SQUARE, 2, solver=ocp.Greedy(16))
    # The optimum is at a corner, a kink of Q(s): BFGS creeps up on it (to ~1e-9)
    assert float(square_result().value) >= float(greedy.value) * (1 - 1e-8)


def test_greedy_and_exhaustive_match_brute_force():
    """On 12 candidates (4 per side of a triangle), against plain loops over visibility."""
    objective = ocp.Foreshortened()
    candidates = np.asarray(TRIANGLE.cameras(TRIANGLE.candidates(4)))
    assert candidates.shape == (12, 2)

    def q(cams):
        return float(ocp.visibility(TWO_CIRCLES, jnp.asarray(cams), objective))

    # exhaustive: every pair
    pairs = list(itertools.combinations(range(12), 2))
    values = [q(candidates[list(p)]) for p in pairs]
    best = candidates[list(pairs[int(np.argmax(values))])]
    result = ocp.place(TWO_CIRCLES, objective, TRIANGLE, 2, solver=ocp.Exhaustive(4, chunk=16))
    np.testing.assert_allclose(result.cameras, best, atol=1e-12)
    assert float(result.value) == pytest.approx(max(values), rel=1e-12)
    assert result.num_evaluations == 66
    # greedy: the best single camera, then the best second one
    first = candidates[int(np.argmax([q(c[None]) for c in candidates]))]
    second = candidates[int(np.argmax([q(np.stack([first, c])) for c in candidates]))]
    result = ocp.place(TWO_CIRCLES, objective, TRIANGLE, 2, solver=ocp.Greedy(4, chunk=16))
    np.testing.assert_allclose(result.cameras, [first, second], atol=1e-12)
    assert result.num_evaluations == 24
    assert len(result.stage_values) == 2 and result.stage_values[0].shape == (12,)


def test_greedy_drops_inadmissible_candidates():
    """Region candidates within the clearance are never chosen."""
    result = ocp.place(CIRCLE, ocp.VisibleLength(), BOX, 1, solver=ocp.Greedy(7, chunk=16))
    distances = np.linalg.norm(np.asarray(result.candidates), axis=-1)
    assert np.all(distances >= 1.5) and len(distances) == 49 - 9  # the 3 x 3 around the centre
    np.testing.assert_allclose(np.abs(np.asarray(result.cameras[0])), [3.0, 3.0], atol=1e-12)


def test_searches_grow_an_overflowed_budget():
    """A budget too small for the events (a circle has two tangents from every camera,
    over a budget of one) is grown, with a warning, and the search finds what it finds
    with the default budgets."""
    tight = ocp.VisibilityOptions(max_tangents=1)
    for search in (ocp.Greedy, ocp.Exhaustive):
        solver = search(resolution=3, chunk=16)
        want = ocp.place(CIRCLE, ocp.VisibleLength(), BOX, 1, solver=solver)
        with pytest.warns(UserWarning, match=r"VisibilityOptions\(max_tangents=2"):
            got = ocp.place(CIRCLE, ocp.VisibleLength(), BOX, 1, solver=solver, options=tight)
        assert float(got.value) == float(want.value)
        np.testing.assert_array_equal(np.asarray(got.cameras), np.asarray(want.cameras))


def test_slsqp_from_the_same_starts():
    solver = ocp.SLSQP(starts=square_starts(), max_steps=60)
    result = ocp.place(TWO_CIRCLES, ocp.Foreshortened(), SQUARE, 2, solver=solver)
    assert isinstance(result, ocp.Solution) and result.start_values.shape == (4,)
    assert np.asarray(result.start_results == ocp.RESULTS.successful).shape == (4,)
    assert result.num_evaluations > 4
    assert float(result.value) <= float(square_result().value) + 1e-6
    assert float(SQUARE.violation(result.cameras)) <= 1e-8


def test_bad_input():
    vl = ocp.VisibleLength()
    with pytest.raises(ValueError, match="n_cameras must be a positive int"):
        ocp.place(CIRCLE, vl, SQUARE, 0)
    with pytest.raises(ValueError, match="MultiStart: n_starts must be a positive int"):
        ocp.MultiStart(n_starts=0)
    with pytest.raises(ValueError, match="SLSQP: max_steps must be a positive int"):
        ocp.SLSQP(max_steps=0)
    with pytest.raises(ValueError, match="Greedy: resolution must be a positive int"):
        ocp.Greedy(resolution=0)
    with pytest.raises(ValueError, match="Exhaustive: chunk must be a positive int"):
        ocp.Exhaustive(chunk=-1)
    for solver in (ocp.MultiStart, ocp.SLSQP):  # camera positions, not boundary parameters
        with pytest.raises(ValueError, match=r"of shape \(n_starts, n_cameras=2, 1\)"):
            ocp.place(CIRCLE, vl, SQUARE, 2, solver=solver(starts=jnp.zeros((3, 2, 2))))
    with pytest.raises(ValueError, match=r"exceed Exhaustive\(max_evaluations=1000\)"):
        ocp.place(CIRCLE, vl, SQUARE, 3, solver=ocp.Exhaustive(64, max_evaluations=1000))


def test_infeasible_placement_is_named():
    """A placement inside the object: every start and every candidate is infeasible."""
    inside = ocp.Region(jnp.array([-0.5, -0.5]), jnp.array([0.5, 0.5]))
    with pytest.raises(ValueError, match="every start is infeasible"):
        ocp.place(CIRCLE, ocp.VisibleLength(), inside, 1, solver=ocp.MultiStart(n_starts=2))
    with pytest.raises(ValueError, match="every candidate of the placement"):
        ocp.place(CIRCLE, ocp.VisibleLength(), inside, 1, solver=ocp.Greedy(3))


def test_visibility_with_a_status_instead_of_an_error():
    """`throw=False` under jit: Q and `successful` outside the circle; NaN and
    `invalid_cameras` inside it; `budget_exceeded` for a budget too small."""
    q = jax.jit(
        lambda c, o: ocp.visibility(CIRCLE, c, ocp.VisibleLength(), o, throw=False),
        static_argnums=1,
    )
    value, result = q(jnp.array([[3.0, 0.0]]), ocp.VisibilityOptions())
    assert result == ocp.RESULTS.successful
    assert float(value) == pytest.approx(2 * math.acos(1 / 3), rel=1e-12)
    value, result = q(jnp.array([[0.2, 0.0]]), ocp.VisibilityOptions())
    assert result == ocp.RESULTS.invalid_cameras and np.isnan(float(value))
    value, result = q(jnp.array([[3.0, 0.0]]), ocp.VisibilityOptions(max_tangents=1))
    assert result == ocp.RESULTS.budget_exceeded and np.isnan(float(value))


SHARDED = """
import jax, jax.numpy as jnp, numpy as np
jax.config.update("jax_enable_x64", True)
import ocp_jax as ocp
assert len(jax.devices()) == 2
scene = ocp.Scene([ocp.Circle(jnp.array([-1.5, 0.0]), 1.0), ocp.Circle(jnp.array([1.8, 0.6]), 0.7)])
placement = ocp.RectangleBoundary(jnp.array([0.5, 0.0]), 10.0, 8.0)
starts = placement.sample(jax.random.key(3), 2, 4)[:3]  # 3 starts on 2 devices: padded
solver = ocp.MultiStart(starts=starts, max_steps=60)
result = ocp.place(scene, ocp.Foreshortened(), placement, 2, solver=solver)
np.save("{out}", np.asarray(result.start_cameras))
"""


def test_starts_sharded_over_two_devices(tmp_path):
    """The same starts give the same results laid out over two (host) devices."""
    out = tmp_path / "cameras.npy"
    flags = os.environ.get("XLA_FLAGS", "")  # conftest's optimisation level too
    env = {**os.environ, "XLA_FLAGS": f"{flags} --xla_force_host_platform_device_count=2"}
    subprocess.run([sys.executable, "-c", SHARDED.format(out=out)], check=True, env=env)
    np.testing.assert_allclose(np.load(out), square_result().start_cameras[:3], atol=1e-9)


def test_coupled_equality_constraint_known_optimum():
    """Two cameras on the ring |C| = 6, held opposite each other by a coupled g: by
    symmetry they look at the ellipse broadside from both sides, (0, 6) and (0, -6)."""

    def g(c):
        return jnp.concatenate([jnp.linalg.norm(c, axis=1) - RING_RADIUS, c[0] + c[1]])

    pair = ocp.EqualityConstraint(
        g, jnp.array([-7.0, -7.0]), jnp.array([7.0, 7.0]), per_camera=False
    )
    solver = ocp.MultiStart(n_starts=4, max_steps=60)
    result = ocp.place(ELLIPSE, ocp.Foreshortened(), pair, 2, solver=solver)
    np.testing.assert_allclose(np.abs(np.asarray(result.cameras)), [[0, 6], [0, 6]], atol=1e-6)
    assert result.violation <= 1e-6
    broadside = ocp.visibility(ELLIPSE, jnp.array([[0.0, 6.0], [0.0, -6.0]]), ocp.Foreshortened())
    assert float(result.value) == pytest.approx(float(broadside), rel=1e-9)
