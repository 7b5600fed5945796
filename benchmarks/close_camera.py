"""Quadrature accuracy of Foreshortened Q for a camera close to a circle.

    python benchmarks/close_camera.py

q = cos^2 is nearly singular where the camera is close to the curve. Prints the relative
error of Q against the closed form (tests/helpers.circle_foreshortened) for cameras at
distance d from the centre of a unit circle, in the directions of the points t = 0 (a
panel breakpoint), 0.02 and 0.09 (inside a panel), with 16 and 32 Gauss-Legendre nodes,
and whether `ocp.visibility` accepts the camera (it refuses cameras closer than
(2.5 / nodes)^2 of the curve's radius). The error is computed without that check
(`_events` and `_value`, the engine's own steps) so that the refused rows show why.
"""

import math
import os
import sys

import jax
import jax.numpy as jnp

jax.config.update("jax_enable_x64", True)

import ocp_jax as ocp  # noqa: E402
from ocp_jax._visibility import _events, _poses, _value  # noqa: E402

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests"))
from helpers import circle_foreshortened  # noqa: E402


def main():
    scene = ocp.scenes.circle()
    directions = (0.0, 0.02, 0.09)
    errors = "  ".join(f"{f'error t={t}':>12}" for t in directions)
    print(f"{'d / r':>6}  {'nodes':>5}  {errors}  visibility()")
    for d in (3.0, 1.3, 1.2, 1.1, 1.05, 1.03, 1.01):
        for nodes in (16, 32):
            options = ocp.VisibilityOptions(quadrature=nodes)
            cells = []
            for t in directions:
                angle = 2 * math.pi * t
                cameras = jnp.array([[d * math.cos(angle), d * math.sin(angle)]])
                events = _events(scene, _poses(scene, cameras), ocp.Foreshortened(), options)
                value, _ = _value(scene, events, ocp.Foreshortened(), options)
                cells.append(f"{abs(float(value) / circle_foreshortened(1.0, d) - 1):12.1e}")
            try:
                ocp.visibility(scene, cameras, ocp.Foreshortened(), options)
                accepted = "accepts"
            except Exception:  # noqa: BLE001 (equinox's runtime error)
                accepted = "refuses (too close)"
            print(f"{d:6.2f}  {nodes:5d}  {'  '.join(cells)}  {accepted}")


if __name__ == "__main__":
    main()
