"""Where cameras may go: placement sets parametrised so that every parameter value is
feasible (the thesis's constraint g(C) = 0 of Eq. 3.16, solved by construction).

A placement maps unconstrained parameters (one row per camera) to camera positions,
samples starting parameters and candidate grids (for the discrete baselines), and
reports how far given cameras are from the set.
"""

import abc

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float, PRNGKeyArray

from ._curves import _is_concrete

__all__ = ["AbstractPlacement", "RectangleBoundary"]


class AbstractPlacement(eqx.Module):
    """A set of admissible camera positions with a parametrisation of it."""

    @abc.abstractmethod
    def cameras(self, params: Float[Array, "k p"]) -> Float[Array, "k 2"]:
        """Camera positions of the parameters (any real values are admissible)."""

    @abc.abstractmethod
    def sample(self, key: PRNGKeyArray, n_cameras: int, n_starts: int) -> Float[Array, "s k p"]:
        """`n_starts` random parameter sets of `n_cameras` cameras, uniform on the set."""

    @abc.abstractmethod
    def candidates(self, resolution: int) -> Float[Array, "n p"]:
        """A grid of single-camera parameters covering the set, `resolution` per side
        (or per unit of the set's own measure, as the subclass documents)."""

    @abc.abstractmethod
    def violation(self, cameras: Float[ArrayLike, "k 2"]) -> Float[Array, ""]:
        """The largest distance of a camera from the set (0 for admissible cameras)."""


class RectangleBoundary(AbstractPlacement):
    """Cameras on the boundary of an axis-aligned rectangle (the thesis's Sec. 5.1.1).

    One parameter per camera, s in R: the point at arc length (s mod 1) L along the
    boundary, L = 2 (width + height), counter-clockwise from the lower-left corner.

    **Arguments:**
    - `center`: the rectangle's centre, shape (2,).
    - `width`, `height`: its side lengths (> 0).
    """

    center: Float[Array, "2"]
    width: Float[Array, ""]
    height: Float[Array, ""]

    def __init__(self, center: Float[ArrayLike, "2"], width: float, height: float):
        self.center = jnp.asarray(center, float)
        self.width = jnp.asarray(width, float)
        self.height = jnp.asarray(height, float)
        if self.center.shape != (2,):
            raise ValueError(
                f"RectangleBoundary center must have shape (2,), got {self.center.shape}."
            )
        if _is_concrete(self.width, self.height) and not (self.width > 0 and self.height > 0):
            raise ValueError(
                f"RectangleBoundary width and height must be positive, got {float(self.width)} "
                f"and {float(self.height)}."
            )

    def cameras(self, params):
        w, h = self.width, self.height
        arc = jnp.mod(params[..., 0], 1.0) * 2 * (w + h)
        # Distance travelled along each of the four sides, in order.
        bottom = jnp.clip(arc, 0, w)
        right = jnp.clip(arc - w, 0, h)
        top = jnp.clip(arc - w - h, 0, w)
        left = jnp.clip(arc - 2 * w - h, 0, h)
        x = bottom - top
        y = right - left
        along = jnp.stack([x, y], -1)
        corner = self.center - 0.5 * jnp.stack([w, h])
        return jnp.broadcast_to(corner, along.shape) + along

    def sample(self, key, n_cameras, n_starts):
        return jax.random.uniform(key, (n_starts, n_cameras, 1), self.center.dtype)

    def candidates(self, resolution):
        """`resolution` candidates per side (the thesis used 128), corners included once."""
        side = jnp.arange(resolution) / resolution
        w, h = self.width, self.height
        perimeter = 2 * (w + h)
        starts = jnp.stack([0.0, w, w + h, 2 * w + h]) / perimeter
        lengths = jnp.stack([w, h, w, h]) / perimeter
        return (starts[:, None] + lengths[:, None] * side[None]).reshape(-1, 1)

    def violation(self, cameras):
        cameras = jnp.asarray(cameras)
        half = 0.5 * jnp.stack([self.width, self.height])
        offset = jnp.abs(cameras - jnp.broadcast_to(self.center, cameras.shape))
        offset = offset - jnp.broadcast_to(half, cameras.shape)
        outside = jnp.linalg.norm(jnp.maximum(offset, 0.0), axis=-1)
        inside = -jnp.max(jnp.minimum(offset, 0.0), axis=-1)
        return jnp.max(outside + inside)
