"""How many root slots the built-in scenes use, and what smaller budgets save.

    python benchmarks/budgets.py

`VisibilityOptions.max_tangents` (8) and `max_shadows` (16) are static slot counts per
curve and camera: every array after the root solves (the rays, the shadow search, the
events, the intervals tested and integrated) is sized by them, used or not. For the banana
and 3 blobs, this prints the most slots any camera used on any curve (the counts before
packing, which `visible_intervals` returns), over a grid of cameras around the scene (those
outside every object, with room to spare: budgets 16 and 32). Then it times Q of
evaluate.py's one-camera rows of both scenes with the default budgets and with smaller
ones, in alternating blocks in one process (float64, Foreshortened, best and median block).
A budget that a camera exceeds raises an error naming the option, so a smaller one can be
tried safely. (The intervals a camera tests are budgeted from the same counts: with both
budgets small, a camera with many events may need `max_camera_intervals` raised too, as
evaluate.py's four cameras on the banana do with 4 and 8.)
"""

import statistics

import jax
import jax.numpy as jnp
import numpy as np
from compiler_options import alternating
from evaluate import OBJECTIVE, case, ocp

from ocp_jax._visibility import _as_input, _events, _poses, valid_visibility

GENEROUS = ocp.VisibilityOptions(max_tangents=16, max_shadows=32)
BUDGETS = {
    "default (8, 16)": ocp.VisibilityOptions(),
    "max_tangents=4": ocp.VisibilityOptions(max_tangents=4),
    "max_shadows=8": ocp.VisibilityOptions(max_shadows=8),
    "both (4, 8)": ocp.VisibilityOptions(max_tangents=4, max_shadows=8),
}


def camera_grid(scene: ocp.Scene, n: int = 40) -> jnp.ndarray:
    """n x n cameras on the scene's bounding box grown by 60% on every side, as (n^2, 1, 2)."""
    points = np.concatenate([np.asarray(c(jnp.linspace(0, 1, 64))) for c in scene.curves])
    lo, hi = points.min(0), points.max(0)
    lo, hi = lo - 0.6 * (hi - lo), hi + 0.6 * (hi - lo)
    x, y = np.meshgrid(np.linspace(lo[0], hi[0], n), np.linspace(lo[1], hi[1], n))
    return jnp.asarray(np.stack([x, y], -1).reshape(-1, 1, 2))


def slots_used(scene: ocp.Scene) -> tuple[int, int, int]:
    """(valid cameras, most tangency slots, most shadow slots) over `camera_grid`, from
    the engine's events (internal: `visible_intervals` returns the same counts but raises
    for a camera inside an object, which the grid has)."""

    def one(c):
        partitions = _events(scene, _poses(scene, _as_input(c)), OBJECTIVE, GENEROUS).partitions
        valid = valid_visibility(scene, c, OBJECTIVE, GENEROUS)[1]
        return valid, partitions.tangents.count.max(), partitions.shadows.count.max()

    counts = jax.jit(lambda cs: jax.lax.map(one, cs, batch_size=64))(camera_grid(scene))
    valid, tangents, shadows = (np.asarray(a) for a in counts)
    return int(valid.sum()), int(tangents[valid].max()), int(shadows[valid].max())


def main():
    print("slots used over a grid of cameras (per curve and camera):")
    print(f"  {'scene':8s} {'cameras':>8s} {'tangents':>9s} {'shadows':>8s}")
    rows = {name: case(name, 1) for name in ("banana", "blobs3")}
    for name, (scene, _) in rows.items():
        count, tangents, shadows = slots_used(scene)
        print(f"  {name:8s} {count:8d} {tangents:9d} {shadows:8d}")
    print("\nQ with k = 1 (evaluate.py's camera), us per call: best (median) of 15 blocks")
    for name, (scene, cameras) in rows.items():
        programs = [
            jax.jit(lambda s, c, o=options: ocp.visibility(s, c, OBJECTIVE, o))
            for options in BUDGETS.values()
        ]
        times = alternating(programs, (scene, cameras), blocks=15)
        for label, t in zip(BUDGETS, times):
            best, median = 1e6 * min(t), 1e6 * statistics.median(t)
            print(f"  {name:8s} {label:18s} {best:7.1f} ({median:.1f})")


if __name__ == "__main__":
    main()
