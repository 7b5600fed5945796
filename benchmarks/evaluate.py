"""Speed of the exact visibility engine, float64, after compilation.

    python benchmarks/evaluate.py [--quick]

Prints one table: per scene and number of cameras k, the compile time of value+grad,
the time of Q and of value+grad (best of three medians of repeated calls), compiled as
the README recommends ("Which program for which job"): with `ocp.compiler_options()`
for one camera and for batches, under a plain `jax.jit` for several cameras; Q compiled
the other way beside them, and the independent NumPy reference (tests/reference.py) at
matching accuracy (its best median), the speed-up of Q over it (the median of three
ratios, each of the two timed one right after the other) and the relative difference of
the two Q values; then the throughput of a vmapped batch of 1024 single-camera sets on
the banana, with the options and under a plain jit. Targets (issue 2,
2-core CPU): banana k=1 value+grad <= 200 us; 10 blobs k=4 <= 5 ms; batch >= 10,000
value+grad/s; compile <= 10 s; >= 100x faster than the reference. `taskset -c 0 python
benchmarks/evaluate.py` gives the same table for a process on one core (README: small
programs run faster there, large ones, compiling and batches slower).
"""

import argparse
import os
import statistics
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)

import ocp_jax as ocp
from ocp_jax import scenes

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests"))
from helpers import to_reference
from reference import reference_visibility

OBJECTIVE = ocp.Foreshortened()
REFERENCE_GRID = 1024  # root-detection grid of the reference (finds every event here)
REFERENCE_TOL = 1e-10  # its adaptive quadrature tolerance: ~1e-10, matching ours


def ring_cameras(scene: ocp.Scene, k: int) -> np.ndarray:
    """k cameras on a circle around the scene, 0.8 of its bounding box's diagonal away."""
    points = np.concatenate([np.asarray(c(jnp.linspace(0, 1, 64))) for c in scene.curves])
    lo, hi = points.min(0), points.max(0)
    centre, radius = 0.5 * (lo + hi), 0.8 * np.linalg.norm(hi - lo)
    angle = 0.3 + 2 * np.pi * np.arange(k) / k
    return centre + radius * np.stack([np.cos(angle), np.sin(angle)], -1)


def rectangle_cameras(k: int, rng) -> np.ndarray:
    """k random cameras on the thesis's rectangle around the banana."""
    rectangle = ocp.RectangleBoundary(*scenes.BANANA_RECTANGLE)
    return np.asarray(rectangle.cameras(jnp.asarray(rng.uniform(0, 1, (k, 1)))))


def timed(fn, *args, budget=0.5, repeats=3):
    """Wall time of fn(*args) (blocked): the best of `repeats` medians, each over calls
    that fill `budget` seconds (the timeit convention: the best repeat is the one least
    disturbed by other work on the machine)."""
    medians = []
    for _ in range(repeats):
        times = []
        while sum(times) < budget or len(times) < 5:
            start = time.perf_counter()
            jax.block_until_ready(fn(*args))
            times.append(time.perf_counter() - start)
        medians.append(statistics.median(times))
    return min(medians)


def paired_speed_up(reference, engine, *args, rounds=3) -> tuple[float, float]:
    """(seconds of the reference, its time over the engine's): the median over `rounds`
    of the ratio of the two, each round timing one right after the other. This machine's
    speed drifts by up to 2x within minutes, so the ratio of two times taken minutes
    apart says more about the drift than about the engine."""
    pairs = [(timed(reference, repeats=1), timed(engine, *args, repeats=1)) for _ in range(rounds)]
    return min(r for r, _ in pairs), statistics.median(r / e for r, e in pairs)


def cases(rng, quick: bool = False):
    """The rows of the table, (scene name, scene, cameras) for k = 1, 2, 4 cameras: on the
    banana drawn from `rng` on its rectangle, on the others a ring around the scene."""
    scenes_ = [
        ("circle", scenes.circle()),
        ("banana", scenes.banana()),
        ("blobs3", scenes.blobs(3)),
        ("blobs10", scenes.blobs(10)),
    ]
    for name, scene in scenes_:
        for k in (1,) if quick else (1, 2, 4):
            if name == "banana":
                cameras = rectangle_cameras(k, rng)
            else:
                cameras = ring_cameras(scene, k)
            yield name, scene, jnp.asarray(cameras)


def case(name: str, k: int) -> tuple[ocp.Scene, jnp.ndarray]:
    """(scene, cameras) of the table's row `name` with k cameras, as `main` draws them."""
    for row_name, scene, cameras in cases(np.random.default_rng(0)):
        if row_name == name and cameras.shape[0] == k:
            return scene, cameras
    raise ValueError(f"evaluate.py has no row {name!r} with k = {k}")


def print_row(cells, widths):
    print("  ".join(str(c).rjust(w) for c, w in zip(cells, widths)), flush=True)


def value(scene, cameras):
    """Q of the table (the Foreshortened objective)."""
    return ocp.visibility(scene, cameras, OBJECTIVE)


value_and_grad = jax.value_and_grad(value, 1)


def programs(**jit_options):
    """Q and its value+grad in the cameras, each under one `jax.jit(..., **jit_options)`."""
    return jax.jit(value, **jit_options), jax.jit(value_and_grad, **jit_options)


def jit_options(k: int) -> dict:
    """The `jax.jit` options the README recommends for a program of k cameras: XLA's
    memory-optimized scheduler for one camera (and for batches), none for several, where
    it is about even, or slower."""
    return {"compiler_options": ocp.compiler_options()} if k == 1 else {}


# Under a plain jax.jit (the other benchmarks compile these their own ways), and with
# the memory-optimized scheduler.
VALUE, VALUE_AND_GRAD = programs()
TUNED_VALUE, TUNED_VALUE_AND_GRAD = programs(**jit_options(1))


def recommended(k: int) -> tuple[str, tuple, tuple]:
    """(name, (Q, value+grad), other Q) for k cameras: compiled as the README recommends
    (`jit_options`), and Q compiled the other way."""
    if jit_options(k):
        return "opts", (TUNED_VALUE, TUNED_VALUE_AND_GRAD), VALUE
    return "plain", (VALUE, VALUE_AND_GRAD), TUNED_VALUE


def reference_program(scene: ocp.Scene, cameras):
    """A call of the NumPy reference (tests/reference.py) on `scene` and `cameras` at the
    table's accuracy."""
    spec, cameras = to_reference(scene), np.asarray(cameras)
    return lambda: reference_visibility(
        spec, cameras, "foreshortened", REFERENCE_GRID, REFERENCE_TOL
    )


def engine_times(
    scene, cameras, value_program=VALUE, grad_program=VALUE_AND_GRAD
) -> tuple[float, float, float]:
    """Seconds: compile of value+grad, Q, value+grad (after compilation)."""
    start = time.perf_counter()
    grad_program.lower(scene, cameras).compile()
    compile_s = time.perf_counter() - start
    return compile_s, timed(value_program, scene, cameras), timed(grad_program, scene, cameras)


def banana_batch(rng, sets: int = 1024, k: int = 1):
    """(value+grad of one set of k cameras on the banana, `sets` such sets (sets, k, 2)
    drawn from `rng` on its rectangle)."""
    banana = scenes.banana()
    batch = jnp.asarray(rectangle_cameras(sets * k, rng).reshape(sets, k, 2))
    return jax.value_and_grad(lambda c: ocp.visibility(banana, c, OBJECTIVE)), batch


def row(name, scene, cameras, reference=True):
    cameras = jnp.asarray(cameras)
    compiled, (value_fn, grad_fn), other = recommended(cameras.shape[0])
    compile_s, t_value, t_grad = engine_times(scene, cameras, value_fn, grad_fn)
    q = float(value_fn(scene, cameras))
    jax.block_until_ready(other(scene, cameras))  # (compiled before it is timed)
    t_other = timed(other, scene, cameras)
    cells = [name, cameras.shape[0], compiled, f"{compile_s:.1f}"]
    cells += [f"{1e6 * t_value:.0f}", f"{1e6 * t_grad:.0f}", f"{1e6 * t_other:.0f}"]
    if reference:
        reference = reference_program(scene, cameras)
        ref, t_ref, speed_up = reference(), *paired_speed_up(reference, value_fn, scene, cameras)
        cells += [f"{1e3 * t_ref:.0f}", f"{speed_up:.0f}x", f"{abs(q / ref - 1):.1e}"]
    else:
        cells += ["-", "-", "-"]
    return cells, q


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="k = 1 only, no reference")
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    print(f"JAX {jax.__version__} on {jax.devices()[0].device_kind}, float64, Foreshortened")
    header = ["scene", "k", "jit", "compile s", "Q us", "Q+grad us", "other jit Q us"]
    header += ["NumPy ref ms", "speed-up", "|rel diff|"]
    widths = [10, 2, 5, 10, 9, 10, 15, 13, 9, 10]
    print_row(header, widths)
    for name, scene, cameras in cases(rng, args.quick):
        cells, _ = row(name, scene, cameras, reference=not args.quick)
        print_row(cells, widths)

    per_set, batch = banana_batch(rng)
    print("\nbanana, 1024 single-camera sets, value+grad:")
    mapped = lambda b: jax.lax.map(per_set, b, batch_size=64)
    options = ocp.compiler_options()
    for label, fn in (
        ("jit(vmap)", jax.jit(jax.vmap(per_set), compiler_options=options)),
        ("jit(lax.map, batch_size=64)", jax.jit(mapped, compiler_options=options)),
        ("plain jit(vmap)", jax.jit(jax.vmap(per_set))),
    ):
        start = time.perf_counter()
        jax.block_until_ready(fn(batch))
        compile_s = time.perf_counter() - start
        t = timed(fn, batch, budget=2.0)
        print(f"  {label:28s} {1024 / t:8.0f} per second   (first call {compile_s:.1f} s)")


if __name__ == "__main__":
    main()
