"""The scene's frame: the engine computes in coordinates where the scene has unit size.

Everything the engine decides is invariant under x -> (x - o) / s (a translation and a
uniform scaling) applied to the scene and the cameras together: tangency, shadow and
crossover times are curve parameters, and whether a line of sight is blocked does not
depend on units. Its tests
do multiply lengths, though: the occlusion test's products reach the sixth power of the
scene's size and the derivative of cos^2 in a crossover search the eighth, which in
float32 underflow for a scene of size 1e-6 and overflow for one of size 1e6 (Q was then
off by up to 65% and its gradient NaN). So the engine works
in the scene's frame: o the centre of the scene's bounding box, s the power of two just
above its size, and only the local objective sees the user's units
(`AbstractLocalObjective.in_frame`).

With s a power of two, dividing by it is exact: a scene scaled by 2^j gives bitwise the
Q of the scene, times 2^j. Q, an integral over arc length, scales back by s. The frame
carries no derivative: Q is the same for every o and s, so its derivatives with respect
to them vanish. The frame is the scene's only: a camera some 1e5 scene sizes away can
still take float32's products of lengths out of range.
"""

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from .scene import Scene


class Frame(NamedTuple):
    """The coordinates (x - origin) / scale."""

    origin: Float[Array, "2"]
    scale: Float[Array, ""]


def scene_frame(scene: Scene) -> Frame:
    """The centre of the scene's bounding box and the power of two in (size, 2 size] for
    its larger side (origin 0 and scale 1 where they are not finite positive numbers: the
    input checks then say what is wrong)."""
    low, high = jax.lax.stop_gradient(scene.bounds())
    size = jnp.max(high - low)
    origin = low + 0.5 * (high - low)
    usable = jnp.isfinite(size) & (size > 0)  # (then the origin is finite too)
    _, exponent = jnp.frexp(jnp.where(usable, size, 1.0))  # size = m 2^e, m in [1/2, 1)
    scale = jnp.ldexp(jnp.ones_like(size), exponent)
    return Frame(jnp.where(usable, origin, 0.0), jnp.where(usable, scale, 1.0))
