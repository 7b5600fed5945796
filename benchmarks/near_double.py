"""How close two tangency roots may be for the banana's grid to find both, and what a
missed pair costs.

    python benchmarks/near_double.py

A camera on the tangent line of one of the banana's two inflections, moved off it so that
the tangency function has two roots `sep` apart in t (tests/helpers.near_double_camera):
per grid (36 cells, the default of two per degree, and 72, the earlier four), whether
both roots are found, and the relative error of VisibleLength and Foreshortened Q
against the NumPy reference (tests/reference.py, 4096-cell grid, tolerance 1e-12). A
missed pair hides a sliver around a point where the line of sight grazes the curve:
VisibleLength loses its length, Foreshortened almost nothing (q = cos^2 vanishes there).
"""

import os
import sys

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)

import ocp_jax as ocp

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests"))
import helpers as H
from reference import reference_visibility

GRIDS = (36, 72)
# (inflection, distance along its tangent line) of tests/test_visibility.py's cases
INFLECTIONS = ((0, -30.0), (1, 30.0))
SEPARATIONS = (4e-3, 1e-3, 3e-4, 1e-4)


def grid_results(grid: int):
    """camera (1, 2) -> (tangency times, validity, VisibleLength Q, Foreshortened Q)."""
    options = ocp.VisibilityOptions(grid=grid)

    def results(camera):
        tangents = ocp.visible_intervals(H.BANANA, camera, options).tangents
        return (
            tangents.t[0, 0],
            tangents.valid[0, 0],
            ocp.visibility(H.BANANA, camera, ocp.VisibleLength(), options),
            ocp.visibility(H.BANANA, camera, ocp.Foreshortened(), options),
        )

    return jax.jit(results)


def main():
    spec = H.to_reference(H.BANANA)
    programs = {grid: grid_results(grid) for grid in GRIDS}
    columns = "  ".join(f"{f'{g} cells: found, VL err, FS err':>32}" for g in GRIDS)
    print(f"{'inflection':>10}  {'sep':>7}  {columns}")
    for which, distance in INFLECTIONS:
        for sep in SEPARATIONS:
            camera, pair = H.near_double_camera("banana", 0, which, distance, 1, sep)
            camera = np.asarray([camera])
            want = [
                reference_visibility(spec, camera, objective, 4096, 1e-12)
                for objective in ("visible_length", "foreshortened")
            ]
            cells = []
            for program in programs.values():
                t, valid, vl, fs = program(jnp.asarray(camera))
                t = np.asarray(t)[np.asarray(valid)]
                found = sum(t.size > 0 and np.min(np.abs(t - root)) < 1e-9 for root in pair)
                errors = [abs(float(q) / w - 1) for q, w in zip((vl, fs), want)]
                cells.append(f"{found}/2  {errors[0]:9.1e}  {errors[1]:9.1e}")
            print(f"{which:>10}  {sep:7.0e}  " + "  ".join(f"{c:>32}" for c in cells))


if __name__ == "__main__":
    main()
