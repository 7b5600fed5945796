"""Built-in scenes.

`banana()` is our reconstruction of the thesis's example (Sec. 5.1.1): a non-convex closed
Bezier curve of degree 18. The thesis does not give its control points and its numbers
do not fit together, so we fitted a crescent (a centre-line arc of radius 42 about
(0, -18) from 40 to 140 degrees, width 14 sin(pi s)^0.8 + 0.5) by regularised least
squares with a curve that is C2 at the seam (`BezierCurve.closed_c2`), and rounded the
16 free points to one decimal. The cameras' placement set of the thesis, the boundary of
the 100 x 80 rectangle centred at (0, 20), encloses it.
"""

import jax.numpy as jnp
import numpy as np

from ._curves import BezierCurve, BSplineCurve, Circle, Ellipse
from ._scene import Scene

__all__ = [
    "BANANA_FREE_POINTS",
    "BANANA_RECTANGLE",
    "banana",
    "blobs",
    "circle",
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
