"""Random floor plans: the cost of Foreshortened Q's value and gradient against
VisiLibity1's visibility polygons for the same cameras, as the floor and the number of
cameras grow.

Floors come from `ocp.scenes.floor(seed, cells, cells // 2, jagged=...)` (a random union
of grid cells with furniture of every curve type; `--jagged 1`, the default, grows spurs,
about 1.4 walls per cell, so that the default cells give about 16 to 256 walls) and
cameras from `ocp.scenes.free_points`. Each row
sizes the event budgets with `ocp.fit_options` (headroom 1), compiles value and gradient
under one jit (the compile column), and times the compiled call (median of `--repeat`).
VisiLibity1 computes the k visibility polygons of the same cameras (its environment,
with every smooth object as a 64-gon, built once beforehand), in the same run. `ratio`
is ocp_jax / VisiLibity; `growth` is the value+grad time over that of the same k on the
previous floor (the floors double). Float64 throughout.

    python benchmarks/floors.py                      # every size: long on 2 cores
    python benchmarks/floors.py --cells 12 24 --cameras 1 4
"""

import argparse
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)
import numpy as np

import ocp_jax as ocp

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from visilibity_reference import environment, outline, visibility_polygon


def corners(polygon: np.ndarray) -> int:
    """The number of corners (and so of walls) of a polygon whose edges may be split."""
    before, after = polygon - np.roll(polygon, 1, 0), np.roll(polygon, -1, 0) - polygon
    return int(np.count_nonzero(before[:, 0] * after[:, 1] - before[:, 1] * after[:, 0]))


def median_time(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - start)
    return float(np.median(times))


def row(cells: int, k: int, seed: int, repeat: int, jagged: float) -> dict:
    scene = ocp.scenes.floor(seed, cells, max(1, cells // 2), jagged=jagged)
    cameras = ocp.scenes.free_points(scene, k, seed)
    objective = ocp.Foreshortened()
    options = ocp.fit_options(scene, cameras, objective)
    fn = jax.jit(jax.value_and_grad(lambda c: ocp.visibility(scene, c, objective, options)))
    start = time.perf_counter()
    compiled = fn.lower(cameras).compile()
    compile_s = time.perf_counter() - start
    engine = median_time(lambda: compiled(cameras), repeat)
    env, _, _ = environment(outline(scene.curves[-1]), [outline(c) for c in scene.objects])
    reference = median_time(
        lambda: [visibility_polygon(env, c) for c in np.asarray(cameras)], repeat
    )
    return {
        "walls": corners(outline(scene.curves[-1])),
        "objects": len(scene.objects),
        "k": k,
        "engine": engine,
        "compile": compile_s,
        "visilibity": reference,
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cells", type=int, nargs="+", default=[12, 24, 48, 96, 192])
    parser.add_argument("--jagged", type=float, default=1.0)
    parser.add_argument("--cameras", type=int, nargs="+", default=[1, 4, 16, 64])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    print(
        "| walls | objects | k | value+grad ms | compile s | VisiLibity ms | ratio | growth |\n"
        "|---:|---:|---:|---:|---:|---:|---:|---:|"
    )
    previous = {}
    for cells in args.cells:
        for k in args.cameras:
            r = row(cells, k, args.seed, args.repeat, args.jagged)
            before = previous.get(k)
            growth = f"{r['engine'] / before:.2f}x" if before else ""
            previous[k] = r["engine"]
            print(
                f"| {r['walls']} | {r['objects']} | {k} | {1e3 * r['engine']:.1f} | "
                f"{r['compile']:.1f} | {1e3 * r['visilibity']:.1f} | "
                f"{r['engine'] / r['visilibity']:.1f}x | {growth} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
