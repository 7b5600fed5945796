"""Pictures of scenes, cameras, what they see, objective landscapes and optimiser runs.

matplotlib only; every function draws into `ax` (a new figure when None), returns the
Axes and never calls `show()`, so it works headless (Agg) and in notebooks alike.
Camera c is drawn in colour `CAMERA_COLOURS[c % 10]` (matplotlib's tab10).
"""

import jax
import jax.numpy as jnp
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.collections import LineCollection
from matplotlib.colors import Normalize
from matplotlib.lines import Line2D

from ._geometry.camera import Camera
from ._geometry.scene import Scene
from ._objectives.local import Foreshortened, as_local_objective
from ._placement.placement import AbstractBoundary, AbstractPlacement, DirectionalPlacement, Region
from ._solvers.discrete import values_of_sets
from ._solvers.problem import Solution
from ._visibility.visibility import VisibilityOptions, visible_intervals

__all__ = ["CAMERA_COLOURS", "plot_landscape", "plot_optimization", "plot_scene"]

CAMERA_COLOURS = tuple(plt.get_cmap("tab10")(i) for i in range(10))
OBJECT_COLOUR = "0.65"
SHARED_COLOUR = "black"


def _axes(ax):
    if ax is None:
        _, ax = plt.subplots(figsize=(6, 5))
    return ax


def _curve_points(scene: Scene, t: np.ndarray) -> np.ndarray:
    """Points (m, n, 2) of every curve at the parameters t (n,)."""
    return np.asarray(scene.derivatives(jnp.broadcast_to(jnp.asarray(t), (len(scene), len(t))))[0])


def _draw_objects(ax, scene: Scene, colour=OBJECT_COLOUR, resolution: int = 512) -> np.ndarray:
    """Every curve as a thin line; returns the points drawn (m, resolution + 1, 2)."""
    points = _curve_points(scene, np.linspace(0.0, 1.0, resolution + 1))
    for curve in points:
        ax.plot(*curve.T, color=colour, linewidth=1.5, zorder=2)
    return points


def _runs(points: np.ndarray, mask: np.ndarray) -> list[np.ndarray]:
    """The polyline's pieces over the runs of consecutive segments j (point j to j + 1)
    where mask[j], each as one polyline (so that antialiasing does not show the joins)."""
    edges = np.diff(np.concatenate([[0], mask.astype(int), [0]]))
    starts, ends = np.nonzero(edges == 1)[0], np.nonzero(edges == -1)[0]
    return [points[a : b + 1] for a, b in zip(starts, ends)]


def _positions(cameras) -> np.ndarray:
    """Camera positions, from positions or a `Camera`."""
    return np.asarray(cameras.position if isinstance(cameras, Camera) else cameras)


def plot_placement(placement: AbstractPlacement, ax=None, **style):
    """The set where cameras may go: a boundary's walls, a region's box and polygon, or
    (other placements) its candidate points."""
    ax = _axes(ax)
    style = {"color": "0.3", "linestyle": "--", "linewidth": 1, **style}
    if isinstance(placement, DirectionalPlacement):
        placement = placement.positions
    if isinstance(placement, AbstractBoundary):
        corners = np.asarray(placement.vertices())
        ax.plot(*np.vstack([corners, corners[:1]]).T, **style)
    elif isinstance(placement, Region):
        lo, hi = np.asarray(placement.lower), np.asarray(placement.upper)
        ax.plot([lo[0], hi[0], hi[0], lo[0], lo[0]], [lo[1], lo[1], hi[1], hi[1], lo[1]], **style)
        if placement.polygon is not None:
            polygon = np.asarray(placement.polygon)
            ax.plot(*np.vstack([polygon, polygon[:1]]).T, **{**style, "linestyle": "-"})
    else:
        points = np.asarray(placement.cameras(placement.candidates(32)))
        ax.plot(*points.T, ".", color=style["color"], markersize=2)
    return ax


def plot_scene(
    scene: Scene,
    cameras=None,
    placement: AbstractPlacement | None = None,
    *,
    events: bool = False,
    ax=None,
    resolution: int = 2048,
    options: VisibilityOptions = VisibilityOptions(),
):
    """The objects, the placement set, the cameras and what each sees.

    Each camera's seen arcs are drawn thick in its colour; arcs seen by two or more
    cameras get a thin black line along their middle; what no camera sees stays grey.
    With `events=True` also the occlusion events (the thesis's Figs. 3.1 and 5.1):
    tangency points (circles) with their lines of sight, and shadow points (crosses)
    with the rays that reach them. A legend says which is which.

    **Arguments:**

    - `scene`; `cameras`: positions (k, 2), a `Camera` (its view wedges are drawn
      dashed) or None; `placement`: drawn dashed if given.
    - `events`: draw the occlusion events; `resolution`: points per curve.
    - `ax`: a matplotlib Axes (a new figure when None); `options`: the engine's options.

    **Returns:** the Axes.
    """
    ax = _axes(ax)
    t = np.linspace(0.0, 1.0, resolution + 1)
    points = _draw_objects(ax, scene, resolution=resolution)
    if placement is not None:
        plot_placement(placement, ax)
    if cameras is not None:
        poses = cameras if isinstance(cameras, Camera) else Camera(jnp.asarray(cameras, float))
        poses = jax.tree.map(lambda a: np.atleast_1d(np.asarray(a)), poses)
        seen = visible_intervals(scene, poses, options)
        cameras = np.atleast_2d(poses.position)
        middle = 0.5 * (t[:-1] + t[1:])
        count = np.zeros((len(scene), resolution), int)
        for c, camera in enumerate(cameras):
            colour = CAMERA_COLOURS[c % len(CAMERA_COLOURS)]
            for i in range(len(scene)):
                mask = np.zeros(resolution, bool)
                for a, b in seen.to_list(c, i):
                    mask |= (middle >= a) & (middle <= b)
                count[i] += mask
                ax.add_collection(
                    LineCollection(_runs(points[i], mask), colors=[colour], linewidths=4, zorder=3)
                )
            ax.plot(*camera, "o", color=colour, markersize=8, markeredgecolor="black", zorder=5)
            if poses.half_fov is not None:
                _draw_wedge(ax, points, jax.tree.map(lambda a: a[c], poses), colour)
            if events:
                _draw_events(ax, scene, camera, seen, c, colour)
        for i in range(len(scene)):
            shared = _runs(points[i], count[i] >= 2)
            ax.add_collection(
                LineCollection(shared, colors=[SHARED_COLOUR], linewidths=1, zorder=4)
            )
    _legend(ax, 0 if cameras is None else len(cameras), placement is not None, events)
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.set_aspect("equal")
    ax.autoscale_view()
    return ax


def _legend(ax, n_cameras: int, placement: bool, events: bool) -> None:
    """What the colours and line styles of `plot_scene` mean, outside the axes."""
    entries = [Line2D([], [], color=OBJECT_COLOUR, linewidth=1.5, label="unseen")]
    for c in range(min(n_cameras, len(CAMERA_COLOURS))):
        colour = CAMERA_COLOURS[c]
        entries.append(
            Line2D(
                [],
                [],
                color=colour,
                linewidth=4,
                marker="o",
                markeredgecolor="black",
                label=f"camera {c + 1} and what it sees",
            )
        )
    if n_cameras > 1:
        entries.append(Line2D([], [], color=SHARED_COLOUR, linewidth=1, label="seen by 2 or more"))
    if placement:
        entries.append(Line2D([], [], color="0.3", linestyle="--", linewidth=1, label="placement"))
    if events:
        entries.append(Line2D([], [], color="0.3", marker="o", linestyle="-", label="tangency"))
        entries.append(Line2D([], [], color="0.3", marker="x", linestyle=":", label="shadow"))
    ax.legend(handles=entries, loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=8)


def _draw_wedge(ax, points, pose: Camera, colour):
    """The view wedge's edges, as far as the range (or the scene's extent) reaches."""
    assert pose.half_fov is not None  # (drawn for cameras with a wedge only)
    extent = np.ptp(np.concatenate(points), axis=0).max()
    reach = float(pose.range) if pose.range is not None else extent
    for side in (1.0, -1.0):
        angle = float(pose.heading) + side * float(pose.half_fov)
        end = pose.position + reach * np.array([np.cos(angle), np.sin(angle)])
        ax.plot(*np.stack([pose.position, end]).T, "--", color=colour, linewidth=1, zorder=2)


def _draw_events(ax, scene, camera, seen, c: int, colour):
    """Tangency points with their lines of sight, shadow points with their rays."""
    for roots, marker, style in ((seen.tangents, "o", "-"), (seen.shadows, "x", ":")):
        t = np.asarray(roots.t[c])
        valid = np.asarray(roots.valid[c])
        points = np.asarray(scene.derivatives(jnp.asarray(t))[0])[valid]
        for p in points:
            ax.plot(
                [camera[0], p[0]], [camera[1], p[1]], style, color=colour, linewidth=0.7, zorder=1
            )
        ax.plot(*points.T, marker, color=colour, markersize=5, fillstyle="none", zorder=6)


def plot_landscape(
    scene: Scene,
    placement: AbstractPlacement,
    cameras=None,
    index: int = 0,
    objective=Foreshortened(),
    *,
    result: Solution | None = None,
    resolution: int = 256,
    ax=None,
    options: VisibilityOptions = VisibilityOptions(),
):
    """Q as camera `index` moves over the placement set, the other `cameras` fixed.

    On a boundary: Q against the arc-length fraction s (the thesis's Fig. 5.5; its kinks
    are where an occlusion event appears or vanishes), corners dotted. Elsewhere: a heat
    map of Q over the placement's candidate grid, the objects drawn on top. The optimised
    position of camera `index` in `result` is starred.

    **Arguments:**

    - `scene`, `placement`; `cameras` (k, 2): the fixed cameras (None: one camera).
    - `index`: which camera moves; `objective`: q; `result`: a `Solution` of
      `ocp.place` to mark.
    - `resolution`: samples along the boundary, or per axis of the grid.

    **Returns:** the Axes.
    """
    if isinstance(placement, DirectionalPlacement) or isinstance(cameras, Camera):
        raise TypeError(
            "plot_landscape draws Q over positions only: pass a placement of positions and "
            "position cameras (k, 2)."
        )
    ax = _axes(ax)
    objective = as_local_objective(objective)
    fixed = np.zeros((1, 2)) if cameras is None else np.atleast_2d(np.asarray(cameras, float))
    boundary = isinstance(placement, AbstractBoundary)
    params = (
        jnp.linspace(0, 1, resolution, endpoint=False)[:, None]
        if boundary
        else placement.candidates(resolution)
    )
    positions = np.asarray(placement.cameras(params))
    sets = np.repeat(fixed[None], len(positions), 0)
    sets[:, index] = positions
    values, _ = values_of_sets(scene, objective, options, sets, 512)
    values = np.where(np.isfinite(values), values, np.nan)  # -inf: undefined
    if boundary:
        s = np.asarray(params[:, 0])
        ax.plot(s, values, color=CAMERA_COLOURS[index % 10])
        for corner in np.asarray(placement.arc_fraction(placement.vertices())):
            ax.axvline(corner, color="0.7", linestyle=":", linewidth=0.8)
        if result is not None:
            s_best = float(placement.arc_fraction(_positions(result.cameras)[index][None])[0])
            ax.plot(s_best, float(result.value), "*", color="black", markersize=12)
        ax.set_xlabel("camera position s along the boundary (fraction of its length)")
        ax.set_ylabel("Q")
    else:
        defined = np.isfinite(values)  # Q is undefined inside and too near the objects
        x, y = positions[defined].T
        image = ax.tricontourf(x, y, values[defined], levels=32, cmap="viridis")
        plt.colorbar(image, ax=ax, label="Q")
        _draw_objects(ax, scene, colour="white")
        if result is not None:
            best = _positions(result.cameras)[index]
            ax.plot(*best, "*", color="red", markersize=12, markeredgecolor="black")
        ax.set_aspect("equal")
    return ax


def plot_optimization(
    result: Solution,
    scene: Scene | None,
    placement: AbstractPlacement,
    *,
    ax=None,
    cmap="viridis",
    substeps: int = 16,
):
    """Every start's path from start (circle) to end (triangle), per camera, coloured by
    the start's final Q; the best placement starred; the scene (unless None) and the
    placement beneath. The recorded parameters are joined in parameter space
    (`substeps` points between records), so a path on a boundary follows its walls.

    **Returns:** the Axes.
    """
    if result.paths is None:
        raise ValueError(
            "plot_optimization draws the paths of a continuous solver's starts "
            "(MultiStart, SLSQP); this Solution has none."
        )
    ax = _axes(ax)
    if scene is not None:
        _draw_objects(ax, scene)
    plot_placement(placement, ax)
    params = np.asarray(result.paths)  # (n, s, k, p)
    fraction = np.linspace(0.0, 1.0, substeps, endpoint=False)[:, None, None, None, None]
    between = params[:-1][None] + fraction * np.diff(params, axis=0)[None]  # (sub, n-1, s, k, p)
    fine = np.concatenate([np.moveaxis(between, 0, 1).reshape(-1, *params.shape[1:]), params[-1:]])
    paths = _positions(placement.cameras(jnp.asarray(fine)))  # (points, s, k, 2)
    final = np.asarray(result.start_values)
    finite = np.isfinite(final)
    low, high = (final[finite].min(), final[finite].max()) if finite.any() else (0.0, 1.0)
    norm = Normalize(low, high if high > low else low + 1)
    colours = plt.get_cmap(cmap)(norm(np.where(finite, final, low)))
    for start in range(paths.shape[1]):
        for camera in range(paths.shape[2]):
            path = paths[:, start, camera]
            ax.plot(*path.T, color=colours[start], linewidth=1, alpha=0.8)
            ax.plot(*path[0], "o", color=colours[start], markersize=3)
            ax.plot(*path[-1], "^", color=colours[start], markersize=5)
    best = _positions(result.cameras)
    ax.plot(*best.T, "*", color="red", markersize=14, markeredgecolor="black")
    plt.colorbar(plt.cm.ScalarMappable(norm=norm, cmap=cmap), ax=ax, label="final Q of the start")
    ax.set_aspect("equal")
    return ax
