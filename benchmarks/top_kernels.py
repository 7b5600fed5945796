"""The kernels that take the time of one program, from the JAX profiler's trace.

    python benchmarks/top_kernels.py [--row blobs10] [--k 4] [--program value+grad] [--top 15]

For one row of evaluate.py's table (float64, Foreshortened): the kernels of the compiled
program by their summed time per call (over 20 traced calls), with their launches per
call and the operation XLA names them after (the `op_name` of the JAX primitive that
produced the kernel's root). A kernel much slower than the work its output suggests is
a sign of XLA fusing an expensive producer (a reduction, say) into a consumer that reads
each element many times, such as a gather: `optimization_barrier` does not survive
XLA's CPU pipeline, so such code has to be written differently. The profiler slows every
kernel down; compare kernels with each other, not with evaluate.py's wall times.
"""

import argparse
import collections
import re

from compile_split import kernel_names, profiled_events
from evaluate import VALUE, VALUE_AND_GRAD, case, ocp

# An HLO instruction's name and the op_name of its metadata.
_OP_NAME = re.compile(r"^\s+(?:ROOT )?%(\S+) = .*?op_name=\"([^\"]*)\"", re.MULTILINE)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--row", default="blobs10", choices=["circle", "banana", "blobs3", "blobs10"]
    )
    parser.add_argument("--k", type=int, default=4, choices=[1, 2, 4])
    parser.add_argument("--program", default="value+grad", choices=["Q", "value+grad"])
    parser.add_argument("--top", type=int, default=15)
    args = parser.parse_args()
    scene, cameras = case(args.row, args.k)
    program = VALUE if args.program == "Q" else VALUE_AND_GRAD
    compiled = program.lower(scene, cameras).compile()
    hlo = compiled.as_text()
    kernels = kernel_names(hlo)
    op_names = dict(_OP_NAME.findall(hlo))
    calls = 20
    time_us, launches = collections.Counter(), collections.Counter()
    for kernel, _, duration_ns in profiled_events(compiled, scene, cameras, calls, warm=5):
        if kernel in kernels:
            time_us[kernel] += duration_ns / 1e3 / calls
            launches[kernel] += 1 / calls
    print(f"{ocp.__file__}: {args.row}, k = {args.k}, {args.program}")
    print(f"kernels {sum(time_us.values()):.0f} us per call, {sum(launches.values()):.0f} launches")
    print(f"{'us':>8s} {'launches':>8s}  kernel / op_name")
    for kernel, us in time_us.most_common(args.top):
        print(f"{us:8.1f} {launches[kernel]:8.0f}  {kernel} / {op_names.get(kernel, '')}")


if __name__ == "__main__":
    main()
