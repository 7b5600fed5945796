"""Where value+grad of Foreshortened Q spends its time on a random floor: the compiled
program's operations, from a profiler trace, with their output shapes.

    python dev/profile_floor.py --cells 96 --cameras 16

The shapes name the step: (k, queries, occluders, ...) is the occlusion test,
(pairs, m, ...) the crossovers, (m, union) the union sort of `_value`, (k, m, slots)
a camera's event rows. Operations inside a while loop are timed as the loop.
"""

import argparse
import collections
import glob
import gzip
import json
import re
import tempfile
import time

import jax
from floor_program import value_and_grad_program


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cells", type=int, default=96)
    parser.add_argument("--cameras", type=int, default=16)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--top", type=int, default=30)
    args = parser.parse_args()

    fn, cameras, _ = value_and_grad_program("floor", args.cells, args.cameras, args.seed)
    compiled = fn.lower(cameras).compile()
    jax.block_until_ready(compiled(cameras))
    start = time.perf_counter()
    jax.block_until_ready(compiled(cameras))
    print(f"value+grad {1e3 * (time.perf_counter() - start):.1f} ms")

    shapes = {}
    for line in compiled.as_text().splitlines():
        found = re.match(r"\s*(?:ROOT )?%?([\w.\-]+) = (\S+)", line)
        if found:
            shapes[found.group(1)] = found.group(2)
    with tempfile.TemporaryDirectory() as folder:
        with jax.profiler.trace(folder, create_perfetto_trace=True):
            jax.block_until_ready(compiled(cameras))
        (path,) = glob.glob(f"{folder}/plugins/profile/*/perfetto_trace.json.gz")
        events = json.load(gzip.open(path))["traceEvents"]
    spent = collections.Counter()
    for event in events:
        if event.get("ph") == "X" and event["name"] in shapes:
            spent[event["name"]] += event.get("dur", 0)
    print(f"{'ms':>8}  operation                       output")
    for name, us in spent.most_common(args.top):
        print(f"{us / 1e3:8.2f}  {name[:30]:30s}  {shapes[name][:60]}")


if __name__ == "__main__":
    main()
