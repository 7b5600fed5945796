"""When XLA's CPU runtime hands kernels to a second thread: a count per program.

    python benchmarks/thunk_splits.py [--rows circle banana] [--k 1 2 4]

XLA's CPU runtime runs a program's kernels (thunks) in dependency order from a FIFO queue
of ready ones. Whenever, after taking one, more than 8 others are ready (`kSplitThreshold`
of its `ThunkExecutor`), it hands half of the queue to a thread of its pool. On this 2-core
VM such a hand-over costs tens of microseconds (`runtime_trace.py`), as much as a small
program's kernels. A program runs on one thread when every buffer is at most 512 bytes or
it has at most 8 thunks; the benchmarks' programs have neither.

For Q and value+grad of every row of evaluate.py's table (float64, Foreshortened), compiled
by default and with `ocp.compiler_options()`, this prints the thunks of the top-level
program, its source thunks (ready at the start), the most thunks ready at once, and the
split points: the thunks after which more than 8 are ready, replaying the FIFO queue on
one thread (a model of the runtime, read from its execution graph, which XLA logs at
verbosity 6; loop bodies are programs of their own and not counted). The counts do not
depend on the machine's load.
"""

import argparse
import collections
import os
import re
import subprocess
import sys

_LOGGING = {"TF_CPP_MIN_LOG_LEVEL": "0", "TF_CPP_VMODULE": "thunk_executor=6"}
_THUNK = re.compile(r"thunk #(\d+): op_name=(\S+), kind=[\w-]+, dependencies=\[(.*?)\]")
_MARK = "thunk_splits.py row: "
SPLIT_THRESHOLD = 8  # ThunkExecutor: the ready queue is split when longer than this


def replay(graph: list[tuple[str, list[str]]]) -> tuple[int, int, int]:
    """(sources, most ready at once, split points) of one execution graph, a list of
    (thunk name, names of the thunks it depends on) in the program's order, run from a
    FIFO queue."""
    latest, waiting, unlocks = {}, [len(deps) for _, deps in graph], [[] for _ in graph]
    for i, (name, deps) in enumerate(graph):
        for d in deps:  # (a name may recur: a dependency is its latest thunk before i)
            unlocks[latest[d]].append(i)
        latest[name] = i
    ready = collections.deque(i for i, n in enumerate(waiting) if n == 0)
    sources, most, splits = len(ready), len(ready), 0
    while ready:
        i = ready.popleft()
        splits += len(ready) > SPLIT_THRESHOLD
        for j in unlocks[i]:
            waiting[j] -= 1
            if waiting[j] == 0:
                ready.append(j)
        most = max(most, len(ready))
    return sources, most, splits


def graphs(log: str) -> dict[str, list[tuple[str, list[str]]]]:
    """Per row marker of `log`, the largest execution graph XLA logged after it."""
    out, row, graph = {}, None, None
    for line in log.splitlines():
        if line.startswith(_MARK):
            row, graph = line[len(_MARK) :], None
        elif "ThunkExecutor execution graph" in line or "ThunkExecutor: #thunks=" in line:
            graph = []
        elif (match := _THUNK.search(line)) and graph is not None and row is not None:
            deps = [d.strip() for d in match.group(3).split(",") if d.strip()]
            graph.append((match.group(2), deps))
            if len(graph) > len(out.get(row, [])):
                out[row] = list(graph)
    return out


def compile_rows(rows, ks):
    """In a process with XLA's logging on: compile every program, each after a marker."""
    import jax  # noqa: F401  (imported after the logging variables are set)
    import numpy as np
    from evaluate import VALUE, VALUE_AND_GRAD, cases, ocp

    for name, scene, cameras in cases(np.random.default_rng(0)):
        if name not in rows or cameras.shape[0] not in ks:
            continue
        for program, fn in (("Q", VALUE), ("value+grad", VALUE_AND_GRAD)):
            lowered = fn.trace(scene, cameras).lower()
            for compiled_with, options in (("default", None), ("options", ocp.compiler_options())):
                print(
                    f"{_MARK}{name} {cameras.shape[0]} {program} {compiled_with}", file=sys.stderr
                )
                sys.stderr.flush()
                lowered.compile(compiler_options=options)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", nargs="+", default=["circle", "banana", "blobs3", "blobs10"])
    parser.add_argument("--k", nargs="+", type=int, default=[1, 2, 4])
    parser.add_argument("--compile", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.compile:
        compile_rows(args.rows, args.k)
        return
    command = [sys.executable, __file__, "--compile", "--rows", *args.rows, "--k"]
    command += [str(k) for k in args.k]
    log = subprocess.run(
        command, env={**os.environ, **_LOGGING}, stderr=subprocess.PIPE, text=True, check=True
    ).stderr
    found = graphs(log)
    widths = [8, 2, 11, 7, 8, 6, 12, 12]
    header = ["scene", "k", "program", "thunks", "sources", "ready", "splits dflt", "splits opts"]
    print("  ".join(h.rjust(w) for h, w in zip(header, widths)))
    for row in dict.fromkeys(r.rsplit(" ", 1)[0] for r in found):
        default, options = found[f"{row} default"], found.get(f"{row} options", [])
        sources, most, splits = replay(default)
        cells = [*row.split(" "), len(default), sources, most, splits, replay(options)[2]]
        print("  ".join(str(c).rjust(w) for c, w in zip(cells, widths)))


if __name__ == "__main__":
    main()
