"""Random floor plans (`ocp.scenes.floor`) with default options, and invalid geometry.

The floors are seeded but not designed: the engine must size its own budgets for them
(`fit_options`), agree with VisiLibity1 on polygon floors and with the NumPy reference on
mixed ones, and refuse scenes that are not valid.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import central_differences, to_reference
from reference import reference_visibility
from visilibity_reference import outline, union_visible_length

import ocp_jax as ocp
from ocp_jax._visibility import events as _events
from ocp_jax._visibility import occlusion as _occlusion
from ocp_jax._visibility.visibility import signed_distances

POLYGONS = ("rectangle", "l_shape", "triangle")
CURVED = ("circle", "blob", "ellipse", "rounded_rectangle")


POLYGON_FLOOR_CASES = {
    "16 cameras, default options": (16, ocp.VisibilityOptions()),
    # a polygon's crossings have a closed form and a slot per ray: no root budget applies
    "4 cameras, one tangency and one shadow slot": (
        4,
        ocp.VisibilityOptions(max_tangents=1, max_shadows=1),
    ),
}


@pytest.mark.parametrize("case", POLYGON_FLOOR_CASES)  # (one camera: test_polygons.py)
def test_polygon_floor_matches_visilibity(case):
    """Visible length of a random polygon floor, under jit (every ray casts one shadow,
    each polygon has a slot for each), against the union of VisiLibity1's visibility
    polygons (1e-9 relative)."""
    cameras, options = POLYGON_FLOOR_CASES[case]
    scene = ocp.scenes.floor(seed=cameras, cells=10, objects=5, kinds=POLYGONS)
    positions = ocp.scenes.free_points(scene, cameras, seed=cameras)
    fn = jax.jit(lambda c: ocp.visibility(scene, c, ocp.VisibleLength(), options))
    value = float(fn(positions))
    holes = [outline(c) for c in scene.objects]
    want = union_visible_length(outline(scene.curves[-1]), holes, np.asarray(positions))
    assert want > 0
    assert abs(value / want - 1) <= 1e-9


MIXED_FLOOR_CASES = {  # floor (seed, cells, objects, kinds), cameras (count, seed, clearance)
    "curved furniture, 2 cameras": ((7, 6, 4, CURVED), (2, 7, 0.1)),
    # conics occlude the other curves in closed form, the blobs on the grid
    "every kind, 4 cameras": ((11, 8, 6, POLYGONS + CURVED), (4, 11, 0.1)),
    # on the ellipse the two cameras' q cross twice 3e-3 apart, inside one grid cell
    # whose Hermite interpolant of q_a - q_b does not dip across zero
    "a pair of crossovers inside one cell": ((3236, 10, 5, ocp.scenes.FURNITURE), (2, 3036, 0.3)),
    # two of the six cameras' q cross on a polygon edge whose far end is a corner, where
    # q jumps (the next edge's normal); around a pair of crossovers 1e-3 apart on an
    # edge, q_a - q_b peaks far more sharply than a cubic on its grid cell
    "a crossover beside a corner, 6 cameras": ((5204, 4, 2, ocp.scenes.FURNITURE), (6, 5004, 0.3)),
    "a sharp pair of crossovers, 5 cameras": ((5200, 7, 2, ocp.scenes.FURNITURE), (5, 5000, 0.3)),
}


def _mixed_floor_error(case: str) -> float:
    """Foreshortened Q of a mixed floor case under jit with default options, relative to
    the NumPy reference."""
    (seed, cells, objects, kinds), (cameras, camera_seed, clearance) = MIXED_FLOOR_CASES[case]
    scene = ocp.scenes.floor(seed=seed, cells=cells, objects=objects, kinds=kinds)
    positions = ocp.scenes.free_points(scene, cameras, seed=camera_seed, clearance=clearance)
    value = float(jax.jit(lambda c: ocp.visibility(scene, c, ocp.Foreshortened()))(positions))
    want = reference_visibility(
        to_reference(scene),
        np.asarray(positions),
        "foreshortened",
        observed=list(np.asarray(scene.observed())),
    )
    return abs(value / want - 1)


@pytest.mark.parametrize("case", MIXED_FLOOR_CASES)
def test_mixed_floor_matches_reference(case):
    """Foreshortened Q of a floor with curved furniture, under jit with default options
    (where a budget that overflows raises), against the NumPy reference (1e-12 relative)."""
    assert _mixed_floor_error(case) <= 1e-12


def test_occluders_and_crossovers_in_many_chunks_match_reference(monkeypatch):
    """With chunks of a few pairs (`roots.over_chunks`), the occlusion test's (query,
    occluder) pairs, its queries on their own curves and the crossovers' (pair, curve)
    items are packed and looped over in many steps: Q still matches the reference (1e-12
    relative)."""
    monkeypatch.setattr(_events, "CHUNK_ELEMENTS", 256)
    monkeypatch.setattr(_occlusion, "CHUNK_ELEMENTS", 256)
    assert _mixed_floor_error("every kind, 4 cameras") <= 1e-12


def test_floor_gradient_matches_central_differences():
    """The gradient of Q on a random floor, under jit with options sized beforehand by
    `fit_options`, against central differences (1e-6 relative to the gradient's size)."""
    scene = ocp.scenes.floor(seed=3, cells=8, objects=4, kinds=("rectangle", "circle", "blob"))
    positions = ocp.scenes.free_points(scene, 2, seed=3, clearance=0.3)
    options = ocp.fit_options(scene, positions, ocp.Foreshortened(), headroom=2.0)
    value = jax.jit(lambda c: ocp.visibility(scene, c, ocp.Foreshortened(), options))
    grad = np.asarray(
        jax.jit(jax.grad(lambda c: ocp.visibility(scene, c, ocp.Foreshortened(), options)))(
            positions
        )
    )
    want = central_differences(lambda c: float(value(c)), np.asarray(positions), 1e-6)
    assert np.max(np.abs(grad - want)) <= 1e-6 * max(1.0, np.max(np.abs(want)))


@pytest.mark.parametrize("seed", range(3))
def test_random_floors_are_valid_scenes(seed):
    """No false refusals: random floors of every size and kind are valid scenes, and
    their free points lie in free space."""
    cells = (4, 12, 24)[seed]
    scene = ocp.scenes.floor(seed=seed, cells=cells, objects=max(1, cells // 2))
    assert scene.room and len(scene.objects) == max(1, cells // 2)
    positions = ocp.scenes.free_points(scene, 8, seed=seed)
    assert np.all(np.asarray(signed_distances(scene, positions)) > 0.1)


def test_jagged_floors_have_more_walls_and_are_valid():
    """`jagged` grows spurs: more walls from the same cells, still a valid scene."""
    compact = ocp.scenes.floor(seed=4, cells=48, objects=8)
    jagged = ocp.scenes.floor(seed=4, cells=48, objects=8, jagged=1.0)
    walls = [len(outline(s.curves[-1])) for s in (compact, jagged)]
    assert walls[1] > 1.3 * walls[0]
    positions = ocp.scenes.free_points(jagged, 4, seed=4)
    assert np.all(np.asarray(signed_distances(jagged, positions)) > 0.1)
    with pytest.raises(ValueError, match="0 <= jagged <= 1"):
        ocp.scenes.floor(seed=4, cells=8, jagged=1.5)


def _equations(scene: ocp.Scene) -> int:
    t = jnp.full((len(scene), 8), 0.3)
    return len(jax.make_jaxpr(lambda s: s.components(t))(scene).jaxpr.eqns)


def test_polygons_of_any_corner_count_share_one_evaluation():
    """Curves made of Bezier segments of one degree are evaluated from one table, so a
    floor of squares, triangles and L-shapes in an L-shaped room traces the same
    program as one of squares in a square room."""
    square = np.array([[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]])
    ell = np.array([[-0.5, -0.5], [0.5, -0.5], [0.5, 0.0], [0.0, 0.0], [0.0, 0.5], [-0.5, 0.5]])
    triangle = np.array([[-0.5, -0.5], [0.5, -0.5], [0.0, 0.5]])
    room_ell = np.array([[0.0, 0.0], [8.0, 0.0], [8.0, 4.0], [4.0, 4.0], [4.0, 8.0], [0.0, 8.0]])
    room_square = np.array([[0.0, 0.0], [8.0, 0.0], [8.0, 8.0], [0.0, 8.0]])
    centres = np.array([[2.0, 2.0], [6.0, 2.0], [2.0, 6.0]])
    squares = ocp.Scene([_POLYGON(square + c) for c in centres], room=_POLYGON(room_square))
    mixed = ocp.Scene(
        [_POLYGON(shape + c) for shape, c in zip((square, ell, triangle), centres)],
        room=_POLYGON(room_ell),
    )
    assert _equations(mixed) == _equations(squares)


_POLYGON = ocp.PiecewiseCurve.polygon
_SQUARE_ROOM = jnp.array([[-5.0, -5.0], [5.0, -5.0], [5.0, 5.0], [-5.0, 5.0]])


def _two_circles(a, b):
    return ocp.Scene([ocp.Circle(a, 1.0), ocp.Circle(b, 1.0)])


def _in_square_room(center):
    return ocp.Scene([ocp.Circle(center, 1.0)], room=_POLYGON(_SQUARE_ROOM))


# name: (build, its arrays, the error's words). Each scene is built from the arrays as
# they are (refused on the host) and from traced arrays under jit (refused when it runs).
INVALID = {
    "bow-tie": (
        lambda v: ocp.Scene([_POLYGON(v)]),
        [[[0.0, 0.0], [1.0, 1.0], [1.0, 0.0], [0.0, 1.0]]],
        "curve 0 crosses or touches itself",
    ),
    "overlapping circles": (_two_circles, [[0.0, 0.0], [1.5, 0.0]], "curve 0 and curve 1 cross"),
    "touching circles": (_two_circles, [[0.0, 0.0], [2.0, 0.0]], "curve 0 and curve 1 cross"),
    "square crossing a circle": (
        lambda v, c: ocp.Scene([_POLYGON(v), ocp.Circle(c, 1.0)]),
        [[[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]], [2.5, 1.0]],
        "curve 0 and curve 1 cross or touch",
    ),
    "a blob inside a circle": (
        lambda c: ocp.Scene([ocp.Circle(c, 3.0), ocp.scenes.blob((0.0, 0.0), 1.0, 0)]),
        [[0.0, 0.0]],
        "curve 1 lies inside curve 0",
    ),
    "outside the room": (_in_square_room, [[20.0, 0.0]], "curve 0 lies outside the room"),
    "crossing a wall": (_in_square_room, [[5.0, 0.0]], "curve 0 and the room cross or touch"),
    "zero-length edge": (
        lambda v: ocp.Scene([_POLYGON(v)]),
        [[[0.0, 0.0], [1.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]],
        "not regular",  # (the polygon itself refuses it, before the scene)
    ),
}
# Where the words under jit differ: a polygon checks its own arrays only when concrete.
INVALID_UNDER_JIT = {"zero-length edge": "curve 0 has an edge of zero length"}


@pytest.mark.parametrize("name", INVALID)
def test_invalid_geometry_is_refused(name):
    build, arrays, message = INVALID[name]
    with pytest.raises(ValueError, match=message):
        build(*map(jnp.asarray, arrays))


@pytest.mark.parametrize("name", INVALID)
def test_invalid_geometry_built_under_jit_is_refused(name):
    build, arrays, message = INVALID[name]
    with pytest.raises(Exception, match=INVALID_UNDER_JIT.get(name, message)):
        jax.block_until_ready(jax.jit(build)(*map(jnp.asarray, arrays)))


@pytest.mark.parametrize("seed", [2, 3])
def test_valid_floors_built_under_jit_are_not_refused(seed):
    """Floors with furniture of every curve type, rebuilt from traced arrays: the checks
    in the program pass, and the arrays come out as they went in."""
    scene = ocp.scenes.floor(seed=seed, cells=10, objects=len(ocp.scenes.FURNITURE))
    leaves, treedef = jax.tree.flatten(scene)

    def rebuilt(leaves):
        curves = jax.tree.unflatten(treedef, leaves).curves
        return ocp.Scene(curves[:-1], room=curves[-1])

    for got, want in zip(jax.tree.leaves(jax.jit(rebuilt)(leaves)), leaves):
        np.testing.assert_array_equal(np.asarray(got), np.asarray(want))


def test_zero_length_edge_of_a_long_polygon_is_named():
    """A repeated vertex among hundreds of edges, where the curve's regularity check
    samples too coarsely to be sure to see it: the scene check names the edge."""
    angle = np.linspace(0.0, 2 * np.pi, 300, endpoint=False)
    vertices = np.stack([np.cos(angle), np.sin(angle)], -1)
    vertices = np.insert(vertices, 123, vertices[123], axis=0)
    with pytest.raises(ValueError, match="edge of zero length|not regular"):
        ocp.Scene([_POLYGON(jnp.asarray(vertices))])
