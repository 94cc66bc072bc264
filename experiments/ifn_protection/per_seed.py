"""ifn-protection's per-seed data: the cells Monte Carlo, one seed per infected cell: its virions, and for every
control the cells its progeny infects (the rows share their virions), with the paired differences the report
compares. The lineage simulations of the generations are summarised per generation, not per seed: they stay in
metrics.json."""

from __future__ import annotations

import numpy as np

from jaxdip.runner.per_seed import PerSeed, fraction_of, mean_of


def cells_data(Z: np.ndarray, I: np.ndarray, names: list[str], partners: dict[str, str]) -> PerSeed:
    """``Z`` (seed,): virions released by the cell; ``I`` (seed, control): cells they infect under each control;
    ``partners``: lattice rule -> the continuum rule it is compared with, paired."""
    data = PerSeed(coords={"control": names, "paired_rule": list(partners),
                           "paired_partner": ("paired_rule", list(partners.values()))})
    data.add("virions", ("seed",), Z, "1", "virions the cell releases (Z)",
             **mean_of("model.E_Z_mc", None, "model.E_Z_ci95"))
    data.add("no_virion", ("seed",), Z == 0, "1", "the cell releases no virion",
             **fraction_of("model.P_Z0_mc", "model.P_Z0_ci95"))
    data.add("infected", ("seed", "control"), I, "1", "cells the cell's progeny infects under the control (I)",
             **mean_of("controls_mc.{control}.E_I_mc", None, "controls_mc.{control}.E_I_ci95"))
    pairs = np.stack([I[:, names.index(a)] - I[:, names.index(b)] for a, b in partners.items()], 1)
    data.add("paired_difference", ("seed", "paired_rule"), pairs, "1",
             "I under the lattice rule minus I under its continuum rule, the same virions",
             **mean_of("controls_mc.{paired_rule}.paired_difference_mc", None,
                       "controls_mc.{paired_rule}.paired_difference_ci95"))
    return data
