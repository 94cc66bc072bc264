"""Several generations of the infection with the same per-cell control (beyond the chapter).

Every newly infected cell starts its own copy of the process (A1)–(A6) around itself, and the host answers it
with the same protection control relative to that cell (same shape in its own time since release and its own
position). In the branching approximation (an unbounded domain of susceptible cells, protections of
different infected cells not interacting) the offspring counts are i.i.d. with the law of I, geometric with
mean R = E[I] (``model.offspring_pgf``), so P(extinct by generation g) = G^g(0) and the extinction probability
is the smallest fixed point of G, min(1, 1/R).

The Monte Carlo runs ``lineages`` independent infections generation by generation, each cell's offspring
count from the full per-cell sampler (entry thinning on, see ``sampling``); a lineage whose generation reaches
``cap`` cells stops being simulated and counts as surviving from then on: a population of n cells dies out with
probability q^n (q the extinction probability from one cell), negligible at the cap used for R > 1.
"""

from __future__ import annotations

import jax
import numpy as np

from jaxdip import stats
from jaxdip.immune.sampling import CellSampler, simulate_cells


def simulate_generations(sampler: CellSampler, key, lineages: int, generations: int, *, cap: int = 1000,
                         chunk: int = 4096, progress: bool = False) -> dict:
    """Fractions of lineages extinct by generation 1 .. G (Wilson 95% intervals), mean generation sizes, and
    the pooled offspring counts of every simulated cell (first control of ``sampler``).

    Generation g's cells are numbered 0, 1, ... in lineage order and cell j uses ``fold_in(fold_in(key, g), j)``.
    """
    size = np.ones(lineages, dtype=np.int64)
    escaped = np.zeros(lineages, dtype=bool)
    extinct, mean_size, offspring = [], [], []
    for g in range(1, generations + 1):
        active = np.where(escaped, 0, size)
        owners = np.repeat(np.arange(lineages), active)
        if owners.size:
            out = simulate_cells(sampler, jax.random.fold_in(key, g), int(owners.size), chunk=chunk,
                                 progress=progress, desc=f"generation {g}")
            kids = np.asarray(out["I"][:, 0], dtype=np.int64)
            offspring.append(kids)
            size = np.bincount(owners, weights=kids, minlength=lineages).astype(np.int64)
        else:
            size = np.zeros(lineages, dtype=np.int64)
        escaped |= size >= cap
        dead = int(np.sum((size == 0) & ~escaped))
        p, ci = stats.wilson(dead, lineages)
        extinct.append({"generation": g, "extinct": p, "extinct_ci95": ci})
        mean_size.append(float(np.mean(np.where(escaped, cap, size))))
    return {"extinct_by_generation": extinct, "escaped": int(escaped.sum()), "cap": cap,
            "offspring": np.concatenate(offspring) if offspring else np.zeros(0, np.int64)}
