"""tune's config and its held-out scenarios: which targets exist, the tuning and held-out seeds, and the draw
that scales each held-out seed's initial state, sensor bias and disturbance (see ``experiments.tune``)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Optional

import equinox as eqx
import jax
import jax.numpy as jnp

from jaxdip import config as C
from jaxdip.resources import Load, steps_of


IMPLEMENTED = ("cpx", "rwp", "dmso", "rp", "extra")
HELDOUT_OFFSET = 1_000_000  # held-out seed i is base seed HELDOUT_OFFSET + i; tuning seeds are 0 .. seeds-1
# the held-out scenario of seed i is drawn from fold_in(key_i, SCENARIO_TAG): a stream none of the trial's own
# draws uses (they take fold_in(key_i, 0) and splits of key_i), so a seed's noise is the same with or without
# scenario variation, and the paper's, tuned and random-search values meet the same scenarios (paired)
SCENARIO_TAG = 0x5CE9A410
SCENARIO_KINDS = ("x0", "bias", "disturbance")


@dataclass
class TuneConfig:
    target: str = C.field("cpx", doc=f"what to tune: one of {', '.join(IMPLEMENTED)}")
    seeds: int = C.field(32, C.positive, doc="tuning seeds (common to every optimiser step with crn = true)")
    heldout_seeds: int = C.field(256, C.positive, doc="held-out evaluation seeds, disjoint from the tuning seeds")
    seed: int = C.field(0, C.nonneg, doc="base PRNG key")
    duration: float = C.field(2.0, C.positive_finite, doc="simulated time per closed loop (s)")
    substeps: int = C.field(10, C.positive, doc="RK4 sub-steps per period")
    steps: int = C.field(30, C.positive, doc="optimiser steps (at most)")
    lr: float = C.field(0.3, C.positive_finite,
                        doc="Adam learning rate / Rprop initial step (on the log of each hyperparameter)")
    optimizer: str = C.field("adam", C.one_of("adam", "rprop"),
                             doc="adam (after clipping), or rprop: per-coordinate steps that grow x1.2 while the "
                                 "gradient's sign holds and halve when it flips (clipping does not apply)")
    clip: float = C.field(1.0, C.positive_finite, doc="global-norm gradient clipping")
    crn: bool = C.field(True, doc="common random numbers: the same seeds' noise at every step (false: resample)")
    patience: int = C.field(10, C.nonneg, doc="early stopping after this many steps without improvement (0: off)")
    smoothing: str = C.field("straight_through", C.one_of("straight_through", "none"),
                             doc="derivative of the encoder quantiser: identity (straight-through) or 0 (exact)")
    mode: str = C.field("forward", C.one_of("forward", "reverse"), doc="forward- or reverse-mode derivatives")
    divergence_penalty: float = C.field(1000.0, C.nonneg_finite,
                                        doc="added to a diverged seed's loss (in the target's loss unit; not rp)")
    search_low: float = C.field(1.0, C.positive_finite, doc="random search / landscape: lowest gamma")
    search_high: float = C.field(1e5, C.positive_finite, doc="random search / landscape: highest gamma")
    landscape_points: int = C.field(9, C.positive, doc="points of the loss landscape along gamma")
    search_factor: float = C.field(10.0, C.positive_finite,
                                   doc="rwp, dmso, rp, extra: random search / landscape log-uniform within paper value "
                                       "x/÷ this")
    wheel_weight: float = C.field(1e-3, C.nonneg_finite,
                                  doc="rwp: weight of the integrated squared wheel speed ((rad/s)^2 s) in the loss")
    heldout_x0_spread: float = C.field(
        0.5, C.nonneg_finite,
        doc="held-out seeds: each scales its initial state by (1 + U(-s, s)) per entry (cpx, rp: the radius / std of "
            "the initial-state draw; rwp: theta0; dmso, extra: x0); 0: the tuning scenario")
    heldout_bias_spread: float = C.field(
        0.5, C.nonneg_finite,
        doc="held-out seeds: each scales the constant sensor bias by (1 + U(-s, s)) (rwp: d = -0.08 rad; the other "
            "targets have none)")
    heldout_disturbance_spread: float = C.field(
        0.5, C.nonneg_finite,
        doc="held-out seeds: each scales the disturbance's size by (1 + U(-s, s)) (cpx: the white input "
            "disturbance's std; rp: the state noise's std; extra: the gains of d1, d2 (185); rwp, dmso: none)")

    def loads(self) -> list[Load]:
        n = steps_of(self.duration, 0.001)  # the finest period of the targets (the DIP's 1 ms)
        return [Load("a tuning step", ("seeds", "duration"), self.seeds, n, saved=64 * n),
                Load("the held-out evaluation", ("heldout_seeds", "duration"), self.heldout_seeds, n)]

    def validate(self):
        if self.target not in IMPLEMENTED:
            raise C.ConfigError("target", f"must be one of {', '.join(map(repr, IMPLEMENTED))}")
        if self.search_high <= self.search_low:
            raise C.ConfigError("search_high", "must exceed search_low")
        for kind in SCENARIO_KINDS:
            if getattr(self, f"heldout_{kind}_spread") >= 1.0:  # a factor 1 + U(-s, s) must stay positive
                raise C.ConfigError(f"heldout_{kind}_spread", "must be below 1 (the factor 1 + U(-s, s) keeps its sign)")

    def scenario_spreads(self) -> dict:
        """{kind: spread} of the held-out scenario draw."""
        return {k: getattr(self, f"heldout_{k}_spread") for k in SCENARIO_KINDS}


class ScenarioDraw(eqx.Module):
    """A Monte Carlo trial ``fn(key, *rest)`` whose scenario is drawn per seed: every leaf that a ``where``
    selects is multiplied by 1 + U(-s, s) (independently per entry), from ``fold_in(key, SCENARIO_TAG)``; the
    trial then runs with its own key unchanged."""

    fn: Any
    wheres: tuple = eqx.field(static=True)
    spreads: tuple = eqx.field(static=True)

    def __call__(self, key, *rest):
        ks = jax.random.split(jax.random.fold_in(key, SCENARIO_TAG), len(self.wheres))
        fn = self.fn
        for where, s, k in zip(self.wheres, self.spreads, ks):
            leaf = where(fn)
            fn = eqx.tree_at(where, fn, leaf * scenario_factor(k, s, jnp.shape(leaf)))
        return fn(key, *rest)


def scenario_factor(key, spread: float, shape=()):
    """1 + U(-spread, spread), per entry of ``shape``."""
    return 1.0 + spread * jax.random.uniform(key, shape, minval=-1.0, maxval=1.0)


def with_scenarios(fn, leaves: dict, spreads: Optional[dict]):
    """``fn`` drawing its scenario per seed (``ScenarioDraw``) over the ``leaves`` ({kind: [where, ...]}) whose
    kind has a positive spread; ``fn`` itself when none has (the tuning scenario, unchanged)."""
    pairs = [(w, float(spreads[k])) for k, ws in leaves.items() for w in ws if spreads and spreads.get(k, 0.0) > 0]
    if not pairs:
        return fn
    return ScenarioDraw(fn, tuple(w for w, _ in pairs), tuple(s for _, s in pairs))
