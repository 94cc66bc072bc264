"""Super-level sets {u in [0, u_max] : f(u) >= 0} of a scalar function on a segment, as shells.

This is how every radial control becomes a list of shells at a given time: f(u) is the log of g/h minus the log
of the threshold along a ray, in the similarity variable u = |x| / sqrt(4 D t).

``piecewise_monotone_intervals`` is the exact method, used for every level set {g/h >= r}. The caller splits
[0, u_max] at the points where f may jump (a cost that is discontinuous in |x|) into pieces on each of which f is
nonincreasing. That is proven for every cost here, term by term: log g = const - u^2 decreases in u, log h
increases in |x| or is constant between the jumps, and min(log g, const) (the flat cost) is nonincreasing
(docs/immune.md). On a nonincreasing piece [e_j, e_{j+1}) the set {f >= 0} is a single interval [e_j, b_j):
empty when f(e_j) < 0, the whole piece when f is still >= 0 just before e_{j+1}, and otherwise b_j is the one
place where f changes sign, bracketed by the piece's two ends. So no component can be missed, however narrow (a
piece of width 1e-12 is handled like any other), and each bracket is bisected until its two ends are adjacent
floating-point numbers (machine precision). Every returned slot is [e_j, b_j) with e_j <= b_j: as a function of
time, e_j(t) and b_j(t) are min/max compositions of nonincreasing functions of t, which the quadrature's error
bound uses.

``grid_intervals`` is the approximate method, left only for the randomly tilted competitors of Theorem 4.4.1's
check ({g/h >= r e^xi}, xi a smooth random field), which are not monotone along the ray: sign changes on a grid,
refined by bisection. A component narrower than the grid spacing can be missed there; the quadrature then
integrates g and h over the same (slightly different) set, so the competitor's two masses stay consistent.

Boundaries are differentiable in whatever f depends on (the threshold, a tilt) by the implicit function theorem:
at a boundary u* with f(u*) = 0, du* = -df / f'(u*). That derivative is applied as one Newton step whose value is
(numerically) zero, so the forward value is the bisection's and the tangent is the implicit one. A boundary at a
piece's end (a jump of the cost) does not move with the threshold and gets tangent zero.
"""

from __future__ import annotations

from typing import Callable

import jax
import jax.numpy as jnp

U_MAX = 6.5  # P(d/2, U_MAX^2) = 1 - O(e^{-42}) for d <= 3: the heat kernel has no mass beyond it that matters
BISECT_ITERS = 80  # halving [0, 6.5] 80 times reaches 5e-24: the two ends are adjacent floats long before


def _bisect(pred, lo, hi, iters):
    """Shrink [lo, hi] keeping pred(lo) true and pred(hi) false (pred monotone on the bracket)."""

    def body(_, c):
        lo, hi = c
        mid = 0.5 * (lo + hi)
        ok = pred(mid)
        return jnp.where(ok, mid, lo), jnp.where(ok, hi, mid)

    return jax.lax.fori_loop(0, iters, body, (lo, hi))


def _implicit(f, root, moves):
    """The root's value with the implicit tangent -df/f' where ``moves`` (a smooth crossing), zero elsewhere."""
    fr, dfdu = jax.jvp(f, (root,), (jnp.ones_like(root),))
    dfdu = jax.lax.stop_gradient(dfdu)
    step = jnp.where(moves & (dfdu != 0), fr / jnp.where(dfdu != 0, dfdu, 1.0), 0.0)
    return root - (step - jax.lax.stop_gradient(step))


def piecewise_monotone_intervals(f: Callable, edges, *, iters: int = BISECT_ITERS):
    """Shells (a, b), one per piece, with {f >= 0} ∩ [edges[0], edges[-1]) = union of [a_j, b_j).

    ``edges`` (sorted, shape (P + 1,)) split the segment into P pieces [edges[j], edges[j+1]); ``f(u, j)`` must
    be nonincreasing in u on piece j (j is an int array: the branch of f that holds on that piece, so a jump at
    an edge is evaluated on the right side, whatever rounding does at the edge). Returns a = edges[:-1] and
    b_j in [a_j, edges[j+1]]. See the module docstring for why no component can be missed."""
    lo, hi = edges[:-1], edges[1:]
    j = jnp.arange(lo.shape[0])
    f_sg = lambda u: jax.lax.stop_gradient(f(u, j))  # noqa: E731
    # the largest float below the piece's end: the piece's own branch, as close to its end as it gets
    hi_in = jnp.maximum(lo, jnp.nextafter(hi, -jnp.inf))
    start_in = f_sg(lo) >= 0
    end_in = f_sg(hi_in) >= 0
    crossing = start_in & ~end_in & (hi > lo)
    # the bracket [lo, hi_in] has f(lo) >= 0 > f(hi_in) wherever a crossing is; elsewhere it is not used
    a_br, _ = _bisect(lambda u: f_sg(u) >= 0, lo, hi_in, iters)
    root = _implicit(lambda u: f(u, j), a_br, crossing)
    b = jnp.where(crossing, root, jnp.where(start_in, hi, lo))
    return lo, b


def grid_intervals(f: Callable, *, u_max: float = U_MAX, n_grid: int = 129, max_intervals: int = 4,
                   iters: int = 60, jump_tol: float = 1e-6):
    """Intervals (a, b), each of shape (max_intervals,), with {f >= 0} ∩ [0, u_max] ≈ union of [a_i, b_i), found
    from sign changes on an ``n_grid`` grid (approximate: see the module docstring; only for tilted sets).

    Unused slots are empty (a = b = 0). Also returns ``overflow``: true when the grid saw more sign changes than
    ``max_intervals`` can hold (the intervals are then incomplete)."""
    grid = jnp.linspace(0.0, u_max, n_grid)
    vals = jax.lax.stop_gradient(f(grid))
    inside = vals >= 0
    change = inside[1:] != inside[:-1]
    n_edges = 2 * max_intervals
    (idx,) = jnp.nonzero(change, size=n_edges, fill_value=n_grid - 1)
    valid = idx < n_grid - 1
    idx_c = jnp.minimum(idx, n_grid - 2)
    lo, hi = grid[idx_c], grid[idx_c + 1]
    f_sg = lambda u: jax.lax.stop_gradient(f(u))  # noqa: E731
    inside_lo = inside[idx_c]
    lo, hi = _bisect(lambda u: (f_sg(u) >= 0) == inside_lo, lo, hi, iters)
    root = 0.5 * (lo + hi)
    smooth = jnp.abs(f_sg(lo) - f_sg(hi)) <= jump_tol
    root = _implicit(f, root, smooth)
    # crossings come out of nonzero in increasing order, so the edges (a start at 0 if u = 0 is inside, the
    # crossings, an end at u_max if u_max is inside) alternate start, end, start, ... without sorting
    root = jnp.where(valid, root, jnp.nan)
    edges = jnp.where(inside[0], jnp.concatenate([jnp.zeros(1), root[:-1]]), root)
    count = jnp.sum(valid) + inside[0]
    edges = jnp.where(inside[-1] & (jnp.arange(n_edges) == count), u_max, edges)
    a, b = edges[0::2], edges[1::2]
    empty = jnp.isnan(a) | jnp.isnan(b)
    overflow = jnp.sum(change) + inside[0] + inside[-1] > n_edges
    return jnp.where(empty, 0.0, a), jnp.where(empty, 0.0, b), overflow
