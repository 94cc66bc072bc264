"""Quadrature reference for §4.5's cell-autonomous rule on a lattice (``autonomous.CellAutonomous``).

A cell of side a centred at x_c is protected at time t while its sensed signal passes its threshold; while it is,
it removes from E[I] the g-mass of the cell, c e^{-kt} P(W_t in cell), with P(W_t in cell) a product of
normal-CDF differences (each coordinate of W_t has variance 2 D t). In s = 1 - e^{-kt}:

    int_A g = R0 sum_cells int_0^1 1{cell protected at t(s)} P(W_t(s) in cell) ds,

so the expected number of cells the first infected cell infects under the rule is E[I] = R0 - int_A g.

Each cell's protected times are found on a grid of ``n_s`` panels in s (sign changes of the rule's test, each
refined by bisection to 1e-15 in s) and P is integrated over the protected part of every panel by
Gauss–Legendre. A protection window shorter than a panel, or two switches inside one panel, could be missed:
the function returns the change from halving the grid as its error estimate, and the cells on the edge of the box
of cells it sums over must never be protected (checked: an error otherwise).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from jaxdip import program_cache
from jaxdip.immune.autonomous import log_cell_density, log_interval_prob
from jaxdip.immune.model import Infection

GL_POINTS = 8
BISECT_ITERS = 56
MAX_SWITCHES = 6  # per cell; more is an error (the grid would be too coarse to trust)


def _rule(model: Infection, cost, log_theta, size: float, offset):
    """The rule's test f(t, centre) >= 0 (``CellAutonomous.protected`` at the cell's centre), minus ``offset``."""

    def f(t, xc):
        log_v = log_cell_density(model, t, xc, size)
        log_g = log_v + jnp.log(model.gamma)
        rho_c = jnp.sqrt(jnp.sum(xc * xc))
        return cost.log_ratio(t, rho_c, log_g) - jnp.log(model.gamma) - log_theta - offset

    return f


def _log_cell_prob(model, t, xc, size):
    sigma = jnp.sqrt(2.0 * model.diffusion * t)
    return jnp.sum(log_interval_prob((xc - size / 2) / sigma, (xc + size / 2) / sigma))


@program_cache.jit
def _cells_mass(model, cost, log_theta, offset, centres, count, s_end, size, n_s: int):
    f = _rule(model, cost, log_theta, size, offset)
    x, w = np.polynomial.legendre.leggauss(GL_POINTS)
    x, w = jnp.asarray(x), jnp.asarray(w)
    s = jnp.linspace(0.0, 1.0, n_s + 1) * s_end
    s = s.at[0].set(s_end * 1e-12)  # t = 0 is a point mass

    def t_of(sv):
        return model.t_of_s(sv)

    def one(xc):
        fv = jax.vmap(lambda sv: f(t_of(sv), xc))(s)
        on = fv >= 0
        lo, hi = s[:-1], s[1:]
        on_lo, on_hi = on[:-1], on[1:]
        switch = on_lo != on_hi
        (idx,) = jnp.nonzero(switch, size=MAX_SWITCHES, fill_value=0)
        from_on = on_lo[idx]

        def body(_, c):  # the switch inside each panel whose ends disagree
            a, b = c
            mid = 0.5 * (a + b)
            same = (jax.vmap(lambda sv: f(t_of(sv), xc))(mid) >= 0) == from_on
            return jnp.where(same, mid, a), jnp.where(same, b, mid)

        a, b = jax.lax.fori_loop(0, BISECT_ITERS, body, (lo[idx], hi[idx]))
        cut = jnp.zeros(n_s).at[idx].set(0.5 * (a + b))
        # the protected part of each panel: all of it, none, [lo, cut) or [cut, hi)
        p_lo = jnp.where(on_lo, lo, cut)
        p_hi = jnp.where(on_hi, hi, cut)
        keep = on_lo | on_hi
        half = 0.5 * (p_hi - p_lo)
        nodes = (p_lo + half)[:, None] + half[:, None] * x[None, :]
        P = jnp.exp(jax.vmap(jax.vmap(lambda sv: _log_cell_prob(model, t_of(sv), xc, size)))(nodes))
        total = jnp.sum(jnp.where(keep, half * jnp.sum(w * P, axis=1), 0.0))
        return total, on.any(), on[-1], jnp.sum(switch) > MAX_SWITCHES

    def one_or_none(c):  # a padding row (``cells_mass``) costs a branch, not a cell's work
        xc, real = c
        none = (jnp.zeros(()), jnp.zeros((), bool), jnp.zeros((), bool), jnp.zeros((), bool))
        return jax.lax.cond(real, one, lambda _: none, xc)

    mass, ever, last, over = jax.lax.map(one_or_none, (centres, jnp.arange(centres.shape[0]) < count))
    return model.R0 * mass, ever, last.any() | over.any()


def _rows(k: int) -> int:
    """The padded number of cells for k: a power of two, at least 512, so that boxes of a few hundred cells of
    any size share one compiled program (each size compiled its own, about 0.5 s each)."""
    return max(512, 1 << (k - 1).bit_length())


def cells_mass(model: Infection, cost, log_theta, offset, centres, s_end, size,
               n_s: int) -> tuple[np.ndarray, np.ndarray, bool]:
    """(R0 times each cell's protected g-mass, whether each cell is ever protected, whether any cell is still
    protected on the last node or switches too often) for the cells centred at the rows of ``centres``, as NumPy
    arrays. A cell's numbers do not depend on the other rows (nor on the padding)."""
    centres = np.asarray(centres, float)
    k = centres.shape[0]
    padded = np.zeros((_rows(k), centres.shape[1]))
    padded[:k] = centres
    mass, ever, bad = _cells_mass(model, cost, log_theta, offset, jnp.asarray(padded), jnp.asarray(k), s_end, size,
                                  int(n_s))
    return np.asarray(mass)[:k], np.asarray(ever)[:k], bool(bad)


def lattice_mass(model: Infection, cost, log_theta, size: float, *, offset: float = 0.0, n_s: int = 2048,
                 reach: float, t_end: float) -> tuple[float, float]:
    """(int_A g, error estimate) for the cell-autonomous rule with cells of side ``size`` (cells protected where
    the test minus ``offset`` is >= 0). ``reach``: a distance beyond which no cell is ever protected (the box of
    cells summed over extends 2 cells past it, and its edge is checked); ``t_end``: a time after which no cell
    is protected (checked on the grid's last node)."""
    n_half = int(math.ceil(reach / size)) + 2
    idx = np.arange(-n_half, n_half + 1)
    grids = np.meshgrid(*([idx] * model.dim), indexing="ij")
    cells = np.stack([g.ravel() for g in grids], axis=1)
    edge = np.max(np.abs(cells), axis=1) >= n_half
    reps, copies = symmetry_classes(cells)
    s_end = float(model.s_of_t(t_end))
    args = (model, cost, jnp.asarray(log_theta, float), jnp.asarray(offset, float), reps * size,
            jnp.asarray(s_end), jnp.asarray(size, float))
    fine, ever, bad = cells_mass(*args, int(n_s))
    coarse, _, _ = cells_mass(*args, int(n_s) // 2)
    ever = ever[copies]
    if ever[edge].any():
        raise RuntimeError(f"cells on the edge of the lattice box (reach {reach}) are protected: raise reach")
    if bad:
        raise RuntimeError(f"a cell is still protected at t_end = {t_end} or switches more than {MAX_SWITCHES} "
                           "times: raise t_end or n_s")
    # summed over every cell of the box in its order, so the total is the one a pass over all cells gives
    fine, coarse = float(np.sum(fine[copies])), float(np.sum(coarse[copies]))
    return fine, abs(fine - coarse)


def symmetry_classes(cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(representatives, index of each cell's representative) of integer lattice cells (rows) under the
    symmetries that leave every cell's computed mass unchanged to the last bit.

    The rule and P(W_t in cell) see a cell through its coordinates one at a time (``log_interval_prob``, which
    gives a mirrored interval the same operands) and through sums over coordinates; costs are radial. So a
    sign flip of any coordinate changes no floating-point operation, and in dimension <= 2 neither does swapping
    coordinates (a sum of two terms is commutative in floating point; of three it is not associative, so in 3-d
    only the sign flips are used). Unit cells in 2-d then need an eighth of the work."""
    key = np.abs(cells)
    if cells.shape[1] <= 2:
        key = np.sort(key, axis=1)
    reps, copies = np.unique(key, axis=0, return_inverse=True)
    return reps, copies.reshape(-1)
