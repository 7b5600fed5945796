"""The `ocp-jax` command line.

ocp-jax demo                              optimise 1 and 2 cameras on the banana
ocp-jax optimize PROBLEM.json --cameras K [--starts N] [--max-steps M] [--greedy]
                                          [--picture OUT.png]
ocp-jax example                           print the banana problem as JSON
"""

import argparse
import pathlib
import sys
import time

import jax
import matplotlib
import numpy as np

from . import scenes
from ._baselines import greedy
from ._objectives import Foreshortened
from ._optimize import optimize
from ._placement import RectangleBoundary
from ._problem_file import load_problem, problem_to_json


def _stage(message: str) -> float:
    print(message, flush=True)
    return time.perf_counter()


def _cameras(cameras) -> str:
    return np.array2string(np.asarray(cameras), precision=4, separator=", ").replace("\n", "")


def _run(scene, placement, objective, k, starts, max_steps, compare_greedy, progress):
    """Optimise k cameras (and greedy beside it); print what each found."""
    clock = _stage(
        f"\n{k} camera(s): multi-start BFGS from {starts} starts (compiles on first use)"
    )
    result = optimize(
        scene, objective, placement, k, n_starts=starts, max_steps=max_steps, progress=progress
    )
    converged = sum(s == "converged" for s in result.start_status)
    print(
        f"  Q = {float(result.value):.6f} at {_cameras(result.cameras)}; "
        f"{result.num_evaluations} evaluations, {converged}/{starts} starts converged, "
        f"{time.perf_counter() - clock:.1f} s in all"
    )
    if compare_greedy:
        clock = _stage(f"{k} camera(s): greedy search over the placement's candidate grid")
        baseline = greedy(scene, objective, placement, k)
        print(
            f"  Q = {float(baseline.value):.6f} at {_cameras(baseline.cameras)}; "
            f"{baseline.num_evaluations} evaluations, {time.perf_counter() - clock:.1f} s in all"
        )
        gain = float(result.value) / float(baseline.value) - 1
        print(f"  multi-start vs greedy: {100 * gain:+.4f} %")
    return result


def demo() -> None:
    """Optimise 1 and 2 cameras on the rectangle around the built-in banana, beside greedy."""
    jax.config.update("jax_enable_x64", True)
    print(f"ocp_jax demo: JAX {jax.__version__} on {jax.default_backend()}, float64")
    print("Scene: the banana (degree-18 closed Bezier); cameras on the 100 x 80 rectangle")
    print("around it; objective: foreshortened visible length (Eq. 3.13, corrected).")
    scene, placement = scenes.banana(), RectangleBoundary(*scenes.BANANA_RECTANGLE)
    results = [_run(scene, placement, Foreshortened(), k, 16, 100, True, True) for k in (1, 2)]
    _picture(scene, placement, results[-1], pathlib.Path("ocp_jax_demo.png"))


def _picture(scene, placement, result, path: pathlib.Path) -> None:
    """What the optimised cameras see, written to `path`."""
    matplotlib.use("Agg")
    from . import plot

    ax = plot.plot_scene(scene, result.cameras, placement)
    k = result.cameras.shape[0]
    ax.set_title(f"{k} camera(s), Q = {float(result.value):.4f}")
    ax.figure.savefig(path, dpi=120, bbox_inches="tight")
    print(f"\nPicture of the {k}-camera placement: {path.resolve()}")


def optimize_file(args) -> None:
    jax.config.update("jax_enable_x64", True)
    try:
        problem = load_problem(args.problem)
    except (OSError, ValueError) as error:
        sys.exit(f"ocp-jax: {error}")
    print(
        f"{args.problem}: {len(problem.scene)} curve(s), {type(problem.placement).__name__}, "
        f"{type(problem.objective).__name__}"
    )
    try:
        result = _run(
            problem.scene,
            problem.placement,
            problem.objective,
            args.cameras,
            args.starts,
            args.max_steps,
            args.greedy,
            True,
        )
    except ValueError as error:  # e.g. fewer cameras than the objective's groups
        sys.exit(f"ocp-jax: {error}")
    if args.picture:
        _picture(problem.scene, problem.placement, result, pathlib.Path(args.picture))


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(
        prog="ocp-jax", description="Optimal camera placement with exact visibility."
    )
    commands = parser.add_subparsers(dest="command")
    commands.add_parser("demo", help="optimise 1 and 2 cameras on the banana, beside greedy")
    run = commands.add_parser("optimize", help="optimise cameras for a JSON problem file")
    run.add_argument("problem", help="problem file (see `ocp-jax example` for the format)")
    run.add_argument("--cameras", type=int, default=1, help="number of cameras (default 1)")
    run.add_argument("--starts", type=int, default=16, help="random starts (default 16)")
    run.add_argument("--max-steps", type=int, default=100, help="BFGS steps per start")
    run.add_argument("--greedy", action="store_true", help="also run the greedy baseline")
    run.add_argument("--picture", metavar="PNG", help="write a picture of the result here")
    commands.add_parser("example", help="print the banana problem in the JSON form")
    args = parser.parse_args(argv)
    if args.command in (None, "demo"):
        demo()
    elif args.command == "optimize":
        if args.cameras < 1 or args.starts < 1 or args.max_steps < 1:
            parser.error("--cameras, --starts and --max-steps must be positive")
        optimize_file(args)
    else:
        placement = RectangleBoundary(*scenes.BANANA_RECTANGLE)
        print(problem_to_json(scenes.banana(), placement, Foreshortened()))
