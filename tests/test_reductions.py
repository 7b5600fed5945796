"""`fused_reduce` gives jnp's reductions, in one kernel on XLA's CPU backend, and
`sorted_rows` jnp.sort from two of them."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ocp_jax._visibility.xla_cpu import fused_reduce, sorted_rows

SHAPES_AND_AXES = [
    ((37,), -1),  # odd, folded onto itself (max, min, any, all) or padded (sum)
    ((3, 36), -1),
    ((3, 36), None),
    ((2, 5, 33), (-1, -2)),
    ((2, 5, 33), 0),
    ((4, 7), -1),  # short: no fold
    ((2, 3, 130), 2),  # two folds
]


@pytest.mark.parametrize("shape, axis", SHAPES_AND_AXES)
@pytest.mark.parametrize("reduction", [jnp.sum, jnp.max, jnp.min])
def test_numbers_match_jnp(shape, axis, reduction):
    x = jnp.asarray(np.random.default_rng(len(shape)).normal(size=shape))
    expected = reduction(x, axis=axis)
    got = fused_reduce(reduction, x, axis)
    assert got.shape == expected.shape
    np.testing.assert_allclose(got, expected, rtol=1e-13, atol=1e-13)


@pytest.mark.parametrize("shape, axis", SHAPES_AND_AXES)
@pytest.mark.parametrize("reduction, density", [(jnp.any, 0.03), (jnp.all, 0.97), (jnp.sum, 0.5)])
def test_booleans_match_jnp(shape, axis, reduction, density):
    """Masks sparse (any) or dense (all) enough that the results differ between rows;
    a sum of booleans counts them (its fold adds, not ors) in jnp.sum's integer dtype."""
    x = jnp.asarray(np.random.default_rng(1).uniform(size=shape) < density)
    expected = reduction(x, axis=axis)
    got = fused_reduce(reduction, x, axis)
    assert got.dtype == expected.dtype
    np.testing.assert_array_equal(got, expected)


@pytest.mark.parametrize("n", [7, 32, 33, 36, 37, 130])
def test_every_entry_reaches_the_result(n):
    """One entry that decides the result, at every position of the axis (the odd last
    entry and the overlap of idempotent folds included): any of a single True, all of a
    single False, the max and min of a single extreme, the sum of a single one."""
    # Row 0 holds no decisive entry, row 1 + p one at position p.
    hot = jnp.concatenate([jnp.zeros((1, n), bool), jnp.eye(n, dtype=bool)])
    spike = hot.astype(float)
    found = [0.0] + [1.0] * n
    assert fused_reduce(jnp.any, hot).tolist() == [False] + [True] * n
    assert fused_reduce(jnp.all, ~hot).tolist() == [True] + [False] * n
    assert fused_reduce(jnp.max, spike).tolist() == found
    assert fused_reduce(jnp.min, -spike).tolist() == [-v for v in found]
    assert fused_reduce(jnp.sum, spike).tolist() == found


def test_a_long_reduction_is_not_split():
    """jnp.max over 37 entries compiles to a windowed reduction and a reduction of its
    windows on XLA's CPU backend; the folded one to one reduction, fused with the
    elementwise work before it."""

    def hlo(fn):
        return jax.jit(fn).lower(jnp.ones((13, 37))).compile().as_text()

    assert "reduce-window(" in hlo(lambda x: jnp.max(jnp.sin(x), -1))
    folded = hlo(lambda x: fused_reduce(jnp.max, jnp.sin(x)))
    assert "reduce-window(" not in folded and folded.count(" fusion(") == 1


SORT_SHAPES = [(1,), (2,), (25,), (3, 44), (2, 4, 25), (2, 64)]  # all sorted by counting


@pytest.mark.parametrize("shape", SORT_SHAPES)
def test_sorted_rows_is_jnp_sort(shape):
    """Values and derivatives of jnp.sort, ties in jnp.sort's (stable) order: events
    padded with t = 1, repeated values, and -0.0 beside 0.0."""
    rng = np.random.default_rng(len(shape))
    x = rng.choice(np.array([-0.0, 0.0, 0.25, 1.0]), size=shape)
    x = np.where(rng.uniform(size=shape) < 0.5, rng.uniform(-1.0, 1.0, size=shape), x)
    x = jnp.asarray(x)
    np.testing.assert_array_equal(sorted_rows(x), jnp.sort(x, axis=-1))
    for jacobian in (jax.jacfwd, jax.jacrev):
        np.testing.assert_array_equal(
            jacobian(sorted_rows)(x), jacobian(lambda a: jnp.sort(a, axis=-1))(x)
        )


def test_short_rows_are_sorted_without_a_sort():
    """XLA's CPU sort is a kernel of its own that calls a comparator per comparison; the
    counts of rows of up to 64 entries are two reductions, fused with the elementwise
    work around them. Longer rows keep the sort."""

    def hlo(fn, n):
        return jax.jit(fn).lower(jnp.ones((3, n))).compile().as_text()

    assert " sort(" in hlo(lambda x: jnp.sort(jnp.sin(x), axis=-1), 44)
    counted = hlo(lambda x: sorted_rows(jnp.sin(x)), 44)
    assert " sort(" not in counted and counted.count(" fusion(") <= 3
    assert " sort(" in hlo(lambda x: sorted_rows(jnp.sin(x)), 65)
