"""The speed-up over the NumPy reference, checked by a control revision on the same machine.

    python benchmarks/control_speedup.py [--control ac1a126] [--rows banana:1 circle:2 ...]

This VM's speed drifts, and the Python-bound reference and the compiled engine do not
always slow down alike (on the night to 2026-12-03 the reference took 2.5-2.8x its quiet
time, the engine 1.1-1.5x). So a speed-up measured on a loaded machine may flatter. Here
each row times the reference (tests/reference.py at evaluate.py's accuracy) and Q back
to back, each as its median over about 0.5 s, in five rounds, and prints the median of
the five ratios (and their range): for the current tree, compiled as evaluate.py
recommends, and for the control revision, compiled as it was then (a plain `jax.jit`).
Each runs in a process of its own, the control from a temporary git worktree (so the
timing is this script's own: the control's evaluate.py predates `paired_speed_up`).

The control ac1a126 is the engine of the quiet run of 2026-12-02 07:40 (benchmarks/
HISTORY.md), whose banana with one camera measured 77x there (72-84x paired in the slow
spells after it). Where the control's ratio matches that, the machine's state does not
distort this run's ratios.
"""

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROWS = [f"{scene}:{k}" for scene in ("circle", "banana", "blobs3", "blobs10") for k in (1, 2, 4)]


def measure(root: str, rows: list[str], rounds: int = 5, budget: float = 0.5):
    """In this process, with the package, benchmarks and tests of `root`: print each row's
    paired ratio of the reference's time to Q's."""
    sys.path[:0] = [root, os.path.join(root, "benchmarks"), os.path.join(root, "tests")]
    import evaluate as ev
    import jax
    import numpy as np
    from helpers import to_reference
    from reference import reference_visibility

    import ocp_jax as ocp

    def median_time(fn):
        times, start = [], time.perf_counter()
        while time.perf_counter() - start < budget:
            begin = time.perf_counter()
            fn()
            times.append(time.perf_counter() - begin)
        return statistics.median(times)

    def paired(scene, cameras, options) -> list[tuple[float, float]]:
        """(reference seconds, Q seconds) per round."""
        program = jax.jit(lambda s, c: ocp.visibility(s, c, ev.OBJECTIVE), **options)
        spec, positions = to_reference(scene), np.asarray(cameras)

        def engine():
            jax.block_until_ready(program(scene, cameras))

        def reference():
            reference_visibility(
                spec, positions, "foreshortened", ev.REFERENCE_GRID, ev.REFERENCE_TOL
            )

        for _ in range(100):
            engine()
        reference()
        return [(median_time(reference), median_time(engine)) for _ in range(rounds)]

    cases = {(name, c.shape[0]): (s, c) for name, s, c in ev.cases(np.random.default_rng(0))}
    for row in rows:
        name, k = row.split(":")
        options = getattr(ev, "jit_options", lambda k: {})(int(k))  # (none at old revisions)
        pairs = paired(*cases[name, int(k)], options)
        ratios = [r / e for r, e in pairs]
        jit = "opts" if options else "plain"
        print(
            f"{name:>8} {k:>2} {jit:>6} {1e3 * statistics.median(r for r, _ in pairs):10.2f}"
            f" {1e6 * statistics.median(e for _, e in pairs):10.0f}"
            f" {statistics.median(ratios):8.0f}x ({min(ratios):.0f}-{max(ratios):.0f})",
            flush=True,
        )


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--control", default="ac1a126")
    parser.add_argument("--rows", nargs="+", default=ROWS, help="scene:k, e.g. banana:1")
    parser.add_argument("--measure", help=argparse.SUPPRESS)  # (a tree, in a child process)
    args = parser.parse_args()
    if args.measure:
        return measure(args.measure, args.rows)
    git = ["git", "-C", os.path.dirname(HERE)]
    with tempfile.TemporaryDirectory() as scratch:
        control = os.path.join(scratch, "control")
        subprocess.run(
            git + ["worktree", "add", "--detach", "-q", control, args.control], check=True
        )
        try:
            print("scene:k rows; reference ms, Q us (medians of five rounds), paired speed-up")
            print("   scene  k    jit     ref ms       Q us  speed-up (range)")
            for label, root in (("this tree", os.path.dirname(HERE)), (args.control, control)):
                print(f"{label}:", flush=True)
                command = [sys.executable, __file__, "--measure", root, "--rows", *args.rows]
                subprocess.run(command, check=True, env={**os.environ, "PYTHONPATH": ""})
        finally:
            subprocess.run(git + ["worktree", "remove", "--force", control], check=False)


if __name__ == "__main__":
    main()
