"""The root finder: grid brackets, refinement and their derivatives."""

import functools
import math
import re

import helpers as H
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import VL, visible_length_of
from reference import reference_visibility

import ocp_jax as ocp
from ocp_jax._geometry.vec import Vec
from ocp_jax._visibility import roots as _roots
from ocp_jax._visibility.xla_cpu import computed_on_one_thread, materialize


# ===========================================================================
# the root finder
# ===========================================================================
def test_hermite_extremum_is_exact_for_cubics():
    # p(t) = (t - 0.2)(t - 0.9)(t + 1.5) on the cell [0, h]: its Hermite interpolant is p
    h = 1.0
    p = np.polynomial.Polynomial.fromroots([0.2, 0.9, -1.5])
    dp = p.deriv()
    s, value, turning = _roots.hermite_extremum(
        jnp.asarray(p(0.0)), jnp.asarray(p(h)), jnp.asarray(dp(0.0)), jnp.asarray(dp(h)), h
    )
    crit = [c.real for c in dp.roots() if 0 < c.real < h]
    assert len(crit) == 1 and bool(turning)
    assert abs(float(s) * h - crit[0]) < 1e-14
    assert abs(float(value) - p(crit[0])) < 1e-14
    # monotone on the cell: no split, the value is the right end
    s, value, turning = _roots.hermite_extremum(
        jnp.asarray(0.0), jnp.asarray(1.0), jnp.asarray(0.5), jnp.asarray(2.0), 1.0
    )
    assert not bool(turning) and float(s) == 1.0 and float(value) == 1.0


def _pair_function(t, a):
    """F(t) = (t - a)(t - a - 0.002) - 1e-7 t: two roots 0.002 apart (inside one cell)."""
    value = (t - a) * (t - a - 0.002) - 1e-7 * t
    slope = 2 * t - 2 * a - 0.002 - 1e-7
    return value, slope, jnp.ones_like(t)


@functools.partial(jax.jit, static_argnums=1)
def _pair_roots(a, budget):
    t = jnp.linspace(0.0, 1.0, 9)  # cells of 1/8
    values, slopes, _ = _pair_function(t, a)
    brackets = _roots.grid_brackets(t, values[None], slopes[None], budget)
    roots, valid, _ = _roots.solve_roots(_pair_function, a, brackets, 30, 1.0, False)
    return brackets, roots, valid


def test_grid_brackets_split_near_double_roots_and_count_them():
    brackets, roots, valid = _pair_roots(jnp.asarray(0.4), 4)
    assert int(brackets.count) == 2  # no sign change on the grid, yet two roots
    exact = np.sort(np.polynomial.Polynomial([0.4 * 0.402, -(0.802 + 1e-7), 1.0]).roots().real)
    got = np.sort(np.asarray(roots)[np.asarray(valid)])
    # (the roots are 0.002 apart: F' = +-0.002 there, so F's rounding moves them ~1e-14)
    np.testing.assert_allclose(got, exact, rtol=0, atol=1e-13)
    # a budget too small for the roots reports the true count
    small, _, _ = _pair_roots(jnp.asarray(0.4), 1)
    assert int(small.count) == 2 and np.asarray(small.candidate).sum() == 1


def _shallow_pair(t, c):
    """F(t) = u^2 - 1e-6 - 2 u^4, u = t - c: two roots 2e-3 apart that the cubic Hermite
    interpolant on cells of 1/8 does not show (it lies above F by 2 s^2 (1 - s)^2 / 8^4,
    over 1e-6 in most of a cell)."""
    u = t - c
    return u * u - 1e-6 - 2.0 * u**4, 2.0 * u - 8.0 * u**3, jnp.ones_like(t)


def _sharp_peak(t, c):
    """F(t) = 1e-4 - u^2 / (u^2 + w^2), u = t - c, w = 3e-3: a peak 40 times narrower than
    a cell of 1/8, far from any cubic there, with two roots 6e-5 apart."""
    u, w2 = t - c, 9e-6
    r = u * u + w2
    return 1e-4 - u * u / r, -2.0 * u * w2 / (r * r), jnp.ones_like(t)


DIP_CASES = {  # F, half the distance between its two roots
    "shallow quartic": (_shallow_pair, math.sqrt((1 - math.sqrt(1 - 8e-6)) / 4)),
    "sharp peak": (_sharp_peak, 3e-3 * math.sqrt(1e-4 / (1 - 1e-4))),
}


@functools.partial(jax.jit, static_argnums=(0, 2))
def _dip_pair_roots(fn, c, probed):
    t = jnp.linspace(0.0, 1.0, 9)
    values, slopes, _ = fn(t, c)
    probes = None
    if probed:
        probes = _roots.dip_probes(lambda t: fn(t, c)[:2], t, values[None], slopes[None])
    brackets = _roots.grid_brackets(t, values[None], slopes[None], 4, probes=probes)
    roots, valid, _ = _roots.solve_roots(fn, c, brackets, 30, 1.0, False)
    return brackets.count, roots, valid


@pytest.mark.parametrize("fraction", [0.2, 0.5, 0.85])
@pytest.mark.parametrize("case", DIP_CASES)
def test_dip_probes_reveal_a_pair_the_interpolant_misses(case, fraction):
    fn, half = DIP_CASES[case]
    c = jnp.asarray((3 + fraction) / 8)  # in the cell [3/8, 4/8]
    assert int(_dip_pair_roots(fn, c, False)[0]) == 0  # the interpolant alone misses it
    count, roots, valid = _dip_pair_roots(fn, c, True)
    assert int(count) == 2
    got = np.sort(np.asarray(roots)[np.asarray(valid)])
    np.testing.assert_allclose(got, [float(c) - half, float(c) + half], rtol=0, atol=1e-13)


def _cusp_cell(t, _):
    """On [0, 1): the cubic Hermite p with p(0) = 1, p'(0) = 0, p(1) = -0.01, p'(1) = 5,
    whose Newton steps from regula falsi leave the cell at its end; on [1, 2]: 1, a jump
    at the node 1 (the next piece of a curve with a corner)."""
    left = t < 1.0
    value = jnp.where(left, 1.0 - 8.03 * t**2 + 7.02 * t**3, 1.0)
    slope = jnp.where(left, -16.06 * t + 21.06 * t**2, 0.0)
    return value, slope, jnp.ones_like(t)


def test_a_bracket_ending_at_a_jump_finds_the_root_inside():
    t = jnp.asarray([0.0, 1.0, 2.0])
    right = (jnp.asarray([[1.0, 1.0, 1.0]]), jnp.asarray([[0.0, 0.0, 0.0]]))
    left = (jnp.asarray([[1.0, -0.01, 1.0]]), jnp.asarray([[0.0, 5.0, 0.0]]))
    brackets = _roots.grid_brackets(t, (right[0], left[0]), (right[1], left[1]), 2)
    assert int(brackets.count) == 1
    roots, valid, settled = _roots.solve_roots(_cusp_cell, None, brackets, 30, 1.0, False)
    exact = [r.real for r in np.roots([7.02, -8.03, 0.0, 1.0]) if 0 < r.real < 1 and not r.imag]
    got = np.asarray(roots)[np.asarray(valid)]
    assert bool(settled) and len(exact) == 1
    np.testing.assert_allclose(got, exact, rtol=0, atol=1e-14)


def test_materialize_is_the_identity_with_an_identity_derivative():
    tree = {
        "a": Vec(jnp.arange(3.0), jnp.arange(3.0) + 10),
        "b": jnp.ones((2, 3)),
        "c": jnp.arange(4),
        "d": Vec(jnp.arange(3.0) + 20, jnp.arange(3.0) + 30),
    }
    out = jax.jit(materialize)(tree, tree)
    for want, got in zip(jax.tree.leaves(tree), jax.tree.leaves(out)):
        assert got.dtype == want.dtype
        np.testing.assert_array_equal(got, want)
    x = jnp.array([0.5, -2.0])
    fn = lambda x: materialize(Vec(jnp.sin(x), x**2), x).y  # noqa: E731
    np.testing.assert_allclose(jax.jacfwd(fn)(x), np.diag(2 * np.asarray(x)), rtol=1e-15)
    np.testing.assert_allclose(jax.jacrev(fn)(x), np.diag(2 * np.asarray(x)), rtol=1e-15)


def test_computed_on_one_thread_is_fn_with_the_derivatives_of_fn():
    def fn(a, b):
        return Vec(jnp.sin(a) * b, a**2), a > b, jnp.arange(3) * 2

    a, b = jnp.array([0.5, -2.0, 1.0]), jnp.array(0.7)
    out = jax.jit(lambda a, b: computed_on_one_thread(fn, (a, b), a))(a, b)
    for want, got in zip(jax.tree.leaves(fn(a, b)), jax.tree.leaves(out)):
        assert got.dtype == want.dtype
        np.testing.assert_array_equal(got, want)
    once = lambda a, b: computed_on_one_thread(fn, (a, b), a)[0].x
    plain = lambda a, b: fn(a, b)[0].x
    for argnums in (0, 1, (0, 1)):
        for jac in (jax.jacfwd, jax.jacrev):
            for got, want in zip(
                jax.tree.leaves(jac(once, argnums)(a, b)),
                jax.tree.leaves(jac(plain, argnums)(a, b)),
            ):
                np.testing.assert_allclose(got, want, rtol=1e-15)
    # a tangent along b only: a is held (its tangent a symbolic zero), so y = a^2 has none
    _, dy = jax.jvp(lambda b: computed_on_one_thread(fn, (a, b), a)[0].y, (b,), (1.0,))
    np.testing.assert_array_equal(dy, 0.0)
    for batch in (a[None], jnp.stack([a, a + 1])):  # in place, and stored (a batch)
        np.testing.assert_array_equal(
            jax.vmap(lambda a: once(a, b))(batch), jax.vmap(lambda a: plain(a, b))(batch)
        )
        np.testing.assert_allclose(
            jax.vmap(jax.grad(lambda a: once(a, b).sum()))(batch),
            jax.vmap(jax.grad(lambda a: plain(a, b).sum()))(batch),
            rtol=1e-15,
        )
    # a NaN key skips the loop: NaN floats (not values computed from other inputs)
    key = a.at[0].set(jnp.nan)
    assert np.isnan(computed_on_one_thread(fn, (a, b), key)[0].x).all()


@pytest.mark.parametrize("size", [1, 5, 40])
def test_first_true_equals_numpy_nonzero(size):
    mask = np.random.default_rng(size).uniform(size=(3, 2, 40)) < [[[0.0]], [[0.1]], [[0.6]]]
    index, filled, count = _roots.first_true(jnp.asarray(mask), size)
    assert index.shape == filled.shape == (3, 2, size)
    rows = zip(
        mask.reshape(-1, 40), index.reshape(-1, size), filled.reshape(-1, size), count.ravel()
    )
    for row, got, got_filled, n in rows:
        want = np.nonzero(row)[0][:size]
        assert int(n) == row.sum()
        np.testing.assert_array_equal(got, np.pad(want, (0, size - want.size)))
        np.testing.assert_array_equal(got_filled, np.arange(size) < want.size)


@pytest.mark.parametrize("density", [0.0, 0.05, 0.5, 1.0])
@pytest.mark.parametrize("size", [7, 64, 1000])
def test_over_chunks_visits_every_true_entry_once(density, size):
    """`over_chunks` folds its step over exactly the True entries of the mask, each once,
    whether they fill several chunks, one, or none (a mask shorter than a chunk is one
    unpacked chunk, its False entries not live)."""
    mask = np.random.default_rng(size).random(300) < density

    def step(carry, index, live):
        return carry.at[jnp.where(live, index, 300)].add(1, mode="drop")

    visits = jax.jit(lambda m: _roots.over_chunks(m, size, step, jnp.zeros(300, int)))(mask)
    np.testing.assert_array_equal(np.asarray(visits), mask.astype(int))


def test_newton_in_brackets_takes_no_step_without_candidates():
    """F(t) = t - 0.3: one Newton step from any guess lands on the root. Slots move only
    where some slot of the batch element holds a candidate."""
    fn = lambda t, _: (t - 0.3, jnp.ones_like(t), jnp.ones_like(t))  # noqa: E731
    shape = (2, 3)
    candidate = jnp.array([[False, False, False], [False, True, False]])
    brackets = _roots.Brackets(
        lo=jnp.zeros(shape),
        hi=jnp.ones(shape),
        guess=jnp.full(shape, 0.5),
        sign_lo=-jnp.ones(shape),
        turning=jnp.zeros(shape, bool),
        curvature=jnp.ones(shape),
        candidate=candidate,
        source=jnp.zeros(shape, int),
        count=candidate.sum(1),
    )
    solve = jax.jit(jax.vmap(lambda b: _roots.newton_in_brackets(fn, None, b, 8)))
    t, valid, settled = solve(brackets)
    np.testing.assert_array_equal(settled, True)
    np.testing.assert_array_equal(t[0], 0.5)  # no candidate: no step
    np.testing.assert_allclose(t[1], 0.3, rtol=0, atol=1e-16)
    np.testing.assert_array_equal(valid, candidate)


def test_newton_in_brackets_stops_once_newtons_error_is_below_eps():
    """F(t) = exp(t) - 1.7 on cells of 1/8: the guess from the Hermite cubic is ~1e-7
    off, Newton's first step leaves ~1e-14, its second ~1e-27. After the second the
    predicted error (curvature d^2, curvature >= 8 here) is far below eps, so the root is
    final: F is evaluated in two steps and once for the validity check, with no third
    step only to see that the root no longer moves."""
    calls = []

    def fn(t, _):
        jax.debug.callback(calls.append, t)
        return jnp.exp(t) - 1.7, jnp.exp(t), jnp.exp(t) + 1.7

    t = jnp.linspace(0.0, 1.0, 9)
    brackets = _roots.grid_brackets(t, (jnp.exp(t) - 1.7)[None], jnp.exp(t)[None], 2)
    assert abs(float(brackets.guess[0]) - math.log(1.7)) > 1e-9  # Newton has work to do
    roots, valid, _ = jax.jit(lambda b: _roots.newton_in_brackets(fn, None, b, 8))(brackets)
    jax.effects_barrier()
    assert len(calls) == 3
    assert bool(valid[0]) and abs(float(roots[0]) - math.log(1.7)) <= 2e-16


def test_newton_in_brackets_stores_f_once_per_step():
    """XLA's CPU backend computes an elementwise producer in every consumer fusion, so a
    Newton step whose F updates four carried arrays compiles F four times (for a
    degree-18 Bezier, hundreds of instructions each). With `store`, each step and the
    validity check after the loop compute F in one kernel (`materialize`, whose loop
    condition reads its key, no copy of F): F = sin t - 0.4 and F' = cos t are one stack
    per step, plus one sine for the check. Without it: four in the step (the bracket's
    ends, the iterate, the confirmed sign) and the check's F in each of its two consumers
    (the roots' validity and the search's done flag)."""
    fn = lambda t, _: (jnp.sin(t) - 0.4, jnp.cos(t), jnp.ones_like(t))  # noqa: E731
    t = jnp.linspace(0.0, 1.0, 9)
    brackets = _roots.grid_brackets(t, (jnp.sin(t) - 0.4)[None], jnp.cos(t)[None], 2)
    for store, sines in ((True, 2), (False, 6)):
        solve = jax.jit(lambda b, s=store: _roots.newton_in_brackets(fn, None, b, 8, s))
        hlo = solve.lower(brackets).compile().as_text()
        assert len(re.findall(r" sine\(", hlo)) == sines, store
        roots, valid, _ = solve(brackets)
        assert bool(valid[0]) and abs(float(roots[0]) - math.asin(0.4)) <= 2e-16


def test_newton_in_brackets_says_whether_every_root_was_final_within_its_steps():
    """F(t) = t^2 - 1e-8 from the guess 1 in [0, 1]: Newton halves the distance to the
    root 1e-4 per step until it is close (Heron's square root), about 13 steps, then
    converges in four more. Within 8 steps the search is not done (and visibility reports
    that, `test_a_root_search_not_done_in_its_newton_steps_is_reported`); within 32 it is."""
    fn = lambda t, _: (t * t - 1e-8, 2.0 * t, t * t + 1e-8)  # noqa: E731
    brackets = _roots.Brackets(
        lo=jnp.zeros(1),
        hi=jnp.ones(1),
        guess=jnp.ones(1),
        sign_lo=-jnp.ones(1),
        turning=jnp.zeros(1, bool),
        curvature=jnp.ones(1),
        candidate=jnp.ones(1, bool),
        source=jnp.zeros(1, int),
        count=jnp.array(1),
    )
    for steps, done in ((8, False), (32, True)):
        roots, valid, settled = _roots.newton_in_brackets(fn, None, brackets, steps)
        assert bool(settled) == done and bool(valid[0])
    assert abs(float(roots[0]) - 1e-4) < 1e-15  # final: a step of at most 4 eps


def test_a_root_search_not_done_in_its_newton_steps_is_reported():
    """A camera 1e-6 from the banana (1.7e-8 of its size): a tangency time beside its
    nearest point takes more than 8 Newton steps. With 8 the call raises an error that
    says what to pass (before, it returned a root short of its final value); with the
    default (32) VisibleLength equals the reference to 1e-8 (the arc seen is 0.005 long;
    up to 9e-9 at this distance)."""
    spec = H.to_reference(H.BANANA)[0]
    camera = jnp.asarray(H.cameras_beside(spec, np.array([0.2698]), (1e-6,)))
    few = ocp.VisibilityOptions(newton_iterations=8)
    with pytest.raises(Exception, match=r"not done in 8 Newton steps.*newton_iterations=\.\.\."):
        jax.block_until_ready(ocp.visibility(H.BANANA, camera, VL, few))
    q = visible_length_of("banana")(camera)
    ref = reference_visibility([spec], np.asarray(camera), "visible_length")
    assert abs(float(q[0]) / ref - 1) < 1e-8


def test_implicit_root_derivative():
    """d t*/da for t*(a) = the larger root of (t - a)(t - a - 0.002) = 1e-7 t."""

    def larger_root(a):
        _, roots, valid = _pair_roots(a, 4)
        return jnp.max(jnp.where(valid, roots, -1.0))

    a = 0.4
    B = 2 * a + 0.002 + 1e-7
    # root = (B + sqrt(B^2 - 4 a (a + 0.002))) / 2
    disc = B * B - 4 * a * (a + 0.002)
    want = (2 + (2 * B * 2 - 4 * (2 * a + 0.002)) / (2 * math.sqrt(disc))) / 2
    got = float(jax.jit(jax.grad(larger_root))(jnp.asarray(a)))
    assert abs(got / want - 1) < 1e-9
    got_fwd = float(jax.jit(jax.jacfwd(larger_root))(jnp.asarray(a)))
    assert abs(got_fwd / want - 1) < 1e-9
