"""Plane vectors stored as two arrays (structure of arrays).

The engine works on `Vec(x, y)` pairs of same-shaped arrays rather than arrays with a
trailing axis of size 2: XLA's CPU code for elementwise work over a minor axis of length 2
is several times slower, and every hot loop here is elementwise.
"""

from typing import NamedTuple

import jax.numpy as jnp
from jaxtyping import Array


class Vec(NamedTuple):
    x: Array
    y: Array

    @classmethod
    def of(cls, a) -> "Vec":
        """From an array with a trailing axis of size 2."""
        a = jnp.asarray(a)
        return cls(a[..., 0], a[..., 1])

    def stack(self) -> Array:
        """To an array with a trailing axis of size 2."""
        return jnp.stack([self.x, self.y], -1)

    def map(self, fn) -> "Vec":
        return Vec(fn(self.x), fn(self.y))


def sub(a: Vec, b: Vec) -> Vec:
    return Vec(a.x - b.x, a.y - b.y)


def add(a: Vec, b: Vec) -> Vec:
    return Vec(a.x + b.x, a.y + b.y)


def scale(s, a: Vec) -> Vec:
    return Vec(s * a.x, s * a.y)


def cross(a: Vec, b: Vec) -> Array:
    return a.x * b.y - a.y * b.x


def dot(a: Vec, b: Vec) -> Array:
    return a.x * b.x + a.y * b.y


def norm(a: Vec) -> Array:
    return jnp.sqrt(dot(a, a))
