"""Gradient-based tuning of hyperparameters with optax (``tune``), constrained through per-leaf transforms
(``Log``, ``Softplus``, ``Bounded``, ``SPDFactor``), a random-search baseline, and memory-bounded Monte Carlo
objectives over closed loops (``mc_objective``: ``jax.checkpoint`` over chunks of the scan)."""

from jaxdip.tune.objective import Objective, checkpointed, mc_objective
from jaxdip.tune.transforms import (Bounded, Identity, Log, Softplus, SPDFactor, Transform, identity_spec,
                                    to_constrained, to_unconstrained)
from jaxdip.tune.tuner import (SearchResult, TuneResult, default_optimizer, random_search, tune,
                               value_and_grad_fn)

__all__ = ["Bounded", "Identity", "Log", "Softplus", "SPDFactor", "Transform", "identity_spec", "to_constrained",
           "to_unconstrained", "SearchResult", "TuneResult", "default_optimizer", "random_search", "tune", "value_and_grad_fn",
           "Objective", "checkpointed", "mc_objective"]
