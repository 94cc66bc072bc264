"""§4.5: the cell-autonomous threshold rule and the stochastic response of the non-unique case.

A cell protects itself while the expected density of free virions it senses, v(t, x) = E[Z] e^{-kt} p(t, x)
= g(t, x) / gamma, is at least theta h(t, x): a per-cell threshold proportional to its cost. With h = 1 this is
L_r with r = gamma theta (Theorem 4.4.1 says the optimal set is exactly this); with a varying cost it is the
level set of g/h at the same r. So the optimal control needs no central planner: each cell compares a local
signal with its own threshold.

Cells here are the squares (cubes) of a lattice of spacing ``cell_size`` centred on the integer multiples of
it; a cell senses the virion density averaged over itself (the expected number of free virions in it divided by
its volume) and protects all of itself. ``cell_size = 0`` is the continuum limit, the level set itself.

Where g/h is flat at the threshold (Corollary 4.4.2 fails), a switch protects the whole flat set and
over-shoots the target; ``stochastic`` makes each cell on the tie band (|log(v / (theta h))| <= tie_tol)
respond with probability ``tie_prob``, drawn once per cell from the infected cell's key (a fixed random
pattern per infection), which meets the target in expectation at the optimal cost.
"""

from __future__ import annotations


import equinox as eqx
import jax
import jax.numpy as jnp
from jax.scipy.special import log_ndtr

from jaxdip.immune.model import as_float, Infection


def log_interval_prob(lo, hi):
    """log(Phi(hi) - Phi(lo)) without cancellation in either tail."""
    upper = lo > 0  # both in the upper tail: use Phi(-lo) - Phi(-hi)
    a = jnp.where(upper, -hi, lo)
    b = jnp.where(upper, -lo, hi)
    lb, la = log_ndtr(b), log_ndtr(a)
    return lb + jnp.log1p(-jnp.exp(jnp.minimum(la - lb, 0.0)))


def log_cell_density(model: Infection, t, center, size: float):
    """log of the expected free-virion density averaged over the cube of side ``size`` at ``center``."""
    sigma = jnp.sqrt(2.0 * model.diffusion * t)
    lp = jnp.sum(log_interval_prob((center - size / 2) / sigma, (center + size / 2) / sigma))
    return jnp.log(model.mean_burst) - model.k * t + lp - model.dim * jnp.log(size)


class CellAutonomous(eqx.Module):
    """Protect a cell while (sensed virion density) >= theta * h at the cell; see the module docstring."""

    cost: eqx.Module
    log_theta: jax.Array = eqx.field(converter=as_float)
    tie_tol: jax.Array = eqx.field(converter=as_float, default=0.0)
    tie_prob: jax.Array = eqx.field(converter=as_float, default=1.0)
    cell_size: float = eqx.field(static=True, default=1.0)
    stochastic: bool = eqx.field(static=True, default=False)

    def protected(self, model, t, x, key_cell, key_virion):
        if self.cell_size > 0:
            idx = jnp.round(x / self.cell_size)
            xc = idx * self.cell_size
            log_v = log_cell_density(model, t, xc, self.cell_size)
            ukey = key_cell
            for i in range(model.dim):
                ukey = jax.random.fold_in(ukey, idx[i].astype(jnp.int32))
        else:
            xc = x
            log_v = model.log_virion_density(t, jnp.sqrt(jnp.sum(x * x)))
            ukey = key_virion
        rho_c = jnp.sqrt(jnp.sum(xc * xc))
        log_g = log_v + jnp.log(model.gamma)
        f = self.cost.log_ratio(t, rho_c, log_g) - jnp.log(model.gamma) - self.log_theta
        if not self.stochastic:
            return f >= 0
        u = jax.random.uniform(jax.random.fold_in(ukey, 23))
        return (f > self.tie_tol) | ((f >= -self.tie_tol) & (u < self.tie_prob))


def theta_of_r(model: Infection, log_r):
    """The density threshold theta with gamma theta = r (log form)."""
    return log_r - jnp.log(model.gamma)


def tie_probability(F_strict, F_closed, V):
    """Probability with which cells on the tie band respond so that the expected g-mass is V: the band holds
    F(r_bar) - F(r_bar+) of it, the strict set F(r_bar+)."""
    return jnp.clip((V - F_strict) / (F_closed - F_strict), 0.0, 1.0)
