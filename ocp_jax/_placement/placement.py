"""Where cameras may go: the thesis's constraint g(C) = 0 of Eq. 3.16 and its relatives.

A placement maps unconstrained parameters (one row per camera) to camera positions.
Where the set can be parametrised exactly, every parameter value is admissible:
boundaries by arc length (`RectangleBoundary`, `PolygonBoundary`), boxes by a smooth
map (`Region`). What cannot be parametrised is returned by `constraints` (equalities
that must vanish, inequalities that must stay >= 0) and enforced by the optimiser's
augmented-Lagrangian loop: a `Region`'s polygon and its clearance from the objects, a
general `EqualityConstraint`.

Every placement samples starting parameters and candidate grids (for the discrete
baselines) and reports how far given cameras are from the set (`violations`).
"""

import abc
from collections.abc import Callable, Sequence
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, PRNGKeyArray, Real

from .._geometry.camera import Camera
from .._geometry.curves import is_concrete

__all__ = [
    "AbstractPlacement",
    "Constraints",
    "DirectionalPlacement",
    "EqualityConstraint",
    "FreePlacement",
    "PolygonBoundary",
    "RectangleBoundary",
    "Region",
]


class Constraints(NamedTuple):
    """Constraints on a camera set that its parametrisation does not enforce."""

    equal: Float[Array, " r"]  # must be 0
    at_least: Float[Array, " q"]  # must be >= 0


def _lift(vector: Array, like: Array) -> Array:
    """`vector` (d,) with leading axes of size 1, to broadcast against `like` (..., d)."""
    return vector.reshape((1,) * (like.ndim - 1) + vector.shape)


def _no_constraints(cameras: Array) -> Constraints:
    empty = jnp.zeros((0,), cameras.dtype)
    return Constraints(empty, empty)


class AbstractPlacement(eqx.Module):
    """A set of admissible camera positions with a parametrisation of it."""

    @abc.abstractmethod
    def cameras(self, params: Float[Array, "k p"]) -> Float[Array, "k 2"]:
        """Camera positions of the parameters (any real values are admissible)."""

    @abc.abstractmethod
    def sample(self, key: PRNGKeyArray, n_cameras: int, n_starts: int) -> Float[Array, "s k p"]:
        """`n_starts` random parameter sets of `n_cameras` cameras, spread over the set."""

    @abc.abstractmethod
    def candidates(self, resolution: int) -> Float[Array, "n p"]:
        """A grid of single-camera parameters covering the set (`resolution` per side, or
        per axis; see the subclass). Candidates that break `constraints` are dropped by
        the searches that use them."""

    def has_constraints(self) -> bool:
        """Whether `constraints` can be non-empty (static): the optimiser then runs its
        augmented-Lagrangian loop."""
        return False

    def constraints(self, cameras: Float[Array, "k 2"], scene) -> Constraints:
        """Equalities (= 0) and inequalities (>= 0) the parametrisation does not enforce."""
        return _no_constraints(cameras)

    def distances(self, cameras: Float[Array, "k 2"]) -> Float[Array, " k"]:
        """Each camera's distance from the parametrised set (0 on it)."""
        return jnp.zeros(cameras.shape[:1], cameras.dtype)

    def violations(
        self, cameras: Real[ArrayLike, "k 2"] | Sequence | Camera, scene=None
    ) -> Float[Array, " k"]:
        """Per camera: its distance from the parametrised set plus the largest breach of
        its `constraints` (checked only when `scene` is given); 0 for an admissible
        camera."""
        cameras = jnp.atleast_2d(jnp.asarray(cameras, float))
        worst = self.distances(cameras)
        if self.has_constraints() and scene is not None:
            per_camera = jax.vmap(lambda c: self.constraints(c[None], scene))(cameras)
            breach = jnp.concatenate(
                [jnp.abs(per_camera.equal), jnp.maximum(-per_camera.at_least, 0.0)], axis=1
            )
            worst = worst + jnp.max(breach, axis=1, initial=0.0)
        return worst

    def violation(
        self, cameras: Real[ArrayLike, "k 2"] | Sequence | Camera, scene=None
    ) -> Float[Array, ""]:
        """The largest of `violations`."""
        return jnp.max(self.violations(cameras, scene))


# ---------------------------------------------------------------------------------------
# Boundaries: closed polygonal chains, parametrised by arc length.


def _polygon_edges(vertices: Array) -> tuple[Array, Array]:
    """Edge vectors of the closed polygon and their lengths."""
    edges = jnp.roll(vertices, -1, axis=0) - vertices
    return edges, jnp.linalg.norm(edges, axis=-1)


def _segment_distances(points: Array, vertices: Array) -> Array:
    """Distance from each point (n, 2) to each edge of the closed polygon: (n, e)."""
    edges, lengths = _polygon_edges(vertices)
    rel = points[:, None, :] - vertices[None]
    along = jnp.clip(jnp.sum(rel * edges[None], -1) / lengths[None] ** 2, 0.0, 1.0)
    return jnp.linalg.norm(rel - along[..., None] * edges[None], axis=-1)


def _inside_polygon(points: Array, vertices: Array) -> Array:
    """Even-odd rule: is each point (n, 2) inside the closed polygon?"""
    a, b = vertices[None], jnp.roll(vertices, -1, axis=0)[None]
    x, y = points[:, None, 0], points[:, None, 1]
    straddles = (a[..., 1] > y) != (b[..., 1] > y)
    crossing_x = a[..., 0] + (y - a[..., 1]) * (b[..., 0] - a[..., 0]) / jnp.where(
        straddles, b[..., 1] - a[..., 1], 1.0
    )
    return jnp.sum(straddles & (x < crossing_x), axis=1) % 2 == 1


def _check_polygon(vertices, name: str) -> Array:
    vertices = jnp.asarray(vertices, float)
    if vertices.ndim != 2 or vertices.shape[1] != 2 or vertices.shape[0] < 3:
        raise ValueError(f"{name} must have shape (n, 2) with n >= 3, got {vertices.shape}.")
    if is_concrete(vertices):
        v = np.asarray(vertices)
        if not np.all(np.isfinite(v)):
            raise ValueError(f"{name} contains NaN or inf.")
        if np.any(np.linalg.norm(np.roll(v, -1, 0) - v, axis=1) == 0):
            raise ValueError(
                f"{name} has two equal consecutive vertices (a zero-length edge); remove one "
                "(do not repeat the first vertex at the end: the polygon closes itself)."
            )
    return vertices


class AbstractBoundary(AbstractPlacement):
    """Cameras on a closed polygonal chain (walls), one parameter per camera: s in R is
    the point at arc length (s mod 1) L along the chain of length L, from vertex 0."""

    @abc.abstractmethod
    def vertices(self) -> Float[Array, "n 2"]:
        """The chain's corners in order (closed: the last joins the first)."""

    def cameras(self, params):
        vertices = self.vertices()
        edges, lengths = _polygon_edges(vertices)
        starts = jnp.cumsum(lengths) - lengths
        arc = jnp.mod(params, 1.0) * jnp.sum(lengths)  # (..., 1)
        # Distance travelled along each edge: the sum is continuous and piecewise linear.
        starts, lengths = _lift(starts, arc), _lift(lengths, arc)
        travelled = jnp.clip(arc - starts, 0.0, lengths)
        along = (travelled / lengths) @ edges
        return _lift(vertices[0], along) + along

    def sample(self, key, n_cameras, n_starts):
        return jax.random.uniform(key, (n_starts, n_cameras, 1), self.vertices().dtype)

    def candidates(self, resolution):
        """`resolution` equally spaced candidates per edge, each corner once (the thesis
        used 128 per side of its rectangle)."""
        _, lengths = _polygon_edges(self.vertices())
        perimeter = jnp.sum(lengths)
        starts = (jnp.cumsum(lengths) - lengths) / perimeter
        side = jnp.arange(resolution) / resolution
        return (starts[:, None] + (lengths / perimeter)[:, None] * side[None]).reshape(-1, 1)

    def distances(self, cameras):
        return jnp.min(_segment_distances(cameras, self.vertices()), axis=1)

    def arc_fraction(self, cameras: Real[ArrayLike, "k 2"] | Sequence) -> Float[Array, " k"]:
        """The parameter s in [0, 1) of each camera's nearest point of the chain (the
        inverse of `cameras` on the chain)."""
        cameras = jnp.atleast_2d(jnp.asarray(cameras, float))
        vertices = self.vertices()
        edges, lengths = _polygon_edges(vertices)
        edge = jnp.argmin(_segment_distances(cameras, vertices), axis=1)
        along = jnp.sum((cameras - vertices[edge]) * edges[edge], -1) / lengths[edge] ** 2
        start = (jnp.cumsum(lengths) - lengths)[edge]
        travelled = start + jnp.clip(along, 0.0, 1.0) * lengths[edge]
        return jnp.mod(travelled / jnp.sum(lengths), 1.0)


class PolygonBoundary(AbstractBoundary):
    """Cameras on the walls of a polygonal room (a closed polygon, any orientation).

    **Arguments:**

    - `corners`: the polygon's vertices in order, shape (n, 2), n >= 3, without repeating
      the first at the end.
    """

    corners: Float[Array, "n 2"]

    def __init__(self, corners: Real[ArrayLike, "n 2"] | Sequence):
        self.corners = _check_polygon(corners, "PolygonBoundary corners")

    def vertices(self):
        return self.corners


class RectangleBoundary(AbstractBoundary):
    """Cameras on the boundary of an axis-aligned rectangle (the thesis's Sec. 5.1.1).

    s in R is the point at arc length (s mod 1) 2 (width + height), counter-clockwise
    from the lower-left corner.

    **Arguments:**

    - `center`: the rectangle's centre, shape (2,).
    - `width`, `height`: its side lengths (> 0).
    """

    center: Float[Array, "2"]
    width: Float[Array, ""]
    height: Float[Array, ""]

    def __init__(
        self,
        center: Real[ArrayLike, "2"] | Sequence,
        width: Real[ArrayLike, ""],
        height: Real[ArrayLike, ""],
    ):
        self.center = jnp.asarray(center, float)
        self.width = jnp.asarray(width, float)
        self.height = jnp.asarray(height, float)
        if self.center.shape != (2,):
            raise ValueError(
                f"RectangleBoundary center must have shape (2,), got {self.center.shape}."
            )
        if is_concrete(self.width, self.height) and not (self.width > 0 and self.height > 0):
            raise ValueError(
                f"RectangleBoundary width and height must be positive, got {float(self.width)} "
                f"and {float(self.height)}."
            )

    def vertices(self):
        half_w, half_h = 0.5 * self.width, 0.5 * self.height
        corners = jnp.stack(
            [
                jnp.stack([-half_w, -half_h]),
                jnp.stack([half_w, -half_h]),
                jnp.stack([half_w, half_h]),
                jnp.stack([-half_w, half_h]),
            ]
        )
        return self.center[None] + corners


# ---------------------------------------------------------------------------------------
# Two-dimensional sets: one point (two parameters) per camera.


def _box_grid(lower: Array, upper: Array, resolution: int) -> Array:
    """`resolution` x `resolution` points of the box, edges included: (n, 2)."""
    axis = jnp.linspace(0.0, 1.0, resolution)
    u, v = jnp.meshgrid(axis, axis, indexing="ij")
    unit = jnp.stack([u.ravel(), v.ravel()], -1)
    return _lift(lower, unit) + _lift(upper - lower, unit) * unit


def _in_box(key: PRNGKeyArray, lower: Array, upper: Array, shape: tuple) -> Array:
    """Uniform random points of the box, shape `shape + (2,)`."""
    unit = jax.random.uniform(key, (*shape, 2), lower.dtype)
    return _lift(lower, unit) + _lift(upper - lower, unit) * unit


def _check_box(lower, upper, name: str) -> tuple[Array, Array]:
    lower, upper = jnp.asarray(lower, float), jnp.asarray(upper, float)
    if lower.shape != (2,) or upper.shape != (2,):
        raise ValueError(f"{name} lower and upper must have shape (2,).")
    if is_concrete(lower, upper) and not np.all(np.asarray(upper) > np.asarray(lower)):
        raise ValueError(f"{name} needs upper > lower in both coordinates.")
    return lower, upper


class FreePlacement(AbstractPlacement):
    """Cameras anywhere outside the objects (the parameters are the positions).

    The box only says where starting points and candidates are drawn from; the optimiser
    is not kept inside it. Q need not be bounded in the distance (foreshortening does not
    fade with it), so a `Region` is usually the better model of a real site.

    **Arguments:**

    - `lower`, `upper`: corners of the box of starting points, shape (2,) each.
    """

    lower: Float[Array, "2"]
    upper: Float[Array, "2"]

    def __init__(
        self, lower: Real[ArrayLike, "2"] | Sequence, upper: Real[ArrayLike, "2"] | Sequence
    ):
        self.lower, self.upper = _check_box(lower, upper, "FreePlacement")

    def cameras(self, params):
        return params

    def sample(self, key, n_cameras, n_starts):
        return _in_box(key, self.lower, self.upper, (n_starts, n_cameras))

    def candidates(self, resolution):
        """A `resolution` x `resolution` grid of the box."""
        return _box_grid(self.lower, self.upper, resolution)


class Region(AbstractPlacement):
    """Cameras in a box (optionally only its part inside a polygon), outside every object
    and at least `clearance` away from each.

    The box is parametrised by the smooth map C = centre + half-size * sin(u) (every u is
    admissible); the polygon and the clearance are inequality constraints, enforced by
    the optimiser's augmented-Lagrangian loop: signed distance to the polygon's edges
    (>= 0 inside) and, per curve, signed distance from it minus `clearance` (>= 0).

    **Arguments:**

    - `lower`, `upper`: the box's corners, shape (2,) each.
    - `polygon`: optional (n, 2) vertices of a room the cameras must stay inside.
    - `clearance`: the least distance from every object (>= 0).
    """

    lower: Float[Array, "2"]
    upper: Float[Array, "2"]
    polygon: Float[Array, "n 2"] | None
    clearance: Float[Array, ""]

    def __init__(
        self,
        lower: Real[ArrayLike, "2"] | Sequence,
        upper: Real[ArrayLike, "2"] | Sequence,
        polygon: Real[ArrayLike, "n 2"] | Sequence | None = None,
        clearance: float = 0.0,
    ):
        self.lower, self.upper = _check_box(lower, upper, "Region")
        self.polygon = None if polygon is None else _check_polygon(polygon, "Region polygon")
        self.clearance = jnp.asarray(clearance, float)
        if is_concrete(self.clearance) and not self.clearance >= 0:
            raise ValueError(f"Region clearance must be >= 0, got {float(self.clearance)}.")

    def _centre_half(self):
        return 0.5 * (self.upper + self.lower), 0.5 * (self.upper - self.lower)

    def cameras(self, params):
        centre, half = self._centre_half()
        return _lift(centre, params) + _lift(half, params) * jnp.sin(params)

    def _params(self, points: Array) -> Array:
        centre, half = self._centre_half()
        unit = (points - _lift(centre, points)) / _lift(half, points)
        return jnp.arcsin(jnp.clip(unit, -1.0, 1.0))

    def sample(self, key, n_cameras, n_starts):
        """Uniform in the box; with a polygon, points outside it are replaced by points
        inside it where 16 tries per point find one."""
        tries = 16 if self.polygon is not None else 1
        points = _in_box(key, self.lower, self.upper, (tries, n_starts, n_cameras))
        if self.polygon is not None:
            inside = _inside_polygon(points.reshape(-1, 2), self.polygon).reshape(points.shape[:3])
            points = jnp.take_along_axis(points, jnp.argmax(inside, axis=0)[None, ..., None], 0)
        return self._params(points[0])

    def candidates(self, resolution):
        """A `resolution` x `resolution` grid of the box (with a polygon: the grid points
        inside it)."""
        points = _box_grid(self.lower, self.upper, resolution)
        if self.polygon is not None:
            points = points[np.asarray(_inside_polygon(points, self.polygon))]
        return self._params(points)

    def has_constraints(self):
        return True

    def constraints(self, cameras, scene):
        from .._visibility.visibility import signed_distances

        at_least = [(signed_distances(scene, cameras) - self.clearance).ravel()]
        if self.polygon is not None:
            edge = jnp.min(_segment_distances(cameras, self.polygon), axis=1)
            at_least.append(jnp.where(_inside_polygon(cameras, self.polygon), edge, -edge))
        return Constraints(jnp.zeros((0,), cameras.dtype), jnp.concatenate(at_least))

    def distances(self, cameras):
        # outside the box by how much (the map covers the closed box)
        return jnp.linalg.norm(
            jnp.maximum(_lift(self.lower, cameras) - cameras, 0.0)
            + jnp.maximum(cameras - _lift(self.upper, cameras), 0.0),
            axis=-1,
        )


class EqualityConstraint(AbstractPlacement):
    """Cameras on the set g(C) = 0 of a user's JAX function (the thesis's Eq. 3.16).

    `per_camera=True` (default): `g(camera (2,)) -> (r,)` constrains each camera alone;
    `per_camera=False`: `g(cameras (k, 2)) -> (r,)` may couple them (a distance between
    cameras, a common line). The parameters are the positions; the optimiser enforces
    g = 0 by an augmented Lagrangian. Starting points are points of the box projected onto
    the set by Gauss-Newton steps (C <- C - J^+ g; a coupled g projects each start's set
    jointly). Candidates (for the discrete searches) exist only for a per-camera g: the
    projected points of a grid that reach |g| <= 1e-10.

    **Arguments:**

    - `g`: the constraint function (residuals in units of length keep it well scaled).
    - `lower`, `upper`: a box around the part of the set of interest, shape (2,) each.
    - `per_camera`: whether g takes one camera or the whole set.
    """

    g: Callable[[Array], Array] = eqx.field(static=True)
    lower: Float[Array, "2"]
    upper: Float[Array, "2"]
    per_camera: bool = eqx.field(static=True)

    def __init__(
        self,
        g: Callable,
        lower: Real[ArrayLike, "2"] | Sequence,
        upper: Real[ArrayLike, "2"] | Sequence,
        per_camera: bool = True,
    ):
        if not callable(g):
            raise TypeError("EqualityConstraint needs a callable g(camera) -> residuals.")
        self.g = g
        self.lower, self.upper = _check_box(lower, upper, "EqualityConstraint")
        self.per_camera = bool(per_camera)

    def _residual(self, cameras: Array) -> Array:
        """g of a camera set (k, 2), flattened."""
        if self.per_camera:
            return jax.vmap(lambda c: jnp.atleast_1d(self.g(c)))(cameras).ravel()
        return jnp.atleast_1d(self.g(cameras)).ravel()

    def _project(self, sets: Array, steps: int = 30) -> Array:
        """Gauss-Newton projection of camera sets (..., k, 2) onto g = 0 (per camera,
        or per set when g couples the cameras)."""
        shape = sets.shape
        sets = sets.reshape(-1, 1, 2) if self.per_camera else sets.reshape(-1, *shape[-2:])

        def newton(cameras):
            def body(_, c):
                jac = jax.jacfwd(self._residual)(c).reshape(-1, c.size)
                return c - (jnp.linalg.pinv(jac) @ self._residual(c)).reshape(c.shape)

            return jax.lax.fori_loop(0, steps, body, cameras)

        return jax.vmap(newton)(sets).reshape(shape)

    def cameras(self, params):
        return params

    def sample(self, key, n_cameras, n_starts):
        return self._project(_in_box(key, self.lower, self.upper, (n_starts, n_cameras)))

    def candidates(self, resolution):
        """Projections of a `resolution` x `resolution` grid of the box, duplicates (to
        1e-9 of the box) removed."""
        if not self.per_camera:
            raise ValueError(
                "EqualityConstraint candidates need a per-camera g (per_camera=True): a g "
                "that couples the cameras has no single-camera grid for greedy/exhaustive."
            )
        points = np.asarray(self._project(_box_grid(self.lower, self.upper, resolution)))
        residual = np.abs(np.asarray(jax.vmap(self._residual)(jnp.asarray(points)[:, None])))
        size = float(jnp.max(self.upper - self.lower))
        kept = points[residual.max(1) <= 1e-10 * max(size, 1.0)]
        _, first = np.unique(np.round(kept / (1e-9 * size)), axis=0, return_index=True)
        return jnp.asarray(kept[np.sort(first)])

    def has_constraints(self):
        return True

    def constraints(self, cameras, scene):
        return Constraints(self._residual(cameras), jnp.zeros((0,), cameras.dtype))

    def violations(self, cameras, scene=None):
        """Per camera |g| (per-camera g); a coupled g's largest |g| for every camera."""
        if self.per_camera:
            return super().violations(cameras, scene)
        cameras = jnp.atleast_2d(jnp.asarray(cameras, float))
        worst = 0.0 if scene is None else jnp.max(jnp.abs(self._residual(cameras)))
        return jnp.full(cameras.shape[:1], worst, cameras.dtype)


def _bounds(value, name: str) -> tuple[float, float] | None:
    """(lower, upper) of a pose parameter: a number is fixed (lower == upper)."""
    if value is None:
        return None
    low, high = (value, value) if np.ndim(value) == 0 else tuple(value)
    low, high = float(low), float(high)
    if not 0 < low <= high:
        raise ValueError(
            f"DirectionalPlacement {name} must satisfy 0 < lower <= upper, got {value}."
        )
    return low, high


class DirectionalPlacement(AbstractPlacement):
    """Directional cameras (`Camera` poses): positions on any placement, a free heading
    each, and a half field of view and a range that are fixed or optimised within bounds.

    The parameters of a camera are its position's parameters, then its heading (any
    real value), then u_fov and u_range where those are optimised, mapped into their
    bounds by lower + (upper - lower) (1 + sin u) / 2 (every u is admissible).

    **Arguments:**

    - `positions`: where the cameras may be (any placement: `PolygonBoundary` of a
      room's walls, `Region`, ...).
    - `half_fov`: a number (fixed) or (lower, upper) in (0, pi].
    - `range`: None (unlimited), a number, or (lower, upper).
    """

    positions: AbstractPlacement
    half_fov: tuple[float, float] = eqx.field(static=True)
    range: tuple[float, float] | None = eqx.field(static=True)
    position_params: int = eqx.field(static=True)

    def __init__(self, positions: AbstractPlacement, half_fov, range=None):
        if not isinstance(positions, AbstractPlacement) or isinstance(
            positions, DirectionalPlacement
        ):
            raise TypeError("DirectionalPlacement positions must be a placement of positions.")
        self.positions = positions
        fov = _bounds(half_fov, "half_fov")
        if fov is None or fov[1] > np.pi:
            raise ValueError(
                f"DirectionalPlacement half_fov must be a number or (lower, upper) in (0, pi], "
                f"got {half_fov}."
            )
        self.half_fov = fov
        self.range = _bounds(range, "range")
        self.position_params = int(positions.sample(jax.random.key(0), 1, 1).shape[-1])

    def _free(self) -> list[tuple[float, float]]:
        return [b for b in (self.half_fov, self.range) if b is not None and b[0] < b[1]]

    def _pose_value(self, bounds, params, column):
        if bounds is None:
            return None, column
        low, high = bounds
        if low == high:
            return jnp.full(params.shape[:-1], low, params.dtype), column
        u = params[..., column]
        return low + (high - low) * 0.5 * (1.0 + jnp.sin(u)), column + 1

    def cameras(self, params):
        p = self.position_params
        fov, column = self._pose_value(self.half_fov, params, p + 1)
        reach, _ = self._pose_value(self.range, params, column)
        return Camera(self.positions.cameras(params[..., :p]), params[..., p], fov, reach)

    def sample(self, key, n_cameras, n_starts):
        """Positions from `positions`; headings within 90 degrees of the direction to
        the middle of the placement set (inwards: a camera on a room's wall or on a
        boundary around the objects faces them); free pose parameters uniform in their
        bounds."""
        k_position, k_heading, k_free = jax.random.split(key, 3)
        position = self.positions.sample(k_position, n_cameras, n_starts)
        middle = jnp.mean(self.positions.cameras(self.positions.candidates(8)), axis=0)
        inward = middle[None, None] - self.positions.cameras(position)
        shape = (n_starts, n_cameras, 1)
        spread = jax.random.uniform(k_heading, shape, position.dtype, -0.5 * np.pi, 0.5 * np.pi)
        heading = jnp.arctan2(inward[..., 1:], inward[..., :1]) + spread
        free = jax.random.uniform(
            k_free, shape[:2] + (len(self._free()),), position.dtype, -0.5 * np.pi, 0.5 * np.pi
        )
        return jnp.concatenate([position, heading, free], axis=-1)

    def candidates(self, resolution):
        """The position candidates, each with 16 headings (free pose parameters at the
        middle of their bounds)."""
        position = self.positions.candidates(resolution)
        headings = jnp.arange(16, dtype=position.dtype) * (2.0 * np.pi / 16)
        n = position.shape[0]
        return jnp.concatenate(
            [
                jnp.repeat(position, 16, axis=0),
                jnp.tile(headings, n)[:, None],
                jnp.zeros((16 * n, len(self._free())), position.dtype),
            ],
            axis=1,
        )

    def has_constraints(self):
        return self.positions.has_constraints()

    def constraints(self, cameras: Camera, scene):
        return self.positions.constraints(cameras.position, scene)

    def distances(self, cameras: Camera):
        return self.positions.distances(cameras.position)

    def violations(self, cameras: Camera, scene=None):
        return self.positions.violations(cameras.position, scene)
