"""Quadrature of int_A g and int_A h, the function F(r) of (4.7) and the threshold r_bar of (4.8).

In the coordinate s = 1 - exp(-(gamma + delta) t) the g-integral of a control is R0 times the integral over
s in [0, 1) of m(s), the heat kernel's mass inside A(t(s)) (a number in [0, 1]); the h-integral is the integral
of H(t(s)) / ((gamma + delta)(1 - s)), H(t) = int_{A(t)} h dx. For radial controls the inner (space) integrals are
closed forms over shells; only the s-integral is numerical, on segments whose ends are every time where A(t)
jumps or changes shape (``breakpoints``: window ends; for level sets the times where a boundary meets a jump of
the cost or the set vanishes), so the integrands are smooth inside each segment.

Value. Simpson's rule on n panels per segment in a graded variable (s = lo + span (3x^2 - 2x^3)): O(n^-4) on
smooth segments; against brentq + quad references it is within 1e-11 relative at n = 1024 (tests).

Bracket. On a panel where a function is monotone, its integral lies between the panel width times the smaller
and times the larger end value. For shells, m = sum_i q_i (w(b_i) - w(a_i)) is bracketed term by term: every
shell end a_i(t), b_i(t) of an untilted level set (``levelset``), of a ball over a window (inside the window) and
of the windowed sets is nonincreasing in t, so sum q_i w(b_i) and sum q_i w(a_i) are each monotone on every
panel and the bracket [lo(outer) - hi(inner), hi(outer) - lo(inner)] holds without any condition on m itself
(up to rounding and the 1e-10 nudge of segment ends). It is rigorous for those sets; for the tilted
perturbations and for the h-integrands (which rise and fall) it is an estimate. The bracket of F(r) is
monotone in r (the inner ends of a level set's shells do not depend on r and its outer ends shrink as r grows),
so bisection on its two ends brackets r_bar rigorously as well.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxdip import program_cache
from jaxdip.engine.memo import memoised
from jaxdip.immune.controls import LevelSet
from jaxdip.immune.model import Infection, mass_fraction

S_MAX = 1.0 - 1e-12  # s = 1 is t = inf; every control here has finite cost or none beyond
T_MIN = 1e-12  # the heat kernel at t = 0 is a point mass: evaluate just after
NUDGE = 1e-10  # segment ends are evaluated this fraction inside, so jumps fall between nodes


class Masses(NamedTuple):
    """int_A g and int_A h, each with its bracket [lo, hi]."""

    g: jax.Array
    g_lo: jax.Array
    g_hi: jax.Array
    h: jax.Array
    h_lo: jax.Array
    h_hi: jax.Array


def _panel_bracket(f, widths):
    """sum over panels of width * min and width * max of the end values: the panel integrals' bounds for a
    function monotone on every panel."""
    a, b = f[..., :-1], f[..., 1:]
    return jnp.sum(widths * jnp.minimum(a, b)), jnp.sum(widths * jnp.maximum(a, b))


def _simpson(f, dphi, span, n):
    """Simpson's rule in the graded variable x of each segment (s = lo + span phi(x)): O(h^4) where f is smooth
    on the segment, and phi' = 0 at both ends tames the t log t of the cost integrand at t = 0."""
    w = jnp.where(jnp.arange(n + 1) % 2 == 1, 4.0, 2.0).at[0].set(1.0).at[n].set(1.0) / (3.0 * n)
    return jnp.sum(span * w * dphi * f)


def _parts(control, model, t, cost):
    """(w of the outer ends, w of the inner ends, H) at one time: m = first - second. For shells each part is a
    weighted sum of w(b_i(t)) (or w(a_i(t))), nonincreasing in t wherever the ends are."""
    if hasattr(control, "shells"):
        a, b, wt = control.shells(model, t)
        w = lambda r: mass_fraction(model.u_of_rho(t, r), model.dim)  # noqa: E731
        return jnp.sum(wt * w(b)), jnp.sum(wt * w(a)), jnp.sum(wt * cost.shell_mass(model, t, a, b))
    m, H = control.profile(model, t, cost)
    return m, jnp.zeros_like(m), H


MEMO_SIZE = 4096  # results kept by ``masses``: a few scalars each


def masses(model: Infection, control, cost, n: int = 4096) -> Masses:
    """int_A g and int_A h of a control with a ``profile``, n panels per segment between consecutive
    breakpoints (n rounded up to even): the value by Simpson's rule in a graded variable, the bracket from the
    panels' end values (see the module docstring). A call with the same arguments as an earlier one (equal
    values, not only equal shapes) returns that call's result."""
    return _masses(model, control, cost, int(n))


@memoised(MEMO_SIZE)
@program_cache.jit
def _masses(model: Infection, control, cost, n: int) -> Masses:
    n = n + (n % 2)
    bp = model.s_of_t(control.breakpoints(model))
    bp = jnp.clip(jnp.where(jnp.isnan(bp), 0.0, bp), 0.0, S_MAX)
    edges = jnp.sort(jnp.concatenate([jnp.zeros(1), bp, jnp.full(1, S_MAX)]))
    lo_e, hi_e = edges[:-1], edges[1:]
    x = jnp.linspace(0.0, 1.0, n + 1)
    phi, dphi = x * x * (3.0 - 2.0 * x), 6.0 * x * (1.0 - x)
    span = (hi_e - lo_e)[:, None]
    nodes = lo_e[:, None] + span * phi[None, :]
    nodes = jnp.clip(nodes, lo_e[:, None] + NUDGE * span, hi_e[:, None] - NUDGE * span)
    widths = span * jnp.diff(phi)[None, :]
    t = jnp.maximum(model.t_of_s(nodes), T_MIN)
    outer, inner, H = jax.vmap(jax.vmap(lambda tt: _parts(control, model, tt, cost)))(t)
    o_lo, o_hi = _panel_bracket(outer, widths)
    i_lo, i_hi = _panel_bracket(inner, widths)
    hf = H / (model.k * (1.0 - nodes))
    h_lo, h_hi = _panel_bracket(hf, widths)
    g = model.R0 * _simpson(outer - inner, dphi, span, n)
    return Masses(g, model.R0 * (o_lo - i_hi), model.R0 * (o_hi - i_lo), _simpson(hf, dphi, span, n), h_lo, h_hi)


def level_set(cost, log_r, **kw) -> LevelSet:
    return LevelSet(cost=cost, log_r=log_r, **kw)


def F(model: Infection, cost, log_r, n: int = 4096) -> Masses:
    """F(r) = int_{L_r} g (4.7) (and the h-mass of L_r), at r = exp(log_r)."""
    return masses(model, level_set(cost, log_r), cost, n)


def bisect_largest(fun, target, lo, hi, iters: int = 64):
    """Largest x in [lo, hi] with fun(x) >= target, for fun nonincreasing (fun(lo) >= target assumed; returns
    hi if fun(hi) >= target). Traceable (``lax.fori_loop``); fun may return an array, each entry bisected on its
    own (then lo and hi are arrays of the same shape)."""
    lo, hi = jnp.asarray(lo, float), jnp.asarray(hi, float)
    done = fun(hi) >= target

    def body(_, c):
        lo, hi = c
        mid = 0.5 * (lo + hi)
        ok = fun(mid) >= target
        return jnp.where(ok, mid, lo), jnp.where(ok, hi, mid)

    lo, hi = jax.lax.fori_loop(0, iters, body, (lo, hi))
    return jnp.where(done, hi, lo)


def bisect_host(fun, target: float, lo: float, hi: float, xtol: float = 1e-13, max_iter: int = 200) -> float:
    """Largest x in [lo, hi] with fun(x) >= target for fun nonincreasing, as a host loop over a jitted ``fun``
    (float -> float): no program of its own to compile, so every search over one kind of set reuses the one
    compiled ``masses``.

    Regula falsi with the Illinois modification keeps the bracket fun(lo) >= target > fun(hi) and converges
    superlinearly where fun is smooth; a plain bisection step is taken whenever two steps have not halved the
    bracket, so a jump of fun (the non-unique case of (4.8)) costs at most twice a bisection. Returns lo once
    hi - lo <= xtol (or hi if fun(hi) >= target)."""
    f_hi = float(fun(hi)) - target
    if f_hi >= 0:
        return hi
    f_lo = float(fun(lo)) - target
    side, width, it = 0, hi - lo, 0
    while hi - lo > xtol and it < max_iter:
        it += 1
        if it % 2 == 0:
            halved = hi - lo <= 0.5 * width
            width = hi - lo
        else:
            halved = True
        if halved and f_lo > f_hi:
            x = (lo * f_hi - hi * f_lo) / (f_hi - f_lo)
            x = min(max(x, lo + 0.01 * xtol), hi - 0.01 * xtol)
        else:
            x = 0.5 * (lo + hi)
        fx = float(fun(x)) - target
        if fx >= 0:
            lo, f_lo = x, fx
            if side == 1:
                f_hi *= 0.5
            side = 1
        else:
            hi, f_hi = x, fx
            if side == -1:
                f_lo *= 0.5
            side = -1
    return lo


class Threshold(NamedTuple):
    """r_bar of (4.8) in log form, bracketed: log_r_lo <= log r_bar <= log_r_hi (rigorous for the untilted level
    sets: the bracket of F is, see the module docstring), with F and its bracket at the estimate."""

    log_r: float
    log_r_lo: float
    log_r_hi: float
    at: Masses


def threshold(model: Infection, cost, V: float, n: int = 4096, lo: float = -80.0, hi: float = 80.0,
              xtol: float = 1e-12) -> Threshold:
    """r_bar = max{r : F(r) >= V} by bisection on log r in [lo, hi], run on the Simpson value of F and on both
    ends of its bracket (F_lo <= F <= F_hi gives r_bar(F_lo) <= r_bar <= r_bar(F_hi))."""
    V = float(V)

    def at(x):
        return F(model, cost, jnp.asarray(x, float), n)

    x = bisect_host(lambda x: at(x).g, V, lo, hi, xtol)
    # the bracket's ends lie within a small fraction of a nat of x: search them from there (rigorous as long as
    # the answers stay inside, which is checked)
    w = 1.0
    x_lo = bisect_host(lambda x: at(x).g_lo, V, x - w, x + w, xtol)
    x_hi = bisect_host(lambda x: at(x).g_hi, V, x - w, x + w, xtol)
    if not (x - w < x_lo <= x + 2 * xtol and x - 2 * xtol <= x_hi < x + w):
        raise RuntimeError(f"the bracket of r_bar is wider than {w} nat: use more panels (n = {n})")
    # bisect_host returns the lower end of its final bracket: r_bar(F_hi) lies within xtol above x_hi
    return Threshold(x, x_lo, x_hi + xtol, at(x))
