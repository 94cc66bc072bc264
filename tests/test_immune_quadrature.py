"""Level sets, the bracketed quadrature of (4.4)/(4.7), r_bar of (4.8), and Theorem 4.4.1 at small scale."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import integrate, optimize, special

from jaxdip import stats
from jaxdip.immune import alternatives as Al
from jaxdip.immune import quadrature as Q
from jaxdip.immune.controls import BallWindow, LevelSet, OffsetBallWindow, Window
from jaxdip.immune.costs import Distance, Flat, Shell, Uniform
from jaxdip.immune.model import Infection
from jaxdip.immune.sampling import CellSampler, simulate_cells

MODEL = Infection()
LOG_R = -7.2765  # about the threshold with E[I] = 1 for the default model


def reference_F_and_volume(m, log_r):
    """F(r) and the space-time volume of L_r for h = 1 with scipy: the radius of L_r at time t solves
    |x|^2 = 4 D t L(t), L(t) = log c - log r - k t - (d/2) log(4 pi D t)."""
    c, k, D, d = float(m.c), float(m.k), float(m.diffusion), m.dim

    def L(t):
        return math.log(c) - log_r - k * t - d / 2 * math.log(4 * math.pi * D * t)

    t_max = optimize.brentq(L, 1e-12, 200.0, xtol=1e-15)
    F = integrate.quad(lambda t: c * math.exp(-k * t) * special.gammainc(d / 2, max(L(t), 0.0)), 0, t_max,
                       epsabs=1e-13, epsrel=1e-13, limit=400)[0]
    vd = math.pi ** (d / 2) / math.gamma(d / 2 + 1)
    vol = integrate.quad(lambda t: vd * (4 * D * t * max(L(t), 0.0)) ** (d / 2), 0, t_max, epsabs=1e-11,
                         epsrel=1e-13, limit=400)[0]
    return F, vol


@pytest.mark.parametrize("dim", [1, 2, 3])
def test_F_uniform_against_scipy(dim):
    m = Infection(dim=dim)
    log_r = LOG_R - (0.0 if dim == 2 else 2.0 * (dim - 2))
    F_ref, vol_ref = reference_F_and_volume(m, log_r)
    ms = Q.F(m, Uniform(), jnp.asarray(log_r), 2048)
    assert float(ms.g_lo) <= F_ref <= float(ms.g_hi)
    # the trapezoid value is far inside its bracket (d = 1: a square-root end point at t_max slows it)
    assert abs(float(ms.g) - F_ref) < 3e-5
    assert float(ms.h_lo) <= vol_ref <= float(ms.h_hi)
    assert float(ms.h) == pytest.approx(vol_ref, rel=5e-5)


def test_bracket_shrinks_like_one_over_n():
    w = [float(Q.F(MODEL, Uniform(), jnp.asarray(LOG_R), n).g_hi - Q.F(MODEL, Uniform(), jnp.asarray(LOG_R), n).g_lo)
         for n in (512, 2048)]
    assert w[0] / w[1] == pytest.approx(4.0, rel=0.05)


def test_distance_cost_level_set_against_scipy():
    m, ell = MODEL, 10.0
    c, k, D = float(m.c), float(m.k), float(m.diffusion)

    def radius(t):  # g(t, rho) = r (1 + rho^2 / ell^2): one crossing, found by brentq
        def f(rho):
            return (math.log(c) - k * t - math.log(4 * math.pi * D * t) - rho**2 / (4 * D * t)
                    - LOG_R - math.log1p((rho / ell) ** 2))
        return optimize.brentq(f, 0.0, 200.0, xtol=1e-14) if f(0.0) > 0 else 0.0

    t_max = optimize.brentq(lambda t: math.log(c) - k * t - math.log(4 * math.pi * D * t) - LOG_R, 1e-9, 50)
    g_ref = integrate.quad(lambda t: c * math.exp(-k * t) * -math.expm1(-radius(t) ** 2 / (4 * D * t)), 0, t_max,
                           epsabs=1e-12, epsrel=1e-12, limit=400)[0]
    h_ref = integrate.quad(lambda t: math.pi * radius(t) ** 2 + math.pi * radius(t) ** 4 / (2 * ell**2), 0, t_max,
                           epsabs=1e-9, epsrel=1e-12, limit=400)[0]
    ms = Q.F(m, Distance(ell), jnp.asarray(LOG_R), 2048)
    assert float(ms.g_lo) <= g_ref <= float(ms.g_hi)
    assert float(ms.g) == pytest.approx(g_ref, abs=1e-5)
    assert float(ms.h) == pytest.approx(h_ref, rel=1e-5)


def test_threshold_brackets_the_reference():
    V = 2.0
    th = Q.threshold(MODEL, Uniform(), V, n=1024)
    ref = optimize.brentq(lambda lr: reference_F_and_volume(MODEL, lr)[0] - V, -9.0, -6.0, xtol=1e-13)
    assert th.log_r_lo <= ref <= th.log_r_hi
    assert th.log_r == pytest.approx(ref, abs=1e-5)
    assert float(th.at.g) == pytest.approx(V, abs=1e-9)


def test_F_monotone_and_upper_semicontinuous():
    grid = np.linspace(LOG_R - 4, LOG_R + 3, 15)
    for cost in (Uniform(), Shell(6.0, 10.0, 4.0)):
        F = [Q.F(MODEL, cost, jnp.asarray(x), 512) for x in grid]
        lo, hi = np.array([float(f.g_lo) for f in F]), np.array([float(f.g_hi) for f in F])
        assert np.all(np.diff(lo) <= 0) and np.all(np.diff(hi) <= 0)
    # the flat cost: F jumps down at r_f; left-continuous, so F(r_f) is the larger one-sided value (u.s.c.)
    rf = LOG_R - 1.0
    cost = Flat(rf)
    at = float(Q.F(MODEL, cost, jnp.asarray(rf), 1024).g)
    before = [float(Q.F(MODEL, cost, jnp.asarray(rf - e), 1024).g) for e in (1e-2, 1e-4, 1e-8)]
    after = float(Q.F(MODEL, cost, jnp.asarray(rf + 1e-8), 1024).g)
    assert at == pytest.approx(float(Q.F(MODEL, Uniform(), jnp.asarray(rf), 1024).g), abs=1e-12)
    assert before[-1] == pytest.approx(at, abs=1e-6) and before[0] >= before[1] >= before[2] >= at - 1e-12
    assert after == 0.0 and at > 2.0


def test_stochastic_shells_weight_the_flat_band():
    rf = LOG_R - 1.0
    cost = Flat(rf)
    q = 0.37
    st = LevelSet(cost=cost, log_r=jnp.asarray(rf), stochastic=True, tie_tol=1e-9, tie_prob=q)
    got = Q.masses(MODEL, st, cost, 1024)
    full = Q.F(MODEL, cost, jnp.asarray(rf), 1024)
    assert float(got.g) == pytest.approx(q * float(full.g), rel=1e-9)
    assert float(got.h) == pytest.approx(q * float(full.h), rel=1e-9)
    # on the flat set h = g / r_f, so the cost of any part of it is its g-mass / r_f
    assert float(full.h) == pytest.approx(float(full.g) / math.exp(rf), rel=1e-6)
    late = Window(LevelSet(cost=cost, log_r=jnp.asarray(rf)), 0.3, jnp.inf)
    ml = Q.masses(MODEL, late, cost, 1024)
    assert float(ml.h) == pytest.approx(float(ml.g) / math.exp(rf), rel=1e-5)


def test_quadrature_against_monte_carlo():
    """(4.4) by quadrature inside the Monte Carlo interval for three kinds of set, on the same virions: a level
    set of a costly-shell h, a ball over a window, and a ball off the infected cell (not radial about it)."""
    ctrls = (LevelSet(cost=Shell(6.0, 10.0, 4.0), log_r=jnp.asarray(LOG_R)), BallWindow(8.0, 0.2, 1.5),
             OffsetBallWindow(jnp.asarray([8.0, 0.0]), 6.0, 0.25, 2.0))
    out = simulate_cells(CellSampler(MODEL, ctrls), jax.random.PRNGKey(5), 16384, chunk=4096)
    for j, ctrl in enumerate(ctrls):
        m, ci = stats.mean_ci(out["I"][:, j].astype(float))
        e = float(MODEL.R0) - float(Q.masses(MODEL, ctrl, Uniform(), 1024).g)
        half = (ci[1] - ci[0]) / 2
        assert abs(m - e) < 1.5 * half, j  # 1.5 x the 95% half-width: a 3-sigma check
    # the controls remove different amounts, so the check can tell them apart
    assert out["I"][:, 0].mean() < out["I"][:, 1].mean() < out["I"][:, 2].mean()


def test_level_set_beats_ball_and_perturbation():
    V, n = 2.0, 1024
    th = Q.threshold(MODEL, Uniform(), V, n=n)
    ball, bm = Al.best_ball_window(MODEL, Uniform(), V, grid=10, refine=1, n_quad=n)
    assert float(bm.g) == pytest.approx(V, abs=1e-9)
    assert float(bm.h_lo) > float(th.at.h_hi)
    (pert, pm), = Al.perturbations(MODEL, Uniform(), th.log_r, V, jax.random.PRNGKey(0), 1, eps=1.0, n_quad=n)
    assert float(pm.g) == pytest.approx(V, abs=1e-9)
    assert float(pm.h) > float(th.at.h)


def test_masses_returns_a_repeat_from_its_memo_and_recomputes_any_other_value():
    """A call equal in every value to an earlier one returns that result; an argument one ulp away, another cost
    or another n is computed afresh (against the compiled quadrature called directly), and a traced call (inside
    a gradient) is never served from the memo."""
    x = LOG_R + 0.1234567
    a = Q.masses(MODEL, LevelSet(cost=Uniform(), log_r=jnp.asarray(x)), Uniform(), 64)
    b = Q.masses(MODEL, LevelSet(cost=Uniform(), log_r=jnp.asarray(x)), Uniform(), 64)
    assert a is b
    near = float(np.nextafter(x, np.inf))
    for ctrl, cost, n in [(LevelSet(cost=Uniform(), log_r=jnp.asarray(near)), Uniform(), 64),
                          (LevelSet(cost=Distance(10.0), log_r=jnp.asarray(x)), Distance(10.0), 64),
                          (LevelSet(cost=Uniform(), log_r=jnp.asarray(x)), Uniform(), 32)]:
        got = Q.masses(MODEL, ctrl, cost, n)
        assert got is not a
        assert all(float(u) == float(v) for u, v in zip(got, Q._masses(MODEL, ctrl, cost, n)))
    assert float(Q.masses(MODEL, LevelSet(cost=Uniform(), log_r=jnp.asarray(near)), Uniform(), 64).g) != float(a.g)
    # under a trace the memo is bypassed: the gradient is the gradient of F, not of a stored constant
    g = jax.grad(lambda lr: Q.masses(MODEL, LevelSet(cost=Uniform(), log_r=lr), Uniform(), 64).g)(jnp.asarray(x))
    assert float(g) < 0


def test_compiled_breakpoints_equal_the_op_by_op_ones():
    """``controls.breakpoints`` (one compiled program) gives a control's breakpoints to the last bit as the
    method run op by op does, for level sets of radial and flat costs, a stochastic one and a window."""
    from jaxdip.immune.controls import breakpoints

    flat = Flat(LOG_R - 0.5)
    for ctrl in [LevelSet(cost=Uniform(), log_r=jnp.asarray(LOG_R)),
                 LevelSet(cost=Shell(6.0, 10.0, 4.0), log_r=jnp.asarray(LOG_R - 0.3)),
                 LevelSet(cost=flat, log_r=jnp.asarray(LOG_R), stochastic=True, tie_tol=1e-9, tie_prob=0.5),
                 Window(LevelSet(cost=Uniform(), log_r=jnp.asarray(LOG_R)), jnp.asarray(0.5), jnp.asarray(jnp.inf))]:
        want = np.asarray(ctrl.breakpoints(MODEL))
        assert np.isfinite(want).any()
        np.testing.assert_array_equal(np.asarray(breakpoints(MODEL, ctrl)), want)
