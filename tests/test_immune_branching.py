"""Generations: extinction by Monte Carlo against the generating function's iterates."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats as ss

from jaxdip.immune import quadrature as Q
from jaxdip.immune.branching import simulate_generations
from jaxdip.immune.controls import LevelSet
from jaxdip.immune.costs import Uniform
from jaxdip.immune.model import Infection, extinction_iterates
from jaxdip.immune.sampling import CellSampler

MODEL = Infection()


def _run(lineages, generations, target=1.5):
    th = Q.threshold(MODEL, Uniform(), float(MODEL.R0) - target, n=1024)
    R = float(MODEL.R0) - float(th.at.g)
    sampler = CellSampler(MODEL, (LevelSet(cost=Uniform(), log_r=jnp.asarray(th.log_r)),), thin=True)
    return R, simulate_generations(sampler, jax.random.PRNGKey(2), lineages, generations, cap=200, chunk=2048)


def _check(R, sim, generations):
    q = np.asarray(extinction_iterates(R, generations))
    for e, qg in zip(sim["extinct_by_generation"], q):
        lo, hi = e["extinct_ci95"]
        pad = 0.5 * (hi - lo)  # Wilson 95% widened to ~3 sigma
        assert lo - pad <= qg <= hi + pad
    off = sim["offspring"]
    geo = ss.geom(1 / (1 + R), loc=-1)  # I is geometric with mean R
    n = off.size
    assert abs(off.mean() - geo.mean()) < 4.5 * geo.std() / np.sqrt(n)
    p0 = geo.pmf(0)
    assert abs(np.mean(off == 0) - p0) < 4.5 * np.sqrt(p0 * (1 - p0) / n)


def test_extinction_small():
    R, sim = _run(1024, 5)
    _check(R, sim, 5)


@pytest.mark.slow
def test_extinction_full():
    R, sim = _run(8192, 10)
    _check(R, sim, 10)
