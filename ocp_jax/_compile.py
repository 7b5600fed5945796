"""How ocp_jax's programs are compiled.

A value and gradient of Q is a program of a few hundred small kernels (microseconds each).
XLA's CPU runtime runs the kernels that do not depend on each other on different threads.
Its default schedule keeps many buffers live, so that many kernels are independent; its
memory-optimized schedule reuses buffers, which orders more kernels one after another.
For these programs the second is faster on two cores: handing small kernels between
threads costs more than running them in turn (benchmarks/compare_revisions.py
--xla-flags, README "Performance").
"""

import equinox as eqx


def compiler_options() -> dict[str, str]:
    """XLA compile options for programs that evaluate ocp_jax: the CPU backend's
    memory-optimized scheduler (other backends ignore the option).

    JAX takes compile options from the outermost `jax.jit` only (a nested jit with options
    is an error), so pass them to the one that wraps ocp_jax in your program:

        jax.jit(jax.value_and_grad(f), compiler_options=ocp.compiler_options())

    `ocp.optimize`, `ocp.greedy`, `ocp.exhaustive` and `ocp.slsqp` compile with them;
    `ocp.visibility` and `ocp.visible_intervals`, which run inside users' jits, cannot.
    """
    return {"xla_cpu_scheduler_type": "CPU_SCHEDULER_TYPE_MEMORY_OPTIMIZED"}


def jit(fun):
    """`equinox.filter_jit` with `compiler_options()`, for functions that are only ever
    called outside any jit."""
    return eqx.filter_jit(fun, compiler_options=compiler_options())
