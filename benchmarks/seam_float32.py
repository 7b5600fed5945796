"""float32 against float64 where a tangency lies next to the seam t = 0 of a closed curve.

    python benchmarks/seam_float32.py

Cameras on the banana's tangent lines at t = -+1e-6 to -+1e-3 (beside the seam) and at
t = 0.1 to 0.9 (away from it), `along` = -+2 and -+5 units along them: the relative
difference of VisibleLength Q in float32 from the float64 engine's. A camera that either
precision refuses (inside the object, or within sqrt(eps) of the scene's size from the
curve: float32's threshold is 0.02 here) is skipped. Between the seam and a tangency
beside it lies a visible sliver of the curve, as long as the tangency's t; until the
own curve's line of sight was deflated at the query point's periodic images t_m -+ 1
too (`_occlusion.py`), float32 lost it.
"""

import os
import sys

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)

import ocp_jax as ocp

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests"))
from helpers import to_float32

BESIDE_SEAM = (-1e-3, -1e-4, -3e-5, -1e-5, -3e-6, -1e-6, 1e-6, 3e-6, 1e-5, 3e-5, 1e-4, 1e-3)
AWAY = (0.1, 0.2, 0.3, 0.45, 0.6, 0.75, 0.9)
ALONG = (2.0, -2.0, 5.0, -5.0)


def float32_errors(scene, tangencies):
    """(t, along, Q in float64, |Q32 / Q64 - 1|) for the cameras that both precisions
    accept."""
    scene32 = to_float32(scene)
    curve = scene.curves[0]
    rows = []
    for t in tangencies:
        t = jnp.float64(t % 1.0)
        x, tangent = np.asarray(curve(t)), np.asarray(jax.jacfwd(curve)(t))
        for along in ALONG:
            camera = x + along * tangent / np.linalg.norm(tangent)
            try:
                q64 = float(ocp.visibility(scene, camera, ocp.VisibleLength()))
                q32 = float(ocp.visibility(scene32, np.float32(camera), ocp.VisibleLength()))
            except eqx.EquinoxRuntimeError:  # a camera that one precision refuses
                continue
            rows.append((float(t), along, q64, abs(q32 / q64 - 1)))
    return rows


def main():
    banana = ocp.scenes.banana()
    print(f"JAX {jax.__version__} on {jax.default_backend()}: banana, VisibleLength")
    print(f"{'tangency t':>12} {'along':>6} {'Q float64':>12} {'float32 rel diff':>17}")
    for label, tangencies in (("beside the seam", BESIDE_SEAM), ("away from it", AWAY)):
        rows = float32_errors(banana, tangencies)
        for t, along, q64, error in rows:
            print(f"{t:12.6f} {along:6.0f} {q64:12.6f} {error:17.1e}")
        worst = max(error for *_, error in rows)
        print(f"{label}: {len(rows)} cameras, largest difference {worst:.1e}\n")


if __name__ == "__main__":
    main()
