"""`fused_reduce` gives jnp's reductions, in one kernel on XLA's CPU backend."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ocp_jax._reductions import fused_reduce

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
@pytest.mark.parametrize("reduction", [jnp.any, jnp.all, jnp.sum])
def test_booleans_match_jnp(shape, axis, reduction):
    """Including a sum of booleans, which counts them (their fold adds, not ors)."""
    x = jnp.asarray(np.random.default_rng(1).uniform(size=shape) < 0.9)
    expected = reduction(x, axis=axis)
    got = fused_reduce(reduction, x, axis)
    assert got.dtype == expected.dtype
    np.testing.assert_array_equal(got, expected)


def test_a_long_reduction_is_not_split():
    """jnp.max over 37 entries compiles to a windowed reduction and a reduction of its
    windows on XLA's CPU backend; the folded one to one reduction, fused with the
    elementwise work before it."""

    def hlo(fn):
        return jax.jit(fn).lower(jnp.ones((13, 37))).compile().as_text()

    assert "reduce-window(" in hlo(lambda x: jnp.max(jnp.sin(x), -1))
    folded = hlo(lambda x: fused_reduce(jnp.max, jnp.sin(x)))
    assert "reduce-window(" not in folded and folded.count(" fusion(") == 1
