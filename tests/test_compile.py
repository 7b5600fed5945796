"""ocp_jax compiles its programs with `ocp.compiler_options()`, and XLA applies them."""

import functools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ocp_jax as ocp
from ocp_jax import scenes
from ocp_jax._visibility.xla_cpu import SMALL_BATCH, computed_on_one_thread, jit


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


def _split_kernels(compiled) -> int:
    """Kernels XLA's CPU backend splits between threads: those given a non-empty list of
    partitions."""
    return compiled.as_text().count('"outer_dimension_partitions":["')


def _polynomial(t, p):
    """A kernel XLA judges worth two threads: a polynomial of degree 60 at 2048 points."""
    return functools.reduce(lambda acc, i: acc * t + p[i % 7], range(60), jnp.zeros_like(t))


_T, _P = jnp.linspace(0.0, 1.0, 2048).reshape(4, 32, 16), jnp.linspace(-1.0, 1.0, 7)


@functools.cache
def _plain_polynomial():
    """The polynomial compiled as it is: split between threads, except in a process on
    one core, where XLA splits nothing and the tests below cannot fail (they skip)."""
    plain = jax.jit(_polynomial).lower(_T, _P).compile()
    if _split_kernels(plain) == 0:
        pytest.skip("XLA splits no kernel in a process with one core")
    return plain


def test_computed_on_one_thread_is_not_split_between_threads():
    t, p, plain = _T, _P, _plain_polynomial()
    once = lambda t, p: computed_on_one_thread(_polynomial, (t, p), p)
    compiled = jax.jit(once).lower(t, p).compile()
    assert _split_kernels(compiled) == 0
    np.testing.assert_array_equal(compiled(t, p), plain(t, p))
    # a vmap over up to SMALL_BATCH elements (the cameras of a call) keeps it on one
    # thread; over more (a batch of camera sets) the kernel is larger and split as XLA
    # sees fit
    for size, split in ((1, False), (SMALL_BATCH, False), (SMALL_BATCH + 1, True)):
        batch = t[None] * jnp.arange(1.0, size + 1.0)[:, None, None, None]
        batched = jax.jit(jax.vmap(once, (0, None))).lower(batch, p).compile()
        assert (_split_kernels(batched) > 0) == split
        np.testing.assert_array_equal(batched(batch, p), jax.vmap(_polynomial, (0, None))(batch, p))


def test_a_banana_call_with_one_camera_has_no_split_kernel():
    """The call the README's speed table times: none of its kernels is split between
    threads, whose hand-over costs more than the halved work (benchmarks/HISTORY.md)."""
    _plain_polynomial()
    banana, camera = scenes.banana(), jnp.array([[1.3, 0.4]])
    value = lambda c: ocp.visibility(banana, c, ocp.Foreshortened())
    for program in (value, jax.value_and_grad(value)):
        compiled = jax.jit(program, compiler_options=ocp.compiler_options()).lower(camera)
        assert _split_kernels(compiled.compile()) == 0
