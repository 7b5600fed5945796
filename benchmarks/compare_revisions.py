"""Speed of git revisions side by side, measured in turn so that outside load falls on all.

    python benchmarks/compare_revisions.py REV [REV ...] [--rounds 3] [--k 1] [--one-core]
        [--xla-flags FLAGS]
    python benchmarks/compare_revisions.py REV [REV ...] --paired [--calls 1000] [--k 1]

Each revision is checked out in a temporary git worktree and measured in a fresh process
(its `ocp_jax`; this checkout's evaluate.py: its rows with `--k` cameras, default 1, and
its batch), revision after revision, `--rounds` times. Prints per measurement the best
round of every revision and the range over rounds. On a machine whose speed drifts
between runs, only such interleaved comparisons tell a change from the drift;
evaluate.py gives the absolute figures on a quiet machine.

With --one-core every revision is also measured in a process pinned to one CPU core
(Linux's sched_setaffinity, as `taskset -c 0` does). XLA's CPU runtime sizes its thread
pool by the cores it may use: on several, it runs the independent kernels of a program
on different threads and splits its largest kernels between them; on one, it runs every
kernel in turn, with no hand-over between threads.

With --paired the revisions' programs run in one process, call by call in turn: each
revision compiles its rows' Q and value+grad and the batch in a process of its own and
hands them over as serialized executables (jax.experimental.serialize_executable), which
this process loads and times, one call of each revision after the other. The medians and
the median ratio of each call's time to the first revision's are far less disturbed by
the machine's drift than separate processes' times (a change of 5% shows). The programs
are compiled with EQX_ON_ERROR=nan (an error check is a host callback, which cannot be
serialized), and they take the scene's arrays as arguments, both sides alike.

With --xla-flags every revision is also measured with FLAGS appended to XLA_FLAGS, e.g.
--xla-flags=--xla_cpu_scheduler_type=CPU_SCHEDULER_TYPE_MEMORY_OPTIMIZED, the option of
`ocp.compiler_options()` for every program of the process.
"""

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
SCENES = ("circle", "banana", "blobs10")
BATCH = "banana batch of 1024, jit(vmap)"
# (label, unit, better): the measurements `measure` prints.
MEASUREMENTS = [
    (f"{name} {what}", unit, min)
    for name in SCENES
    for what, unit in (("Q", "us"), ("value+grad", "us"), ("value+grad compile", "s"))
] + [(BATCH, "/s", max)]


def measure(k: int) -> None:
    """Print the measurements of the `ocp_jax` on sys.path as one JSON line (evaluate.py's
    rows with k cameras and its batch)."""
    import jax
    import numpy as np

    sys.path.insert(0, HERE)
    from evaluate import banana_batch, cases, engine_times, ocp, timed

    values = {}
    for name, scene, cameras in cases(np.random.default_rng(0), quick=k == 1):
        if name in SCENES and cameras.shape[0] == k:
            compile_s, t_value, t_grad = engine_times(scene, cameras)
            values[f"{name} Q"] = 1e6 * t_value
            values[f"{name} value+grad"] = 1e6 * t_grad
            values[f"{name} value+grad compile"] = compile_s
    per_set, batch = banana_batch(np.random.default_rng(1))
    batched = jax.jit(jax.vmap(per_set))
    jax.block_until_ready(batched(batch))
    values[BATCH] = 1024 / timed(batched, batch, budget=2.0)
    print(json.dumps({"ocp_jax": ocp.__file__, **values}))


def serialize_programs(k: int) -> None:
    """Write to stdout, pickled, the compiled programs of the `ocp_jax` on sys.path (run
    with EQX_ON_ERROR=nan) with their arguments: Q and value+grad of evaluate.py's rows
    with k cameras, compiled as it recommends, and its batch."""
    import pickle

    import jax
    import jax.numpy as jnp
    import numpy as np
    from jax.experimental import serialize_executable

    sys.path.insert(0, HERE)
    from evaluate import banana_batch, cases, jit_options, ocp, value

    def entry(program, options, *args):
        compiled = jax.jit(program, **options).lower(*args).compile()
        return serialize_executable.serialize(compiled), jax.tree.map(np.asarray, args)

    programs = {}
    for name, scene, cameras in cases(np.random.default_rng(0), quick=k == 1):
        if name in SCENES and cameras.shape[0] == k:
            leaves, treedef = jax.tree.flatten(scene)
            leaves = [jnp.asarray(np.asarray(leaf)) for leaf in leaves]  # none weakly typed

            def q(leaves, cameras, treedef=treedef):
                return value(jax.tree.unflatten(treedef, leaves), cameras)

            programs[f"{name} Q"] = entry(q, jit_options(k), leaves, cameras)
            grad = jax.value_and_grad(q, 1)
            programs[f"{name} value+grad"] = entry(grad, jit_options(k), leaves, cameras)
    per_set, batch = banana_batch(np.random.default_rng(1))
    programs[BATCH] = entry(jax.vmap(per_set), {}, batch)
    sys.stdout.buffer.write(pickle.dumps((ocp.__file__, programs)))


def paired(trees: dict, k: int, calls: int) -> None:
    """Print, per program, each revision's median time per call and the median ratio of
    its calls to the first revision's, the revisions called in turn (see --paired)."""
    import pickle
    import statistics
    import time

    import jax
    from jax.experimental import serialize_executable

    jax.config.update("jax_enable_x64", True)
    loaded = {}
    for revision, tree in trees.items():
        out = run_in_tree(tree, "--serialize", k, {"EQX_ON_ERROR": "nan"})
        module, programs = pickle.loads(out)
        if not module.startswith(tree):
            raise RuntimeError(f"the programs were compiled from an ocp_jax outside {tree}")
        loaded[revision] = {
            label: (serialize_executable.deserialize_and_load(*executable), jax.device_put(args))
            for label, (executable, args) in programs.items()
        }
        print(f"{revision}: compiled and loaded", file=sys.stderr)
    first = next(iter(trees))
    width = max(12, *(len(r) for r in trees))
    print(
        f"calls in turn, rows with k = {k} cameras; each cell: median per call (us) or "
        f"throughput (/s), and the median ratio of its call times to {first}'s"
    )
    print(f"{'':34s}" + "".join(f"{r:>{width + 16}s}" for r in trees))
    for label in loaded[first]:
        n = max(10, calls // 50) if label == BATCH else calls
        times = {revision: [] for revision in trees}
        for _ in range(n):
            for revision, programs in loaded.items():
                program, args = programs[label]
                start = time.perf_counter()
                jax.block_until_ready(program(*args))
                times[revision].append(time.perf_counter() - start)
        cells = []
        for revision, measured in times.items():
            ratio = statistics.median(t / f for t, f in zip(measured, times[first]))
            median = statistics.median(measured)
            shown = f"{1024 / median:.0f} /s" if label == BATCH else f"{1e6 * median:.0f} us"
            cells.append(f"{shown} ({ratio:.3f})")
        print(f"{label:34s}" + "".join(f"{c:>{width + 16}s}" for c in cells), flush=True)


def run_in_tree(tree: str, mode: str, k: int, environment: dict, **options) -> bytes:
    """The output of this script in `mode` (--measure, --serialize) for k cameras, run on
    the checkout at `tree` in a fresh process (its `ocp_jax` first on the path)."""
    return subprocess.run(
        [sys.executable, os.path.abspath(__file__), mode, "--k", str(k)],
        cwd=tree,
        env=dict(os.environ, PYTHONPATH=tree, **environment),
        capture_output=True,
        check=True,
        **options,
    ).stdout


def pin_to_one_core() -> None:
    """Pins this process (a child, before it starts Python) to its first allowed core."""
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})


def run_revision(tree: str, one_core: bool, xla_flags: str, k: int) -> dict:
    """The measurements of the checkout at `tree`, from a fresh process (pinned to one
    core if `one_core`, with `xla_flags` appended to XLA_FLAGS)."""
    environment = {}
    if xla_flags:
        environment["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {xla_flags}".strip()
    pin = pin_to_one_core if one_core else None
    out = run_in_tree(tree, "--measure", k, environment, preexec_fn=pin).decode()
    values = json.loads(out.strip().splitlines()[-1])
    if not values.pop("ocp_jax").startswith(tree):
        raise RuntimeError(f"the measurement imported an ocp_jax outside {tree}")
    return values


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("revisions", nargs="*", help="git revisions (commits, branches)")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--k", type=int, choices=(1, 2, 4), default=1, help="cameras per row")
    parser.add_argument(
        "--one-core", action="store_true", help="also measure each revision on one core"
    )
    parser.add_argument(
        "--xla-flags", default="", help="also measure each revision with these XLA_FLAGS"
    )
    parser.add_argument(
        "--paired", action="store_true", help="time the revisions call by call in one process"
    )
    parser.add_argument("--calls", type=int, default=1000, help="calls per program (--paired)")
    parser.add_argument("--measure", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--serialize", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.measure:
        return measure(args.k)
    if args.serialize:
        return serialize_programs(args.k)
    if not args.revisions:
        parser.error("name at least one revision, e.g. HEAD~1 HEAD")
    if args.one_core and not hasattr(os, "sched_setaffinity"):
        parser.error(f"--one-core needs os.sched_setaffinity (Linux), which {sys.platform} lacks")
    repository = subprocess.run(
        ["git", "rev-parse", "--show-toplevel"],
        cwd=HERE,
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    git = ["git", "-C", repository]
    # a SIGTERM unwinds like Ctrl-C, so that the worktrees are removed either way
    signal.signal(signal.SIGTERM, lambda *_: sys.exit("compare_revisions: terminated"))
    with tempfile.TemporaryDirectory() as scratch:
        trees = {}
        try:
            for revision in args.revisions:
                tree = os.path.realpath(os.path.join(scratch, f"tree{len(trees)}"))
                subprocess.run(
                    git + ["worktree", "add", "--detach", "-q", tree, revision], check=True
                )
                trees[revision] = tree
            if args.paired:
                return paired(trees, args.k, args.calls)
            # (column, worktree, pinned to one core, added XLA flags)
            settings = [("", False, "")]
            if args.one_core:
                settings.append((" 1 core", True, ""))
            if args.xla_flags:
                settings.append((" +flags", False, args.xla_flags))
            columns = [
                (revision + suffix, tree, one_core, flags)
                for suffix, one_core, flags in settings
                for revision, tree in trees.items()
            ]
            rounds = {column: [] for column, *_ in columns}
            for i in range(args.rounds):
                for column, *setting in columns:
                    rounds[column].append(run_revision(*setting, args.k))
                    print(f"round {i + 1}/{args.rounds}: {column} measured", file=sys.stderr)
        finally:
            for tree in trees.values():
                subprocess.run(git + ["worktree", "remove", "--force", tree], check=False)

    width = max(12, *(len(c) for c in rounds))
    print(
        f"{args.rounds} interleaved rounds, rows with k = {args.k} cameras; "
        "each cell: best round (range over rounds)"
    )
    if args.xla_flags:
        print(f"+flags: XLA_FLAGS {args.xla_flags}")
    print(f"{'':34s}" + "".join(f"{c:>{width + 16}s}" for c in rounds))
    for label, unit, better in MEASUREMENTS:
        digits = 1 if unit == "s" else 0
        cells = []
        for measured in rounds.values():
            values = [r[label] for r in measured]
            cells.append(
                f"{better(values):.{digits}f} ({min(values):.{digits}f}-{max(values):.{digits}f})"
            )
        print(f"{label + ' ' + unit:34s}" + "".join(f"{c:>{width + 16}s}" for c in cells))


if __name__ == "__main__":
    main()
