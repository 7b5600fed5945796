"""Where the time of one call of Q goes: the engine's work against the runtime's per call.

    python benchmarks/call_anatomy.py [--sets 128]

For the two rows of evaluate.py with targets (the banana with 1 camera, 10 blobs with 4),
compiled as evaluate.py compiles them, this prints per program (Q, value+grad):

- `floor`: one call of a program of the same arguments that does nothing (one addition):
  the cost of dispatching a call from Python (flattening the scene, launching).
- `one call`: one call of the program, as evaluate.py times it.
- `in lax.map`: the time per camera set of one call that evaluates `--sets` different
  camera sets in turn (`jax.lax.map`, a loop inside the compiled program, as
  `ocp.optimize` runs its steps), divided by the number of sets: the engine's own work
  per evaluation, with the scene's samples computed once per call.
- the NumPy reference (`tests/reference.py`, as evaluate.py runs it) on the first set,
  and its time over the engine's per set in the loop and in one call.

Each time is the best of three medians (evaluate.py's `timed`), after compilation; the
ratios are of times taken within seconds of each other, not paired as in evaluate.py.
"""

import argparse
import os
import sys

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
# (evaluate.py sets up float64 and puts the tests' helpers on the path)
from evaluate import (
    case,
    jit_options,
    print_row,
    recommended,
    rectangle_cameras,
    reference_program,
    timed,
    value,
    value_and_grad,
)


def camera_sets(name: str, cameras: jnp.ndarray, sets: int, rng) -> jnp.ndarray:
    """`sets` camera sets like `cameras`: drawn on the banana's rectangle, or the ring
    cameras of evaluate.py moved by up to 2% of their distance from the first."""
    k = cameras.shape[0]
    if name == "banana":
        return jnp.asarray(rectangle_cameras(sets * k, rng).reshape(sets, k, 2))
    scale = 0.02 * float(jnp.linalg.norm(cameras[0] - cameras[1]))
    return cameras[None] + scale * jnp.asarray(rng.uniform(-1, 1, (sets, k, 2)))


def in_loop(per_set, **options):
    """One program evaluating `per_set(scene, cameras)` for every set of a batch in turn."""
    return jax.jit(lambda scene, batch: jax.lax.map(lambda c: per_set(scene, c), batch), **options)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sets", type=int, default=128, help="camera sets per loop")
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    print(f"JAX {jax.__version__}, float64, Foreshortened; times in us")
    header = ["scene", "k", "program", "floor", "one call", "in lax.map", "NumPy ref"]
    header += ["ref/loop", "ref/call"]
    widths = [8, 2, 11, 6, 9, 11, 10, 9, 9]
    print_row(header, widths)
    for name, k in (("banana", 1), ("blobs10", 4)):
        scene, cameras = case(name, k)
        batch = camera_sets(name, cameras, args.sets, rng)
        _, programs, _ = recommended(k)
        options = jit_options(k)
        floor = jax.jit(lambda s, c: s.curves[0].control_points[0, 0] + c[0, 0], **options)
        t_floor = timed(floor, scene, batch[0])
        t_ref = timed(reference_program(scene, batch[0]), repeats=1)
        for label, program, per_set in zip(("Q", "value+grad"), programs, (value, value_and_grad)):
            looped = in_loop(per_set, **options)
            jax.block_until_ready((program(scene, batch[0]), looped(scene, batch)))  # compile
            t_call = timed(program, scene, batch[0])
            t_loop = timed(looped, scene, batch) / args.sets
            cells = [name, k, label, f"{1e6 * t_floor:.0f}", f"{1e6 * t_call:.0f}"]
            cells += [f"{1e6 * t_loop:.0f}", f"{1e6 * t_ref:.0f}"]
            cells += [f"{t_ref / t_loop:.0f}x", f"{t_ref / t_call:.0f}x"]
            print_row(cells, widths)


if __name__ == "__main__":
    main()
