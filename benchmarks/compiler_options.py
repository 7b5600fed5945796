"""Value+grad compiled with and without `ocp.compiler_options()`, side by side.

    python benchmarks/compiler_options.py [--blocks 9]

For every row of evaluate.py's table (float64, Foreshortened) and for vmapped batches of
camera sets on the banana (k = 1, 2, 4), the same lowered program is compiled twice, with
XLA's default CPU scheduler and with the options (its memory-optimized scheduler), and
the two are timed in alternating blocks in one process, so that the machine's drift falls
on both. Prints the best and the median block of each, and the speed-up of the options
(value+grad in microseconds per call, batches in camera sets per second).
"""

import argparse
import statistics
import time

import jax
import numpy as np
from evaluate import VALUE_AND_GRAD, banana_batch, cases, ocp


def alternating(programs, args, blocks: int, budget: float = 0.05):
    """Seconds per call of each program, per block: the programs run in turn, block after
    block, each block as many calls as fill about `budget` seconds."""
    for program in programs:
        jax.block_until_ready(program(*args))
    start = time.perf_counter()
    jax.block_until_ready(programs[0](*args))
    calls = max(1, int(budget / (time.perf_counter() - start)))
    times = [[] for _ in programs]
    for _ in range(blocks):
        for program, record in zip(programs, times):
            start = time.perf_counter()
            for _ in range(calls):
                jax.block_until_ready(program(*args))
            record.append((time.perf_counter() - start) / calls)
    return times


def both(jitted, *args):
    """`jitted` compiled for `args` by default and with `ocp.compiler_options()`."""
    lowered = jitted.trace(*args).lower()
    return lowered.compile(), lowered.compile(compiler_options=ocp.compiler_options())


def print_row(label, default, options, show):
    """The best and the median block of each (seconds, shown by `show`) and the speed-up
    of the options (default time / options time: above 1 is faster with them)."""
    cells = []
    for pick in (min, statistics.median):
        without, with_options = pick(default), pick(options)
        cells += [f"{show(without):>12s}", f"{show(with_options):>12s}"]
        cells.append(f"{without / with_options:8.2f}")
    print(f"{label:22s} " + " ".join(cells), flush=True)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--blocks", type=int, default=9)
    args = parser.parse_args()
    print(f"JAX {jax.__version__} on {jax.devices()[0].device_kind}; {ocp.compiler_options()}")
    print(f"{args.blocks} alternating blocks; speed-up = default time / options time")
    print(
        f"{'':22s} {'best default':>12s} {'options':>12s} {'speed-up':>8s}"
        f" {'median def.':>12s} {'options':>12s} {'speed-up':>8s}"
    )
    for name, scene, cameras in cases(np.random.default_rng(0)):
        times = alternating(both(VALUE_AND_GRAD, scene, cameras), (scene, cameras), args.blocks)
        print_row(f"{name} k={cameras.shape[0]}", *times, lambda s: f"{1e6 * s:.0f} us")

    rng = np.random.default_rng(1)
    for k, sets in ((1, 1024), (2, 512), (4, 256)):
        per_set, batch = banana_batch(rng, sets, k)
        times = alternating(both(jax.jit(jax.vmap(per_set)), batch), (batch,), args.blocks, 0.3)
        print_row(f"banana batch {sets}, k={k}", *times, lambda s, n=sets: f"{n / s:.0f}/s")


if __name__ == "__main__":
    main()
