"""VisibleLength of cameras right beside a curve, against the NumPy reference.

    python benchmarks/beside_curves.py [--scene banana|three_objects|blobs|room]
                                       [--points 60] [--seed 0] [--float32]

A camera close to a curve sees a short arc of it between two tangency times that can
lie closer together than the grid of the root search resolves, and lines of sight that
cross the curve again just behind it, at a depth the grid's interpolation misjudges (the
camera's nearest point is a node of the tangency search since 2026-12-04, and of the
occlusion test since 2026-12-05). For cameras at distance d along the normal on the free
side of `--points` random points of each curve of a built-in scene (`ocp.scenes`; blobs:
three of them), prints per d: the largest relative difference of VisibleLength from
`tests/reference.py`, how many differ by more than 1e-7, and how many the engine sees
nothing of where the reference sees an arc. Cameras the engine refuses (inside another
object, or on a curve: closer than sqrt(eps) times the scene's size) are counted apart.
With `--float32` the engine computes in float32 (scene and cameras cast after they are
placed), refuses cameras closer than 3.5e-4 of the scene's size, and is counted off
beyond 1e-4.
Foreshortened is not run: it refuses cameras closer than 2.4% of a curve's radius.
"""

import argparse
import os
import sys

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)

import ocp_jax as ocp  # noqa: E402
from ocp_jax._visibility import valid_visibility  # noqa: E402

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests"))
from helpers import cameras_beside, to_float32, to_reference  # noqa: E402
from reference import eval_curve, reference_visibility  # noqa: E402

DISTANCES = (1e-1, 1e-2, 1e-3, 1e-4, 1e-5, 1e-6)
SCENES = {
    "banana": ocp.scenes.banana,
    "three_objects": ocp.scenes.three_objects,
    "blobs": lambda: ocp.scenes.blobs(3),
    "room": ocp.scenes.room,
}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="banana", choices=SCENES)
    parser.add_argument("--points", type=int, default=60)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--float32", action="store_true", help="the engine in float32")
    args = parser.parse_args()
    precision, tolerance = (to_float32, 1e-4) if args.float32 else ((lambda tree: tree), 1e-7)
    scene = SCENES[args.scene]()
    reference = to_reference(scene)
    observed = list(scene.observed())  # a room's walls occlude but are not integrated
    options = ocp.VisibilityOptions()
    value = jax.jit(
        jax.vmap(
            lambda s, c: valid_visibility(s, c[None], ocp.VisibleLength(), options)[:2], (None, 0)
        )
    )
    t = np.linspace(0.0, 1.0, 4097)
    dense = np.concatenate([eval_curve(spec, t)[0] for spec in reference])
    size = float(np.max(np.ptp(dense, 0)))
    print(
        f"{args.scene}: {len(scene)} curves, extent {size:.3g}, {args.points} points per curve,"
        f" the engine in {'float32' if args.float32 else 'float64'}"
    )
    print(
        f"{'d':>8} {'d / extent':>10} {'cameras':>8} {'refused':>8} {'largest':>9}"
        f" {f'> {tolerance:.0e}':>7} {'none seen':>9}"
    )
    for distance in DISTANCES:
        rng = np.random.default_rng(args.seed)
        cams = np.concatenate(  # beside random points of every curve, on its free side
            [
                cameras_beside(spec, rng.uniform(0.0, 1.0, args.points), [distance], side)
                for spec, side in zip(reference, scene.sides())
            ]
        )
        q, valid = (np.asarray(a) for a in value(*precision((scene, jnp.asarray(cams)))))
        errors, missed = [], 0
        for c, qc in zip(cams[valid], q[valid]):
            ref = reference_visibility(reference, c[None], "visible_length", observed=observed)
            errors.append(abs(float(qc) - ref) / abs(ref))
            missed += (qc == 0) & (ref > 0)
        errors = np.array(errors)
        print(
            f"{distance:8.0e} {distance / size:10.1e} {len(cams):8d} {int((~valid).sum()):8d}"
            f" {max(errors, default=np.nan):9.1e} {int((errors > tolerance).sum()):7d} {missed:9d}",
            flush=True,
        )


if __name__ == "__main__":
    main()
