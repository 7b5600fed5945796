"""Scenes, cameras and shared compiled functions for the ocp_jax test-suite.

Compile time dominates the suite (every distinct (scene structure, number of cameras,
objective, options, transformation) is one XLA compilation of several seconds), so all
visibility evaluations go through the few jitted functions defined here. They take a
*batch* of scenes and camera sets of one fixed batch size `BATCH` (padded), so one
compilation per (scene structure, k) serves the reference comparisons, the finite
differences (perturbed scenes and cameras are just more batch members) and the
gradient checks.

`to_reference(scene)` converts an `ocp.Scene` into the curve-spec list of the
independent NumPy reference (tests/reference.py).
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

import ocp_jax as ocp
from ocp_jax._geometry.vec import Vec
from ocp_jax._visibility import events as _events
from ocp_jax._visibility import visibility as _visibility


# ---------------------------------------------------------------------------
# scenes
# ---------------------------------------------------------------------------
def circle_scene(center=(0.0, 0.0), radius=1.0) -> ocp.Scene:
    return ocp.Scene([ocp.Circle(jnp.asarray(center, jnp.float64), radius)])


def two_circles(big_center, big_radius, small_center, small_radius) -> ocp.Scene:
    return ocp.Scene(
        [
            ocp.Circle(jnp.asarray(big_center, jnp.float64), big_radius),
            ocp.Circle(jnp.asarray(small_center, jnp.float64), small_radius),
        ]
    )


# A non-convex closed Bezier (two inflections; a dent facing -x), C2 at the seam.
BEZIER_FREE = np.array(
    [
        [3.6, -1.4],
        [3.68, -0.62],
        [2.69, -0.22],
        [2.21, -1.0],
        [2.85, -1.4],
        [2.21, -1.8],
        [2.69, -2.58],
        [3.68, -2.18],
    ]
)
# A deep "C" (cubic periodic B-spline) opening towards +x.
C_POINTS = np.array(
    [
        [0.95, 0.75],
        [0.0, 1.15],
        [-1.05, 0.7],
        [-1.15, -0.5],
        [0.0, -1.15],
        [1.0, -0.8],
        [0.05, -0.3],
        [0.05, 0.3],
    ]
)


def mixed_scene() -> ocp.Scene:
    """A Bezier, a B-spline, a circle and an ellipse (two of them non-convex)."""
    return ocp.Scene(
        [
            ocp.BezierCurve.closed_c2(jnp.asarray(BEZIER_FREE)),
            ocp.BSplineCurve(jnp.asarray(C_POINTS), degree=3),
            ocp.Circle(jnp.array([-0.6, 2.4]), 0.5),
            ocp.Ellipse(jnp.array([2.5, 1.3]), jnp.array([0.6, 0.3]), 0.6),
        ]
    )


THREE = ocp.scenes.three_objects()
BLOBS3 = ocp.scenes.blobs(3)
MIXED = mixed_scene()
BANANA = ocp.scenes.banana()

# Cameras (outside every object; checked in test_visibility.py). Single cameras, pairs
# and triples; some are placed between the objects, where the occlusions are richest.
CAMERAS = {
    "three": {
        1: [[5.0, 4.0], [-4.5, 2.5], [1.2, -4.0], [3.1, 0.2], [-1.4, 2.2]],
        2: [[[5.0, 4.0], [-4.5, 2.5]], [[3.1, 0.2], [-3.0, -2.8]], [[1.2, -4.0], [0.2, 4.5]]],
        3: [[[5.0, 4.0], [-4.5, 2.5], [1.2, -4.0]], [[3.1, 0.2], [-1.4, 2.2], [4.0, -2.0]]],
    },
    "blobs3": {
        1: [[7.0, 5.0], [-3.0, -2.5], [1.5, 1.6], [1.0, -3.5], [6.5, -0.5]],
        2: [[[7.0, 5.0], [-3.0, -2.5]], [[1.5, 1.6], [6.5, -0.5]], [[-3.0, 4.5], [1.0, -3.5]]],
        3: [[[7.0, 5.0], [-3.0, -2.5], [1.0, -3.5]], [[1.5, 1.6], [-3.0, 4.5], [6.5, -0.5]]],
    },
    "mixed": {
        1: [[1.7, -0.2], [6.0, 0.5], [-3.5, -2.0], [1.0, 4.2], [3.0, -4.0]],
        2: [[[1.7, -0.2], [-3.5, -2.0]], [[6.0, 0.5], [1.0, 4.2]], [[3.0, -4.0], [-2.5, 3.0]]],
        3: [[[1.7, -0.2], [6.0, 0.5], [-3.5, -2.0]], [[1.0, 4.2], [3.0, -4.0], [-2.5, 3.0]]],
    },
}
# Cameras on the thesis's placement set: the 100 x 80 rectangle centred at (0, 20).
BANANA_CAMERAS = [
    [50.0, 0.0],
    [-50.0, 40.0],
    [0.0, 60.0],
    [20.0, -20.0],
    [-50.0, -20.0],
    [50.0, 60.0],
    [-20.0, -20.0],
]

SCENES = {"three": THREE, "blobs3": BLOBS3, "mixed": MIXED, "banana": BANANA}


def to_reference(scene: ocp.Scene) -> list[dict]:
    """The curve specs of tests/reference.py for `scene`."""
    out = []
    for c in scene.curves:
        if isinstance(c, ocp.BezierCurve):
            out.append({"type": "bezier", "points": np.asarray(c.control_points, float)})
        elif isinstance(c, ocp.BSplineCurve):
            out.append(
                {
                    "type": "bspline",
                    "points": np.asarray(c.control_points, float),
                    "degree": int(c.degree),
                }
            )
        elif isinstance(c, ocp.Circle):
            out.append(
                {"type": "circle", "center": np.asarray(c.center, float), "radius": float(c.radius)}
            )
        elif isinstance(c, ocp.Ellipse):
            out.append(
                {
                    "type": "ellipse",
                    "center": np.asarray(c.center, float),
                    "axes": tuple(float(a) for a in np.asarray(c.semi_axes)),
                    "angle": float(c.angle),
                }
            )
        elif isinstance(c, ocp.PiecewiseCurve):
            out.append({"type": "piecewise", "segments": np.asarray(c.control_points, float)})
        else:  # pragma: no cover
            raise TypeError(type(c))
    return out


# ---------------------------------------------------------------------------
# batched, jitted evaluations (one compilation per scene structure and k)
# ---------------------------------------------------------------------------
BATCH = 16
VL = ocp.VisibleLength()
FS = ocp.Foreshortened()


def stack_trees(trees):
    return jax.tree.map(lambda *xs: jnp.stack(xs), *trees)


def unstack_tree(tree, i):
    return jax.tree.map(lambda a: a[i], tree)


def to_float32(tree):
    """A scene, cameras (or any pytree of them) cast to float32."""
    return jax.tree.map(lambda a: jnp.asarray(a, jnp.float32), tree)


def _values(scene, cameras):
    return ocp.visibility(scene, cameras, VL), ocp.visibility(scene, cameras, FS)


def _values_and_grad(scene, cameras):
    """(VisibleLength, Foreshortened, d Foreshortened / d(scene, cameras))."""
    fs, grad = jax.value_and_grad(ocp.visibility, argnums=(0, 1))(scene, cameras, FS)
    return ocp.visibility(scene, cameras, VL), fs, grad


def _values_and_grads(scene, cameras):
    """Both objectives and both gradients (used for circle scenes with closed forms)."""
    vl, gvl = jax.value_and_grad(ocp.visibility, argnums=(0, 1))(scene, cameras, VL)
    fs, gfs = jax.value_and_grad(ocp.visibility, argnums=(0, 1))(scene, cameras, FS)
    return vl, fs, gvl, gfs


_batched = {
    "values": jax.jit(jax.vmap(_values)),
    "grad": jax.jit(jax.vmap(_values_and_grad)),
    "grads": jax.jit(jax.vmap(_values_and_grads)),
}


def batched(kind: str, scenes, cameras):
    """Evaluate `kind` ("values", "grad" or "grads") for a list of scenes (or one scene
    for all) and a list of camera sets (n, k, 2), in padded batches of BATCH. Returns
    the outputs as NumPy arrays with leading axis n."""
    cameras = np.asarray(cameras)
    n = cameras.shape[0]
    if isinstance(scenes, ocp.Scene):
        scenes = [scenes] * n
    assert len(scenes) == n
    dtype = scenes[0].dtype
    fn = _batched[kind]
    outs = []
    for start in range(0, n, BATCH):
        idx = list(range(start, min(start + BATCH, n)))
        idx += [idx[-1]] * (BATCH - len(idx))
        out = fn(stack_trees([scenes[i] for i in idx]), jnp.asarray(cameras[idx], dtype))
        outs.append(jax.tree.map(np.asarray, out))
    return jax.tree.map(lambda *xs: np.concatenate(xs)[:n], *outs)


# ---------------------------------------------------------------------------
# closed forms
# ---------------------------------------------------------------------------
def circle_visible_length(r, d):
    """Visible length of a circle of radius r from distance d > r: 2 r acos(r/d)."""
    return 2.0 * r * math.acos(r / d)


def foreshortened_antiderivative(phi, r, d, xp=np):
    """G(phi) with G' = r q(phi): q = cos^2(alpha) on a circle of radius r seen from
    distance d, phi the angle at the centre measured from the direction of the camera.

    Derivation: with D = r^2 + d^2 - 2 r d cos(phi) = |x - C|^2 and n.(x - C) =
    r - d cos(phi) = (D + r^2 - d^2) / (2 r),
        q = (D + r^2 - d^2)^2 / (4 r^2 D)
          = [3 r^2 - d^2 - 2 r d cos(phi) + (d^2 - r^2)^2 / D] / (4 r^2),
    and int dphi / (A - B cos phi) = 2 / sqrt(A^2 - B^2) atan(sqrt((A+B)/(A-B)) tan(phi/2))
    with A = r^2 + d^2, B = 2 r d, sqrt(A^2 - B^2) = d^2 - r^2. Valid for |phi| < pi.
    """
    return (
        (3 * r * r - d * d) * phi
        - 2 * r * d * xp.sin(phi)
        + 2 * (d * d - r * r) * xp.arctan((d + r) / (d - r) * xp.tan(phi / 2))
    ) / (4 * r)


def circle_foreshortened(r, d, xp=np):
    """Foreshortened Q of a circle (radius r) from distance d: G(alpha) - G(-alpha),
    alpha = acos(r/d) the half-angle of the visible arc. `xp` is np or jnp."""
    alpha = xp.arccos(r / d)
    g = foreshortened_antiderivative
    return g(alpha, r, d, xp) - g(-alpha, r, d, xp)


def central_differences(f, x, eps):
    """df/dx by central differences in every coordinate of the array x."""
    x = np.asarray(x, float)
    out = np.zeros_like(x)
    for i in np.ndindex(x.shape):
        step = np.zeros_like(x)
        step[i] = eps
        out[i] = (f(jnp.asarray(x + step)) - f(jnp.asarray(x - step))) / (2 * eps)
    return out


def relative_error(a, b):
    a, b = np.asarray(a, float), np.asarray(b, float)
    return float(np.linalg.norm(a - b) / max(np.linalg.norm(b), 1e-300))


# ---------------------------------------------------------------------------
# near-double tangency roots (computed with the reference's curve evaluation only)
# ---------------------------------------------------------------------------
def _cross(a, b):
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def outward_normals(spec: dict, t) -> np.ndarray:
    """Unit outward normals of a reference curve at the parameters `t`: (y', -x') / |x'|
    turned by the orientation of its dense polygon (shoelace area)."""
    from reference import eval_curve

    x = eval_curve(spec, np.arange(20000) / 20000)[0]
    ccw = np.sign(np.sum(x[:, 0] * np.roll(x[:, 1], -1) - np.roll(x[:, 0], -1) * x[:, 1]))
    dx = eval_curve(spec, t)[1]
    return ccw * np.stack([dx[..., 1], -dx[..., 0]], -1) / np.linalg.norm(dx, axis=-1)[..., None]


def cameras_beside(spec: dict, t, distances, side: float = 1.0) -> np.ndarray:
    """Cameras at each distance along the normal of a reference curve at each t, on its
    free side (`side` +1: outside an object; -1: inside a room), shape (len(t) *
    len(distances), 2), the distances varying fastest."""
    from reference import eval_curve

    points, normals = eval_curve(spec, t)[0], side * outward_normals(spec, t)
    offsets = np.asarray(distances)[None, :, None] * normals[:, None]
    return (points[:, None] + offsets).reshape(-1, 2)


def inflections(spec: dict, n: int = 20000) -> np.ndarray:
    """Parameters where the curvature cross(x', x'') changes sign (bisected)."""
    from reference import eval_curve

    t = (np.arange(n) + 0.5) / n
    _, dx, ddx = eval_curve(spec, t)
    k = _cross(dx, ddx)
    out = []
    for j in np.nonzero(np.sign(k[:-1]) != np.sign(k[1:]))[0]:
        lo, hi = t[j], t[j + 1]
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            _, d, dd = eval_curve(spec, np.array([lo, mid]))
            kk = _cross(d, dd)
            lo, hi = (mid, hi) if np.sign(kk[0]) == np.sign(kk[1]) else (lo, mid)
        out.append(0.5 * (lo + hi))
    return np.array(out)


def tangency_roots_near(spec: dict, camera, t0: float, width=0.02, n=4001) -> np.ndarray:
    """Sign changes of cross(x'(t), x(t) - C) in [t0 - width, t0 + width] (bisected)."""
    from reference import eval_curve

    camera = np.asarray(camera, float)

    def f(t):
        x, dx, _ = eval_curve(spec, t)
        return _cross(dx, x - camera)

    t = np.linspace(t0 - width, t0 + width, n)
    v = f(t)
    roots = []
    for j in np.nonzero(np.sign(v[:-1]) * np.sign(v[1:]) < 0)[0]:
        lo, hi, flo = t[j], t[j + 1], v[j]
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            fm = f(np.array(mid))
            lo, hi = (mid, hi) if np.sign(fm) == np.sign(flo) else (lo, mid)
        roots.append(0.5 * (lo + hi))
    return np.mod(np.array(roots), 1.0)


@functools.cache
def near_double_camera(
    scene_name: str, curve: int, which: int, distance: float, side: int, separation: float = 0.004
):
    """A camera at `distance` along the tangent line of the `which`-th inflection of
    `curve`, moved off the line (towards `side`) just enough that the tangency function
    has two roots `separation` apart (two roots close to a double root: closer than one
    cell of the curve's default grid, `grid_cells()`). Returns (camera, (t1, t2))."""
    spec = to_reference(SCENES[scene_name])[curve]
    from reference import eval_curve

    t0 = float(inflections(spec)[which])
    x0, d0, _ = eval_curve(spec, np.array(t0))
    u = d0 / np.linalg.norm(d0)
    normal = np.array([-u[1], u[0]])

    def gap(eps):
        r = tangency_roots_near(spec, x0 + distance * u + side * eps * normal, t0)
        return (r.max() - r.min()) if r.size == 2 else 0.0

    lo, hi = 0.0, 1e-4 * (1.0 + abs(distance))
    while gap(hi) < separation:
        hi *= 2.0
        if hi > 10.0:  # pragma: no cover - wrong side
            raise ValueError("no pair of tangency roots on this side of the tangent line")
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if gap(mid) < separation else (lo, mid)
    camera = x0 + distance * u + side * hi * normal
    roots = tangency_roots_near(spec, camera, t0)
    return camera, tuple(float(r) for r in np.sort(roots))


rel = relative_error

OPTIONS = ocp.VisibilityOptions()  # the defaults, whose budgets the tests read
J = np.array([[0.0, -1.0], [1.0, 0.0]])  # n = J x' (the library's Eq. 2.3)
R = np.array([[0.0, 1.0], [-1.0, 0.0]])  # the thesis's matrix in Eqs. 5.14-5.20, 5.29-5.32


def grid_cells(scene):
    """The number of grid cells the library uses for `scene` by default."""
    return OPTIONS.grid or scene.grid_cells()


# --- shared by several test modules: the engine's events as visibility computes them,
# and the batched results of the named scenes


def camera_grid(scene, camera: Vec, samples):
    """The camera's grid, as visibility builds it (its nearest point on each curve an
    extra node)."""
    frozen = jax.lax.stop_gradient(scene)
    sense = _visibility._sense(frozen, samples)
    cameras = camera.map(lambda a: jnp.reshape(a, (1,)))
    nearest = _visibility._nearest_points(frozen, cameras, samples, sense).t[:, 0]
    return _events.with_nearest_node(scene, samples, nearest)


def tangency_times(scene, camera: Vec, samples):
    """The camera's tangency times, as visibility computes them (on its grid)."""
    grid = camera_grid(scene, camera, samples)
    return _events.tangency_times(
        scene, camera, grid, OPTIONS.max_tangents, OPTIONS.newton_iterations
    )


def camera_events(scene, camera):
    """One camera's tangency times, ray sources (tangency points, silhouette corners)
    and shadow times, as visibility computes them."""
    samples = _events.sample(jax.lax.stop_gradient(scene), grid_cells(scene))
    cam = Vec(camera[0], camera[1])
    tangents = tangency_times(scene, cam, samples)
    points = _events.tangency_points(scene, tangents)
    sources = _events.tangency_sources(scene, points)
    if scene.has_corners:
        sources = _events.join_sources(sources, _events.silhouette_corners(scene, cam, samples))
    probes = _events.grazing_probes(cam, samples, tangents, points)
    shadows = _events.shadow_times(
        scene, cam, samples, sources, probes, OPTIONS.max_shadows, OPTIONS.newton_iterations
    )
    return tangents, sources, shadows


def _events_fn(scene, camera):
    """The tangency and shadow times of one camera, as visibility computes them."""
    tan, _, sh = camera_events(scene, camera)
    return tan.t, tan.valid, sh.t, sh.valid


def _events_and_jacobian(scene, camera):
    tan_t, tan_valid, sh_t, sh_valid = _events_fn(scene, camera)

    def times(s, c):
        out = _events_fn(s, c)
        return out[0], out[2]

    jac = jax.jacfwd(times, argnums=(0, 1))(scene, camera)
    return (tan_t, tan_valid, sh_t, sh_valid), jac


@functools.cache
def events_and_jacobian():
    return jax.jit(_events_and_jacobian)


# ===========================================================================
# the NumPy reference on non-convex scenes with several objects
# ===========================================================================
# scenes whose (k) batch also yields gradients (used by the finite-difference tests)
GRAD_SETS = {("three", 2), ("mixed", 1)}


# Cameras nearly on an inflection tangent line (helpers.near_double_camera arguments:
# scene, curve, inflection, distance along the line, side, separation of the two roots).
# Of three_objects' kidney B-spline:
KIDNEY_NEAR_DOUBLE = [("three", 0, 1, 4.0, 1, 0.004), ("three", 0, 1, 4.0, 1, 0.001)]


# of the banana's two inflections (cameras inside the thesis's rectangle):
BANANA_NEAR_DOUBLE = [
    ("banana", 0, 0, -30.0, 1, 0.004),
    ("banana", 0, 1, 30.0, 1, 0.004),
    ("banana", 0, 0, -30.0, 1, 0.002),
    ("banana", 0, 0, -30.0, 1, 0.001),
]


def camera_sets(name, k):
    sets = np.asarray(CAMERAS[name][k], float).reshape(-1, k, 2)
    if (name, k) == ("three", 1):
        extra = [near_double_camera(*args)[0] for args in KIDNEY_NEAR_DOUBLE]
        sets = np.concatenate([sets, np.asarray(extra)[:, None]])
    return sets


@functools.cache
def scene_results(name, k):
    """(camera sets, outputs) of the shared batched function for this scene and k."""
    if name == "banana":
        extra = [near_double_camera(*args)[0] for args in BANANA_NEAR_DOUBLE]
        cams = np.concatenate([np.asarray(BANANA_CAMERAS), extra])[:, None]
    else:
        cams = camera_sets(name, k)
    kind = "grad" if (name, k) in GRAD_SETS else "values"
    return cams, batched(kind, SCENES[name], cams)


@functools.cache
def visible_length_of(name):
    """VisibleLength of `name`'s scene for a batch of single cameras, jitted once."""
    return jax.jit(jax.vmap(lambda c: ocp.visibility(SCENES[name], c[None], VL)))


# name: (camera, big centre, big radius, small centre, small radius)
TWO_CIRCLE_CASES = {
    "in line": ((7.0, 0.3), (0.0, 0.0), 2.0, (4.0, 0.0), 0.6),
    "from above left": ((-3.0, 5.0), (1.0, -1.0), 1.5, (-0.9, 1.8), 0.35),
    "from above": ((2.0, 6.0), (0.5, 0.0), 1.2, (1.5, 3.0), 0.3),
}
