"""The sigmoid-smoothed visibility of the thesis's Chapter 6 (Eqs. 6.2-6.7).

The exact engine finds occlusion boundaries as roots; Chapter 6 proposes instead to
replace the sharp indicators of the visibility test (Eq. 6.1) by sigmoids f, and the max
over possible occluders by a threshold on an integral (Eqs. 6.2-6.4):

    chi(t, C) = 1 - f( int f(|x(t) - C| - |x(t') - C|) f(cone(t, t')) dt' ),      (6.5)

which needs no roots, no event budgets and no assumptions on the curves, and is smooth
in the cameras and the scene. We evaluate it by quadrature: every curve is sampled at N
midpoint nodes t_j = (j + 1/2) / N, every node is a target and an occluder, and Q is the
midpoint rule for sum_i int max_G [prod_{C in G} chi(t, C) q(x, x', G)] ||x'|| dt. With one
`width` w (radians) for every sigmoid sigma(z / w) and a cone of half-angle
`delta` (default 2 w), for a target x_i seen along the unit vector u_i at distance r_i
and an occluder node x_j (u_j, r_j):

- cone (Eq. 6.3): a_ij = sigma((delta - |u_i - u_j|) / w), |u_i - u_j| ~ the angle
  between the two lines of sight;
- in front (Eq. 6.2): b_ij = sigma((r_i - r_j) / (w r_i)), depth relative to distance;
- the integral (Eq. 6.4) is taken over the angle the occluder subtends, |d phi_j| =
  |cross(x_j - C, x_j')| / r_j^2 dt, not over dt': normalised by the cone's own angular
  measure 2 w softplus(delta / w) it counts occluding layers, O_i ~ 0 (free) or >= 1
  (hidden), independently of the curves' parametrisation and of the scene's scale;
- threshold: chi_i = 1 - sigma((O_i - 1/2) / w) times the facing factor
  sigma(cos(alpha_i) / w) (alpha_i between the outward normal and the direction to the
  camera): a back-facing point of a closed curve is hidden, the exact test the engine
  also starts with (without it the back side next to a silhouette stays in the
  silhouette's window and counts as seen).

Trivial self-occlusions (Eqs. 6.6, 6.7). Every point's own neighbours on its curve lie
in its cone at about its depth, so Eq. 6.5 alone hides half of every object. The thesis
removes from the integral the largest window (t - eps_l, t + eps_r) that stays within
the cone. We remove it smoothly: walking from t_i along the curve (both ways), the
angle swept outside the cone so far is H_ij = sum_{l between i and j} (1 - a_il)
|d phi_l|; node j belongs to the window with weight exp(-H_ij / w) (for a monotone sweep
out of the cone this equals a_ij: the window ends where the cone does, as Eq. 6.7 asks),
and counts as an occluder with weight (1 - e_forward)(1 - e_backward). A part of the same
curve reached only after leaving the cone (a real self-occlusion) keeps its full weight.

Cost: O((m N)^2) per camera (every node against every node), against the exact
engine's events; memory is bounded by evaluating one camera at a time. Error, measured
in benchmarks/smoothed_vs_exact.py: on a convex object O(w^2) for the visible length and
about O(w^4) (rates 3.5-4) for the foreshortened Q once w <= ~0.025 (for wider w the
threshold's error, ~exp(-1 / (2 w)), dominates, and near w = 0.05 the two errors, of
opposite signs, cancel); with occluders O(w), the cone widening every shadow by about
delta times the distance. The midpoint rule adds its own unless the node spacing is well
below w times the camera distance.
"""

from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._geometry.camera import Camera
from .._geometry.curves import is_concrete
from .._geometry.vec import Vec, cross, norm, sub
from .local import AbstractLocalObjective, as_local_objective, group_members

__all__ = ["Smoothed"]


class Smoothed(AbstractLocalObjective):
    """The local objective `objective` seen through the smoothed visibility of Chapter 6:
    `visibility(scene, cameras, Smoothed(objective, width))` integrates the same q as
    `objective`, with the sharp visibility indicator replaced by sigmoids of width
    `width` (see the module docstring for the formulas). Differentiable everywhere in
    the cameras and the scene (for one camera; several take the max over camera groups,
    as the exact Q does), converges to the exact Q as `width` -> 0 and `nodes` -> inf.

    **Arguments:**

    - `objective`: the local objective q (any, including camera groups).
    - `width`: the sigmoids' width w (radians for angles, relative for depths, layers for
      the occlusion count); stored as an array, so that a continuation over widths
      reuses one compiled program.
    - `delta`: the cone's half-angle (Eq. 6.3's delta); None: 2 w.
    - `nodes`: quadrature nodes per curve (midpoint rule), static. Needs node spacing
      well below `width` times the camera distance.
    """

    objective: AbstractLocalObjective
    width: Float[Array, ""]
    delta: Float[Array, ""] | None
    nodes: int = eqx.field(static=True)
    is_constant: ClassVar[bool] = False

    def __init__(self, objective, width, delta=None, nodes: int = 128):
        self.objective = as_local_objective(objective)
        # Arrays, not Python floats (which jit would treat as constants): a continuation
        # over widths reuses one compiled program.
        self.width = jnp.asarray(width)
        self.delta = None if delta is None else jnp.asarray(delta)
        self.nodes = nodes

    def in_frame(self, origin, scale):
        # (the widths are angles and relative depths: unchanged)
        return eqx.tree_at(lambda s: s.objective, self, self.objective.in_frame(origin, scale))

    def __check_init__(self):
        if isinstance(self.objective, Smoothed):
            raise TypeError("Smoothed(Smoothed(...)): smooth a plain local objective once.")
        if not isinstance(self.nodes, (int, np.integer)) or self.nodes < 8:
            raise ValueError(f"Smoothed.nodes must be an int >= 8, got {self.nodes!r}.")
        for name in ("width", "delta"):
            value = getattr(self, name)
            if value is not None and is_concrete(value) and not np.all(np.asarray(value) > 0):
                raise ValueError(f"Smoothed.{name} must be positive, got {value!r}.")

    @property
    def group_size(self) -> int:  # pyright: ignore[reportIncompatibleVariableOverride]
        return self.objective.group_size

    def __call__(self, point, tangent, *cameras):
        return self.objective(point, tangent, *cameras)

    def evaluate(self, point, tangent, *cameras):
        return self.objective.evaluate(point, tangent, *cameras)


def _nodes(scene, count: int):
    """Midpoint nodes t_j = (j + 1/2) / count on every curve: x, x' (Vecs (m, N))."""
    t = (jnp.arange(count, dtype=scene.dtype) + 0.5) / count
    x, dx, _ = scene.components(jnp.broadcast_to(t, (len(scene), count)))
    return x, dx


def _window_keep(outside: Float[Array, "N N"], width) -> Float[Array, "N N"]:
    """Weights (1 - e_fwd)(1 - e_bwd) of the same-curve occluders of every target
    (row i, column j): e = exp(-H / w), H the angle swept outside the cone walking from
    i to j forward (nodes i+1 .. j) resp. backward (j .. i-1) along the closed curve
    (`outside[i, l]` = (1 - a_il) |d phi_l|). Prefix sums, no gathers."""
    upto = jnp.cumsum(outside, axis=1)  # [i, j]: sum over l <= j
    before = upto - outside  # sum over l < j
    total = upto[:, -1:]
    at_target = jnp.diagonal(upto)[:, None]  # sum over l <= i
    below_target = jnp.diagonal(before)[:, None]  # sum over l < i
    index = jnp.arange(outside.shape[0])
    ahead = index[None, :] >= index[:, None]  # j >= i
    forward = jnp.where(ahead, upto - at_target, total - at_target + upto)
    backward = jnp.where(ahead, total - before + below_target, below_target - before)
    return (1 - jnp.exp(-forward / width)) * (1 - jnp.exp(-backward / width))


def _seen(camera: Vec, x: Vec, dx: Vec, sense, width, delta) -> Float[Array, "m N"]:
    """chi at every node (targets (m, N)) for one camera: Eqs. 6.5-6.7 as described in
    the module docstring."""
    m, count = x.x.shape
    sight = sub(x, camera)
    distance = norm(sight)
    facing = sense[:, None] * cross(dx, sight) / (norm(dx) * distance)  # cos(alpha)
    sweep = jnp.abs(cross(sight, dx)) / distance**2 / count  # |d phi| per node
    # Every node against every node: targets i (rows) and occluders j (columns).
    unit = Vec(sight.x / distance, sight.y / distance).map(jnp.ravel)
    distance, sweep = distance.ravel(), sweep.ravel()
    squared = (unit.x[:, None] - unit.x[None]) ** 2 + (unit.y[:, None] - unit.y[None]) ** 2
    positive = squared > 0  # a finite derivative where i = j (|u_i - u_j| = 0)
    gap = jnp.where(positive, jnp.sqrt(jnp.where(positive, squared, 1.0)), 0.0)  # |u_i - u_j|
    cone = jax.nn.sigmoid((delta - gap) / width)  # Eq. 6.3; in front: Eq. 6.2
    front = jax.nn.sigmoid((distance[:, None] - distance[None]) / (width * distance[:, None]))
    # Eqs. 6.6, 6.7: the window of each target's own curve that stays in its cone.
    outside = ((1 - cone) * sweep[None]).reshape(m, count, m, count)
    own = jax.vmap(_window_keep, in_axes=(0, None))(jnp.einsum("iaib->iab", outside), width)
    same_curve = jnp.eye(m, dtype=own.dtype)[:, None, :, None]
    keep = 1 + same_curve * (own[:, :, None, :] - 1)  # other curves: 1
    measure = 2 * width * jax.nn.softplus(delta / width)  # int sigmoid((delta - |phi|)/w) dphi
    layers = jnp.sum(keep.reshape(cone.shape) * cone * front * sweep[None], axis=1) / measure
    hidden = jax.nn.sigmoid((layers.reshape(m, count) - 0.5) / width)  # Eq. 6.4
    return (1 - hidden) * jax.nn.sigmoid(facing / width)


def smoothed_value(scene, poses: Camera, objective: Smoothed, sense, groups, observed):
    """Q of the smoothed visibility by the midpoint rule (see the module docstring)."""
    if poses.half_fov is not None or poses.range is not None:
        raise ValueError(
            "ocp_jax: Smoothed visibility has no view wedge or range yet; pass camera "
            "positions (or Camera(position, heading) without half_fov and range)."
        )
    width = jnp.asarray(objective.width, scene.dtype)
    delta = 2 * width if objective.delta is None else jnp.asarray(objective.delta, scene.dtype)
    x, dx = _nodes(scene, objective.nodes)
    cameras = Vec.of(poses.position)
    seen = jax.lax.map(
        lambda c: _seen(Vec(*c), x, dx, sense, width, delta), (cameras.x, cameras.y)
    )  # (k, m, N)
    by_group = jnp.prod(seen[groups], axis=1)  # (G, m, N)
    members = (c.map(lambda a: a[:, None, None]) for c in group_members(cameras, groups))
    local = objective.objective.evaluate(
        x.map(lambda a: a[None]), dx.map(lambda a: a[None]), *members
    )
    integrand = jnp.max(by_group * local, axis=0) * norm(dx) * jnp.asarray(observed)[:, None]
    return jnp.sum(integrand) / objective.nodes
