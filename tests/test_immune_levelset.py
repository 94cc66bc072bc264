"""Exact level-set boundaries of {g/h >= r} and the threshold r_bar of (4.8), against an independent SciPy
computation (brentq for every boundary and every time where the set changes shape, quad between those times,
brentq again for r_bar), for four costs: uniform, growing with distance, a costly shell, and a thin very costly
shell that cuts a gap narrower than 0.01 in u out of the set."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import integrate, optimize

from jaxdip.immune import quadrature as Q
from jaxdip.immune.controls import LevelSet
from jaxdip.immune.costs import Distance, Shell, Uniform
from jaxdip.immune.levelset import grid_intervals, piecewise_monotone_intervals
from jaxdip.immune.model import Infection

MODEL = Infection()
V = 2.0  # E[I] = 1
C, K, D = float(MODEL.c), float(MODEL.k), float(MODEL.diffusion)


class Reference:
    """F(r), int_{L_r} h and the shells of L_r for h = (1 + rho^2/l^2)(1 + extra 1{inner <= rho < outer}), d = 2,
    written from the formulas alone (plain floats, scipy)."""

    def __init__(self, ell=math.inf, inner=0.0, outer=0.0, extra=0.0):
        self.inv = 0.0 if math.isinf(ell) else 1.0 / ell**2
        self.inner, self.outer, self.extra = inner, outer, extra

    def log_g(self, t, rho):
        return math.log(C) - K * t - math.log(4 * math.pi * D * t) - rho**2 / (4 * D * t)

    def log_h(self, rho, piece):
        return math.log1p(rho**2 * self.inv) + (math.log1p(self.extra) if piece == 1 else 0.0)

    def pieces(self):
        return [p for p in [(0.0, self.inner, 0), (self.inner, self.outer, 1), (self.outer, 1e4, 2)] if p[1] > p[0]]

    def shells(self, t, lr):
        out = []
        for lo, hi, j in self.pieces():
            f = lambda rho: self.log_g(t, rho) - self.log_h(rho, j) - lr  # noqa: E731
            if f(lo) < 0:
                continue
            b = hi if f(hi) >= 0 else optimize.brentq(f, lo, hi, xtol=1e-15, maxiter=500)
            out.append((lo, b, j))
        return out

    def events(self, lr):
        """Times where a boundary meets rho = 0, inner or outer: sign changes on a fine log-t scan, brentq."""
        ts = np.exp(np.linspace(math.log(1e-9), math.log(60.0), 20001))
        ev = []
        for rho, j in [(0.0, 0), (self.inner, 0), (self.inner, 1), (self.outer, 1), (self.outer, 2)]:
            fn = lambda t: self.log_g(t, rho) - self.log_h(rho, j) - lr  # noqa: E731
            v = np.array([fn(t) for t in ts])
            for i in np.nonzero(np.sign(v[1:]) != np.sign(v[:-1]))[0]:
                ev.append(optimize.brentq(fn, ts[i], ts[i + 1], xtol=1e-15))
        return sorted(set(ev))

    def integrand(self, which, lr):
        def g(t):
            return C * math.exp(-K * t) * sum(math.exp(-a * a / (4 * D * t)) - math.exp(-b * b / (4 * D * t))
                                              for a, b, _ in self.shells(t, lr))

        def h(t):
            return sum(math.pi * (1.0 + (self.extra if j == 1 else 0.0))
                       * (b * b - a * a + self.inv * (b**4 - a**4) / 2) for a, b, j in self.shells(t, lr))

        return g if which == "g" else h

    def mass(self, lr, which="g"):
        ev = self.events(lr)
        pts = [0.0] + [e for e in ev if e < ev[-1]] + [ev[-1]]
        fn = self.integrand(which, lr)
        return sum(integrate.quad(fn, a, b, epsabs=1e-14, epsrel=1e-13, limit=500)[0]
                   for a, b in zip(pts[:-1], pts[1:]) if b - a > 1e-14)

    def log_r_bar(self, guess):
        return optimize.brentq(lambda lr: self.mass(lr) - V, guess - 0.5, guess + 0.5, xtol=1e-13)


CASES = {
    "uniform": (Uniform(), {}),
    "distance": (Distance(10.0), {"ell": 10.0}),
    "shell": (Shell(6.0, 10.0, 4.0), {"inner": 6.0, "outer": 10.0, "extra": 4.0}),
    # h = 51 on 8 <= |x| < 8.1: from t = 0.7 h on the gap it cuts is 0.1 / sqrt(4 D t) < 0.01 wide in u
    "thin gap": (Shell(8.0, 8.1, 50.0), {"inner": 8.0, "outer": 8.1, "extra": 50.0}),
}


@pytest.mark.parametrize("name", list(CASES))
def test_threshold_cost_and_boundaries_against_scipy(name):
    cost, kw = CASES[name]
    ref = Reference(**kw)
    th = Q.threshold(MODEL, cost, V, n=1024)
    lr_ref = ref.log_r_bar(th.log_r)
    # r_bar within 1e-8 relative, inside the rigorous bracket
    assert math.exp(th.log_r) == pytest.approx(math.exp(lr_ref), rel=1e-8)
    assert th.log_r_lo <= lr_ref <= th.log_r_hi
    # the bracket is a bound, not a fine-grid accident: it holds with 32 panels per segment too
    coarse = Q.threshold(MODEL, cost, V, n=32)
    assert coarse.log_r_lo <= lr_ref <= coarse.log_r_hi and coarse.log_r_hi - coarse.log_r_lo > 1e-3
    # the least cost int_{L_r_bar} h within 1e-8 relative
    h_ref = ref.mass(lr_ref, "h")
    assert float(th.at.h) == pytest.approx(h_ref, rel=1e-8)
    # the boundaries at several times, within 1e-10 (cell diameters)
    ls = LevelSet(cost=cost, log_r=jnp.asarray(lr_ref))
    checked = 0
    for t in np.linspace(0.02, 0.98 * ref.events(lr_ref)[-1], 23):
        a, b, _ = (np.asarray(v) for v in ls.shells(MODEL, jnp.asarray(t)))
        got = sorted((x, y) for x, y in zip(a, b) if y > x)
        want = [(x, y) for x, y, _ in ref.shells(t, lr_ref)]
        assert len(got) == len(want), t
        np.testing.assert_allclose(np.ravel(got), np.ravel(want), rtol=0, atol=1e-10)
        checked += len(want)
    assert checked >= 23


def test_the_thin_gap_is_there_and_a_grid_misses_it():
    """At t = 1 h the thin shell cuts a gap of 0.0083 in u out of the set: the exact method returns it, the
    129-point grid of the tilted sets fills it."""
    cost, kw = CASES["thin gap"]
    lr, t = -7.3, 1.0
    ref = Reference(**kw).shells(t, lr)
    assert [(a, j) for a, _, j in ref] == [(0.0, 0), (8.1, 2)] and ref[0][1] == 8.0  # a gap: [8, 8.1) left out
    ls = LevelSet(cost=cost, log_r=jnp.asarray(lr))
    a, b, _ = ls.shells(MODEL, jnp.asarray(t))
    inside = [(float(x), float(y)) for x, y in zip(a, b) if y > x]
    assert len(inside) == 2 and inside[0][1] == pytest.approx(8.0) and inside[1][0] == pytest.approx(8.1)
    u_gap = 0.1 / math.sqrt(4 * D * t)
    assert u_gap < 0.01
    tilted_like = LevelSet(cost=cost, log_r=jnp.asarray(lr))

    def f(u):
        rho = MODEL.rho_of_u(t, u)
        return tilted_like._f(MODEL, t, rho, 0.0)

    ga, gb, _ = grid_intervals(f)
    assert int(np.sum(np.asarray(gb) > np.asarray(ga))) == 1  # the grid sees one ball: the gap is lost


def test_piecewise_intervals_on_known_functions():
    # nonincreasing pieces with a jump up at 2 and a root in each piece: [0, 1) and [2, 3)
    edges = jnp.asarray([0.0, 2.0, 6.5])

    def f(u, j):
        return jnp.where(j == 0, 1.0 - u, 3.0 - u)

    a, b = piecewise_monotone_intervals(f, edges)
    np.testing.assert_array_equal(np.asarray(a), [0.0, 2.0])
    assert float(b[0]) == pytest.approx(1.0, abs=1e-15) and float(b[1]) == pytest.approx(3.0, abs=1e-15)
    # a piece wholly inside ends at its edge; one wholly outside is empty; a piece of width 1e-12 is resolved
    edges = jnp.asarray([0.0, 1.0, 1.0 + 1e-12, 6.5])
    a, b = piecewise_monotone_intervals(lambda u, j: jnp.where(j == 1, 1.0, -1.0) + 0.0 * u, edges)
    np.testing.assert_array_equal(np.asarray(b - a) > 0, [False, True, False])
    assert float(b[1] - a[1]) == pytest.approx(1e-12, rel=1e-3)


def test_boundary_tangent_is_the_implicit_one():
    def bound(s):
        return piecewise_monotone_intervals(lambda u, j: 2.0 - s * u**2, jnp.asarray([0.0, 6.5]))[1][0]

    s = 0.3
    assert float(jax.grad(bound)(s)) == pytest.approx(-0.5 * math.sqrt(2.0) * s**-1.5, rel=1e-9)  # sqrt(2 / s)
    # a boundary at a jump of the cost does not move with the threshold
    jump = lambda s: piecewise_monotone_intervals(  # noqa: E731
        lambda u, j: jnp.where(j == 0, s, -1.0) + 0.0 * u, jnp.asarray([0.0, 2.0, 6.5]))[1][0]
    assert float(jax.grad(jump)(1.0)) == 0.0


def test_event_times_against_brentq():
    rho = jnp.asarray([0.0, 6.0, 10.0])
    level = jnp.asarray([-7.0, -9.5, -12.0])
    t_left, t_right = MODEL.times_where_log_g(rho, level)
    ref = Reference()
    for i in range(3):
        fn = lambda t: ref.log_g(t, float(rho[i])) - float(level[i])  # noqa: E731
        roots = [optimize.brentq(fn, *br, xtol=1e-15) for br in _brackets(fn)]
        got = [float(v) for v in (t_left[i], t_right[i]) if not math.isnan(float(v))]
        np.testing.assert_allclose(got, roots, rtol=1e-12)
        assert len(roots) == (1 if i == 0 else 2)


def _brackets(fn):
    ts = np.exp(np.linspace(math.log(1e-8), math.log(100.0), 4001))
    v = np.array([fn(t) for t in ts])
    return [(ts[i], ts[i + 1]) for i in np.nonzero(np.sign(v[1:]) != np.sign(v[:-1]))[0]]
