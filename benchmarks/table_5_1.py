"""The thesis's Table 5.1 on our banana scene, reproduced and extended.

    python benchmarks/table_5_1.py [--quick]

Cameras on the 100 x 80 rectangle around the banana (Sec. 5.1.1), Foreshortened Q,
float64. Rows per number of cameras k: greedy (128 candidates per edge, as the thesis);
exhaustive search over the same 512 candidates (k <= 2: the best discrete answer); BFGS
from one start near each corner (the thesis's gradient rows) and those four starts
batched; scipy SLSQP from the same four starts (the thesis's pipeline); batched
multi-start BFGS from 16 and 64 random starts. Columns: value-and-gradient or value
evaluations, wall time after compilation, Q, and Q as a fraction of the best found by
any method. Then the anytime curves of the multi-start runs and the time at which each
first matches greedy's Q. `--quick`: k = 1, 2 only.
"""

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)

import ocp_jax as ocp  # noqa: E402
from ocp_jax import scenes  # noqa: E402

SCENE = scenes.banana()
PLACEMENT = ocp.RectangleBoundary(*scenes.BANANA_RECTANGLE)
OBJECTIVE = ocp.Foreshortened()
MATCH = 1e-6  # "matches greedy": within this relative tolerance


def warm(solver, k: int):
    """Place k cameras once to compile, then again to time: the second solution."""
    ocp.place(SCENE, OBJECTIVE, PLACEMENT, k, solver=solver)
    start = time.perf_counter()
    solution = ocp.place(SCENE, OBJECTIVE, PLACEMENT, k, solver=solver)
    return solution, time.perf_counter() - start


def corner_starts(k: int) -> jnp.ndarray:
    """Four starts; start j puts camera i just past corner (j + i) mod 4 (2% along)."""
    corners = np.array([0.0, 100.0, 180.0, 280.0]) / 360.0
    s = [[corners[(j + i) % 4] + 0.02 for i in range(k)] for j in range(4)]
    return jnp.asarray(s)[..., None]


def rows_for(k: int):
    rows = []  # (method, evaluations, seconds, Q)
    greedy, t = warm(ocp.Greedy(), k)
    rows.append(("greedy (512 candidates)", greedy.num_evaluations, t, float(greedy.value)))
    if k <= 2:
        full, t = warm(ocp.Exhaustive(), k) if k == 2 else (greedy, t)
        rows.append(("exhaustive (512 candidates)", full.num_evaluations, t, float(full.value)))
    corners, t = warm(ocp.MultiStart(starts=corner_starts(k)), k)
    for j in range(4):
        rows.append(
            (
                f"BFGS, 1 start near corner {j}",
                int(corners.num_steps[j]),
                None,
                float(corners.start_values[j]),
            )
        )
    rows.append(
        ("BFGS, the 4 corner starts batched", corners.num_evaluations, t, float(corners.value))
    )
    slsqp, t = warm(ocp.SLSQP(starts=corner_starts(k)), k)
    rows.append(
        ("SLSQP (scipy), the 4 corner starts", slsqp.num_evaluations, t, float(slsqp.value))
    )
    multi = {}
    for n in (16, 64):
        multi[n], t = warm(ocp.MultiStart(n_starts=n), k)
        rows.append(
            (f"BFGS multi-start, {n} starts", multi[n].num_evaluations, t, float(multi[n].value))
        )
    return rows, greedy, multi


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="k = 1, 2 only")
    args = parser.parse_args()
    print(f"JAX {jax.__version__} on {jax.devices()[0].device_kind}, float64, Foreshortened")
    print("Banana scene, cameras on the 100 x 80 rectangle centred at (0, 20).\n")
    header = f"{'k':>2}  {'method':38s} {'evaluations':>11} {'seconds':>8} {'Q':>12} {'Q/best':>8}"
    curves = {}
    for k in (1, 2) if args.quick else (1, 2, 3, 4):
        rows, greedy, multi = rows_for(k)
        best = max(q for *_, q in rows)
        print(header)
        for method, evaluations, seconds, q in rows:
            time_cell = "-" if seconds is None else f"{seconds:.3f}"
            print(
                f"{k:>2}  {method:38s} {evaluations:>11} {time_cell:>8} {q:12.6f} {q / best:8.6f}"
            )
        print()
        curves[k] = (greedy, multi)

    print("Anytime curves of the multi-start runs (best Q so far after s seconds / n evaluations):")
    for k, (greedy, multi) in curves.items():
        for n, result in multi.items():
            history = np.asarray(result.history)
            picks = np.unique(np.linspace(0, len(history) - 1, 6).round().astype(int))
            cells = ", ".join(f"{h[0]:.3f}s/{int(h[1])}: {h[2]:.4f}" for h in history[picks])
            print(f"  k={k}, {n} starts: {cells}")
            hit = np.nonzero(history[:, 2] >= float(greedy.value) * (1 - MATCH))[0]
            if len(hit):
                s, ev, _ = history[hit[0]]
                print(
                    f"      matches greedy's Q (to {MATCH:g}) after {s:.3f} s, "
                    f"{int(ev)} evaluations"
                )
            else:
                print(f"      never matches greedy's Q (to {MATCH:g})")
        print(
            f"      greedy: Q {float(greedy.value):.6f} in {greedy.seconds:.3f} s, "
            f"{greedy.num_evaluations} evaluations"
        )


if __name__ == "__main__":
    main()
