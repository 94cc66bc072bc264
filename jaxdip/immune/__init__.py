"""Optimal antiviral protection at the onset of infection (thesis ch. 4) as differentiable Monte Carlo.

- ``model``: the infection process (A1)–(A6), R0, E[Z], g of (4.5), the offspring generating function;
- ``sampling``: exact sampling of infected cells and virions, run over many cells by ``jd.monte_carlo``;
- ``costs``: costs h of problem (P) (uniform, growing with distance, a costly shell, a flat-ratio construction);
- ``controls``: protection sets A (none, balls over windows, off-centre balls, indicators, level sets of g/h);
- ``levelset`` / ``quadrature``: exact shells of level sets, int_A g and int_A h with error brackets, F(r), r_bar;
- ``alternatives``: competitors tuned to the same target (best ball over a window, perturbed level sets);
- ``autonomous``: §4.5's cell-autonomous threshold rule and stochastic response; ``lattice``: its quadrature;
- ``branching``: several generations, extinction by Monte Carlo;
- ``tuning``: E[I] differentiable in the threshold, tuned with optax.
"""

from jaxdip.immune.autonomous import CellAutonomous, tie_probability
from jaxdip.immune.controls import (BallWindow, Indicator, LevelSet, NoControl, OffsetBallWindow, RandomTilt,
                                    Window)
from jaxdip.immune.costs import Distance, Flat, RadialCost, Shell, Uniform
from jaxdip.immune.model import Infection, extinction_iterates, extinction_probability, offspring_pgf
from jaxdip.immune.quadrature import F, Masses, Threshold, masses, threshold
from jaxdip.immune.sampling import CellSampler, simulate_cells
from jaxdip.immune.tuning import EnteringVirion, progeny_and_slope, tune_threshold

__all__ = [
    "BallWindow", "CellAutonomous", "CellSampler", "Distance", "F", "Flat", "Indicator", "Infection", "LevelSet",
    "Masses", "NoControl", "RadialCost", "OffsetBallWindow", "RandomTilt", "Shell", "Threshold", "Uniform", "Window",
    "EnteringVirion", "extinction_iterates", "extinction_probability", "masses", "offspring_pgf",
    "progeny_and_slope", "simulate_cells", "threshold", "tie_probability", "tune_threshold",
]
