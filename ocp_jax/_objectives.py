"""Local visibility objectives q(x, x', C) (thesis Sec. 3.2).

A local objective says how well one point x(t) of an object, with tangent x'(t), is seen
from a camera at C, regardless of occlusion. The global objective integrates it over arc
length on the visible parts (Eq. 3.14), so q never includes the speed ||x'||.

Any JAX function `q(point, tangent, camera) -> scalar` (each argument of shape (2,)) is a
valid local objective; wrap it in `LocalObjective` to give it a name, or pass it directly.
"""

import abc
from collections.abc import Callable
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from ._vec import Vec, cross, dot, sub

__all__ = ["AbstractLocalObjective", "VisibleLength", "Foreshortened", "LocalObjective"]


class AbstractLocalObjective(eqx.Module):
    """q(point, tangent, camera) for single points (arrays of shape (2,)).

    `is_constant` is True when q does not depend on the camera; then several cameras
    never trade places as the best one and no crossover events are needed.
    """

    is_constant: ClassVar[bool] = False

    @abc.abstractmethod
    def __call__(
        self, point: Float[Array, "2"], tangent: Float[Array, "2"], camera: Float[Array, "2"]
    ) -> Float[Array, ""]:
        """How well `point` is seen from `camera`."""

    def evaluate(self, point: Vec, tangent: Vec, camera: Vec) -> Array:
        """q on broadcastable `Vec`s of arrays (the engine's layout); vmaps `__call__`
        unless a subclass gives a direct formula."""
        q = jnp.vectorize(self.__call__, signature="(2),(2),(2)->()")
        shape = jnp.broadcast_shapes(point.x.shape, tangent.x.shape, camera.x.shape)
        point, tangent, camera = (
            v.map(lambda a: jnp.broadcast_to(a, shape)) for v in (point, tangent, camera)
        )
        return q(point.stack(), tangent.stack(), camera.stack())


class VisibleLength(AbstractLocalObjective):
    """q = 1 (Eq. 3.11): Q is the visible length of the objects."""

    is_constant: ClassVar[bool] = True

    def __call__(self, point, tangent, camera):
        return jnp.ones((), jnp.result_type(point, camera))

    def evaluate(self, point, tangent, camera):
        shape = jnp.broadcast_shapes(point.x.shape, camera.x.shape)
        return jnp.ones(shape, jnp.result_type(point.x, camera.x))


class Foreshortened(AbstractLocalObjective):
    """q = cos^2(alpha) = (n . (x - C))^2 / (|n|^2 |x - C|^2), alpha the angle between the
    line of sight and the normal n.

    The thesis prints Eq. 3.13 as `1 - cos^2`, which contradicts its own Sec. 5.1.2 (q must
    vanish at tangency times for Q to be differentiable across them). We use cos^2: a
    surface element seen head-on counts fully, one seen grazing counts zero.
    """

    def __call__(self, point, tangent, camera):
        return self.evaluate(Vec.of(point), Vec.of(tangent), Vec.of(camera))

    def evaluate(self, point, tangent, camera):
        sight = sub(point, camera)
        along = cross(tangent, sight)  # = n . (x - C) up to sign, n = J x'
        return along**2 / (dot(tangent, tangent) * dot(sight, sight))


class LocalObjective(AbstractLocalObjective):
    """A user-supplied local objective `fn(point, tangent, camera) -> scalar`.

    `fn` must be a JAX function of (2,)-shaped arrays; it is vmapped over points and
    differentiated with respect to all three arguments.
    """

    fn: Callable = eqx.field(static=True)

    def __call__(self, point, tangent, camera):
        return self.fn(point, tangent, camera)


def as_local_objective(q) -> AbstractLocalObjective:
    if isinstance(q, AbstractLocalObjective):
        return q
    if callable(q):
        return LocalObjective(q)
    raise TypeError(
        "objective must be a local objective (ocp.VisibleLength(), ocp.Foreshortened()) or "
        f"a function q(point, tangent, camera) -> scalar, got {type(q).__name__}."
    )
