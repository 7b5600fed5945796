"""Built-in scenes.

`banana()` is our reconstruction of the thesis's example (Sec. 5.1.1): a non-convex closed
Bezier curve of degree 18. The thesis does not give its control points and its numbers
do not fit together, so we fitted a crescent (a centre-line arc of radius 42 about
(0, -18) from 40 to 140 degrees, width 14 sin(pi s)^0.8 + 0.5) by regularised least
squares with a curve that is C2 at the seam (`BezierCurve.closed_c2`), and rounded the
16 free points to one decimal. The cameras' placement set of the thesis, the boundary of
the 100 x 80 rectangle centred at (0, 20), encloses it.

`room()` is an L-shaped room (walls `ROOM_WALLS`, metres) with polygonal and rounded
furniture; `room_cameras()` are three directional cameras (90-degree field of view, 9 m
range) mounted on its walls, 5 cm in front of them (`ROOM_MOUNTS`, the walls moved in by
5 cm, is where such cameras may go: `PolygonBoundary(ROOM_MOUNTS)`).
"""

import jax.numpy as jnp
import numpy as np

from ._camera import Camera
from ._curves import BezierCurve, BSplineCurve, Circle, Ellipse, PiecewiseCurve
from ._scene import Scene

__all__ = [
    "BANANA_FREE_POINTS",
    "BANANA_RECTANGLE",
    "ROOM_MOUNTS",
    "ROOM_WALLS",
    "banana",
    "blobs",
    "circle",
    "room",
    "room_cameras",
    "three_objects",
]

# Seam point, then the inner control points P_2..P_16 (see BezierCurve.closed_c2).
BANANA_FREE_POINTS = (
    (4.0, 31.8),
    (-11.6, 32.2),
    (-22.7, 26.5),
    (-33.8, 16.2),
    (-39.4, 6.6),
    (-36.8, 3.4),
    (-27.6, 8.3),
    (-16.0, 17.4),
    (-4.8, 24.2),
    (5.5, 24.1),
    (16.4, 17.3),
    (27.6, 8.3),
    (36.1, 3.8),
    (38.0, 7.6),
    (31.9, 17.5),
    (21.3, 26.9),
)

# The thesis's placement set: centre, width, height of the camera rectangle.
BANANA_RECTANGLE = ((0.0, 20.0), 100.0, 80.0)


def banana() -> Scene:
    """The thesis's example object: a degree-18 closed Bezier banana, C2 at the seam."""
    return Scene([BezierCurve.closed_c2(jnp.asarray(BANANA_FREE_POINTS, float))])


def circle(radius: float = 1.0) -> Scene:
    """One circle at the origin."""
    return Scene([Circle(jnp.zeros(2), radius)])


def blob(center, radius: float, seed: int, points: int = 8) -> BSplineCurve:
    """A smooth, usually non-convex, closed cubic B-spline around `center`."""
    rng = np.random.default_rng(seed)
    angle = 2 * np.pi * (np.arange(points) + 0.25 * rng.uniform(-1, 1, points)) / points
    r = radius * (0.55 + 0.45 * rng.uniform(0, 1, points))
    p = np.asarray(center) + np.stack([r * np.cos(angle), r * np.sin(angle)], -1)
    return BSplineCurve(jnp.asarray(p, float), degree=3)


def blobs(count: int, spacing: float = 3.0, seed: int = 0) -> Scene:
    """`count` B-spline blobs of radius 1 on a jittered grid `spacing` apart."""
    columns = int(np.ceil(np.sqrt(count)))
    rng = np.random.default_rng(seed)
    curves = []
    for i in range(count):
        center = spacing * np.array([i % columns, i // columns]) + rng.uniform(-0.3, 0.3, 2)
        curves.append(blob(center, 1.0, seed * 1000 + i))
    return Scene(curves)


def three_objects() -> Scene:
    """A non-convex B-spline, a circle and an ellipse: self- and mutual occlusion."""
    kidney = BSplineCurve(
        jnp.array(
            [[0.0, 0.0], [1.0, -0.8], [2.2, -0.6], [2.6, 0.4], [1.8, 0.5], [1.0, 0.3],
             [0.4, 1.0], [1.6, 1.6], [0.6, 2.2], [-0.6, 1.4]]
        ),
        degree=3,
    )
    return Scene(
        [
            kidney,
            Circle(jnp.array([3.8, 1.6]), 0.5),
            Ellipse(jnp.array([-1.6, -0.6]), jnp.array([0.7, 0.35]), 0.4),
        ]
    )


ROOM_WALLS = ((0.0, 0.0), (10.0, 0.0), (10.0, 5.0), (6.0, 5.0), (6.0, 8.0), (0.0, 8.0))
ROOM_MOUNTS = ((0.05, 0.05), (9.95, 0.05), (9.95, 4.95), (5.95, 4.95), (5.95, 7.95), (0.05, 7.95))


def room() -> Scene:
    """An L-shaped room with a table, an L-shaped sofa, a round table and a cabinet with
    rounded corners (the walls occlude but are not themselves to be seen)."""
    polygon = PiecewiseCurve.polygon
    furniture = [
        polygon(jnp.array([[2.0, 2.0], [4.0, 2.0], [4.0, 3.0], [2.0, 3.0]])),
        polygon(
            jnp.array([[6.5, 1.0], [9.0, 1.0], [9.0, 3.5], [8.2, 3.5], [8.2, 1.8], [6.5, 1.8]])
        ),
        Circle(jnp.array([2.5, 6.0]), 0.6),
        PiecewiseCurve.rounded_rectangle(jnp.array([4.5, 7.3]), 2.0, 0.8, 0.2),
    ]
    return Scene(furniture, room=polygon(jnp.asarray(ROOM_WALLS)))


def room_cameras() -> Camera:
    """Three cameras on the walls of `room()`, looking into it: 90-degree field of view
    (half_fov pi/4), 9 m range."""
    return Camera(
        jnp.array([[0.05, 4.0], [5.0, 0.05], [9.95, 2.5]]),
        heading=jnp.array([0.0, 0.5 * np.pi, np.pi]),
        half_fov=np.pi / 4,
        range=9.0,
    )
