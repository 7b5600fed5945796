"""Rooms (a curve whose inside is free space), directional cameras on walls, scenes from
SVG and JSON, and optimising camera poses."""

import functools
import json
import math

import helpers as H
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from reference import reference_visibility
from visilibity_reference import visible_lengths

import ocp_jax as ocp
from ocp_jax._io.problem_file import problem_from_dict

ROOM = np.array([[-3, -3], [11, -3], [11, 4], [6, 4], [6, 10], [-3, 10]], float)  # L-shaped
FURNITURE = [
    np.array([[0, 0], [3, 0], [3, 1], [1, 1], [1, 3], [0, 3]], float),
    np.array([[5, 0.5], [7, 1], [5.5, 2.5]], float),
    np.array([[1, 5], [4, 5], [4, 8], [3, 8], [3, 6], [2, 6], [2, 8], [1, 8]], float),
]
POLYGON_ROOM = ocp.Scene(
    [ocp.PiecewiseCurve.polygon(jnp.asarray(p)) for p in FURNITURE],
    room=ocp.PiecewiseCurve.polygon(jnp.asarray(ROOM)),
)
# In free space, off every edge's line; (10.3, 3.1) and (5.2, 9.3) see round the
# room's reflex corner (6, 4) from either side.
ROOM_CAMERAS = [[-2.0, -1.3], [10.3, 3.1], [2.45, 7.4], [4.5, 3.3], [5.2, 9.3], [-2.7, 9.6]]


@functools.cache
def _q(kind):
    """jit(vmap) of Q over camera sets (n, k, 2) or `Camera` batches."""
    objective = H.VL if kind == "visible_length" else H.FS
    return jax.jit(jax.vmap(lambda scene, c: ocp.visibility(scene, c, objective), (None, 0)))


def _pose_value_and_grad(scene, camera):
    return jax.value_and_grad(ocp.visibility, argnums=1)(scene, camera, H.FS)


pose_value_and_grad = jax.jit(jax.vmap(_pose_value_and_grad, (None, 0)))


# ===========================================================================
# rooms against VisiLibity1 and the NumPy reference
# ===========================================================================
@functools.cache
def room_values():
    return np.asarray(_q("visible_length")(POLYGON_ROOM, jnp.asarray(ROOM_CAMERAS)[:, None]))


@pytest.mark.parametrize("camera", ROOM_CAMERAS, ids=str)
def test_room_matches_visilibity(camera):
    """Only the furniture counts in Q; the walls occlude (the reflex corner)."""
    i = ROOM_CAMERAS.index(camera)  # its row of the batch
    want = sum(visible_lengths(ROOM, FURNITURE, ROOM_CAMERAS[i]))
    assert abs(room_values()[i] / want - 1) < 1e-9, (room_values()[i], want)


def test_the_room_corner_occludes():
    """Without the room, more is seen from (10.3, 3.1): the corner (6, 4) hides part."""
    open_space = ocp.Scene(POLYGON_ROOM.objects)
    free = float(ocp.visibility(open_space, jnp.array([ROOM_CAMERAS[1]]), H.VL))
    assert free > room_values()[1] + 0.5


def test_camera_outside_the_room_raises():
    with pytest.raises(Exception, match="outside the room"):
        jax.block_until_ready(_q("visible_length")(POLYGON_ROOM, jnp.array([[[9.0, 8.0]]])))


@functools.cache
def builtin_room_results():
    scene, cameras = ocp.scenes.room(), ocp.scenes.room_cameras()
    batch = jax.tree.map(lambda a: a[None], cameras)
    value, grad = pose_value_and_grad(scene, batch)
    return scene, cameras, float(value[0]), jax.tree.map(lambda a: np.asarray(a[0]), grad)


def test_builtin_room_matches_reference():
    """The built-in room (polygons, a circle, a rounded cabinet) seen by its three
    directional wall cameras (90-degree wedges, 9 m range)."""
    scene, cameras, value, _ = builtin_room_results()
    poses = [
        {"heading": float(h), "half_fov": float(f), "range": float(r)}
        for h, f, r in zip(cameras.heading, cameras.half_fov, cameras.range)
    ]
    want = reference_visibility(
        H.to_reference(scene),
        np.asarray(cameras.position),
        "foreshortened",
        poses=poses,
        observed=list(scene.observed()),
    )
    assert abs(value / want - 1) < 1e-9


def test_directional_cameras_on_the_room_mounts():
    """Sixteen sets of four directional cameras on the built-in room's mounts, 5 cm
    from its walls, as `optimize` draws its starts: Q and its gradient are defined at
    every set (no root search fails so close to a wall, none raises), and two sets match
    the NumPy reference."""
    scene = ocp.scenes.room()
    placement = ocp.DirectionalPlacement(
        ocp.PolygonBoundary(ocp.scenes.ROOM_MOUNTS), half_fov=(0.3, 0.8), range=9.0
    )
    cameras = placement.cameras(placement.sample(jax.random.key(0), 4, 16))
    value, grad = jax.tree.map(np.asarray, pose_value_and_grad(scene, cameras))
    assert np.all(np.isfinite(value)) and np.all(value > 0)
    assert all(np.all(np.isfinite(g)) for g in jax.tree.leaves(grad))
    for i in (0, 1):
        poses = [
            {"heading": float(h), "half_fov": float(f), "range": float(r)}
            for h, f, r in zip(cameras.heading[i], cameras.half_fov[i], cameras.range[i])
        ]
        want = reference_visibility(
            H.to_reference(scene),
            np.asarray(cameras.position[i]),
            "foreshortened",
            poses=poses,
            observed=list(scene.observed()),
        )
        assert abs(value[i] / want - 1) < 1e-9


def test_builtin_room_pose_gradients_match_finite_differences():
    scene, cameras, _, grad = builtin_room_results()
    flat = np.concatenate(
        [np.asarray(cameras.position).ravel(), cameras.heading, cameras.half_fov, cameras.range]
    )
    h = 1e-6
    perturbed = []
    for j in range(flat.size):
        for m in (1, -1):
            p = flat.copy()
            p[j] += m * h
            perturbed.append(p)
    p = jnp.asarray(np.array(perturbed))
    batch = ocp.Camera(p[:, :6].reshape(-1, 3, 2), p[:, 6:9], p[:, 9:12], p[:, 12:15])
    values = np.asarray(pose_value_and_grad(scene, batch)[0]).reshape(-1, 2)
    fd = (values[:, 0] - values[:, 1]) / (2 * h)
    got = np.concatenate([grad.position.ravel(), grad.heading, grad.half_fov, grad.range])
    assert H.relative_error(got, fd) < 1e-6
    assert np.linalg.norm(fd[6:9]) > 1e-2 and np.linalg.norm(fd[9:12]) > 1e-2


# ===========================================================================
# SVG and JSON
# ===========================================================================
SVG = """<svg xmlns="http://www.w3.org/2000/svg" width="20" height="20">
  <path id="walls" d="M -3 3 H 11 V -4 H 6 V -10 H -3 Z"/>
  <polygon points="0,0 3,0 3,-1 1,-1 1,-3 0,-3"/>
  <g transform="translate(5,0)"><polygon points="0,-0.5 2,-1 0.5,-2.5"/></g>
  <path d="M 1 -5 L 4 -5 Q 5 -6.5 4 -8 C 3 -9 1.5 -8.5 1 -7 Z"/>
  <circle cx="3.5" cy="-2" r="0.6"/>
</svg>"""


@functools.cache
def svg_scene():
    return ocp.load_svg(SVG, room="walls")


def test_svg_polygons_are_exact():
    """SVG's y axis points down; load_svg flips it, so the walls and the first two
    polygons are the room and furniture above, split to a power of two of segments."""
    scene = svg_scene()
    assert scene.room and len(scene.objects) == 4
    assert [c.segments for c in scene.curves] == [8, 4, 4, 16, 8]
    same = ocp.Scene(
        [ocp.PiecewiseCurve.polygon(jnp.asarray(p)) for p in FURNITURE[:2]],
        room=ocp.PiecewiseCurve.polygon(jnp.asarray(ROOM)),
    )
    svg_part = ocp.Scene(scene.objects[:2], room=scene.curves[-1])
    camera = jnp.array([[4.5, 3.3]])
    a = float(ocp.visibility(same, camera, H.VL))
    b = float(ocp.visibility(svg_part, camera, H.VL))
    assert abs(a / b - 1) < 1e-13
    assert abs(b / sum(visible_lengths(ROOM, FURNITURE[:2], [4.5, 3.3])) - 1) < 1e-9


def test_svg_curves_match_reference():
    """Lines, a quadratic and a cubic segment, and svgelements' cubic circle."""
    scene = svg_scene()
    cameras = [[4.6, 3.6], [9.5, 2.8]]
    got = float(ocp.visibility(scene, jnp.asarray(cameras), H.FS))
    want = reference_visibility(
        H.to_reference(scene), cameras, "foreshortened", observed=list(scene.observed())
    )
    assert abs(got / want - 1) < 1e-9
    circle = scene.objects[3](jnp.linspace(0, 1, 64))
    radius = np.linalg.norm(np.asarray(circle) - [3.5, 2.0], axis=1)
    assert np.all(np.abs(radius - 0.6) < 1e-3 * 0.6)  # svgelements' arcs: cubic fits


def test_svg_errors():
    with pytest.raises(ValueError, match="SVG path: PiecewiseCurve is not closed"):
        ocp.load_svg('<svg xmlns="http://www.w3.org/2000/svg"><path d="M 0 0 L 1 0 L 1 1"/></svg>')
    with pytest.raises(ValueError, match="No closed path with id 'walls'"):
        ocp.load_svg(
            '<svg xmlns="http://www.w3.org/2000/svg"><rect width="1" height="1"/></svg>',
            room="walls",
        )


def test_json_round_trip_of_a_room():
    scene = ocp.scenes.room()
    placement = ocp.PolygonBoundary(ocp.scenes.ROOM_MOUNTS)
    problem = problem_from_dict(json.loads(ocp.problem_to_json(scene, placement)))
    assert problem.scene.room and len(problem.scene.curves) == len(scene.curves)
    cameras = ocp.scenes.room_cameras()
    a = ocp.visibility(scene, cameras, H.VL)
    b = ocp.visibility(problem.scene, cameras, H.VL)
    assert float(a) == float(b)
    polygon = problem_from_dict(
        {
            "curves": [{"type": "polygon", "vertices": [[0, 0], [4, 0], [0, 3]]}],
            "placement": {"type": "free", "lower": [-5, -5], "upper": [5, 5]},
        }
    )
    assert float(ocp.visibility(polygon.scene, jnp.array([[3.0, 3.0]]), H.VL)) == pytest.approx(
        5.0, rel=1e-14
    )


# ===========================================================================
# optimising poses
# ===========================================================================
def _wedge_arc(d, a):
    """Visible length of the unit circle from distance d through a wedge of half-angle
    a centred on it (both edges hit the circle)."""
    s = d * math.cos(a) - math.sqrt(1.0 - (d * math.sin(a)) ** 2)
    return 2.0 * math.atan2(s * math.sin(a), d - s * math.cos(a))


@functools.cache
def pose_results():
    scene = H.circle_scene()
    placement = ocp.DirectionalPlacement(ocp.RectangleBoundary((0.0, 0.0), 8.0, 8.0), 0.2)
    result = ocp.place(scene, H.VL, placement, 1, solver=ocp.MultiStart(n_starts=8, max_steps=200))
    search = ocp.place(scene, H.VL, placement, 1, solver=ocp.Greedy(resolution=16))
    return result, search


def test_optimize_over_headings():
    """A narrow wedge (half-angle 0.2) on the square |x|, |y| = 4 around the unit circle.
    Up close the wedge cuts the circle; from 1 / sin(0.2) = 5.03 on it holds the whole
    silhouette (half-angle asin(1/d)), which grows with d: the best place is a corner,
    d = 4 sqrt 2, seeing 2 acos(1/d), with the heading anywhere within
    0.2 - asin(1/d) = 0.022 of the centre's direction."""
    result, _ = pose_results()
    position = np.asarray(result.cameras.position[0])
    np.testing.assert_allclose(np.abs(position), [4.0, 4.0], atol=1e-6)
    d = 4.0 * math.sqrt(2.0)
    assert abs(float(result.value) - 2.0 * math.acos(1.0 / d)) < 1e-7
    assert _wedge_arc(4.0, 0.2) < 2.0 * math.acos(1.0 / d) - 1.0  # a side's middle is worse
    toward = math.atan2(-position[1], -position[0])
    offset = abs(math.remainder(float(result.cameras.heading[0]) - toward, 2 * math.pi))
    assert offset <= 0.2 - math.asin(1.0 / d) + 1e-6


def test_greedy_over_poses():
    """Greedy over 16 headings per candidate: a corner looking at the centre (heading a
    multiple of pi/8) is a candidate, so greedy finds the optimum too."""
    result, search = pose_results()
    assert isinstance(search.cameras, ocp.Camera) and search.candidates.shape[1] == 4
    d = 4.0 * math.sqrt(2.0)
    assert abs(float(search.value) - 2.0 * math.acos(1.0 / d)) < 1e-12
    assert float(result.value) >= float(search.value) - 1e-7


def test_pictures_of_poses():
    """plot_scene draws a Camera's wedge edges (dashed, in its colour, from the camera);
    plot_optimization draws the paths of a DirectionalPlacement's positions."""
    import matplotlib

    matplotlib.use("Agg")
    from ocp_jax import plot

    result, _ = pose_results()
    ax = plot.plot_scene(H.circle_scene(), result.cameras)
    position = np.asarray(result.cameras.position[0])
    dashed = [line for line in ax.lines if line.get_linestyle() == "--"]
    assert len(dashed) == 2
    for line in dashed:
        start, end = np.asarray(line.get_xydata())
        np.testing.assert_allclose(start, position)
        angle = math.atan2(*(end - start)[::-1])
        off = abs(math.remainder(angle - float(result.cameras.heading[0]), 2 * math.pi))
        assert abs(off - 0.2) < 1e-9
    placement = ocp.DirectionalPlacement(ocp.RectangleBoundary((0.0, 0.0), 8.0, 8.0), 0.2)
    ax = plot.plot_optimization(result, H.circle_scene(), placement)
    star = [line for line in ax.lines if line.get_marker() == "*"][0]
    np.testing.assert_allclose(np.asarray(star.get_xydata())[0], position)
    matplotlib.pyplot.close("all")


def test_directional_placement_parameters():
    """Position parameters, heading, then u_fov and u_range for optimised bounds, mapped
    by lower + (upper - lower)(1 + sin u)/2; fixed values take no parameter."""
    free = ocp.FreePlacement(jnp.array([-1.0, -1.0]), jnp.array([1.0, 1.0]))
    placement = ocp.DirectionalPlacement(free, half_fov=(0.3, 0.8), range=(2.0, 5.0))
    params = jnp.array([[0.5, -0.5, 1.0, 0.5 * math.pi, -0.5 * math.pi]])
    cameras = placement.cameras(params)
    np.testing.assert_allclose(cameras.position, [[0.5, -0.5]])
    np.testing.assert_allclose(
        [cameras.heading[0], cameras.half_fov[0], cameras.range[0]], [1.0, 0.8, 2.0]
    )
    assert placement.sample(jax.random.key(1), 3, 4).shape == (4, 3, 5)
    assert placement.candidates(4).shape == (16 * 16, 5)
    fixed = ocp.DirectionalPlacement(free, half_fov=0.5)
    assert fixed.sample(jax.random.key(1), 2, 3).shape == (3, 2, 3)
    assert fixed.cameras(jnp.zeros((2, 3))).range is None
    with pytest.raises(
        ValueError, match=r"half_fov must be a number or \(lower, upper\) in \(0, pi\]"
    ):
        ocp.DirectionalPlacement(free, half_fov=(0.5, 4.0))
    with pytest.raises(ValueError, match="0 < lower <= upper"):
        ocp.DirectionalPlacement(free, half_fov=0.5, range=(3.0, 2.0))
