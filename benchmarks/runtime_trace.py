"""Where the wall time of one small evaluation goes: kernels, or the runtime between them.

    python benchmarks/runtime_trace.py [--rows circle banana blobs10] [--k 1]
    taskset -c 0 python benchmarks/runtime_trace.py      (the same on one core)

Per row of evaluate.py's table (Q, float64, Foreshortened), from the JAX profiler's trace
of 20 calls: the kernels one call launches, their summed time, and the span from the
call's first kernel to its last (median over calls), of which `busy` has some kernel
running on some thread; the rest of the span are gaps in which XLA's CPU runtime hands
kernels between the threads of its pool. Then the wall time per call (best of 7 blocks)
of the program compiled by default and with `ocp.compiler_options()` (XLA's
memory-optimized scheduler, which leaves fewer kernels independent of each other),
measured in alternating blocks in one process. The profiler slows every kernel down, so
its columns compare programs, not absolute speeds.
"""

import argparse
import itertools
import statistics

import jax
import numpy as np
from compile_split import kernel_names, profiled_events
from compiler_options import alternating
from evaluate import VALUE, cases, ocp, print_row


def trace(compiled, hlo_text: str, scene, cameras, calls: int = 20):
    """(launches, kernel us, span us, busy us) per call, from the profiler's events."""
    kernels = kernel_names(hlo_text)
    events, starts = [], []
    for name, start, duration in profiled_events(compiled, scene, cameras, calls, warm=50):
        if name in kernels:
            events.append((start, start + duration))
        elif name == "CommonPjRtLoadedExecutable::ExecuteHelperOnSingleDevice":
            starts.append(start)
    events.sort()
    starts = sorted(starts) + [float("inf")]
    spans, busy = [], []
    for begin, end in itertools.pairwise(starts):
        call = [e for e in events if begin <= e[0] < end]
        spans.append(max(e for _, e in call) - call[0][0])
        covered, (lo, hi) = 0, call[0]
        for s, e in call[1:]:
            if s > hi:
                covered, lo = covered + hi - lo, s
            hi = max(hi, e)
        busy.append(covered + hi - lo)
    kernel_ns = sum(e - s for s, e in events)
    return (
        len(events) / calls,
        kernel_ns / calls / 1e3,
        statistics.median(spans) / 1e3,
        statistics.median(busy) / 1e3,
    )


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", nargs="+", default=["circle", "banana", "blobs10"])
    parser.add_argument("--k", type=int, default=1, help="number of cameras")
    args = parser.parse_args()
    print(f"JAX {jax.__version__} on {jax.devices()[0].device_kind}, float64, Q")
    columns = [("scene", 8), ("k", 2), ("launches", 9), ("kernel us", 10), ("span us", 8)]
    columns += [("busy us", 8), ("default us", 11), ("options us", 11)]
    header, widths = zip(*columns)
    print_row(header, widths)
    for name, scene, cameras in cases(np.random.default_rng(0)):
        if name not in args.rows or cameras.shape[0] != args.k:
            continue
        lowered = VALUE.trace(scene, cameras).lower()
        default = lowered.compile()
        options = lowered.compile(compiler_options=ocp.compiler_options())
        launched, kernel, span, busy = trace(default, default.as_text(), scene, cameras)
        times = alternating([default, options], (scene, cameras), blocks=7)
        cells = [name, args.k, f"{launched:.0f}", f"{kernel:.0f}", f"{span:.0f}", f"{busy:.0f}"]
        cells += [f"{1e6 * min(t):.0f}" for t in times]
        print_row(cells, widths)


if __name__ == "__main__":
    main()
