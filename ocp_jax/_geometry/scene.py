"""A scene: a set of closed curves (the objects), evaluated together."""

import functools
import math
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .curves import (
    AbstractConic,
    AbstractCurve,
    PieceTable,
    PiecewiseCurve,
    UnitFrame,
    is_concrete,
    piece_table,
)
from .validity import check_scene, checked_under_trace
from .vec import Vec

__all__ = ["Scene"]


def _structure(curve: AbstractCurve):
    leaves, treedef = jax.tree.flatten(curve)
    return treedef, tuple((jnp.shape(x), jnp.result_type(x)) for x in leaves)


class Scene(eqx.Module):
    """The objects x_1..x_m of a scene (Sec. 2.1), as a pytree of curves, optionally
    inside a room.

    Curves are evaluated in groups (`CurveGroup`), so that a scene of many objects
    compiles to a few evaluations, not one per object: paths of Bezier segments
    (polygons and other `PiecewiseCurve`s, `AbstractCurve.bezier_pieces`) as one table
    per degree whatever their number of segments, conics as one stack of ellipses, and
    other curves (B-splines, Bezier curves) stacked by type and shape.

    The curves must form a valid scene: each simple, no two crossing, touching or
    nested, all inside the room. Built from concrete arrays, an invalid scene raises a
    ValueError that names the curves and a point near the fault; built from traced
    arrays (under `jit`, `vmap` or `grad`), its program raises when it runs.

    **Arguments:**

    - `curves`: a sequence of curves (`BezierCurve`, `BSplineCurve`, `Circle`,
      `PiecewiseCurve`, ...): the objects, seen from outside.
    - `room`: optional closed curve whose inside is the free space (the walls): it
      occludes like any object, cameras must be inside it, and it is not itself part
      of Q (only the objects are to be seen). It is stored as the last of `curves`.
    """

    curves: tuple[AbstractCurve, ...]
    room: bool = eqx.field(static=True)
    # None on a user's scene (only the engine's store them, `_of_checked`): not shown
    groups: tuple["CurveGroup", ...] | None = eqx.field(repr=False)

    def __init__(self, curves: Sequence[AbstractCurve], room: AbstractCurve | None = None):
        if isinstance(curves, AbstractCurve):
            curves = [curves]
        curves = tuple(curves)
        if not curves:
            raise ValueError("A Scene needs at least one curve.")
        if room is not None:
            curves = (*curves, room)
        for c in curves:
            if not isinstance(c, AbstractCurve):
                raise TypeError(
                    f"Scene curves must be ocp_jax curves (BezierCurve, BSplineCurve, "
                    f"Circle, Ellipse, PiecewiseCurve), got {type(c).__name__}."
                )
        if is_concrete(*jax.tree.leaves(curves)):
            check_scene(curves, room is not None)
        else:  # built from traced arrays: refused when the program runs
            curves = checked_under_trace(curves, room is not None)
        self.curves = curves
        self.room = room is not None
        self.groups = None

    @classmethod
    def _of_checked(cls, curves: tuple[AbstractCurve, ...], room: bool) -> "Scene":
        """A scene of curves that are already known to form a valid scene (they come
        from a checked one), built without checking them again, with its `CurveGroup`s
        built once: the engine evaluates its scene, in its frame (`in_frame`), at many
        places, and each would build the tables again. (A user's scene stores none, so
        that its only leaves, and so its derivatives, are its curves'.)"""
        scene = object.__new__(cls)
        object.__setattr__(scene, "curves", curves)
        object.__setattr__(scene, "room", room)
        object.__setattr__(scene, "groups", _grouped(curves))
        return scene

    @property
    def objects(self) -> tuple[AbstractCurve, ...]:
        """The curves that are to be seen (all but the room)."""
        return self.curves[:-1] if self.room else self.curves

    def observed(self) -> np.ndarray:
        """Static (m,) mask of the curves that count in Q (all but the room)."""
        return np.arange(len(self.curves)) < len(self.objects)

    def sides(self) -> np.ndarray:
        """Static (m,) signs: +1 where the free space is outside a curve, -1 inside."""
        return np.where(self.observed(), 1.0, -1.0)

    def __len__(self) -> int:
        return len(self.curves)

    @property
    def dtype(self):
        return jnp.result_type(*jax.tree.leaves(self.curves))

    def _curve_groups(self) -> tuple["CurveGroup", ...]:
        return _grouped(self.curves) if self.groups is None else self.groups

    def _map(self, fn, *args):
        """Apply `fn(curve, *row_args)` to every curve i with the i-th rows of `args`;
        results are stacked along a leading curve axis. A curve alone in its group is
        not vmapped (a batch of one only makes the program longer to trace)."""
        outputs, order = [], []
        for group in self._curve_groups():
            members, form = list(group.members), group.form
            if len(members) == 1:
                (i,) = members
                out = fn(form, *(a[i] for a in args))
                outputs.append(jax.tree.map(lambda a: a[None], out))
            else:
                rows = [
                    a if len(members) == len(self.curves) else a[np.asarray(members)] for a in args
                ]
                outputs.append(_rows_vmapped(fn, form, None, rows))
            order.extend(members)
        if len(outputs) == 1:
            return outputs[0]
        inverse = np.argsort(np.asarray(order))
        return jax.tree.map(lambda *xs: jnp.concatenate(xs)[inverse], *outputs)

    def _map_at(self, fn, curve, t, axis: int = 0):
        """Apply `fn(curve_j, t_j)` at every element j of a flat list, on the curve
        `curve[j]` (an index array (E,)) at its row t[j]; the results' element axis is
        `axis` (as where fn is applied to all of t at once). Each group of curves of one
        type and shape is evaluated at every element, with the element's curve's
        parameters gathered, and the element keeps its own group's result: the cost is
        that of the elements times the number of groups, not of the curves."""
        group_of, local = np.zeros(len(self.curves), int), np.zeros(len(self.curves), int)
        groups = self._curve_groups()
        for g, group in enumerate(groups):
            members = list(group.members)
            group_of[members], local[members] = g, np.arange(len(members))
        outputs = []
        for group in groups:
            if len(group.members) == 1:  # (all of t at once)
                outputs.append(fn(group.form, t))
            else:
                own = jnp.asarray(local)[curve]
                outputs.append(_rows_vmapped(fn, group.form, own, [t], out_axes=axis))
        if len(outputs) == 1:
            return outputs[0]
        group = jnp.asarray(group_of)[curve]

        def select(*xs):
            shape = [1] * xs[0].ndim
            shape[axis] = group.shape[0]
            mine = group.reshape(shape)
            return functools.reduce(
                lambda out, g: jnp.where(mine == g, xs[g], out), range(1, len(xs)), xs[0]
            )

        return jax.tree.map(select, *outputs)

    def components_at(self, curve: Int[Array, " e"], t: Float[Array, "e *shape"]):
        """x, x', x'' of curve `curve[j]` at t[j] for every element j of a flat list."""
        return self._map_at(_components, curve, jnp.asarray(t, self.dtype))

    def point_and_tangent_at(
        self, curve: Int[Array, " e"], t: Float[Array, "e *shape"]
    ) -> Float[Array, "4 e *shape"]:
        """Rows (x, y, x', y') of curve `curve[j]` at t[j] for every element j of a flat
        list (`AbstractCurve.point_and_tangent`)."""
        t = jnp.asarray(t, self.dtype)
        return self._map_at(lambda c, t: c.point_and_tangent(t), curve, t, axis=1)

    def components(self, t: Float[Array, "m *shape"]) -> tuple[Vec, Vec, Vec]:
        """x_i(t[i]), x_i'(t[i]), x_i''(t[i]) for every curve i (row i of `t`), as `Vec`s."""
        t = jnp.asarray(t, self.dtype)
        return self._map(_components, t)

    def point_and_tangent(self, t: Float[Array, "m *shape"]) -> Float[Array, "m 4 *shape"]:
        """Rows (x, y, x', y') of x_i(t[i]) and x_i'(t[i]) for every curve i
        (`AbstractCurve.point_and_tangent`)."""
        t = jnp.asarray(t, self.dtype)
        return self._map(lambda curve, t: curve.point_and_tangent(t), t)

    def components_left(self, t: Float[Array, "m *shape"]) -> tuple[Vec, Vec, Vec]:
        """Left limits of `components` (they differ at corners)."""
        t = jnp.asarray(t, self.dtype)
        return self._map(_components_left, t)

    def bounds(self) -> tuple[Float[Array, "2"], Float[Array, "2"]]:
        """The lower and upper corners of an axis-aligned box that holds every curve."""
        lows, highs = self._map(lambda c: c.bounds())  # (m, 2) each
        return jnp.min(lows, 0), jnp.max(highs, 0)

    def in_frame(self, origin: Float[Array, "2"], scale: Float[Array, ""]) -> "Scene":
        """The same scene in the coordinates (x - origin) / scale."""
        return Scene._of_checked(tuple(c.in_frame(origin, scale) for c in self.curves), self.room)

    @property
    def has_corners(self) -> bool:
        return any(c.corners().size for c in self.curves)

    def corners(self) -> tuple[np.ndarray, np.ndarray]:
        """Static (m, c) arrays: every curve's corner parameters (padded with 1.0, the end
        of [0, 1)) and which entries are corners."""
        corners = [c.corners() for c in self.curves]
        width = max(1, max(len(c) for c in corners))
        times = np.ones((len(corners), width))
        real = np.zeros((len(corners), width), bool)
        for i, c in enumerate(corners):
            times[i, : len(c)] = c
            real[i, : len(c)] = True
        return times, real

    def straight(self) -> np.ndarray:
        """Static (m,) array: which curves are polygons (straight pieces from corner to
        corner: on a grid through the corners, the polygon of grid points is the curve)."""
        return np.array([isinstance(c, PiecewiseCurve) and c.degree == 1 for c in self.curves])

    def pieces(self, cells: int) -> np.ndarray | None:
        """Static (m, cells) array: which smooth piece of its curve each grid cell lies
        on (pieces run from corner to corner; the last and the first are one where t = 0
        is no corner). None for a scene without corners (every curve one piece)."""
        if not self.has_corners:
            return None
        starts = np.arange(cells) / cells
        pieces = np.zeros((len(self.curves), cells), int)
        for i, corners in enumerate(c.corners() for c in self.curves):
            count = np.searchsorted(corners, starts, side="right")  # corners at or before
            pieces[i] = count if len(corners) and corners[0] == 0 else count % max(1, len(corners))
        return pieces

    def rows(self, rows: np.ndarray) -> "Scene":
        """The curves `rows` (static indices) as a scene of objects, for evaluating those
        rows alone: they are curves of this checked scene, so they are not checked again."""
        if np.array_equal(rows, np.arange(len(self.curves))) and not self.room:
            return self
        return Scene._of_checked(tuple(self.curves[i] for i in rows), False)

    def conic(self) -> np.ndarray:
        """Static (m,) array: which curves are conics (whose crossings of a line have
        closed forms, `_conics.py`)."""
        return np.array([isinstance(c, AbstractConic) for c in self.curves])

    @property
    def conics_only(self) -> bool:
        """Whether every curve is a conic (then the events have closed forms, `_conics.py`)."""
        return bool(self.conic().all())

    def conic_frames(self) -> UnitFrame:
        """Every curve's `AbstractConic.unit_frame`, stacked (a scene of conics only)."""
        return self._map(lambda c: c.unit_frame())

    def costly_evaluation(self) -> bool:
        """Whether some curve is costly to evaluate (see `AbstractCurve.costly_evaluation`)."""
        return any(c.costly_evaluation() for c in self.curves)

    def grid_alignment(self) -> int:
        """The grid cell count must be a multiple of this (the least common multiple of
        the curves' segment counts), so that every corner is a grid node."""
        return math.lcm(*(max(1, len(c.corners())) for c in self.curves))

    def derivatives(
        self, t: Float[Array, "m *shape"]
    ) -> tuple[Float[Array, "m *shape 2"], Float[Array, "m *shape 2"], Float[Array, "m *shape 2"]]:
        """x_i(t[i]), x_i'(t[i]), x_i''(t[i]) for every curve i (row i of `t`)."""
        x, dx, ddx = self.components(t)
        return x.stack(), dx.stack(), ddx.stack()

    def grid_cells(self) -> int:
        """Grid cells per curve for root bracketing: the finest any curve asks for,
        rounded up to a multiple of `grid_alignment`."""
        align = self.grid_alignment()
        return align * -(-max(c.grid_cells() for c in self.curves) // align)

    def breakpoints(self) -> Float[Array, "m b"]:
        """Each curve's breakpoints, padded with 1 (the end of [0, 1), as the engine pads
        its events) to a common length."""
        points = [c.breakpoints() for c in self.curves]
        width = max(p.shape[0] for p in points)
        return jnp.stack([jnp.pad(p, (0, width - p.shape[0]), constant_values=1.0) for p in points])


class CurveGroup(eqx.Module):
    """Curves of a scene evaluated together: `members` (their static indices in the
    scene) and `form`, one curve pytree for all of them. Curves made of Bezier segments
    (`AbstractCurve.bezier_pieces`) are one group per degree, as one `PieceTable`;
    conics are one group of `Ellipse`s (`AbstractConic.as_ellipse`); other curves are
    grouped by type and shape and stacked along a leading axis (a curve alone in its
    group: itself)."""

    members: tuple[int, ...] = eqx.field(static=True)
    form: AbstractCurve


def _grouped(curves: tuple[AbstractCurve, ...]) -> tuple[CurveGroup, ...]:
    """The `CurveGroup`s of a scene's curves. A scene stores them, so that the tables are
    built once (where the scene is built), not at every evaluation."""
    dtype = jnp.result_type(*jax.tree.leaves(curves))
    pieces = [c.bezier_pieces() for c in curves]
    curves = tuple(c.as_ellipse() if isinstance(c, AbstractConic) else c for c in curves)
    groups: dict = {}
    for i, (c, p) in enumerate(zip(curves, pieces)):
        key = ("pieces", p.shape[1]) if p is not None else _structure(c)
        groups.setdefault(key, []).append(i)
    out = []
    for key, group in groups.items():
        if key[0] == "pieces":
            table, counts = piece_table([pieces[i] for i in group], dtype)
            form = PieceTable(table, counts)
        elif len(group) == 1:
            form = curves[group[0]]
        else:
            form = jax.tree.map(lambda *xs: jnp.stack(xs), *(curves[i] for i in group))
        out.append(CurveGroup(tuple(group), form))
    return tuple(out)


def _rows_vmapped(fn, form: AbstractCurve, index, args: list, out_axes: int = 0):
    """`fn(curve, *args_j)` vmapped over j on the curves of a group (`CurveGroup`):
    the curve `index[j]` (all in turn where None) and the j-th rows of `args`. A table's
    rows are picked by their index; stacked curves are gathered where `index` is given."""
    if isinstance(form, PieceTable):
        if index is None:
            index = jnp.arange(form.counts.shape[0])
        table, counts = form.table, form.counts
        return jax.vmap(lambda j, *a: fn(PieceTable(table, counts, j), *a), out_axes=out_axes)(
            index, *args
        )
    own = form if index is None else jax.tree.map(lambda a: a[index], form)
    return jax.vmap(fn, out_axes=out_axes)(own, *args)


# A curve evaluation is hundreds of operations (a degree-18 Bezier) and Q evaluates the
# curves at about 20 places: as jitted functions they are traced once per curve type and
# shape of t, not at every place, which shortens tracing (XLA inlines the calls, so the
# compiled program is the same).
@jax.jit
def _components(curve, t):
    return curve.components(t)


@jax.jit
def _components_left(curve, t):
    return curve.components_left(t)
