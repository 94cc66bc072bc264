"""Exact sampling of (A1)–(A6); many infected cells run through the library's driver ``jd.monte_carlo``.

One infected cell, from its key (seed convention: cell i of a run uses ``fold_in(base_key, i)``):
tau_eta ~ Exp(eta) (A1), Z | tau_eta ~ Poisson(beta tau_eta) (A2); virion j of the cell uses
``fold_in(fold_in(cell_key, 2), j)``: tau_delta ~ Exp(delta), tau_gamma ~ Exp(gamma) (A4)–(A5) and, if it
enters first, its position at entry W(tau_gamma) ~ N(0, 2 D tau_gamma I_d) (A6) — exact: whether it infects
depends on the path only through that point. The virions of a cell are drawn in blocks inside a
``while_loop`` until Z are done, so no cap on Z is needed (vmapped, the loop runs to the largest Z of the batch).

``thin=True`` draws the same law faster for the branching generations: each virion independently enters before
decaying with probability gamma / (gamma + delta), so given tau_eta the numbers that enter and that decay are
independent Poisson counts with means beta tau_eta p and beta tau_eta (1 - p) (Poisson splitting), and the entry
time of one that enters is Exp(gamma + delta) (the minimum of the two clocks, given which rings first); only
the entering virions are drawn.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jaxdip.engine.driver import monte_carlo
from jaxdip.immune.model import Infection


def sample_virion(model: Infection, key):
    """(enters, t, x): whether virion enters a cell before it decays, its entry time and position."""
    k_d, k_g, k_x = jax.random.split(key, 3)
    tau_d = jax.random.exponential(k_d) / model.delta
    tau_g = jax.random.exponential(k_g) / model.gamma
    x = jnp.sqrt(2.0 * model.diffusion * tau_g) * jax.random.normal(k_x, (model.dim,))
    return tau_g <= tau_d, tau_g, x


def sample_entering_virion(model: Infection, key):
    """(t, x) of a virion known to enter before decaying: t ~ Exp(gamma + delta), x ~ N(0, 2 D t I)."""
    k_t, k_x = jax.random.split(key)
    t = jax.random.exponential(k_t) / model.k
    return t, jnp.sqrt(2.0 * model.diffusion * t) * jax.random.normal(k_x, (model.dim,))


class CellSampler(eqx.Module):
    """One infected cell's progeny under each of several controls (common random numbers: the same virions)."""

    model: Infection
    controls: tuple
    block: int = eqx.field(static=True, default=16)
    thin: bool = eqx.field(static=True, default=False)

    def __call__(self, key) -> dict:
        m = self.model
        tau = jax.random.exponential(jax.random.fold_in(key, 0)) / m.eta
        k_vir, k_cell = jax.random.fold_in(key, 2), jax.random.fold_in(key, 3)
        if self.thin:  # Poisson splitting: entering and decaying virions are independent Poisson counts
            n = jax.random.poisson(jax.random.fold_in(key, 1), m.beta * m.entry_prob * tau)
            Z = n + jax.random.poisson(jax.random.fold_in(key, 4), m.beta * (1.0 - m.entry_prob) * tau)
        else:
            Z = n = jax.random.poisson(jax.random.fold_in(key, 1), m.beta * tau)

        def virion(j):
            kv = jax.random.fold_in(k_vir, j)
            if self.thin:
                t, x = sample_entering_virion(m, kv)
                enters = jnp.ones((), bool)
            else:
                enters, t, x = sample_virion(m, kv)
            prot = jnp.stack([c.protected(m, t, x, k_cell, kv) for c in self.controls])
            return enters & ~prot, enters

        def body(c):
            j0, counts, entered = c
            js = j0 + jnp.arange(self.block)
            inf, ent = jax.vmap(virion)(js)
            live = js < n
            return (j0 + self.block, counts + jnp.sum(inf & live[:, None], axis=0),
                    entered + jnp.sum(ent & live))

        zero = jnp.zeros((), Z.dtype)
        init = (zero, jnp.zeros(len(self.controls), Z.dtype), zero)
        _, counts, entered = jax.lax.while_loop(lambda c: c[0] < n, body, init)
        return {"tau": tau, "Z": Z, "entered": entered, "I": counts}


def simulate_cells(sampler: CellSampler, key, n: int, *, chunk: int = 2048, shard: bool | None = None,
                   progress: bool = False, desc: str = "cells") -> dict:
    """``sampler`` over n infected cells, cell i from ``fold_in(key, i)`` (the seed convention of
    ``jd.monte_carlo``, which runs it); NumPy arrays with a leading axis of n.

    The run is rounded up to whole chunks of ``chunk`` cells and cut back to n: cell i's numbers do not depend on
    how many cells run, and one compiled program then serves every n (the generations ask for a new n each time).
    """
    if n < 1:
        raise ValueError(f"n must be >= 1, got {n}")
    whole = math.ceil(n / chunk) * chunk
    out = monte_carlo(sampler, key, whole, chunk=chunk, shard=shard, progress=progress, desc=desc)
    return jax.tree_util.tree_map(lambda a: np.asarray(a)[:n], out)
