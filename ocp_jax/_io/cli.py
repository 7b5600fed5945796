"""The `ocp-jax` command line.

ocp-jax demo                              place 1 and 2 cameras on the banana
ocp-jax optimize PROBLEM.json --cameras K [--starts N] [--max-steps M] [--greedy]
                                          [--picture OUT.png]
ocp-jax example                           print the banana problem as JSON

Compiled programs are cached on disk (see `compilation_cache`), so a second run skips
most compilation. `--no-cache`, `--cache-dir DIR` or the environment variable
OCP_JAX_CACHE_DIR (a directory, or "off") change that.
"""

import argparse
import os
import pathlib
import sys
import time

import jax
import matplotlib
import numpy as np

from .. import scenes
from .._objectives.local import Foreshortened
from .._placement.placement import RectangleBoundary
from .._solvers.discrete import Greedy
from .._solvers.multistart import MultiStart
from .._solvers.place import place
from .._types import RESULTS
from .problem_file import load_problem, problem_to_json


def compilation_cache(directory: str | None) -> pathlib.Path | None:
    """Turn on JAX's persistent compilation cache in `directory` (None: the
    environment variable OCP_JAX_CACHE_DIR, else `$XDG_CACHE_HOME/ocp_jax/jax`, else
    `~/.cache/ocp_jax/jax`); "off" turns it off.

    **Returns:** the cache directory, or None when off.
    """
    chosen = directory or os.environ.get("OCP_JAX_CACHE_DIR")
    if chosen == "off":
        return None
    if chosen is None:
        base = os.environ.get("XDG_CACHE_HOME") or pathlib.Path.home() / ".cache"
        path = pathlib.Path(base) / "ocp_jax" / "jax"
    else:
        path = pathlib.Path(chosen).expanduser()
    path.mkdir(parents=True, exist_ok=True)
    jax.config.update("jax_compilation_cache_dir", str(path))
    # cache every program: most of ocp_jax's compile in seconds, not minutes
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return path


def _stage(message: str) -> float:
    print(message, flush=True)
    return time.perf_counter()


def _cameras(cameras) -> str:
    return np.array2string(np.asarray(cameras), precision=4, separator=", ").replace("\n", "")


def _run(scene, placement, objective, k, starts, max_steps, compare_greedy, progress):
    """Place k cameras (and greedy beside them); print what each found."""
    clock = _stage(
        f"\n{k} camera(s): multi-start BFGS from {starts} starts (compiles on first use)"
    )
    solution = place(
        scene,
        objective,
        placement,
        k,
        solver=MultiStart(n_starts=starts, max_steps=max_steps),
        progress=progress,
    )
    converged = int(np.sum(np.asarray(solution.start_results == RESULTS.successful)))
    print(
        f"  Q = {float(solution.value):.6f} at {_cameras(solution.cameras)}; "
        f"{solution.num_evaluations} evaluations, {converged}/{starts} starts converged, "
        f"{time.perf_counter() - clock:.1f} s in all"
    )
    if compare_greedy:
        clock = _stage(f"{k} camera(s): greedy search over the placement's candidate grid")
        baseline = place(scene, objective, placement, k, solver=Greedy())
        print(
            f"  Q = {float(baseline.value):.6f} at {_cameras(baseline.cameras)}; "
            f"{baseline.num_evaluations} evaluations, {time.perf_counter() - clock:.1f} s in all"
        )
        gain = float(solution.value) / float(baseline.value) - 1
        print(f"  multi-start vs greedy: {100 * gain:+.4f} %")
    return solution


def demo(args) -> None:
    """Place 1 and 2 cameras on the rectangle around the built-in banana, beside greedy."""
    print(f"ocp_jax demo: JAX {jax.__version__} on {jax.default_backend()}, float64")
    print("Scene: the banana (degree-18 closed Bezier); cameras on the 100 x 80 rectangle")
    print("around it; objective: foreshortened visible length (Eq. 3.13, corrected).")
    scene, placement = scenes.banana(), RectangleBoundary(*scenes.BANANA_RECTANGLE)
    results = [_run(scene, placement, Foreshortened(), k, 16, 100, True, True) for k in (1, 2)]
    _picture(scene, placement, results[-1], "foreshortened", pathlib.Path(args.picture))


def _picture(scene, placement, solution, objective: str, path: pathlib.Path) -> None:
    """What the placed cameras see, written to `path`."""
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .. import plot

    figure, ax = plt.subplots(figsize=(7, 5))
    plot.plot_scene(scene, solution.cameras, placement, ax=ax)
    k = solution.cameras.shape[0]
    ax.set_title(f"{k} camera(s): Q = {float(solution.value):.4f} ({objective})")
    figure.savefig(path, dpi=120, bbox_inches="tight")
    print(f"\nPicture of the {k}-camera placement: {path.resolve()}")


def optimize_file(args) -> None:
    problem = load_problem(args.problem)
    objective = type(problem.objective).__name__
    print(
        f"{args.problem}: {len(problem.scene)} curve(s), {type(problem.placement).__name__}, "
        f"{objective}"
    )
    solution = _run(
        problem.scene,
        problem.placement,
        problem.objective,
        args.cameras,
        args.starts,
        args.max_steps,
        args.greedy,
        True,
    )
    if args.picture:
        _picture(problem.scene, problem.placement, solution, objective, pathlib.Path(args.picture))


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="ocp-jax", description="Optimal camera placement with exact visibility."
    )
    parser.add_argument("--debug", action="store_true", help="show tracebacks of errors")
    parser.add_argument(
        "--cache-dir",
        metavar="DIR",
        help="where compiled programs are cached (default $OCP_JAX_CACHE_DIR, else "
        "$XDG_CACHE_HOME/ocp_jax/jax or ~/.cache/ocp_jax/jax)",
    )
    parser.add_argument(
        "--no-cache", action="store_true", help="do not cache compiled programs on disk"
    )
    commands = parser.add_subparsers(dest="command")
    demo = commands.add_parser("demo", help="place 1 and 2 cameras on the banana, beside greedy")
    demo.add_argument(
        "--picture", metavar="PNG", default="ocp_jax_demo.png", help="where to draw the result"
    )
    run = commands.add_parser("optimize", help="place cameras for a JSON problem file")
    run.add_argument("problem", help="problem file (see `ocp-jax example` for the format)")
    run.add_argument("--cameras", type=int, default=1, help="number of cameras (default 1)")
    run.add_argument("--starts", type=int, default=16, help="random starts (default 16)")
    run.add_argument("--max-steps", type=int, default=100, help="BFGS steps per start")
    run.add_argument("--greedy", action="store_true", help="also run the greedy baseline")
    run.add_argument("--picture", metavar="PNG", help="write a picture of the result here")
    commands.add_parser("example", help="print the banana problem in the JSON form")
    return parser


def main(argv=None) -> None:
    parser = _parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return
    if args.command == "optimize" and min(args.cameras, args.starts, args.max_steps) < 1:
        parser.error("--cameras, --starts and --max-steps must be positive")
    jax.config.update("jax_enable_x64", True)
    if not args.no_cache:
        compilation_cache(args.cache_dir)
    try:
        if args.command == "demo":
            demo(args)
        elif args.command == "optimize":
            optimize_file(args)
        else:
            placement = RectangleBoundary(*scenes.BANANA_RECTANGLE)
            print(problem_to_json(scenes.banana(), placement, Foreshortened()))
    except Exception as error:  # one line naming the cause; --debug for the traceback
        if args.debug:
            raise
        message = str(error).strip().splitlines()[0] if str(error).strip() else ""
        sys.exit(f"ocp-jax: {type(error).__name__}: {message}")
