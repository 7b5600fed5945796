"""The `ocp-jax` command line: `ocp-jax demo` evaluates the built-in scenes."""

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np

from . import scenes
from ._objectives import Foreshortened, VisibleLength
from ._visibility import visibility, visible_intervals

# (name, scene, cameras): cameras outside every object
DEMO_CASES = (
    ("banana", scenes.banana, [[50.0, 0.0]]),
    ("banana", scenes.banana, [[50.0, 0.0], [-50.0, 40.0]]),
    ("three_objects", scenes.three_objects, [[5.0, -1.5], [-3.0, 2.5]]),
)


def _both_objectives(scene, cameras):
    """(Q, dQ/dcameras) for VisibleLength and for Foreshortened."""
    objectives = (VisibleLength(), Foreshortened())
    return [jax.value_and_grad(visibility, 1)(scene, cameras, q) for q in objectives]


def demo() -> None:
    """Q and dQ/dcameras on built-in scenes, and what the first camera sees."""
    jax.config.update("jax_enable_x64", True)
    print(f"ocp_jax demo: JAX {jax.__version__} on {jax.default_backend()}, float64")
    fn = jax.jit(_both_objectives)
    for name, make, cameras in DEMO_CASES:
        scene, cameras = make(), jnp.asarray(cameras)
        start = time.perf_counter()
        jax.block_until_ready(fn(scene, cameras))
        compiled = time.perf_counter() - start
        start = time.perf_counter()
        results = jax.block_until_ready(fn(scene, cameras))
        run = time.perf_counter() - start
        print(
            f"\n{name}, cameras {cameras.tolist()}"
            f"  (compile {compiled:.1f} s, run {1e3 * run:.2f} ms)"
        )
        for objective, (value, grad) in zip(("VisibleLength", "Foreshortened"), results):
            grad = np.array2string(np.asarray(grad), precision=6, separator=", ").replace("\n", "")
            print(f"  {objective:14s} Q = {float(value):.10f}   dQ/dcameras = {grad}")
        seen = visible_intervals(scene, cameras)
        for c in range(cameras.shape[0]):
            arcs = [
                [(round(a, 4), round(b, 4)) for a, b in seen.to_list(c, i)]
                for i in range(len(scene))
            ]
            print(f"  camera {c} sees the parameter arcs {arcs}")


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(
        prog="ocp-jax", description="Optimal camera placement with exact visibility."
    )
    commands = parser.add_subparsers(dest="command")
    commands.add_parser("demo", help="evaluate Q and its gradient on built-in scenes")
    args = parser.parse_args(argv)
    if args.command in (None, "demo"):
        demo()
