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

`floor(seed, cells, objects)` is a random floor plan (a room of grid cells with furniture
of every curve type) and `free_points(scene, k)` random cameras in its free space: seeded
generators for testing on scenes nobody designed.
"""

import jax.numpy as jnp
import numpy as np

from ._geometry.camera import Camera
from ._geometry.curves import BezierCurve, BSplineCurve, Circle, Ellipse, PiecewiseCurve
from ._geometry.scene import Scene
from ._geometry.validity import inside_polygon

__all__ = [
    "BANANA_FREE_POINTS",
    "BANANA_RECTANGLE",
    "FURNITURE",
    "ROOM_MOUNTS",
    "ROOM_WALLS",
    "banana",
    "blobs",
    "circle",
    "floor",
    "free_points",
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
BANANA_RECTANGLE = (np.array([0.0, 20.0]), 100.0, 80.0)


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
            [
                [0.0, 0.0],
                [1.0, -0.8],
                [2.2, -0.6],
                [2.6, 0.4],
                [1.8, 0.5],
                [1.0, 0.3],
                [0.4, 1.0],
                [1.6, 1.6],
                [0.6, 2.2],
                [-0.6, 1.4],
            ]
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


def _grid_room(rng: np.random.Generator, cells: int, jagged: float) -> np.ndarray:
    """A random simply connected union of `cells` unit grid cells whose boundary is one
    simple orthogonal polygon (no holes, no cells touching at a corner only), grown
    cell by cell from one; with probability `jagged` a step only takes a cell beside
    a single taken one (a new spur). Returns the boundary's vertices, counter-clockwise,
    with the collinear ones dropped."""
    taken = {(0, 0)}
    steps = ((1, 0), (-1, 0), (0, 1), (0, -1))
    while len(taken) < cells:
        x, y = list(taken)[rng.integers(len(taken))]
        dx, dy = steps[rng.integers(4)]
        cell = (x + dx, y + dy)
        if cell in taken:
            continue
        spur = jagged > 0 and rng.uniform() < jagged  # (no extra draw at 0)
        if spur and sum((cell[0] + a, cell[1] + b) in taken for a, b in steps) > 1:
            continue
        grown = taken | {cell}
        if _simple_boundary(grown):
            taken = grown
    return _boundary(taken)


def _edges(taken) -> set:
    """The directed boundary edges of a union of unit cells, counter-clockwise."""
    edges = set()
    for x, y in taken:
        for a, b, side in (
            ((x, y), (x + 1, y), (x, y - 1)),
            ((x + 1, y), (x + 1, y + 1), (x + 1, y)),
            ((x + 1, y + 1), (x, y + 1), (x, y + 1)),
            ((x, y + 1), (x, y), (x - 1, y)),
        ):
            if side not in taken:
                edges.add((a, b))
    return edges


def _simple_boundary(taken) -> bool:
    edges = _edges(taken)
    starts = [a for a, _ in edges]
    if len(set(starts)) != len(starts):  # a vertex where two cells touch at a corner
        return False
    return len(_loop(edges)) == len(edges)  # one loop: no hole


def _loop(edges) -> list:
    following = dict(edges)
    start = min(following)
    loop, vertex = [start], following[start]
    while vertex != start:
        loop.append(vertex)
        vertex = following[vertex]
    return loop


def _boundary(taken) -> np.ndarray:
    loop = np.asarray(_loop(_edges(taken)), float)
    before, after = np.roll(loop, 1, axis=0), np.roll(loop, -1, axis=0)
    turn = (loop[:, 0] - before[:, 0]) * (after[:, 1] - loop[:, 1]) - (
        loop[:, 1] - before[:, 1]
    ) * (after[:, 0] - loop[:, 0])
    return loop[turn != 0]


def _furniture(rng: np.random.Generator, kind: str, center, size: float):
    """One piece of furniture of the given `kind` inside the square of side `size`
    around `center`."""
    c = np.asarray(center, float)
    h = 0.5 * size
    if kind == "rectangle":  # a rectangle
        w, d = h * rng.uniform(0.4, 1.0, 2)
        return PiecewiseCurve.polygon(jnp.asarray(c + [[-w, -d], [w, -d], [w, d], [-w, d]]))
    if kind == "l_shape":  # an L-shape
        w, d = h * rng.uniform(0.6, 1.0, 2)
        a, b = rng.uniform(0.3, 0.7, 2)
        shape = [[-w, -d], [w, -d], [w, -d + 2 * b * d], [-w + 2 * a * w, -d + 2 * b * d],
                 [-w + 2 * a * w, d], [-w, d]]  # fmt: skip
        return PiecewiseCurve.polygon(jnp.asarray(c + np.asarray(shape)))
    if kind == "triangle":  # a triangle
        angle = rng.uniform(0, 2 * np.pi) + np.array([0.0, 2.1, 4.2]) + rng.uniform(-0.4, 0.4, 3)
        r = h * rng.uniform(0.5, 1.0, 3)
        return PiecewiseCurve.polygon(
            jnp.asarray(c + np.stack([r * np.cos(angle), r * np.sin(angle)], -1))
        )
    if kind == "circle":  # a circle
        return Circle(jnp.asarray(c), h * rng.uniform(0.3, 0.9))
    if kind == "ellipse":  # an ellipse
        return Ellipse(
            jnp.asarray(c), jnp.asarray(h * rng.uniform(0.3, 0.9, 2)), rng.uniform(0, np.pi)
        )
    if kind == "rounded_rectangle":  # a rounded rectangle
        w, d = size * rng.uniform(0.4, 0.9, 2)
        return PiecewiseCurve.rounded_rectangle(jnp.asarray(c), w, d, 0.25 * min(w, d))
    if kind == "blob":  # a B-spline blob
        return blob(c, h, int(rng.integers(2**31)))
    raise ValueError(f"unknown kind of furniture {kind!r}; the kinds are {FURNITURE}.")


FURNITURE = ("rectangle", "l_shape", "triangle", "circle", "ellipse", "rounded_rectangle", "blob")


def floor(
    seed: int = 0,
    cells: int = 12,
    objects: int = 8,
    cell_size: float = 2.0,
    kinds: tuple[str, ...] = FURNITURE,
    jagged: float = 0.0,
) -> Scene:
    """A random floor plan: a room of `cells` grid cells of side `cell_size` (a random,
    simply connected union; orthogonal walls, about as many as cells, about 1.4 times as
    many with `jagged=1`) holding `objects`
    pieces of furniture (at most one per cell, in the middle of its cell, so that none
    touches another or a wall) of the `kinds` in turn (`FURNITURE`: rectangles,
    L-shapes, triangles, circles, ellipses, rounded rectangles and B-spline blobs).

    **Arguments:**

    - `seed`: seeds NumPy's generator; the same seed gives the same floor.
    - `cells`, `objects`, `cell_size`: the room's size, the number of objects
      (`objects <= cells`) and the side of a grid cell.
    - `kinds`: the kinds of furniture, from `FURNITURE` (polygons only: the first
      three).
    - `jagged`: in [0, 1], the share of growth steps that may only add a cell beside a
      single cell of the room, starting a spur one cell wide: 0 gives compact rooms,
      1 branching corridors with about 1.4 walls per cell.

    **Returns:** a `Scene` with a room.
    """
    if not 1 <= objects <= cells:
        raise ValueError(f"floor needs 1 <= objects <= cells, got {objects} and {cells}.")
    if not 0.0 <= jagged <= 1.0:
        raise ValueError(f"floor needs 0 <= jagged <= 1, got {jagged}.")
    rng = np.random.default_rng(seed)
    walls = _grid_room(rng, cells, jagged)
    taken = _cells_inside(walls)
    chosen = rng.choice(len(taken), objects, replace=False)
    furniture = [
        _furniture(
            rng, kinds[i % len(kinds)], (np.asarray(taken[j]) + 0.5) * cell_size, 0.7 * cell_size
        )
        for i, j in enumerate(chosen)
    ]
    return Scene(furniture, room=PiecewiseCurve.polygon(jnp.asarray(walls * cell_size)))


def _cells_inside(walls: np.ndarray) -> list:
    """The unit cells of a grid room, from its boundary."""
    low, high = walls.min(0).astype(int), walls.max(0).astype(int)
    cells = [(x, y) for x in range(low[0], high[0]) for y in range(low[1], high[1])]
    inside = inside_polygon(np.asarray(cells, float) + 0.5, walls)
    return [cell for cell, keep in zip(cells, inside) if keep]


def free_points(scene: Scene, count: int, seed: int = 0, clearance: float = 0.1) -> jnp.ndarray:
    """`count` random points of the free space of `scene` (inside the room, outside every
    object), each at least `clearance` from every curve: cameras for a random floor.

    **Returns:** an array of shape (count, 2).
    """
    from ._visibility.visibility import signed_distances

    rng = np.random.default_rng(seed)
    low, high = (np.asarray(b) for b in scene.bounds())
    found = np.zeros((0, 2))
    while len(found) < count:
        trial = rng.uniform(low, high, (4 * count, 2))
        free = np.all(np.asarray(signed_distances(scene, jnp.asarray(trial))) > clearance, 1)
        found = np.concatenate([found, trial[free]])
    return jnp.asarray(found[:count])
