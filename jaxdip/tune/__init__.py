"""Gradient-based tuning of hyperparameters with optax (``tune``), constrained through per-leaf transforms
(``Unconstrained``, ``Log``, ``Softplus``, ``Bounded``, ``SPDFactor``), a random-search baseline, and Monte Carlo
objectives over closed loops through ``jd.monte_carlo`` (``mc_objective``; ``checkpointed``: ``jax.checkpoint``
over chunks of the scan)."""

from jaxdip.tune.objective import Checkpointed, Objective, checkpointed, mc_objective, monte_carlo_at, seed_runs
from jaxdip.tune.transforms import (Bounded, Log, Softplus, SPDFactor, Transform, Unconstrained, to_constrained,
                                    to_unconstrained, unconstrained_spec)
from jaxdip.tune.tuner import (SearchResult, TuneResult, default_optimizer, random_search, tune,
                               value_and_grad_fn)

from jaxdip._public import public_dir

__all__ = ["Bounded", "Log", "Softplus", "SPDFactor", "Transform", "Unconstrained", "to_constrained",
           "to_unconstrained", "unconstrained_spec", "SearchResult", "TuneResult", "default_optimizer",
           "random_search", "tune", "value_and_grad_fn", "Checkpointed", "Objective", "checkpointed",
           "mc_objective", "monte_carlo_at", "seed_runs"]
__dir__ = public_dir(globals())
