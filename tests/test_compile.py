"""ocp_jax compiles its programs with `ocp.compiler_options()`, and XLA applies them."""

import math

import equinox as eqx
import jax
import jax.numpy as jnp

import ocp_jax as ocp
from ocp_jax._compile import jit


def _independent_kernels(x):
    """Kernels that do not depend on each other, which the two schedules order apart."""
    return jnp.sum(jnp.sin(x)) + jnp.max(jnp.cos(x)) + jnp.min(jnp.exp(x)) + jnp.sort(x)[3]


def _program(compiled) -> list[str]:
    """The compiled program's instructions in their scheduled order (equinox's wrapper of
    jax's Compiled; without the metadata, which names the caller's source lines)."""
    text = compiled.compiled.as_text()
    return [line.split(", metadata=")[0] for line in text.splitlines() if " = " in line]


def test_options_reach_xla_and_the_librarys_jit():
    x = jnp.linspace(0.0, 1.0, 100)
    default = _program(eqx.filter_jit(_independent_kernels).lower(x).compile())
    with_options = eqx.filter_jit(_independent_kernels).lower(x).compile(ocp.compiler_options())
    # XLA knows the option (an unknown one raises) and it changes the compiled schedule.
    assert _program(with_options) != default
    assert _program(jit(_independent_kernels).lower(x).compile()) == _program(with_options)
    # A user's jax.jit takes them as well.
    user = jax.jit(_independent_kernels, compiler_options=ocp.compiler_options())
    assert abs(float(user(x)) - float(_independent_kernels(x))) <= 1e-12


def test_visibility_under_a_jit_with_the_options():
    """The documented use: ocp.visibility inside a user's jit that has the options. A
    circle of radius r seen from distance d shows the arc 2 r acos(r / d)."""
    circle = ocp.Scene([ocp.Circle(jnp.array([0.0, 0.0]), 1.5)])
    value_and_grad = jax.jit(
        jax.value_and_grad(lambda c: ocp.visibility(circle, c, ocp.VisibleLength())),
        compiler_options=ocp.compiler_options(),
    )
    value, grad = value_and_grad(jnp.array([[4.0, 0.0]]))
    assert abs(float(value) - 2 * 1.5 * math.acos(1.5 / 4.0)) <= 1e-12
    # d/dd of 2 r acos(r / d) = 2 r^2 / (d sqrt(d^2 - r^2)), along the line to the centre
    slope = 2 * 1.5**2 / (4.0 * math.sqrt(4.0**2 - 1.5**2))
    assert abs(float(grad[0, 0]) - slope) <= 1e-10 and abs(float(grad[0, 1])) <= 1e-12
