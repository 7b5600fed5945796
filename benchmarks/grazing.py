"""Lines of sight that graze a curve: Q on the default grid against a fine one.

    python benchmarks/grazing.py

From (50, 0) each of the banana's two silhouette rays grazes a circle of radius 2 placed
20 units beyond the tangency point, cutting `depth` into it from either side. The
shadow falls on the circle as a pair of roots 2 sqrt(2 r depth) / (2 pi r) apart in t
(3e-3 at depth 1e-4, 1e-4 at 1e-7), and the lines of sight to the arc between them
graze the banana, crossing it twice as close together. Printed: VisibleLength Q on the
default grid (36 cells per curve) and on 1152 cells, and their relative difference.
"""

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)

import ocp_jax as ocp

CAMERA = np.array([50.0, 0.0])
DEPTHS = (1e-4, 1e-5, 1e-6, 1e-7)
FINE = ocp.VisibilityOptions(grid=1152)


def grazed_scenes(banana, tangency, depth, radius=2.0, beyond=20.0):
    """The banana and a circle that the silhouette ray at `tangency` enters by `depth`,
    on either side of the ray."""
    curve = banana.curves[0]
    point = np.asarray(curve(jnp.float64(tangency)))
    along = (point - CAMERA) / np.linalg.norm(point - CAMERA)
    normal = np.array([-along[1], along[0]])
    for side in (1, -1):
        centre = point + beyond * along + side * (radius - depth) * normal
        yield side, ocp.Scene([curve, ocp.Circle(jnp.asarray(centre), radius)])


def main():
    banana = ocp.scenes.banana()
    cameras = jnp.asarray([CAMERA])
    intervals = ocp.visible_intervals(banana, cameras)
    tangents = np.asarray(intervals.tangents.t)[0, 0][np.asarray(intervals.tangents.valid)[0, 0]]
    print(f"JAX {jax.__version__} on {jax.default_backend()}: banana and a grazed circle")
    print(
        f"{'tangency':>9} {'side':>5} {'depth':>6} {'Q, 36 cells':>16} {'Q, 1152 cells':>16} {'rel diff':>9}"
    )
    worst = 0.0
    for tangency in tangents:
        for depth in DEPTHS:
            for side, scene in grazed_scenes(banana, tangency, depth):
                value = float(ocp.visibility(scene, cameras, ocp.VisibleLength()))
                fine = float(ocp.visibility(scene, cameras, ocp.VisibleLength(), FINE))
                difference = abs(value / fine - 1)
                worst = max(worst, difference)
                print(
                    f"{tangency:9.5f} {side:5d} {depth:6.0e} {value:16.10f} {fine:16.10f} "
                    f"{difference:9.1e}"
                )
    print(f"largest difference {worst:.1e}")


if __name__ == "__main__":
    main()
