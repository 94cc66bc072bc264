"""Quadrature of int_A g and int_A h, the function F(r) of (4.7) and the threshold r_bar of (4.8).

In the coordinate s = 1 - exp(-(gamma + delta) t) the g-integral of a control is R0 times the integral over
s in [0, 1) of m(s), the heat kernel's mass inside A(t(s)) (a number in [0, 1]); the h-integral is the integral
of H(t(s)) / ((gamma + delta)(1 - s)), H(t) = int_{A(t)} h dx. For radial controls the inner (space) integrals are
closed forms over shells (``controls.shells_profile``); only the s-integral is numerical: the trapezoid rule on
panels whose edges include every time where A(t) jumps.

Error bound. On a panel where the integrand is monotone, its integral lies between the panel width times the
smaller and times the larger endpoint value; summing gives a bracket [lo, hi] around the trapezoid value
(lo + hi) / 2, whose half-width is at most (max f - min f) / (2 n) per monotone piece with n panels. It is a
rigorous bound wherever the integrand is monotone on each panel: true of m(s) for the level sets of the uniform,
distance and flat costs and for balls (docs/immune.md derives it), and up to the few panels holding a turning
point otherwise (the costly shell, the h-integrands), where it is an estimate. The bracket of F(r) is
monotone in r (the level sets are nested and min/max keep the order), so bisection on its two ends brackets
r_bar rigorously as well.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxdip.engine import effort
from jaxdip.immune.controls import LevelSet
from jaxdip.immune.model import Infection

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


def _trapezoid_bracket(f, widths):
    a, b = f[..., :-1], f[..., 1:]
    return (jnp.sum(widths * 0.5 * (a + b)), jnp.sum(widths * jnp.minimum(a, b)),
            jnp.sum(widths * jnp.maximum(a, b)))


@effort.filter_jit
def masses(model: Infection, control, cost, n: int = 4096) -> Masses:
    """int_A g and int_A h of a control with a ``profile``, by the bracketed trapezoid rule in s, n panels per
    segment between consecutive breakpoints."""
    bp = jnp.clip(model.s_of_t(control.breakpoints(model)), 0.0, S_MAX)
    edges = jnp.sort(jnp.concatenate([jnp.zeros(1), bp, jnp.full(1, S_MAX)]))
    lo_e, hi_e = edges[:-1], edges[1:]
    frac = jnp.linspace(0.0, 1.0, n + 1)
    nodes = lo_e[:, None] + (hi_e - lo_e)[:, None] * frac[None, :]
    span = (hi_e - lo_e)[:, None]
    nodes = jnp.clip(nodes, lo_e[:, None] + NUDGE * span, hi_e[:, None] - NUDGE * span)
    widths = (hi_e - lo_e)[:, None] / n * jnp.ones((1, n))
    t = jnp.maximum(model.t_of_s(nodes), T_MIN)
    m, H = jax.vmap(jax.vmap(lambda tt: control.profile(model, tt, cost)))(t)
    g = _trapezoid_bracket(model.R0 * m, widths)
    h = _trapezoid_bracket(H / (model.k * (1.0 - nodes)), widths)
    return Masses(*g, *h)


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
    """r_bar of (4.8) in log form, bracketed: log_r_lo <= log r_bar <= log_r_hi (rigorous given the bracket
    of F), with F and its bracket at the estimate."""

    log_r: float
    log_r_lo: float
    log_r_hi: float
    at: Masses


def threshold(model: Infection, cost, V: float, n: int = 4096, lo: float = -80.0, hi: float = 80.0,
              xtol: float = 1e-12) -> Threshold:
    """r_bar = max{r : F(r) >= V} by bisection on log r in [lo, hi], run on the trapezoid value of F and on both
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
    return Threshold(x, x_lo, x_hi, at(x))
