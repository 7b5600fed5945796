"""Camera poses: position, heading, field of view and range.

The thesis's cameras are points that see all around (Sec. 2.2). A `Camera` adds the
sensor model it names: an optical axis (heading), a view wedge of half opening angle
`half_fov` around it, and a maximum range. A point x is in view of camera C when

    (x - C) . u >= |x - C| cos(half_fov)   (u = (cos heading, sin heading))
    |x - C| <= range

and no object blocks the open segment (C, x). Position-only cameras are the case
`half_fov = None, range = None` and run exactly the position-only computation.
"""

from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Real

from .curves import is_concrete, to_frame

__all__ = ["Camera"]


def _leaf(value, shape, dtype, name: str) -> Array:
    value = jnp.asarray(value, dtype)
    if value.ndim > len(shape) or value.shape != shape[len(shape) - value.ndim :]:
        raise ValueError(
            f"Camera {name} must be a scalar or have the batch shape {shape} of the "
            f"positions, got {value.shape}."
        )
    return jnp.broadcast_to(value, shape)


class Camera(eqx.Module):
    """Camera poses, batched over a leading shape (k cameras: `position` of shape (k, 2)).

    **Arguments:**

    - `position`: C, shape (..., 2).
    - `heading`: angle of the optical axis in radians (default 0: along +x).
    - `half_fov`: half the opening angle of the view wedge, in (0, pi]; None (default):
      the camera sees all around, with no wedge events at all.
    - `range`: the farthest distance seen, > 0; None (default): unlimited.

    Scalars broadcast to the batch shape. `Camera(positions)` gives exactly the Q of the
    positions themselves; `half_fov = pi` with `range = None` gives it up to rounding
    (the wedge's edges still cut intervals).
    """

    position: Float[Array, "*k 2"]
    heading: Float[Array, "*k"]
    half_fov: Float[Array, "*k"] | None
    range: Float[Array, "*k"] | None

    def __init__(
        self,
        position: Real[ArrayLike, "*k 2"] | Sequence,
        heading: Real[ArrayLike, "*k"] | Sequence = 0.0,
        half_fov: Real[ArrayLike, "*k"] | Sequence | None = None,
        range: Real[ArrayLike, "*k"] | Sequence | None = None,
    ):
        position = jnp.asarray(position)
        if not jnp.issubdtype(position.dtype, jnp.floating):
            position = position.astype(jnp.result_type(float))
        if position.ndim < 1 or position.shape[-1] != 2:
            raise ValueError(f"Camera position must have shape (..., 2), got {position.shape}.")
        shape, dtype = position.shape[:-1], position.dtype
        self.position = position
        self.heading = _leaf(heading, shape, dtype, "heading")
        self.half_fov = None if half_fov is None else _leaf(half_fov, shape, dtype, "half_fov")
        self.range = None if range is None else _leaf(range, shape, dtype, "range")

    def __check_init__(self):
        if not is_concrete(*jax.tree.leaves(self)):
            return
        if self.half_fov is not None:
            fov = np.asarray(self.half_fov)
            if not np.all((fov > 0) & (fov <= np.pi)):
                raise ValueError(
                    "Camera half_fov must lie in (0, pi] radians (pi: all around), got "
                    f"{fov.tolist()}."
                )
        if self.range is not None and not np.all(np.asarray(self.range) > 0):
            raise ValueError(
                "Camera range must be positive (None: unlimited), got "
                f"{np.asarray(self.range).tolist()}."
            )

    @property
    def shape(self) -> tuple[int, ...]:
        return self.position.shape[:-1]

    def in_frame(self, origin: Float[Array, "2"], scale: Float[Array, ""]) -> "Camera":
        """The same poses in the coordinates (x - origin) / scale (angles unchanged)."""
        moved = eqx.tree_at(lambda c: c.position, self, to_frame(self.position, origin, scale))
        if self.range is None:
            return moved
        return eqx.tree_at(lambda c: c.range, moved, self.range / scale)

    def direction(self) -> Float[Array, "*k 2"]:
        """u = (cos heading, sin heading)."""
        return jnp.stack([jnp.cos(self.heading), jnp.sin(self.heading)], -1)
