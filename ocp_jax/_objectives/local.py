"""Local visibility objectives q(x, x', C_1, ..., C_l) (thesis Sec. 3.2, Eq. 3.10).

A local objective says how well one point x(t) of an object, with tangent x'(t), is seen
from a group of l cameras (l = `group_size`: 1 for most objectives, 2 for the
reconstruction error of Sec. 3.2.3), regardless of occlusion. The global objective
integrates, over arc length, the best group among those whose cameras all see the point
(Eqs. 3.14, 3.15), so q never includes the speed ||x'||.

Any JAX function `q(point, tangent, camera) -> scalar` (each argument of shape (2,)) is a
valid local objective; wrap it in `LocalObjective` to give it a name, or pass it directly.
"""

import abc
import itertools
from collections.abc import Callable
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._geometry.curves import is_concrete
from .._geometry.vec import Vec, add, cross, dot, scale, sub

__all__ = [
    "AbstractLocalObjective",
    "Coverage",
    "Foreshortened",
    "LocalObjective",
    "Reconstruction",
    "VisibleLength",
]


class AbstractLocalObjective(eqx.Module):
    """q(point, tangent, *cameras) for single points (arrays of shape (2,)), one camera
    argument per member of a group of `group_size` cameras.

    `is_constant` is True when q does not depend on the cameras; then two groups never
    trade places as the best one and no crossover events are needed. `similar` is True
    when q is unchanged where points and cameras are moved and all lengths scaled
    together (x -> (x - o) / s, tangents x' / s), as angles and ratios of lengths are;
    the engine then evaluates q in its frame as it is (`in_frame`).
    """

    is_constant: ClassVar[bool] = False
    group_size: ClassVar[int] = 1
    similar: ClassVar[bool] = False

    @abc.abstractmethod
    def __call__(
        self, point: Float[Array, "2"], tangent: Float[Array, "2"], *cameras: Float[Array, "2"]
    ) -> Float[Array, ""]:
        """How well `point` is seen from `cameras` (`group_size` of them)."""

    def evaluate(self, point: Vec, tangent: Vec, *cameras: Vec) -> Array:
        """q on broadcastable `Vec`s of arrays (the engine's layout); vmaps `__call__`
        unless a subclass gives a direct formula."""
        signature = ",".join(["(2)"] * (2 + len(cameras))) + "->()"
        q = jnp.vectorize(self.__call__, signature=signature)
        vecs = (point, tangent, *cameras)
        shape = jnp.broadcast_shapes(*(v.x.shape for v in vecs))
        return q(*(v.map(lambda a: jnp.broadcast_to(a, shape)).stack() for v in vecs))

    def in_frame(
        self, origin: Float[Array, "2"], scale: Float[Array, ""]
    ) -> "AbstractLocalObjective":
        """The same q for points, tangents and cameras given in the coordinates
        (x - origin) / scale (the engine's frame, `_frame.py`): q itself where it is
        `similar`, else q of the points mapped back."""
        return self if self.similar else _InFrame(self, origin, scale)


class _InFrame(AbstractLocalObjective):
    """q evaluated in the user's coordinates x = origin + scale x_frame (`in_frame`)."""

    objective: AbstractLocalObjective
    origin: Float[Array, "2"]
    scale: Float[Array, ""]

    @property
    def is_constant(self) -> bool:  # pyright: ignore[reportIncompatibleVariableOverride]
        return self.objective.is_constant

    @property
    def group_size(self) -> int:  # pyright: ignore[reportIncompatibleVariableOverride]
        return self.objective.group_size

    def __call__(self, point, tangent, *cameras):
        return self.evaluate(Vec.of(point), Vec.of(tangent), *map(Vec.of, cameras))

    def evaluate(self, point, tangent, *cameras):
        back = lambda p: add(Vec(*self.origin), scale(self.scale, p))
        return self.objective.evaluate(back(point), scale(self.scale, tangent), *map(back, cameras))


class VisibleLength(AbstractLocalObjective):
    """q = 1 (Eq. 3.11): Q is the visible length of the objects."""

    is_constant: ClassVar[bool] = True
    similar: ClassVar[bool] = True

    def __call__(self, point, tangent, camera):
        return jnp.ones((), jnp.result_type(point, camera))

    def evaluate(self, point, tangent, camera):
        return _ones(point, camera)


def _ones(point: Vec, *cameras: Vec) -> Array:
    shape = jnp.broadcast_shapes(point.x.shape, *(c.x.shape for c in cameras))
    return jnp.ones(shape, jnp.result_type(point.x, *(c.x for c in cameras)))


class Foreshortened(AbstractLocalObjective):
    """q = cos^2(alpha) = (n . (x - C))^2 / (|n|^2 |x - C|^2), alpha the angle between the
    line of sight and the normal n.

    The thesis prints Eq. 3.13 as `1 - cos^2`, which contradicts its own Sec. 5.1.2 (q must
    vanish at tangency times for Q to be differentiable across them). We use cos^2: a
    surface element seen head-on counts fully, one seen grazing counts zero.
    """

    similar: ClassVar[bool] = True

    def __call__(self, point, tangent, camera):
        return self.evaluate(Vec.of(point), Vec.of(tangent), Vec.of(camera))

    def evaluate(self, point, tangent, camera):
        sight = sub(point, camera)
        along = cross(tangent, sight)  # = n . (x - C) up to sign, n = J x'
        return along**2 / (dot(tangent, tangent) * dot(sight, sight))


class Reconstruction(AbstractLocalObjective):
    """How well two cameras locate a point by triangulation (Sec. 3.2.3; l = 2 in Eq. 3.15).

    A camera with angular accuracy `delta` places the point in a wedge of angle `delta`
    about its line of sight; two cameras at distances d1, d2 whose lines of sight meet at
    angle theta place it in the intersection of two such wedges, a quadrilateral of area

        A = delta^2 d1 d2 / sin(theta)     (to first order in delta; the thesis's Fig. 3.3).

    The local objective is larger where that error region is smaller:

        q = 1 / (1 + (A / area)^2),

    1 for a perfectly located point, 1/2 where A equals `area`, 0 where the two lines of
    sight are parallel (theta = 0 or pi). With c = |cross(x - C1, x - C2)| = d1 d2 sin(theta)
    it is the rational function q = area^2 c^2 / (area^2 c^2 + delta^4 (d1 d2)^4): smooth
    everywhere (it uses A^2, so no kink where sin(theta) = 0), symmetric in the cameras.
    Q integrates, over every point, the best pair among the cameras that both see it. q
    depends on `area` / delta^2 only: both are kept because both have a meaning.
    """

    area: float
    delta: float = 0.01
    group_size: ClassVar[int] = 2

    def __check_init__(self):
        for name in ("area", "delta"):
            value = getattr(self, name)
            if is_concrete(value) and not float(value) > 0:
                raise ValueError(f"Reconstruction.{name} must be positive, got {value!r}.")

    def __call__(self, point, tangent, camera_a, camera_b):
        return self.evaluate(Vec.of(point), Vec.of(tangent), Vec.of(camera_a), Vec.of(camera_b))

    def in_frame(self, origin, scale):
        # q depends on lengths through d1 d2 / area only: lengths / scale, area / scale^2
        return eqx.tree_at(lambda q: q.area, self, self.area / scale / scale)

    def evaluate(self, point, tangent, camera_a, camera_b):
        sight_a, sight_b = sub(point, camera_a), sub(point, camera_b)
        spread = self.area * cross(sight_a, sight_b)  # area d1 d2 sin(theta)
        product = dot(sight_a, sight_a) * dot(sight_b, sight_b)  # (d1 d2)^2
        return spread**2 / (spread**2 + self.delta**4 * product**2)


class Coverage(AbstractLocalObjective):
    """q = 1 on the points that at least `m` cameras see together (l = m in Eq. 3.15): Q
    is the length of the objects seen by m or more cameras (Sec. 3.2, "features viewed by
    more than one camera", the coverage needed for reconstruction)."""

    m: int = eqx.field(static=True, default=2)
    is_constant: ClassVar[bool] = True
    similar: ClassVar[bool] = True

    def __check_init__(self):
        if not isinstance(self.m, int) or self.m < 1:
            raise ValueError(f"Coverage.m must be a positive int, got {self.m!r}.")

    @property
    def group_size(self) -> int:  # pyright: ignore[reportIncompatibleVariableOverride]
        return self.m

    def __call__(self, point, tangent, *cameras):
        return jnp.ones((), jnp.result_type(point, *cameras))

    def evaluate(self, point, tangent, *cameras):
        return _ones(point, *cameras)


class LocalObjective(AbstractLocalObjective):
    """A user-supplied local objective `fn(point, tangent, camera) -> scalar`.

    `fn` must be a JAX function of (2,)-shaped arrays; it is vmapped over points and
    differentiated with respect to all three arguments.
    """

    fn: Callable = eqx.field(static=True)

    def __call__(self, point, tangent, camera):
        return self.fn(point, tangent, camera)


def camera_groups(objective: AbstractLocalObjective, k: int) -> np.ndarray:
    """The camera groups of Eq. 3.15: every l-subset of the k cameras, (G, l) indices."""
    size = objective.group_size
    if k < size:
        raise ValueError(
            f"ocp_jax: {type(objective).__name__} values groups of {size} cameras; pass at "
            f"least {size} cameras, got {k}."
        )
    return np.array(list(itertools.combinations(range(k), size)))


def group_members(cameras: Vec, groups: np.ndarray) -> tuple[Vec, ...]:
    """The positions of the groups' members: one `Vec` of shape (G,) per member."""
    return tuple(cameras.map(lambda a: a[groups[:, j]]) for j in range(groups.shape[1]))


def as_local_objective(q) -> AbstractLocalObjective:
    if isinstance(q, AbstractLocalObjective):
        return q
    if callable(q):
        return LocalObjective(q)
    raise TypeError(
        "objective must be a local objective (ocp.VisibleLength(), ocp.Foreshortened()) or "
        f"a function q(point, tangent, camera) -> scalar, got {type(q).__name__}."
    )
