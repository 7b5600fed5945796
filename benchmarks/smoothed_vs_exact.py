"""The smoothed visibility of Chapter 6 against the exact engine.

    python benchmarks/smoothed_vs_exact.py [--quick]

Three tables, float64, on this machine's CPU:

1. Convergence: smoothed Q - exact Q as the width w halves, on a unit circle seen from
   (3, 0) (convex, no occluders; exact: 2 acos(1/3), and the exact engine's foreshortened
   Q, equal to its closed form to 1e-12 in the tests) and on the three-object scene with
   two cameras (occlusions), with the observed rate log2(err(w) / err(w / 2)).
2. Cost: value-and-gradient time after compilation, exact engine against the smoothed
   one at several node counts, on the banana (k = 1) and 10 blobs (k = 2).
3. Continuation: from the same starts, (a) BFGS on the exact Q alone and (b) BFGS on the
   smoothed Q at w = 0.1, then 0.03, then the exact Q, with the same total number of
   steps; on the banana (2 cameras on the thesis's rectangle) and among 10 blobs (2
   cameras in the free space between them). Every start's final exact Q is compared.
"""

import argparse
import math
import time

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)

from evaluate import timed  # noqa: E402  (benchmarks/evaluate.py)

import ocp_jax as ocp  # noqa: E402
from ocp_jax import scenes  # noqa: E402


def convergence(quick: bool):
    print("1. Convergence of the smoothed Q as the width w -> 0")
    widths = [0.2, 0.1, 0.05, 0.025, 0.0125] + ([] if quick else [0.00625])
    cases = [
        (
            "circle (3,0) VisibleLength",
            ocp.Scene([ocp.Circle(jnp.zeros(2), 1.0)]),
            jnp.array([[3.0, 0.0]]),
            ocp.VisibleLength(),
            2 * math.acos(1 / 3),
            4096,
        ),
        (
            "circle (3,0) Foreshortened",
            ocp.Scene([ocp.Circle(jnp.zeros(2), 1.0)]),
            jnp.array([[3.0, 0.0]]),
            ocp.Foreshortened(),
            None,
            4096,
        ),
        (
            "three objects, 2 cameras, Foreshortened",
            scenes.three_objects(),
            jnp.array([[3.1, 0.2], [-3.0, -2.8]]),
            ocp.Foreshortened(),
            None,
            1024,
        ),
    ]
    print(f"{'case':42s} {'nodes':>6s} " + " ".join(f"{'w=' + str(w):>10s}" for w in widths))
    for name, scene, cameras, objective, exact, nodes in cases:
        if exact is None:
            exact = float(ocp.visibility(scene, cameras, objective))
        value = jax.jit(
            lambda w, s=scene, c=cameras, q=objective, n=nodes: ocp.visibility(
                s, c, ocp.Smoothed(q, w, nodes=n)
            )
        )
        errors = [float(value(jnp.asarray(w))) - exact for w in widths]
        print(f"{name:42s} {nodes:6d} " + " ".join(f"{e:10.2e}" for e in errors))
        rates = [math.log2(abs(a / b)) for a, b in zip(errors, errors[1:])]
        print(
            f"{'  rate log2(err(w)/err(w/2))':42s} {'':6s} {'':10s} "
            + " ".join(f"{r:10.2f}" for r in rates)
        )
    print()


def cost(quick: bool):
    print("2. Cost of value and gradient after compilation (median of >= 5 calls, >= 0.5 s)")
    cases = [
        ("banana, k=1", scenes.banana(), jnp.array([[50.0, 0.0]])),
        ("10 blobs, k=2", scenes.blobs(10), jnp.array([[-2.5, 3.0], [11.5, 4.0]])),
    ]
    node_counts = [64, 128, 256] + ([] if quick else [512])
    print(f"{'scene':16s} {'exact':>10s} " + " ".join(f"{'N=' + str(n):>10s}" for n in node_counts))
    for name, scene, cameras in cases:
        row = []
        for objective in [ocp.Foreshortened()] + [
            ocp.Smoothed(ocp.Foreshortened(), 0.02, nodes=n) for n in node_counts
        ]:
            fn = jax.jit(jax.value_and_grad(lambda c, q=objective: ocp.visibility(scene, c, q)))
            row.append(timed(fn, cameras, repeats=1))
        print(f"{name:16s} " + " ".join(f"{1e3 * t:8.2f}ms" for t in row))
    print()


def continuation(quick: bool):
    print("3. Continuation (smoothed w = 0.1 -> 0.03 -> exact) against the exact Q alone,")
    print("   same starts, same total steps; final exact Q of every start")
    n_starts = 8 if quick else 16
    stage_steps = 20 if quick else 40
    blob_scene = scenes.blobs(10)
    problems = [
        (
            "banana, 2 cameras",
            scenes.banana(),
            ocp.RectangleBoundary(*scenes.BANANA_RECTANGLE),
            256,
        ),
        (
            "10 blobs, 2 cameras",
            blob_scene,
            ocp.Region(jnp.array([-3.0, -3.0]), jnp.array([12.0, 9.0]), clearance=0.3),
            64,
        ),
    ]
    print(
        f"{'problem':20s} {'method':28s} {'best Q':>10s} {'median':>10s} {'mean':>10s} "
        f"{'>= 99.9% best':>14s} {'evals':>6s} {'seconds':>8s}"
    )
    for name, scene, placement, nodes in problems:
        starts = placement.sample(jax.random.key(0), 2, n_starts)
        exact = ocp.Foreshortened()
        clock = time.perf_counter()
        solver = ocp.MultiStart(starts=starts, max_steps=3 * stage_steps)
        alone = ocp.place(scene, exact, placement, 2, solver=solver)
        alone_seconds = time.perf_counter() - clock
        clock = time.perf_counter()
        params, evaluations = starts, 0
        for width in (0.1, 0.03):
            smooth = ocp.Smoothed(exact, width, nodes=nodes)
            solver = ocp.MultiStart(starts=params, max_steps=stage_steps)
            stage = ocp.place(scene, smooth, placement, 2, solver=solver)
            params, evaluations = stage.paths[-1], evaluations + stage.num_evaluations
        solver = ocp.MultiStart(starts=params, max_steps=stage_steps)
        final = ocp.place(scene, exact, placement, 2, solver=solver)
        continued_seconds = time.perf_counter() - clock
        evaluations += final.num_evaluations
        values = {
            "exact alone": (np.asarray(alone.start_values), alone.num_evaluations, alone_seconds),
            "continuation -> exact": (
                np.asarray(final.start_values),
                evaluations,
                continued_seconds,
            ),
        }
        best = max(np.nanmax(np.where(np.isfinite(v), v, np.nan)) for v, _, _ in values.values())
        for method, (v, count, seconds) in values.items():
            finite = v[np.isfinite(v)]
            share = np.mean(v >= best * (1 - 1e-3))
            print(
                f"{name:20s} {method:28s} {finite.max():10.5f} {np.median(finite):10.5f} "
                f"{finite.mean():10.5f} {share:14.0%} {count:6d} {seconds:8.1f}"
            )
    print("(seconds include the compilation of each objective's optimiser)")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer widths, nodes and starts")
    args = parser.parse_args()
    print(f"JAX {jax.__version__} on {jax.default_backend()}, float64\n")
    convergence(args.quick)
    cost(args.quick)
    continuation(args.quick)


if __name__ == "__main__":
    main()
