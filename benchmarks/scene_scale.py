"""Q of one scene in other units: float32 and float64 against the float64 Q in the scene's own.

    python benchmarks/scene_scale.py

Two scenes, each moved by x -> scale x + offset with its cameras (Q scales by `scale`):
`three` (ocp.scenes.three_objects() and a triangle, cameras (5, 4) and (-1.4, 2.2)) and
the banana (cameras (50, 0) and (-50, 40)). Per scale and offset, the relative difference
of VisibleLength and Foreshortened Q / scale, in float32 and in float64, from the float64
Q of the unmoved scene, and of the gradient of Foreshortened Q in the cameras (max over
coordinates over the largest). The engine computes in the scene's frame (`_frame.py`):
a scale that is a power of two changes no bit of Q / scale. Run with `PYTHONPATH` set to
an export of an older `ocp_jax` to see it without the frame (NaN: Q or its gradient was
NaN).
"""

import os
import sys

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)

import ocp_jax as ocp

sys.path.insert(0, os.path.dirname(__file__))
from random_scenes import moved, to_float32

TRIANGLE = ocp.PiecewiseCurve.polygon(jnp.array([[2.0, -2.5], [3.5, -1.5], [2.2, -1.0]]))
SCENES = {
    "three": (
        ocp.Scene([*ocp.scenes.three_objects().curves, TRIANGLE]),
        np.array([[5.0, 4.0], [-1.4, 2.2]]),
    ),
    "banana": (ocp.scenes.banana(), np.array([[50.0, 0.0], [-50.0, 40.0]])),
}
MOVES = [(2.0**-30, 0.0), (1e-9, 0.0), (1e-6, 0.0), (1e-3, 0.0), (1.0, 0.0), (1e3, 0.0)]
MOVES += [(1e6, 0.0), (1e9, 0.0), (2.0**30, 0.0), (1.0, 1e3), (1e-6, 1e-3)]


@jax.jit
def evaluate(scene, cameras):
    """VisibleLength Q, Foreshortened Q and its gradient in the cameras."""
    q = lambda c: ocp.visibility(scene, c, ocp.Foreshortened())
    foreshortened, gradient = jax.value_and_grad(q)(cameras)
    return ocp.visibility(scene, cameras, ocp.VisibleLength()), foreshortened, gradient


def differences(values, exact, scale: float) -> list[float]:
    """|Q / scale / Q_exact - 1| for both objectives, and the gradient's relative error."""
    q = [abs(float(values[i]) / scale / float(exact[i]) - 1) for i in (0, 1)]
    gradient = np.asarray(values[2], np.float64)
    return q + [float(np.max(np.abs(gradient - exact[2])) / np.max(np.abs(exact[2])))]


def main():
    print(f"{ocp.__file__}")
    print(
        f"{'scene':7s} {'scale':>8s} {'offset':>7s}   float32: {'VL':>7s} {'FS':>7s} "
        f"{'grad':>7s}   float64: {'VL':>7s} {'FS':>7s} {'grad':>7s}"
    )
    for name, (scene, cameras) in SCENES.items():
        exact = evaluate(scene, jnp.asarray(cameras))
        for scale, offset in MOVES:
            moved_scene, moved_cameras = moved(scene, cameras, scale, offset)
            single = differences(evaluate(*to_float32((moved_scene, moved_cameras))), exact, scale)
            double = differences(evaluate(moved_scene, moved_cameras), exact, scale)
            cells = " ".join(f"{e:7.1e}" for e in single)
            cells += "            " + " ".join(f"{e:7.1e}" for e in double)
            print(f"{name:7s} {scale:8.2g} {offset:7.2g}            {cells}", flush=True)


if __name__ == "__main__":
    main()
