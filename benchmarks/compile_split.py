"""Where the compile time of value+grad goes, float64, Foreshortened.

    python benchmarks/compile_split.py

Per row of evaluate.py's table (scene and number of cameras k): the seconds spent
tracing to a jaxpr, lowering to StableHLO and compiling with XLA, the jaxpr's equation
count (sub-jaxprs included), the compiled program's HLO instructions (every computation,
fused ones included: the code XLA hands to LLVM), its top-level kernels (the
instructions of its entry computation that run, loops counted once), and the kernels
one call launches (loop trips included, counted by the JAX profiler), which bound the
run time of small scenes; and how many kernels XLA splits between threads (its parallel
task assignment, which depends on the cores the process may use: none on one core).
"""

import glob
import re
import tempfile
import time

import jax
import numpy as np
from jax.extend.core import jaxprs_in_params
from jax.profiler import ProfileData

jax.config.update("jax_enable_x64", True)

from evaluate import VALUE_AND_GRAD, cases, print_row  # noqa: E402

_NOT_KERNELS = {"parameter", "constant", "get-tuple-element", "tuple", "bitcast"}
_CONTAINERS = {"while", "conditional", "call"}
# An HLO instruction's name and opcode.
_INSTRUCTION = re.compile(r"^\s+(?:ROOT )?%(\S+) = .*? ([a-z][\w-]*)\(", re.MULTILINE)


def equations(jaxpr) -> int:
    return sum(1 + sum(equations(sub) for sub in jaxprs_in_params(e.params)) for e in jaxpr.eqns)


def instructions(hlo_text: str) -> int:
    return len(_INSTRUCTION.findall(hlo_text))


def top_level_kernels(hlo_text: str) -> int:
    entry = hlo_text.split("\nENTRY ", 1)[1].split("\n}\n", 1)[0]
    return sum(op not in _NOT_KERNELS for _, op in _INSTRUCTION.findall(entry))


def split_kernels(hlo_text: str) -> int:
    """Kernels XLA splits between threads: those given a non-empty list of outer
    dimension partitions (other kernels may carry an empty one)."""
    return hlo_text.count('"outer_dimension_partitions":["')


def kernel_names(hlo_text: str) -> set[str]:
    """The instructions of a compiled program (`hlo_text`) that run as kernels of their
    own: loops and conditionals, which launch their bodies, excluded."""
    instructions = _INSTRUCTION.findall(hlo_text)
    return {name for name, op in instructions if op not in _NOT_KERNELS | _CONTAINERS}


def profiled_events(compiled, scene, cameras, calls: int = 20, warm: int = 1):
    """Every event (name, start ns, duration ns) of the JAX profiler's trace of `calls`
    calls of `compiled`, after `warm` calls untraced."""
    for _ in range(warm):
        jax.block_until_ready(compiled(scene, cameras))
    with tempfile.TemporaryDirectory() as folder:
        with jax.profiler.trace(folder):
            for _ in range(calls):
                jax.block_until_ready(compiled(scene, cameras))
        (path,) = glob.glob(f"{folder}/**/*.xplane.pb", recursive=True)
        profile = ProfileData.from_file(path)
    lines = (line for plane in profile.planes for line in plane.lines)
    return [(e.name, e.start_ns, e.duration_ns) for line in lines for e in line.events]


def launches(compiled, hlo_text: str, scene, cameras, calls: int = 20) -> float:
    """Kernels launched per call: the profiler's events named after a kernel of the
    compiled program."""
    kernels = kernel_names(hlo_text)
    events = profiled_events(compiled, scene, cameras, calls)
    return sum(name in kernels for name, _, _ in events) / calls


def split(scene, cameras):
    start = time.perf_counter()
    traced = VALUE_AND_GRAD.trace(scene, cameras)
    traced_s = time.perf_counter()
    lowered = traced.lower()
    lowered_s = time.perf_counter()
    compiled = lowered.compile()
    compiled_s = time.perf_counter()
    hlo_text = compiled.as_text()
    return (
        traced_s - start,
        lowered_s - traced_s,
        compiled_s - lowered_s,
        equations(traced.jaxpr.jaxpr),
        instructions(hlo_text),
        top_level_kernels(hlo_text),
        launches(compiled, hlo_text, scene, cameras),
        split_kernels(hlo_text),
    )


def main():
    jax.jit(lambda x: x + 1)(1.0)  # JAX's own start-up is not the scene's compile time
    print(f"JAX {jax.__version__} on {jax.devices()[0].device_kind}, float64, value+grad")
    columns = [("scene", 8), ("k", 2), ("trace s", 8), ("lower s", 8), ("XLA s", 7)]
    columns += [("total s", 8), ("equations", 10), ("instructions", 13), ("kernels", 8)]
    columns += [("launches", 9)]
    columns += [("split", 6)]
    header, widths = zip(*columns)
    print_row(header, widths)
    for name, scene, cameras in cases(np.random.default_rng(0)):
        trace, lower, xla, eqns, size, kernels, launched, split_count = split(scene, cameras)
        cells = [name, cameras.shape[0], f"{trace:.2f}", f"{lower:.2f}", f"{xla:.2f}"]
        cells += [f"{trace + lower + xla:.1f}", eqns, size, kernels, f"{launched:.0f}"]
        cells += [split_count]
        print_row(cells, widths)


if __name__ == "__main__":
    main()
