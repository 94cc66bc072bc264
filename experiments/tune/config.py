"""tune's config: which target, the tuning and held-out seeds, the optimiser, and the spreads of the held-out
scenarios (drawn by ``jaxdip.scenarios.heldout``; see ``experiments.tune``)."""

from __future__ import annotations

from dataclasses import dataclass

from jaxdip import config as C
from jaxdip.resources import Load, steps_of
from jaxdip.scenarios.heldout import SCENARIO_KINDS
from jaxdip.scenarios.tune_targets import TARGETS


IMPLEMENTED = tuple(TARGETS)
HELDOUT_OFFSET = 1_000_000  # held-out seed i is base seed HELDOUT_OFFSET + i; tuning seeds are 0 .. seeds-1


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
