"""How ocp_jax's programs are compiled.

A value and gradient of Q is a program of a few hundred small kernels (microseconds each).
XLA's CPU runtime runs the kernels that do not depend on each other on different threads.
Its default scheduler orders them so that many are independent; its memory-optimized
scheduler reuses buffers, which orders more of them one after another. On two cores the
second is faster for the programs of one camera and for vmapped batches of camera sets,
and about as fast for one set of several cameras, slower for the largest (10 blobs, 4
cameras): `python benchmarks/compiler_options.py`, README "Performance".
"""

import equinox as eqx


def compiler_options() -> dict[str, str]:
    """XLA compile options for programs that evaluate ocp_jax: the CPU backend's
    memory-optimized scheduler (a field of XLA's debug options, which every backend
    accepts and only the CPU compiler reads).

    JAX takes compile options from the outermost `jax.jit` only (a nested jit with options
    is an error), so pass them to the one that wraps ocp_jax in your program:

        jax.jit(jax.vmap(jax.value_and_grad(f)), compiler_options=ocp.compiler_options())

    The batched programs of `ocp.optimize`, `ocp.greedy` and `ocp.exhaustive` compile with
    them. `ocp.visibility` and `ocp.visible_intervals`, which run inside users' jits,
    cannot.
    """
    return {"xla_cpu_scheduler_type": "CPU_SCHEDULER_TYPE_MEMORY_OPTIMIZED"}


def jit(fun):
    """`equinox.filter_jit` with `compiler_options()`, for functions that are only ever
    called outside any jit."""
    return eqx.filter_jit(fun, compiler_options=compiler_options())
