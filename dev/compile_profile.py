"""Where compiling value+grad of Foreshortened Q spends its time on a random floor (or a
built-in scene): tracing, lowering, XLA's HLO passes and its code generation (LLVM),
with the sizes each follows (StableHLO lines, HLO instructions, kernels).

    python dev/compile_profile.py --cells 24 --cameras 1
    python dev/compile_profile.py --scene banana --cameras 2 --level 0

`--level 0` compiles as the test-suite does (`--xla_backend_optimization_level=0`). The
HLO-pass and code-generation times come from XLA's own log (its pass pipeline and
`cpu_compiler`), so the script runs itself again with that log turned on.
"""

import argparse
import collections
import os
import re
import subprocess
import sys
import time


def _measure(args):
    from floor_program import value_and_grad_program

    fn, cameras, scene = value_and_grad_program(args.scene, args.cells, args.cameras, args.seed)
    start = time.perf_counter()
    traced = fn.trace(cameras)
    traced_at = time.perf_counter()
    lowered = traced.lower()
    lowered_at = time.perf_counter()
    compiled = lowered.compile()
    compiled_at = time.perf_counter()
    hlo = compiled.as_text()
    # computations inlined into a kernel (fusions) or into an operation (reducers)
    inner = set(re.findall(r"(?:fusion\(.*calls|to_apply)=%([\w.\-]+)", hlo))
    kernels, instructions, skip = collections.Counter(), 0, False
    for line in hlo.splitlines():
        header = re.match(r"^(?:ENTRY )?%?([\w.\-]+) .*\{\s*$", line)
        if header:
            skip = header.group(1) in inner
            continue
        op = re.match(r"\s+(?:ROOT )?%?\S+ = (?:\([^=]*?\)|\S+) ([\w-]+)\(", line)
        if not op:
            continue
        instructions += 1
        free = ("parameter", "constant", "tuple", "get-tuple-element", "bitcast")
        if not skip and op.group(1) not in free:
            kernels[op.group(1)] += 1
    print(f"groups: {[(type(g.form).__name__, len(g.members)) for g in scene._curve_groups()]}")
    print(
        f"trace {traced_at - start:.1f} s, lower {lowered_at - traced_at:.1f} s, "
        f"compile {compiled_at - lowered_at:.1f} s"
    )
    print(
        f"StableHLO lines {lowered.as_text().count(chr(10))}, compiled HLO instructions "
        f"{instructions}, kernels {sum(kernels.values())} (fusions {kernels['fusion']})"
    )


def _xla_split(log: str) -> str:
    """Seconds of XLA's HLO passes and of its code generation for the module that took
    longest, from the time stamps of its log: its first pass pipeline, the start of its
    code generation ("Compiling: name") and its end ("Compilation finished")."""
    stamp = r"^\w(\d\d\d\d) (\d\d):(\d\d):([\d.]+)"
    first, codegen, spans, current = {}, {}, {}, None
    for line in log.splitlines():
        clock = re.match(stamp, line)
        if not clock:
            continue
        now = 3600 * int(clock.group(2)) + 60 * int(clock.group(3)) + float(clock.group(4))
        pipeline = re.search(r"Running HLO pass pipeline on module (\S+):", line)
        if pipeline:
            first.setdefault(pipeline.group(1), now)
        started = re.search(r"cpu_compiler.cc:\d+\] Compiling: (\S+)", line)
        if started:
            current = started.group(1)
            codegen[current] = now
        if "Compilation finished" in line and current is not None:
            spans[current] = (codegen[current] - first.pop(current), now - codegen[current])
            current = None
    name = max(spans, key=lambda n: sum(spans[n]))
    passes, generation = spans[name]
    return f"XLA, module {name}: HLO passes {passes:.1f} s, code generation {generation:.1f} s"


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="floor", help="'floor' or a built-in: banana, room")
    parser.add_argument("--cells", type=int, default=24)
    parser.add_argument("--cameras", type=int, default=1)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--level", type=int, choices=(0, 1, 2, 3), default=None)
    parser.add_argument("--measure", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.measure:
        _measure(args)
        return
    env = dict(os.environ, TF_CPP_MIN_LOG_LEVEL="0")
    env["TF_CPP_VMODULE"] = "hlo_pass_pipeline=1,cpu_compiler=1"
    if args.level is not None:
        level = f"--xla_backend_optimization_level={args.level}"
        env["XLA_FLAGS"] = f"{env.get('XLA_FLAGS', '')} {level}"
    run = subprocess.run(
        [sys.executable, __file__, *sys.argv[1:], "--measure"],
        env=env,
        capture_output=True,
        text=True,
        check=True,
    )
    print(run.stdout, end="")
    print(_xla_split(run.stderr))


if __name__ == "__main__":
    main()
