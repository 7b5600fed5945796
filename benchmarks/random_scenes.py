"""Q and its gradient on random scenes, against the NumPy reference and finite differences.

    python benchmarks/random_scenes.py [--scenes 4] [--seed 0] [--scale 1] [--offset 0]
        [--clearance 0.12] [--gradients] [--float32] [--mix NAME ...]

Scenes the engine was not tuned on: eight mixes of curve types (periodic B-splines of
degree 2, 3 and 4, closed C2 Beziers, circles, ellipses, polygons, rounded rectangles,
paths of quadratic pieces with kinks),
each curve's shape drawn at random (star-shaped control polygons, non-convex, half of
them clockwise), placed on a jittered grid without touching; one mix has tiny objects
(1-10% of the others) around a large ellipse, one has eight objects, one only polygons
(whose grid is coarse: an edge is a cell). Cameras are drawn in
free space, at least `--clearance` from every curve. For `--scenes` random scenes per mix
and number of cameras k (1, 2, 3), this prints the largest relative difference of
`VisibleLength` and `Foreshortened` Q to tests/reference.py (events on a 4096-cell grid,
adaptive quadrature to 1e-14) and the errors the engine raised; with `--gradients`, also
of the gradient of Foreshortened Q to central differences (step 1e-6), |g - g_fd| / |g_fd|
over all the cameras' coordinates, and along one random direction of all the scene's
parameters.

With `--float32` the engine computes in float32 (the scene and cameras cast after they
are drawn); Q is compared with the reference as above, and the gradient with the float64
engine's (central differences resolve nothing in float32), in the cameras and in all of
the scene's parameters.

`--scale` and `--offset` move the scenes and cameras (x -> scale x + offset); the
reference is evaluated on the unmoved scene (Q moves with it and scales with length):
its tolerances are absolute, and it does not finish on a scene 1e4 from the origin.
"""

import argparse
import os
import sys

import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree
from matplotlib.path import Path

jax.config.update("jax_enable_x64", True)

import ocp_jax as ocp

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests"))
from helpers import relative_error, to_float32, to_reference
from reference import reference_visibility

MIXES = {
    "B-spline, circle, ellipse": ["bspline3", "circle", "ellipse"],
    "Bezier, polygon, B-spline": ["bezier", "polygon5", "bspline4"],
    "polygons, circle, rounded": ["polygon4", "polygon6", "circle", "rounded"],
    "B-spline deg 2, Bezier": ["bspline2", "bezier"],
    "tiny objects, large ellipse": [
        "ellipse_large",
        "circle_tiny",
        "circle_tiny",
        "polygon3_tiny",
        "bspline3",
    ],
    "eight objects": [
        "bspline3",
        "bspline3",
        "circle",
        "polygon5",
        "bezier",
        "ellipse",
        "circle_tiny",
        "rounded",
    ],
    # Corners only (a polygon's edges are single grid cells), and curved pieces with kinks.
    "polygons only": ["polygon3", "polygon4", "polygon5", "polygon6"],
    "kinked curved paths, polygon": ["kinked4", "kinked5", "polygon3"],
}
VL, FS = ocp.VisibleLength(), ocp.Foreshortened()
SAMPLES = 1000  # points per curve for the placement checks


def star(rng, count: int, smallest: float, largest: float) -> np.ndarray:
    """`count` points around the origin at random angles and radii, in either orientation."""
    angle = 2 * np.pi * (np.arange(count) + 0.3 * rng.uniform(-1, 1, count)) / count
    radius = rng.uniform(smallest, largest, count)
    points = np.stack([radius * np.cos(angle), radius * np.sin(angle)], -1)
    return points[::-1].copy() if rng.uniform() < 0.5 else points


def curve(rng, kind: str, center, size: float = 1.0) -> ocp.AbstractCurve:
    """A random curve of `kind` ("circle", "bspline3", "polygon5", ...) about `center`;
    the suffixes _tiny and _large draw its size."""
    if kind.endswith("_tiny"):
        return curve(rng, kind.removesuffix("_tiny"), center, rng.uniform(0.01, 0.1))
    if kind.endswith("_large"):
        return curve(rng, kind.removesuffix("_large"), center, rng.uniform(2.0, 3.0))
    center = np.asarray(center, float)
    if kind == "circle":
        return ocp.Circle(center, size * rng.uniform(0.4, 1.0))
    if kind == "ellipse":
        return ocp.Ellipse(center, size * rng.uniform(0.3, 1.0, 2), rng.uniform(0, np.pi))
    if kind.startswith("bspline"):
        degree = int(kind.removeprefix("bspline"))
        points = center + size * star(rng, degree + 5, 0.3, 1.1)
        return ocp.BSplineCurve(jnp.asarray(points), degree=degree)
    if kind == "bezier":
        return ocp.BezierCurve.closed_c2(jnp.asarray(center + size * star(rng, 7, 0.3, 1.0)))
    if kind.startswith("polygon"):
        vertices = center + size * star(rng, int(kind.removeprefix("polygon")), 0.3, 1.1)
        return ocp.PiecewiseCurve.polygon(jnp.asarray(vertices))
    if kind.startswith("kinked"):  # quadratic pieces between star vertices, bulging either way
        vertices = center + size * star(rng, int(kind.removeprefix("kinked")), 0.5, 1.1)
        ends = np.roll(vertices, -1, axis=0)
        chord = ends - vertices
        bulge = rng.uniform(-0.3, 0.3, (len(vertices), 1)) * np.stack(
            [chord[:, 1], -chord[:, 0]], -1
        )
        pieces = [np.stack([a, 0.5 * (a + b) + c, b]) for a, b, c in zip(vertices, ends, bulge)]
        return ocp.PiecewiseCurve.from_segments([jnp.asarray(p) for p in pieces])
    if kind == "rounded":
        width, height = size * rng.uniform(0.8, 1.8, 2)
        radius = rng.uniform(0.05, 0.35) * min(width, height)
        return ocp.PiecewiseCurve.rounded_rectangle(center, width, height, radius)
    raise ValueError(f"unknown curve kind {kind!r}")


def polylines(scene: ocp.Scene) -> list[np.ndarray]:
    t = jnp.linspace(0.0, 1.0, SAMPLES + 1)[:-1]
    return [np.asarray(c(t)) for c in scene.curves]


def random_scene(rng, kinds: list[str]) -> tuple[ocp.Scene, list[np.ndarray]]:
    """The curves of `kinds` on a jittered grid (a large first curve at the centre, the
    others around it), drawn again until no two touch or nest; with their polylines."""
    while True:
        if kinds[0].endswith("_large"):
            radius, angle = rng.uniform(3.5, 5.5, len(kinds)), rng.uniform(0, 2 * np.pi, len(kinds))
            centers = np.stack([radius * np.cos(angle), radius * np.sin(angle)], -1)
            centers[0] = 0.0
        else:
            columns, spacing = (2, 2.3) if len(kinds) <= 4 else (3, 2.6)
            cells = np.arange(len(kinds))
            centers = spacing * np.stack([cells % columns, cells // columns], -1)
            centers = centers + rng.uniform(-0.4, 0.4, centers.shape)
        scene = ocp.Scene([curve(rng, kind, c) for kind, c in zip(kinds, centers)])
        lines = polylines(scene)
        apart = all(
            np.min(np.linalg.norm(a[:, None] - b[None], axis=-1)) > 0.05
            and not Path(a).contains_point(b[0])
            and not Path(b).contains_point(a[0])
            for i, a in enumerate(lines)
            for b in lines[i + 1 :]
        )
        if apart:
            return scene, lines


def random_cameras(rng, lines: list[np.ndarray], k: int, clearance: float) -> np.ndarray:
    """k cameras in free space near the scene's polylines, each at least `clearance` from
    every curve."""
    everything = np.concatenate(lines)
    low, high = everything.min(0) - 1.5, everything.max(0) + 1.5
    cameras = []
    while len(cameras) < k:
        p = rng.uniform(low, high)
        if all(
            not Path(line).contains_point(p)
            and np.min(np.linalg.norm(line - p, axis=1)) > clearance
            for line in lines
        ):
            cameras.append(p)
    return np.array(cameras)


def moved(scene: ocp.Scene, cameras, scale: float, offset: float):
    """Scene and cameras under x -> scale x + offset."""
    move = lambda p: p * scale + offset
    curves = []
    for c in scene.curves:
        if isinstance(c, ocp.Circle):
            curves.append(ocp.Circle(move(c.center), c.radius * scale))
        elif isinstance(c, ocp.Ellipse):
            curves.append(ocp.Ellipse(move(c.center), c.semi_axes * scale, c.angle))
        elif isinstance(c, ocp.BSplineCurve):
            curves.append(ocp.BSplineCurve(move(c.control_points), degree=c.degree))
        elif isinstance(c, ocp.BezierCurve):
            curves.append(ocp.BezierCurve(move(c.control_points)))
        else:
            curves.append(ocp.PiecewiseCurve(move(c.points)))
    return ocp.Scene(curves), move(jnp.asarray(cameras))


values = jax.jit(lambda s, c: jnp.stack([ocp.visibility(s, c, VL), ocp.visibility(s, c, FS)]))
foreshortened = jax.jit(lambda s, c: ocp.visibility(s, c, FS))
gradient = jax.jit(jax.grad(lambda s, c: ocp.visibility(s, c, FS), argnums=(0, 1)))


def engine_message(error: Exception) -> str:
    """The engine's message in an error (under `jax.jit` it is a line of the runtime
    error's text, after the traceback of the callback that raised it)."""
    lines = str(error).splitlines()
    return next((line[line.index("ocp_jax:") :] for line in lines if "ocp_jax:" in line), lines[0])


def gradient_errors(rng, scene, cameras, step: float = 1e-6) -> tuple[float, float]:
    """Relative error of the gradient of Foreshortened Q against central differences: in
    the cameras (every coordinate) and along one random direction of the scene."""
    scene_grad, camera_grad = gradient(scene, cameras)
    central = lambda plus, minus: (foreshortened(*plus) - foreshortened(*minus)) / (2 * step)
    finite = np.zeros(cameras.shape)
    for index in np.ndindex(cameras.shape):
        shift = jnp.zeros(cameras.shape).at[index].set(step)
        finite[index] = central((scene, cameras + shift), (scene, cameras - shift))
    leaves, treedef = jax.tree.flatten(scene)
    direction = [jnp.asarray(rng.normal(size=leaf.shape)) for leaf in leaves]
    shifted = lambda sign: jax.tree.unflatten(
        treedef, [leaf + sign * step * d for leaf, d in zip(leaves, direction)]
    )
    along = central((shifted(1), cameras), (shifted(-1), cameras))
    exact = sum(jnp.vdot(g, d) for g, d in zip(jax.tree.leaves(scene_grad), direction))
    return relative_error(camera_grad, finite), relative_error(exact, along)


def float32_gradient_errors(scene, cameras) -> tuple[float, float]:
    """Relative error of the float32 gradient of Foreshortened Q against the float64
    engine's: in the cameras and in all of the scene's parameters."""
    (scene_exact, cameras_exact), (scene_single, cameras_single) = (
        gradient(scene, cameras),
        gradient(*to_float32((scene, cameras))),
    )
    flat = lambda tree: ravel_pytree(tree)[0]
    return (
        relative_error(cameras_single, cameras_exact),
        relative_error(flat(scene_single), flat(scene_exact)),
    )


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=4, help="random scenes per mix and k")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--scale", type=float, default=1.0)
    parser.add_argument("--offset", type=float, default=0.0)
    parser.add_argument("--clearance", type=float, default=0.12)
    parser.add_argument("--gradients", action="store_true")
    parser.add_argument("--float32", action="store_true", help="the engine in float32")
    parser.add_argument(
        "--mix", action="append", choices=list(MIXES), help="only these mixes (repeatable)"
    )
    args = parser.parse_args()
    dtype, precision = ("float32", to_float32) if args.float32 else ("float64", lambda t: t)
    print(
        f"JAX {jax.__version__}, {dtype}; {args.scenes} scenes per row, seed {args.seed}, "
        f"x -> {args.scale:g} x + {args.offset:g}, cameras >= {args.clearance} from curves"
    )
    header = f"{'mix':28s} {'k':>2s} {'VisibleLength':>14s} {'Foreshortened':>14s}"
    if args.gradients:
        header += f" {'grad cameras':>13s} {'grad scene':>11s}"
    print(header + "  raised")
    worst = 0.0
    for m, (label, kinds) in enumerate(MIXES.items()):
        if args.mix and label not in args.mix:
            continue  # (the scenes of a mix are drawn the same with or without the others)
        for k in (1, 2, 3):
            errors, raised = [], 0
            for j in range(args.scenes):
                rng = np.random.default_rng([args.seed, m, k, j])
                scene, lines = random_scene(rng, kinds)
                cameras = random_cameras(rng, lines, k, args.clearance)
                engine_scene, engine_cameras = moved(scene, cameras, args.scale, args.offset)
                try:
                    engine = values(*precision((engine_scene, engine_cameras)))
                except (ValueError, RuntimeError) as error:  # raised by the engine: shown
                    raised += 1
                    print(f"  {label}, k={k}, scene {j}: {engine_message(error)}")
                    continue
                curves = to_reference(scene)
                row = [
                    relative_error(
                        engine[i], args.scale * reference_visibility(curves, cameras, name)
                    )
                    for i, name in enumerate(("visible_length", "foreshortened"))
                ]
                if args.gradients and args.float32:
                    row += float32_gradient_errors(engine_scene, engine_cameras)
                elif args.gradients:
                    row += gradient_errors(rng, engine_scene, engine_cameras)
                errors.append(row)
            jax.clear_caches()  # (kept, every row's programs exhausted the memory for machine code)
            largest = np.max(errors, axis=0) if errors else []
            worst = max([worst, *largest])
            cells = " ".join(f"{e:>{w}.1e}" for e, w in zip(largest, (14, 14, 13, 11)))
            print(f"{label:28s} {k:2d} {cells}  {raised}", flush=True)
    print(f"largest relative difference: {worst:.1e}")


if __name__ == "__main__":
    main()
