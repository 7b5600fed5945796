"""Vectorised root finding on a grid, with exact implicit-function derivatives.

Every occlusion event is a root of a smooth function F(t; theta) of the curve parameter t
(theta: cameras, scene, line of sight). We find them in three static-shape steps:

1. **Brackets.** F and dF/dt are known at the grid nodes t_0 < ... < t_N. In each cell the
   cubic Hermite interpolant of (F, F') is split at its extremum when F' changes sign in
   the cell, so a pair of roots closer together than a cell (a near-double root) gives two
   brackets; a plain sign change gives one. Where F is known exactly at a point of the
   cell (a probe) with the sign opposite to both ends, the cell is split there instead.
2. **Compaction.** The bracket slots that hold a root are packed into a static budget of
   R slots (`first_true`); the true count is returned so that an exceeded
   budget is reported, never silently truncated.
3. **Refinement.** Safeguarded Newton in each bracket (bisection when a step would leave
   it; a step landing exactly on an end is accepted, and so is a step of a few ulps
   out of it, which is rounding noise at the root), at most a fixed number of
   iterations. A root is final once its last step d was so small that Newton's error
   c d^2 (c = |F'' / 2F'|, estimated from the cubic) is below eps: no further step is
   taken only to see that it no longer moves.

`implicit_root` then attaches the derivative of the implicit function theorem: for
F(t*(theta); theta) = 0, dt* = -(dF/dtheta . dtheta) / (dF/dt) (the general form of the
thesis's Eqs. 5.20 and 5.32), for tangents in any argument of F.
"""

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from .jvp import perturbed_jvp
from .xla_cpu import materialize

# `dip_probes`: the most regula falsi steps, and the bracket (a fraction of the cell)
# narrow enough to stop.
DIP_ITERATIONS = 48
DIP_TOLERANCE = 1e-7
# Elements of work per chunk of `over_chunks`: enough to outweigh a loop step's cost.
CHUNK_ELEMENTS = 1 << 14


class Brackets(NamedTuple):
    """Packed root brackets, shape (..., R) each."""

    lo: Float[Array, "*batch r"]
    hi: Float[Array, "*batch r"]
    guess: Float[Array, "*batch r"]
    sign_lo: Float[Array, "*batch r"]  # sign of F at lo
    turning: Bool[Array, "*batch r"]  # bracket ends are interpolated (near-double root)
    # Newton's error constant |F'' / (2 F')| at the guess, from the Hermite cubic and at
    # least 1 / (cell width): a Newton step of size d leaves an error of about
    # curvature d^2 (inf where the cubic's slope vanishes).
    curvature: Float[Array, "*batch r"]
    candidate: Bool[Array, "*batch r"]
    source: Int[Array, "*batch r"]  # flat index into the (lines, cells, 2) slots
    count: Int[Array, "*batch"]  # slots that held a root, before packing


def safe_divisor(x):
    """x with its zeros replaced by 1: a divisor for quotients that are discarded (or
    limits taken) where x = 0."""
    return jnp.where(x == 0, 1.0, x)


def quadratic_roots(a, b, c, disc):
    """The roots of a x^2 + b x + c = 0 from its discriminant `disc` (b^2 - 4 a c, made
    non-negative by the caller), as the pair c / q, q / a with q = -(b + sign(b)
    sqrt(disc)) / 2, which loses no digits to cancellation (divisions by 0 give 0)."""
    q = -0.5 * (b + jnp.where(b >= 0, 1.0, -1.0) * jnp.sqrt(disc))
    return c / safe_divisor(q), q / safe_divisor(a)


def _hermite_coefficients(f0, f1, d0, d1, h):
    """p(s) = ((a3 s + a2) s + a1) s + f0 on s in [0, 1]: the cubic with p(0) = f0,
    p(1) = f1, p'(0) = h d0, p'(1) = h d1."""
    a1 = h * d0
    a2 = -3.0 * f0 - 2.0 * h * d0 + 3.0 * f1 - h * d1
    a3 = 2.0 * f0 + h * d0 - 2.0 * f1 + h * d1
    return a1, a2, a3


def _critical_points(f0, f1, d0, d1, h):
    """The cubic Hermite interpolant's coefficients (`_hermite_coefficients`), the
    discriminant of p'(s) = 3 a3 s^2 + 2 a2 s + a1 and its two roots (real parts)."""
    a1, a2, a3 = _hermite_coefficients(f0, f1, d0, d1, h)
    disc = 4.0 * a2 * a2 - 12.0 * a3 * a1
    first, second = quadratic_roots(3.0 * a3, 2.0 * a2, a1, jnp.maximum(disc, 0.0))
    return (a1, a2, a3), disc, first, second


def _toward_zero(a2, a3, s, f0):
    """Whether p turns back toward zero at its extremum s: p''(s) of the sign of f0."""
    return (3.0 * a3 * s + a2) * f0 > 0


def dip_probes(fn, t_nodes, values, slopes):
    """Probes (`grid_brackets`) for pairs of roots closer together than the grid resolves.

    Where the cubic Hermite interpolant p of F turns back toward zero inside a cell whose
    ends have one sign (a minimum between positive ends), but not across it, F may still
    cross twice near there: the pair straddles F's extremum, however close together the
    roots are. The probe is that extremum, and F there. F' changes sign at it, which the
    grid resolves even where the dip is too shallow (or too sharp) for p to show: from
    p's extremum s, F' at s and at the cell's ends bracket it, and the Illinois variant of
    regula falsi on F' narrows the bracket until F there has the sign opposite to the
    ends (a pair revealed) or the bracket is below `DIP_TOLERANCE` of the cell (a pair
    missed then is closer together than that, and changes Q by less than rounding).
    Where F' does not change sign across the bracket (p has two extrema in the cell and
    F' at s is of the ends' sign), F(s) is the probe.

    **Arguments:**

    - `fn`: `fn(t) -> (F, F')` at the times t, an array like a cell's (*batch, lines, N).
    - `t_nodes`, `values`, `slopes`: the grid and F, F' at its nodes, as `grid_brackets`
      takes them.

    **Returns:**

    `grid_brackets`' probes: (fraction of each cell, F there or NaN where p does not turn
    back toward zero in the cell).
    """
    f0, f1 = cell_ends(values)
    d0, d1 = cell_ends(slopes)
    h = jnp.broadcast_to(jnp.diff(t_nodes, axis=-1), f0.shape)
    start = jnp.broadcast_to(t_nodes[..., :-1], f0.shape)
    (_, a2, a3), disc, first, second = _critical_points(f0, f1, d0, d1, h)
    s = jnp.where(_toward_zero(a2, a3, first, f0), first, second)
    dips = (disc >= 0) & (f0 * f1 > 0) & (s > 0) & (s < 1) & _toward_zero(a2, a3, s, f0)
    s = jnp.where(dips, s, 0.5)
    value, slope = fn(start + h * s)
    # g = F' sign(f0) rises through zero at the dip's extremum
    sign = jnp.where(f0 > 0, 1.0, -1.0)
    g, g0, g1 = slope * sign, d0 * sign, d1 * sign
    left = g < 0  # the extremum lies right of s
    lo, g_lo = jnp.where(left, s, 0.0), jnp.where(left, g, g0)
    hi, g_hi = jnp.where(left, 1.0, s), jnp.where(left, g1, g)

    def revealed(value):
        return value * f0 < 0

    def done(lo, g_lo, hi, g_hi, value):
        narrow = hi - lo <= DIP_TOLERANCE
        return ~dips | revealed(value) | narrow | ~((g_lo < 0) & (g_hi > 0))

    def running(carry):
        i, lo, g_lo, hi, g_hi, _, _, best = carry
        return (i < DIP_ITERATIONS) & ~jnp.all(done(lo, g_lo, hi, g_hi, best))

    def step(carry):
        i, lo, g_lo, hi, g_hi, last_left, at, best = carry
        finished = done(lo, g_lo, hi, g_hi, best)
        x = (lo * g_hi - hi * g_lo) / safe_divisor(g_hi - g_lo)
        # (strictly inside: at the cell's end F is the next piece's where x' jumps)
        x = jnp.where((x > lo) & (x < hi), x, 0.5 * (lo + hi))
        value, slope = fn(start + h * x)
        better = ~finished & (value * f0 < best * f0)
        at, best = jnp.where(better, x, at), jnp.where(better, value, best)
        g = slope * sign
        left = g < 0
        # x replaces the end of g's sign (both where g = 0: done); Illinois: the g of an
        # end kept twice in a row is halved
        new = (
            jnp.where(g <= 0, x, lo),
            jnp.where(left, g, jnp.where(last_left, g_lo, 0.5 * g_lo)),
            jnp.where(g >= 0, x, hi),
            jnp.where(left, jnp.where(last_left, 0.5 * g_hi, g_hi), g),
        )
        old = (lo, g_lo, hi, g_hi)
        return i + 1, *(jnp.where(finished, a, b) for a, b in zip(old, new)), left, at, best

    carry = (0, lo, g_lo, hi, g_hi, left, s, value)
    *_, at, value = jax.lax.while_loop(running, step, carry)
    return at, jnp.where(dips, value, jnp.nan)


def hermite_extremum(f0, f1, d0, d1, h):
    """The extremum of the cubic Hermite interpolant p on each cell that can show a pair
    of roots, as a fraction s in [0, 1] of the cell, and p there (`turning`): where F'
    changes sign in the cell, p's one extremum there; where p has two there (F' of one
    sign at both ends, dipping between: a pair right beside a root of F'), the one where
    p has the sign opposite to f0, if either has (both cannot, for ends of one sign).
    Elsewhere s = 1 and the value is f1."""
    (a1, a2, a3), _, first, second = _critical_points(f0, f1, d0, d1, h)

    def p(s):
        return ((a3 * s + a2) * s + a1) * s + f0

    one = d0 * d1 < 0  # exactly one root of p' in (0, 1)
    first_in = (first >= 0) & (first <= 1)
    # Of two: p's minimum where f0 > 0 (p'' > 0 there), its maximum where f0 < 0.
    dips = _toward_zero(a2, a3, first, f0)
    s = jnp.clip(jnp.where(jnp.where(one, first_in, dips), first, second), 0.0, 1.0)
    value = p(s)
    # (p' of one sign at both ends has 0 or 2 roots in (0, 1): with one, the other too;
    # a double root is no extremum, and p, monotone, keeps the sign of its ends)
    two = (d0 * d1 > 0) & first_in & (value * f0 < 0)
    turning = one | two
    return jnp.where(turning, s, 1.0), jnp.where(turning, value, f1), turning


def _slot_bounds(f0, f1, d0, d1, h, second, probe=None):
    """The two root slots of a cell, [0, s] (first) and [s, 1] (second), as fractions of
    the cell, with the values at their ends: split at the Hermite interpolant's extremum
    (its value interpolated), or at the `probe` (fraction, exact value or NaN for none)
    where F there has the sign opposite to both ends."""
    s, p, turning = hermite_extremum(f0, f1, d0, d1, h)
    # F changing sign between the ends is one bracket, exact: split at the interpolant's
    # extremum, whose value is only interpolated, its root could lie in the slot without
    # the sign change (the interpolant has one root in such a cell, as F mostly has).
    single = f0 * f1 < 0
    s, p, turning = jnp.where(single, 1.0, s), jnp.where(single, f1, p), turning & ~single
    reveals = False
    if probe is not None:
        at, value = probe
        reveals = (value * f0 < 0) & (value * f1 < 0)
        s, p, turning = jnp.where(reveals, at, s), jnp.where(reveals, value, p), turning & ~reveals
    lo = jnp.where(second, s, 0.0)
    hi = jnp.where(second, 1.0, s)
    f_lo = jnp.where(second, p, f0)
    f_hi = jnp.where(second, f1, p)
    return lo, hi, f_lo, f_hi, turning, reveals


def first_true(mask: Bool[Array, "*batch n"], size: int):
    """The indices of the first `size` True entries along the last axis (padded with 0),
    which of the `size` slots hold one, and the number of True entries, all from one
    running count of the mask.

    `jnp.nonzero` reads the mask three times (its running count, its sum for the fill,
    and the caller's count); XLA's CPU backend, which has no multi-output fusion,
    then computes an elementwise mask three times. Here only the running count reads it:
    the k-th index is the number of entries whose running count is <= k (as in
    `jnp.nonzero`), and the count is the running count's last entry.
    """
    running = jnp.cumsum(mask, axis=-1)
    count = running[..., -1]

    def indices(running):
        return jnp.cumsum(jnp.bincount(running, length=size))

    index = jnp.vectorize(indices, signature="(n)->(r)")(running)
    filled = jnp.broadcast_to(jnp.arange(size), index.shape) < count[..., None]
    return jnp.where(filled, index, 0), filled, count


def over_chunks(mask: Bool[Array, " n"], size: int, step, init, sparse: bool = False):
    """Folds `carry = step(carry, index, live)` over the indices of the True entries of
    `mask`, packed `size` at a time (`index`, `live`: arrays (size,), `live` False on the
    padding of the last chunk), for as many chunks as there are entries: the work
    follows the count, not the mask's length. A mask no longer than a chunk is one
    chunk, unpacked, unless it is `sparse` (mostly False: then no chunk runs where no
    entry is True)."""
    if mask.shape[0] <= size and not sparse:
        return step(init, jnp.arange(mask.shape[0]), mask)
    index, _, count = first_true(mask, mask.shape[0] + size)

    def body(carry):
        chunk, inner = carry
        at = chunk * size
        packed = jax.lax.dynamic_slice(index, (at,), (size,))
        return chunk + 1, step(inner, packed, at + jnp.arange(size) < count)

    def running(carry):
        return carry[0] * size < count

    return jax.lax.while_loop(running, body, (0, init))[1]


def cell_ends(nodes):
    """The values at the start and at the end of every grid cell from node values: one
    array (N + 1) where they are continuous, or a pair (right limits, left limits) of
    such arrays where they may jump at nodes (corners)."""
    start, end = nodes if isinstance(nodes, tuple) else (nodes, nodes)
    return start[..., :-1], end[..., 1:]


def grid_brackets(
    t_nodes: Float[Array, "*lines n1"],
    values,
    slopes,
    budget: int,
    keep: Bool[Array, "*batch lines n"] | None = None,
    scale=None,
    probes=None,
) -> Brackets:
    """Brackets of the roots of F on every line (a family of functions sharing a grid),
    packed over lines and cells into `budget` slots per batch element.

    **Arguments:**

    - `t_nodes`: the grid t_0 < ... < t_N, shared by all lines or one per line (an
      array like `values`).
    - `values`, `slopes`: F and dF/dt at the nodes, arrays (*batch, lines, N + 1), or
      pairs of them (right and left limits, see `cell_ends`) where F or F' jump.
    - `budget`: R, the number of root slots.
    - `keep`: optional mask of the cells that may hold wanted roots.
    - `scale`: optional magnitude of the terms of F at the nodes (like `values`): a
      cell where |F| stays below 1e3 eps scale at both ends holds no resolvable root
      (F vanishes identically up to rounding, e.g. a camera on the line of a polygon
      edge), only rounding noise, and is skipped.
    - `probes`: optional (fraction of the cell, F there or NaN for none), arrays (*batch,
      lines, N): a point in each cell where F is known exactly. Where its F has the sign
      opposite to both ends, the cell holds a pair of roots, one on either side of it,
      however close together (`_events.grazing_probes`): the cell is split there.
    """
    h = jnp.diff(t_nodes, axis=-1)
    f0, f1 = cell_ends(values)
    d0, d1 = cell_ends(slopes)
    h_cells = jnp.broadcast_to(h, f0.shape)
    split = _slot_bounds(f0, f1, d0, d1, h_cells, False, probes)[3]  # F where they meet
    # The two slots of each cell chosen by a select on the slot's index, not stacked: XLA's
    # CPU backend emits a concatenation as a branch on the index of every element, which
    # keeps the kernel that computes the mask (and the values it fuses) from being
    # vectorized; the banana's shadow mask took a fifth of the time in the profiler.
    slot = jnp.arange(2)
    has_root = jnp.where(
        slot == 0,
        ((f0 * split < 0) | (f0 == 0))[..., None],
        (split * f1 < 0)[..., None],
    )
    if keep is not None:
        has_root = has_root & keep[..., None]
    if scale is not None:
        noise = [1e3 * jnp.finfo(f0.dtype).eps * a for a in cell_ends(scale)]
        resolved = (jnp.abs(f0) > noise[0]) | (jnp.abs(f1) > noise[1])
        has_root = has_root & resolved[..., None]
    batch = has_root.shape[:-3]
    index, candidate, count = first_true(has_root.reshape(batch + (-1,)), budget)

    # Recompute the bracket of each packed slot from its cell's values only, gathered
    # at once (XLA's CPU backend launches a kernel per gather).
    cell_index = index // 2
    columns = [f0, f1, d0, d1, h_cells, t_nodes[..., :-1]]
    if probes is not None:
        columns += list(probes)
    table = jnp.stack(jnp.broadcast_arrays(*columns), -1)
    table = jnp.take_along_axis(
        table.reshape(batch + (-1, len(columns))), cell_index[..., None], -2
    )
    f_start, f_end, d_start, d_end, width = jnp.unstack(table[..., :5], axis=-1)
    start = table[..., 5]
    probe = None if probes is None else (table[..., 6], table[..., 7])
    second = index % 2 == 1
    lo, hi, f_lo, f_hi, turning, revealed = _slot_bounds(
        f_start, f_end, d_start, d_end, width, second, probe
    )
    # Initial guess: regula falsi, then two Newton steps on the Hermite cubic (an
    # O(h^4) approximation of F), so that few steps on F itself are needed.
    guess = jnp.where(f_lo == 0, lo, lo + (hi - lo) * f_lo / safe_divisor(f_lo - f_hi))
    a1, a2, a3 = _hermite_coefficients(f_start, f_end, d_start, d_end, width)

    def cubic(s):  # p(s), p'(s), p''(s)
        return (
            ((a3 * s + a2) * s + a1) * s + f_start,
            (3.0 * a3 * s + 2.0 * a2) * s + a1,
            6.0 * a3 * s + 2.0 * a2,
        )

    for _ in range(2):
        p, dp, _ = cubic(guess)
        guess = jnp.clip(guess - p / safe_divisor(dp), lo, hi)
    # In t = start + width s: F'' / (2 F') = p''(s) / (2 p'(s) width), at least 1 / width.
    _, dp, ddp = cubic(guess)
    curvature = jnp.where(dp == 0, jnp.inf, jnp.abs(ddp) / (2.0 * jnp.abs(safe_divisor(dp))))
    if probe is not None:
        # A pair revealed by a probe, which the cubic does not resolve: F near the probe
        # taken for F(probe) + F'' (s - probe)^2 / 2 (F' = 0 there), F'' from the far end
        # of the slot, and its root as the guess; F'' / (2 F') = 1 / (2 |guess - probe|).
        split, far = jnp.where(second, lo, hi), jnp.where(second, hi, lo)
        f_split, f_far = jnp.where(second, f_lo, f_hi), jnp.where(second, f_hi, f_lo)
        ratio = f_split / safe_divisor(f_split - f_far)
        offset = (far - split) * jnp.sqrt(jnp.where(revealed, ratio, 0.0))
        guess = jnp.where(revealed, split + offset, guess)
        curvature = jnp.where(revealed, 0.5 / jnp.abs(safe_divisor(offset)), curvature)
    return Brackets(
        start + width * lo,
        start + width * hi,
        start + width * guess,
        jnp.sign(f_lo),
        turning,
        jnp.maximum(curvature, 1.0) / width,
        candidate,
        index,
        count,
    )


def newton_in_brackets(fn, args, brackets: Brackets, iterations: int, store: bool = False):
    """Safeguarded Newton on `fn(t, args) -> (F, dF/dt, scale)` inside each bracket, at
    most `iterations` steps, stopping once every root is final: its last step moved it
    by at most 4 eps, or was a Newton step d with 16 curvature d^2 <= eps, so that the
    error left (about curvature d^2, quadratic convergence) is below eps / 16. No step
    is taken where no slot holds a candidate.

    Returns the roots (no derivative attached), whether each is a root (a candidate
    from an exact sign change always is; one from an interpolated (near-double) bracket
    only once an iterate has confirmed the sign change, F of the other sign than at the
    bracket's grid node, or |F| <= 1e3 eps scale at the end) and whether the search is
    done: every root final within the `iterations` or |F| <= 1e3 eps scale there (false:
    the budget was exceeded, to be reported).

    With `store`, each step computes F and F' in one kernel and stores them, as does the
    validity check (`materialize`): XLA's CPU backend otherwise computes F in each
    update that reads it (the bracket's ends, the iterate, the confirmed sign) and in
    each consumer of the check's (validity, done). Worth it where F is costly (a long
    polynomial), not where the stored copy's kernels cost more than the repeated
    arithmetic.
    """
    # Each array of the state is a carry of its own: one stacked carry launches fewer
    # kernels per step, but under vmap XLA then evaluates F once per stacked row.
    # The iterates stay below hi: at a cell's end t evaluates the next piece of a curve
    # with corners (the right limit), whose sign says nothing about this bracket.
    lo, hi = brackets.lo, brackets.hi
    t = jnp.where(brackets.guess < hi, brackets.guess, 0.5 * (lo + hi))
    confirmed = ~brackets.turning
    # An interpolated bracket's end at the cubic's extremum has a predicted sign only:
    # its root is confirmed by an iterate of the sign opposite to that at the bracket's
    # grid node, lo in a cell's first slot, hi (of the sign opposite to lo's) in its second.
    second = brackets.source % 2 == 1
    eps = jnp.finfo(t.dtype).eps
    key = (args, lo)  # for `materialize`: a scene parameter where args hold one

    def evaluate(t, used):  # the outputs `used` of fn (indices), stored where `store`
        every = fn(t, args)
        outputs = tuple(every[i] for i in used)
        return materialize(outputs, key) if store else outputs

    def step(carry):
        i, lo, hi, t, confirmed, _ = carry
        value, slope = evaluate(t, (0, 1))
        same = jnp.sign(value) == brackets.sign_lo
        lo = jnp.where(same, t, lo)
        hi = jnp.where(same, hi, t)
        newton = t - value / safe_divisor(slope)
        inside = (newton >= lo) & (newton < hi)
        # A step of a few ulps out of the bracket is rounding noise of F at its root
        # (XLA may round F differently where the sign test and the step use it): stay.
        moved = jnp.abs(newton - t)
        settling = moved <= 4 * eps
        new = jnp.where(inside, newton, jnp.where(settling, t, 0.5 * (lo + hi)))
        # Final: it no longer moves, or Newton's error after this step is below eps / 16.
        final = (jnp.abs(new - t) <= 4 * eps) | (
            inside & (16.0 * brackets.curvature * moved * moved <= eps)
        )
        opposite = jnp.where(second, same, ~same)
        return i + 1, lo, hi, new, confirmed | opposite, final | ~brackets.candidate

    def running(carry):
        i, *_, final = carry
        return (i < iterations) & ~jnp.all(final)

    carry = (0, lo, hi, t, confirmed, ~brackets.candidate)
    _, lo, hi, t, confirmed, final = jax.lax.while_loop(running, step, carry)
    value, scale = evaluate(t, (0, 2))
    converged = jnp.abs(value) <= 1e3 * eps * scale
    valid = brackets.candidate & (confirmed | converged)
    # Not final but |F| at rounding level: at a double root (two cameras' q that touch)
    # the iterates wander in the noise and need not settle, and any of them will do. An
    # unconfirmed interpolated bracket holds no root: its iterates need not settle.
    return t, valid, jnp.all(final | converged | ~valid)


@functools.partial(jax.custom_jvp, nondiff_argnums=(0,))
def implicit_root(fn, t, args):
    """Identity on the roots t of fn(t, args)[0] = 0, with the implicit-function JVP
    dt = -(dF/dargs . dargs) / (dF/dt) for tangents in every leaf of `args`."""
    return t


@functools.partial(implicit_root.defjvp, symbolic_zeros=True)
def _implicit_root_jvp(fn, primals, tangents):
    t, args = primals
    _, dargs = tangents
    _, dvalue, slope = perturbed_jvp(lambda a: fn(t, a)[:2], args, dargs, has_aux=True)
    # Padded (invalid) roots may sit where dF/dt = 0: keep their tangents finite.
    slope = jnp.where(jnp.isfinite(slope) & (slope != 0), slope, 1.0)
    return t, -dvalue / slope


def solve_roots(fn, args, brackets: Brackets, iterations: int, fill: float, store: bool):
    """Roots of `fn` in the packed brackets, differentiable in `args` (`store`: see
    `newton_in_brackets`).

    **Returns:** (t, valid, settled), invalid slots set to `fill` with zero derivative.
    """
    t, valid, settled = newton_in_brackets(
        fn, jax.lax.stop_gradient(args), jax.lax.stop_gradient(brackets), iterations, store
    )
    t = implicit_root(fn, t, args)
    return jnp.where(valid, t, fill), valid, settled
