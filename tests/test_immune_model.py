"""The infection model (A1)–(A6): samplers against scipy.stats, closed forms against scipy.special/integrate."""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import integrate, special
from scipy import stats as ss

from jaxdip.immune import controls as Ct
from jaxdip.immune.costs import Uniform
from jaxdip.immune.model import (Infection, extinction_iterates, extinction_probability, lower_gamma_series,
                                 mass_fraction, offspring_pgf)
from jaxdip.immune.quadrature import masses
from jaxdip.immune.sampling import CellSampler, sample_virion, simulate_cells

MODEL = Infection()


def z_score(sample_mean, expected, sd, n):
    return abs(sample_mean - expected) / (sd / math.sqrt(n))


def test_closed_forms():
    m = Infection(eta=0.2, beta=3.0, gamma=0.3, delta=0.7)
    assert float(m.mean_burst) == pytest.approx(15.0)
    assert float(m.R0) == pytest.approx(3.0 * 0.3 / (0.2 * 1.0))
    assert float(m.c) / float(m.k) == pytest.approx(float(m.R0))  # int g over all of T x R^d = R0


@pytest.fixture(scope="module")
def cells():
    return simulate_cells(CellSampler(MODEL, (Ct.NoControl(),)), jax.random.PRNGKey(1), 20000, chunk=4096)


def test_death_time_and_burst_against_scipy(cells):
    eta, beta = float(MODEL.eta), float(MODEL.beta)
    tau, Z = cells["tau"].astype(float), cells["Z"].astype(float)
    n = tau.size
    expo = ss.expon(scale=1 / eta)
    assert ss.kstest(tau, expo.cdf).pvalue > 1e-3
    # Z | tau Poisson(beta tau): the residual has mean 0 and variance E[beta tau]
    res = Z - beta * tau
    assert z_score(res.mean(), 0.0, math.sqrt(beta / eta), n) < 4.5
    assert res.var() == pytest.approx(beta / eta, rel=0.05)
    # marginally Z is geometric on {0, 1, ...} with p = eta / (eta + beta)
    geo = ss.geom(eta / (eta + beta), loc=-1)
    assert z_score(Z.mean(), geo.mean(), geo.std(), n) < 4.5
    assert Z.var() == pytest.approx(geo.var(), rel=0.06)
    p0 = geo.pmf(0)
    assert z_score(np.mean(Z == 0), p0, math.sqrt(p0 * (1 - p0)), n) < 4.5
    # no control: every virion that enters infects, so I is the entering count
    assert np.array_equal(cells["I"][:, 0], cells["entered"])


def test_virion_clocks_and_position_against_scipy():
    keys = jax.vmap(lambda i: jax.random.fold_in(jax.random.PRNGKey(2), i))(jnp.arange(200000))
    enters, t, x = jax.vmap(lambda k: sample_virion(MODEL, k))(keys)
    enters, t, x = np.asarray(enters), np.asarray(t), np.asarray(x)
    p = float(MODEL.entry_prob)
    assert z_score(enters.mean(), p, math.sqrt(p * (1 - p)), enters.size) < 4.5
    # given entry first, the entry time is Exp(gamma + delta) ...
    assert ss.kstest(t[enters], ss.expon(scale=1 / float(MODEL.k)).cdf).pvalue > 1e-3
    # ... and |W(t)|^2 / (2 D t) is chi-square with d degrees of freedom
    q = np.sum(x**2, axis=1) / (2 * float(MODEL.diffusion) * t)
    assert ss.kstest(q, ss.chi2(MODEL.dim).cdf).pvalue > 1e-3


@pytest.mark.parametrize("dim", [1, 2, 3])
def test_heat_kernel_mass_inside_a_ball(dim):
    m = Infection(dim=dim)
    t, rho = 0.37, 5.0
    D = float(m.diffusion)
    area = 2 * math.pi ** (dim / 2) / math.gamma(dim / 2)

    def p(r):
        return (4 * math.pi * D * t) ** (-dim / 2) * math.exp(-r * r / (4 * D * t)) * area * r ** (dim - 1)

    ref = integrate.quad(p, 0, rho, epsabs=1e-14, epsrel=1e-13)[0]
    got = float(mass_fraction(jnp.asarray(rho / math.sqrt(4 * D * t)), dim))
    assert got == pytest.approx(ref, abs=1e-12)
    u = np.linspace(0, 6, 50)
    np.testing.assert_allclose(np.asarray(mass_fraction(jnp.asarray(u), dim)), special.gammainc(dim / 2, u**2),
                               atol=1e-14)
    assert float(m.log_heat_kernel(t, rho)) == pytest.approx(math.log(p(rho) / (area * rho ** (dim - 1))), rel=1e-12)


@pytest.mark.parametrize("a", [0.5, 1.0, 1.5])
def test_lower_gamma_series(a):
    x = jnp.asarray([0.01, 0.7, 3.0, 25.0])
    got = np.asarray(lower_gamma_series(a, x, 40))
    ref = special.gammainc(a + np.arange(40)[None, :], np.asarray(x)[:, None])
    np.testing.assert_allclose(got, ref, atol=1e-13)


@pytest.mark.parametrize("dim", [2, 3])
def test_offset_ball_mass_against_noncentral_chi_square(dim):
    m = Infection(dim=dim)
    c = jnp.zeros(dim).at[0].set(8.0)
    ctrl = Ct.OffsetBallWindow(c, 6.0, 0.25, 2.0)
    D = float(m.diffusion)
    for t in (0.3, 1.0, 1.9):
        got = float(ctrl.profile(m, jnp.asarray(t), Uniform())[0])
        # |W - c|^2 / (2 D t) is noncentral chi-square with noncentrality |c|^2 / (2 D t)
        ref = ss.ncx2(dim, 64.0 / (2 * D * t)).cdf(36.0 / (2 * D * t))
        assert got == pytest.approx(ref, abs=1e-12)


def test_ball_window_quadrature_against_scipy_dblquad():
    m = MODEL
    ball = Ct.BallWindow(7.0, 0.3, 1.7)
    ms = masses(m, ball, Uniform(), 2048)
    c, k, D = float(m.c), float(m.k), float(m.diffusion)

    def integrand(r, t):
        return c * math.exp(-k * t) * math.exp(-r * r / (4 * D * t)) / (4 * math.pi * D * t) * 2 * math.pi * r

    ref = integrate.dblquad(integrand, 0.3, 1.7, 0.0, 7.0, epsabs=1e-12, epsrel=1e-12)[0]
    assert float(ms.g_lo) <= ref <= float(ms.g_hi)
    assert float(ms.g) == pytest.approx(ref, abs=1e-7)
    vol = math.pi * 49.0 * 1.4  # the ball's area times the window
    assert float(ms.h_lo) <= vol <= float(ms.h_hi)
    assert float(ms.h) == pytest.approx(vol, rel=1e-6)


def test_offspring_law_and_extinction():
    for R in (0.7, 1.0, 1.5, 3.0):
        q = float(extinction_probability(jnp.asarray(R)))
        assert q == pytest.approx(min(1.0, 1.0 / R), abs=2e-4 if R == 1.0 else 1e-10)
        its = np.asarray(extinction_iterates(jnp.asarray(R), 6))
        ref, v = [], 0.0
        for _ in range(6):
            v = 1.0 / (1.0 + R * (1.0 - v))
            ref.append(v)
        np.testing.assert_allclose(its, ref, rtol=1e-14)
    # G is the pgf of the geometric law with mean R
    R = 2.0
    geo = ss.geom(1 / (1 + R), loc=-1)
    s = 0.3
    assert float(offspring_pgf(s, R)) == pytest.approx(sum(geo.pmf(k) * s**k for k in range(200)), rel=1e-12)


def test_cells_follow_the_driver_seed_convention():
    """Cell i is ``sampler(fold_in(key, i))`` whatever the chunk and the run's length."""
    sampler = CellSampler(MODEL, (Ct.BallWindow(5.0, 0.0, 2.0),), thin=True)
    key = jax.random.PRNGKey(7)
    a = simulate_cells(sampler, key, 37, chunk=8)
    b = simulate_cells(sampler, key, 13, chunk=16)
    for k in a:
        assert a[k].shape[0] == 37 and b[k].shape[0] == 13
        np.testing.assert_array_equal(a[k][:13], b[k])
    one = eqx.filter_jit(CellSampler.__call__)(sampler, jax.random.fold_in(key, 5))
    for k in a:
        np.testing.assert_array_equal(a[k][5], np.asarray(one[k]))


def test_thinned_sampler_has_the_same_law():
    ctrl = (Ct.LevelSet(Uniform(), jnp.asarray(-7.28)),)
    full = simulate_cells(CellSampler(MODEL, ctrl), jax.random.PRNGKey(3), 8192, chunk=4096)
    thin = simulate_cells(CellSampler(MODEL, ctrl, thin=True), jax.random.PRNGKey(4), 8192, chunk=4096)
    for k in ("I", "Z"):
        a, b = full[k][:, 0] if k == "I" else full[k], thin[k][:, 0] if k == "I" else thin[k]
        a, b = a.astype(float), b.astype(float)
        se = math.sqrt(a.var() / a.size + b.var() / b.size)
        assert abs(a.mean() - b.mean()) < 4.5 * se
