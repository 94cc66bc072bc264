"""§4.5: the cell-autonomous rule against the level set it implements; sensed densities against scipy."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import integrate
from scipy import stats as ss

from jaxdip import stats
from jaxdip.immune import quadrature as Q
from jaxdip.immune.autonomous import CellAutonomous, log_cell_density, log_interval_prob, theta_of_r
from jaxdip.immune.controls import LevelSet
from jaxdip.immune.lattice import lattice_mass
from jaxdip.immune.costs import Distance, Flat, Uniform
from jaxdip.immune.model import Infection
from jaxdip.immune.sampling import CellSampler, simulate_cells

MODEL = Infection()
LOG_R = -7.2765


def test_interval_probability_in_both_tails():
    for lo, hi in [(-1.0, 0.5), (6.0, 6.5), (-9.0, -8.0), (30.0, 31.0)]:
        ref = math.log(ss.norm.sf(lo) - ss.norm.sf(hi)) if lo > 0 else math.log(ss.norm.cdf(hi) - ss.norm.cdf(lo))
        assert float(log_interval_prob(jnp.asarray(lo), jnp.asarray(hi))) == pytest.approx(ref, rel=1e-10)


def test_cell_density_is_the_cell_average():
    t, a = 0.4, 1.0
    centre = np.array([3.0, -2.0])
    D = float(MODEL.diffusion)

    def dens(y, x):
        return float(MODEL.mean_burst) * math.exp(-float(MODEL.k) * t) * math.exp(-(x * x + y * y) / (4 * D * t)) \
            / (4 * math.pi * D * t)

    ref = integrate.dblquad(dens, centre[0] - a / 2, centre[0] + a / 2, centre[1] - a / 2, centre[1] + a / 2,
                            epsabs=1e-14, epsrel=1e-12)[0] / a**2
    assert float(log_cell_density(MODEL, t, jnp.asarray(centre), a)) == pytest.approx(math.log(ref), rel=1e-10)


@pytest.mark.parametrize("cost", [Uniform(), Distance(10.0)], ids=["uniform", "distance"])
def test_continuum_rule_is_the_level_set(cost):
    rule = CellAutonomous(cost, theta_of_r(MODEL, LOG_R), cell_size=0.0)
    ls = LevelSet(cost=cost, log_r=jnp.asarray(LOG_R))
    key = jax.random.PRNGKey(0)
    t = jax.random.uniform(key, (4000,), minval=0.01, maxval=2.5)
    x = 16.0 * jax.random.normal(jax.random.fold_in(key, 1), (4000, 2))
    a = jax.vmap(lambda tt, xx: rule.protected(MODEL, tt, xx, key, key))(t, x)
    b = jax.vmap(lambda tt, xx: ls.protected(MODEL, tt, xx, key, key))(t, x)
    assert 0.05 < float(jnp.mean(b)) < 0.95  # both answers occur
    np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


@pytest.mark.parametrize("cells", [8192, pytest.param(65536, marks=pytest.mark.slow)])
def test_lattice_rule_approaches_the_level_set_and_stochastic_band_meets_V(cells):
    ctrls = (LevelSet(cost=Uniform(), log_r=jnp.asarray(LOG_R)),
             CellAutonomous(Uniform(), theta_of_r(MODEL, LOG_R), cell_size=1.0))
    rf = LOG_R - 1.0
    F_flat = float(Q.F(MODEL, Flat(rf), jnp.asarray(rf), 1024).g)
    V = float(Q.F(MODEL, Uniform(), jnp.asarray(LOG_R), 1024).g)
    q = V / F_flat
    ctrls += (CellAutonomous(Flat(rf), theta_of_r(MODEL, rf), 1e-9, q, cell_size=0.0, stochastic=True),)
    out = simulate_cells(CellSampler(MODEL, ctrls), jax.random.PRNGKey(9), cells, chunk=4096)
    I = out["I"].astype(float)
    # lattice of unit cells against the continuum: paired (same virions), so the difference is tight
    d, dci = stats.mean_ci(I[:, 1] - I[:, 0])
    assert abs(d) < 0.03
    # the stochastic response on the flat band reaches E[I] = R0 - V on average
    m, ci = stats.mean_ci(I[:, 2])
    e = float(MODEL.R0) - V
    assert abs(m - e) < 1.5 * (ci[1] - ci[0]) / 2


@pytest.mark.parametrize("cells", [4096, pytest.param(32768, marks=pytest.mark.slow)])
def test_lattice_rule_monte_carlo_inside_its_quadrature_interval(cells):
    """The lattice rule's quadrature (unit cells and 4 x 4 squares) inside the Monte Carlo's 95% intervals: E[I]
    over infected cells, and the fraction of entering virions that infect (binomial given the entries)."""
    sizes = (1.0, 4.0)
    ctrls = tuple(CellAutonomous(Uniform(), theta_of_r(MODEL, LOG_R), cell_size=a) for a in sizes)
    out = simulate_cells(CellSampler(MODEL, ctrls), jax.random.PRNGKey(11), cells, chunk=4096)
    R0 = float(MODEL.R0)
    entered = int(out["entered"].sum())
    refs = []
    for j, a in enumerate(sizes):
        g, err = lattice_mass(MODEL, Uniform(), theta_of_r(MODEL, LOG_R), a, reach=22.0, t_end=3.0, n_s=512)
        assert err < 1e-6
        refs.append(g)
        m, ci = stats.mean_ci(out["I"][:, j].astype(float))
        assert ci[0] <= R0 - g <= ci[1], (a, m, ci, R0 - g)
        p, pci = stats.wilson(int(out["I"][:, j].sum()), entered)
        assert pci[0] <= 1.0 - g / R0 <= pci[1], (a, p, pci, 1.0 - g / R0)
    # coarser cells protect less of the g-mass than the continuum level set they approximate
    F = float(Q.F(MODEL, Uniform(), jnp.asarray(LOG_R), 1024).g)
    assert refs[1] < refs[0] < F


@pytest.mark.parametrize("dim", [2, 3])
def test_lattice_mass_by_symmetry_equals_the_sum_over_every_cell(dim):
    """lattice_mass computes one cell of each symmetry class: its total equals, to the last bit, a pass of the
    per-cell quadrature over every cell of the box (the mirrored and, in 2-d, swapped cells cost the same
    floating-point operations), for a radial cost with per-cell thresholds and for the flat band."""
    from jaxdip.immune.lattice import cells_mass, symmetry_classes

    model = Infection(dim=dim)
    # g spreads over more space in 3-d: a lower threshold reaches about as far
    reach, n_s, size, log_r = (10.0, 64, 2.0, LOG_R) if dim == 2 else (6.0, 16, 2.0, LOG_R - 1.0)
    t_end = 3.0
    for cost, offset in [(Distance(10.0), 0.0), (Flat(log_r), -1e-9)]:
        theta = theta_of_r(model, log_r)
        n_half = int(math.ceil(reach / size)) + 2
        idx = np.arange(-n_half, n_half + 1)
        cells = np.stack([g.ravel() for g in np.meshgrid(*([idx] * dim), indexing="ij")], axis=1)
        reps, copies = symmetry_classes(cells)
        assert len(reps) < len(cells) / (4 if dim == 2 else 6)
        s_end = jnp.asarray(float(model.s_of_t(t_end)))
        sums = []
        for n in (n_s, n_s // 2):
            every, _, _ = cells_mass(model, cost, jnp.asarray(theta), jnp.asarray(offset), jnp.asarray(cells * size),
                                     s_end, jnp.asarray(size), n)
            sums.append(float(np.sum(np.asarray(every))))
            if n == n_s:  # a cell's numbers do not depend on the other rows, their order or their count
                sub = len(cells) - 7
                part, _, _ = cells_mass(model, cost, jnp.asarray(theta), jnp.asarray(offset), cells[::-1][:sub] * size,
                                        s_end, jnp.asarray(size), n)
                assert np.array_equal(part, np.asarray(every)[::-1][:sub])
        assert sums[0] > 0
        g, err = lattice_mass(model, cost, theta, size, offset=offset, n_s=n_s, reach=reach, t_end=t_end)
        assert g == sums[0] and err == abs(sums[0] - sums[1])
