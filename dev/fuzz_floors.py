"""Seeded fuzz of the exact engine on random floors it was not tuned on.

For each seed s, a floor `ocp.scenes.floor(seed=s + offset, cells, objects)` and cameras
`ocp.scenes.free_points(scene, k, seed=s, clearance)`, with cells, objects, k and the
clearance drawn from `numpy.random.default_rng(s)` in the ranges given. Q (Foreshortened,
under jit, default options) is compared with the NumPy reference (`tests/reference.py`);
with `--gradient`, dQ/dcameras with central differences as well. Prints one row per seed
and the worst errors, and exits with status 1 if any error passes its tolerance (1e-7
relative for Q, 1e-6 of the gradient's size) or a valid scene raised.

    python dev/fuzz_floors.py --seeds 5000 5100 --cameras 4 6
    python dev/fuzz_floors.py --seeds 0 20 --cameras 1 3 --gradient
"""

import argparse
import sys
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)
import numpy as np

import ocp_jax as ocp

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from helpers import central_differences, to_reference
from reference import reference_visibility


def draw(seed: int, args) -> tuple[ocp.Scene, np.ndarray, str]:
    rng = np.random.default_rng(seed)
    cells = int(rng.integers(args.cells[0], args.cells[1] + 1))
    objects = min(int(rng.integers(args.objects[0], args.objects[1] + 1)), cells)
    k = int(rng.integers(args.cameras[0], args.cameras[1] + 1))
    clearance = float(rng.uniform(*args.clearance))
    scene = ocp.scenes.floor(seed=seed + args.offset, cells=cells, objects=objects)
    cameras = np.asarray(ocp.scenes.free_points(scene, k, seed=seed, clearance=clearance))
    return scene, cameras, f"{cells:5d} {objects:7d} {k:3d} {clearance:9.2f}"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs=2, default=[0, 20], metavar=("FROM", "TO"))
    parser.add_argument("--cells", type=int, nargs=2, default=[4, 11])
    parser.add_argument("--objects", type=int, nargs=2, default=[2, 6])
    parser.add_argument("--cameras", type=int, nargs=2, default=[1, 6])
    parser.add_argument("--clearance", type=float, nargs=2, default=[0.05, 0.5])
    parser.add_argument("--offset", type=int, default=200, help="floor seed = seed + offset")
    parser.add_argument("--gradient", action="store_true")
    args = parser.parse_args()
    objective = ocp.Foreshortened()
    worst_value = worst_gradient = 0.0
    failed = False
    print(" seed cells objects   k clearance   Q rel. error  grad error")
    for seed in range(*args.seeds):
        scene, cameras, drawn = draw(seed, args)
        value = jax.jit(lambda c: ocp.visibility(scene, c, objective))
        try:
            got = float(value(cameras))
        except Exception as error:  # a valid scene must not raise: report and go on
            print(f"{seed:5d} {drawn}   raised {type(error).__name__}: {str(error)[:200]}")
            failed = True
            continue
        observed = list(np.asarray(scene.observed()))
        want = reference_visibility(
            to_reference(scene), cameras, "foreshortened", observed=observed
        )
        error = abs(got / want - 1)
        worst_value = max(worst_value, error)
        failed |= error > 1e-7
        gradient = ""
        if args.gradient:
            grad = np.asarray(
                jax.jit(jax.grad(lambda c: ocp.visibility(scene, c, objective)))(cameras)
            )
            fd = central_differences(lambda c: float(value(c)), cameras, 1e-6)
            g_error = np.max(np.abs(grad - fd)) / max(1.0, np.max(np.abs(fd)))
            worst_gradient = max(worst_gradient, g_error)
            failed |= g_error > 1e-6
            gradient = f"{g_error:11.1e}"
        print(f"{seed:5d} {drawn}   {error:11.1e} {gradient}", flush=True)
    print(
        f"worst: Q {worst_value:.1e}"
        + (f", gradient {worst_gradient:.1e}" if args.gradient else "")
    )
    return int(failed)


if __name__ == "__main__":
    sys.exit(main())
