"""twip-extra-control's config: the thesis's §8.2 settings (cases, gains, the network, the nonlinearities), the
variants of the extra control run beside the main law, and the thesis's Table 8.3 numbers."""

from __future__ import annotations

import math
from dataclasses import dataclass


from jaxdip import config as C
from jaxdip.plants import twip
from jaxdip.resources import Load, steps_of
from jaxdip.scenarios import twip_extra as S

CASES = S.CASES
SYSTEMS = S.SYSTEMS
STATES = twip.STATE_NAMES
DEG = math.pi / 180.0
# Table 8.3 (the thesis has no unmodeled_unstable row)
THESIS = {
    "param": {"lqr": 248.92, "extra": 123.07, "nominal": 240.72},
    "unmodeled": {"lqr": 587.04, "extra": 235.35, "nominal": 240.72},
    "deadzone": {"lqr": 358.42, "extra": 181.53, "nominal": 326.10},
    "deadzone_backlash": {"lqr": 1451.9, "extra": 688.17, "nominal": 1434.5},
}
# the controller's own keys: a variant changes numbers in ExtraControl's fields only (no recompilation)
VARIANT_KEYS = ("virtual", "virtual_sign", "k1", "k2", "gamma", "sigma", "b", "v_scale", "tau_d")
DEFAULT_VARIANTS = ("virtual=printed", "gamma=[0.0, 0.0, 0.0, 0.0]", "k1=10.0")
FIGS = {"param": ("8.15", "8.16"), "unmodeled": ("8.17", "8.19"), "unmodeled_unstable": ("8.18", "8.19"),
        "deadzone": ("8.20", "8.21"), "deadzone_backlash": ("8.22", "8.23")}


@dataclass
class TwipExtraControlConfig:
    seeds: int = C.field(1000, C.positive, doc="Monte Carlo seeds per case (network input weights, x0 spread)")
    seed: int = C.field(0, C.nonneg, doc="base PRNG key")
    cases: list[str] = C.field(list(CASES), doc="which of " + ", ".join(CASES) + " to run")
    duration: float = C.field(20.0, C.positive_finite, doc="simulated time (s); the score sums duration/dt samples")
    dt: float = C.field(0.01, C.positive_finite, doc="control period (s); also the Euler step of the weight laws")
    substeps: int = C.field(10, C.positive, doc="RK4 sub-steps of the true plant per control period")
    x0: list[float] = C.field([1.0, 0.3, 10.0, 1.0], C.finite, C.length(4),
                              doc="initial state [m, m/s, deg, deg/s] (184)")
    init_spread: float = C.field(0.1, C.nonneg_finite,
                                 doc="seed i > 0 starts at x0 * (1 + U(-s, s)) per component")
    v_d: float = C.field(0.1, C.finite, doc="desired constant velocity (m/s) (182)")
    lqr_Q: list[float] = C.field([1.0, 1.0, 0.1, 0.1], C.nonneg_finite, C.length(4),
                                 doc="LQR state weights on [x, x_dot, phi, phi_dot] (181)")
    lqr_R: float = C.field(1.0, C.positive_finite, doc="LQR input weight (180)")
    feedforward: bool = C.field(True, doc="u_nom includes the desired input u_d of (183) (false: (84) literally)")
    u_max: float = C.field(11.1, C.positive_finite, doc="saturation of every control signal (V), §7.5.1")
    k1: float = C.field(2.5, C.finite, doc="virtual-control gain k1 (93)")
    k2: float = C.field(2.5, C.finite, doc="extra-control gain k2 (101)")
    n_hidden: int = C.field(10, C.positive, doc="hidden neurons per layer of each network")
    b: float = C.field(1.0, C.finite, doc="entries of the coefficient vectors B1 = B2 of (111), (113)")
    gamma: list[float] = C.field([0.1, 0.1, 0.1, 0.1], C.nonneg_finite, C.length(4),
                                 doc="learning rates [gamma11, gamma12, gamma21, gamma22] (111)-(114)")
    sigma: list[float] = C.field([0.01, 0.01, 0.01, 0.01], C.nonneg_finite, C.length(4),
                                 doc="damping [sigma11, sigma12, sigma21, sigma22] (111)-(114)")
    v_scale: float = C.field(1.0, C.nonneg_finite, doc="random input weights V1, V2 ~ U(-v_scale, v_scale)")
    virtual: str = C.field("flat", C.one_of("printed", "effective", "flat"),
                           doc="virtual tilt (93): printed (A2), effective (A2 - B1 A4/B2), flat (that gain, flat-output "
                               "errors; see jaxdip.control.extra_control)")
    virtual_sign: float = C.field(1.0, doc="sign in front of the inverted gain of (93): 1 as printed, -1 reversed "
                                               "(the reading of a sign slip in (93))")
    tau_d: float = C.field(0.05, C.nonneg_finite,
                           doc="time constant (s) of the filtered difference giving xbar4 = d xbar3/dt (0: raw)")
    d_gains: list[float] = C.field([0.5, 0.25], C.finite, C.length(2), doc="coefficients of d1, d2 (185)")
    d_gains_unstable: list[float] = C.field([0.75, 0.4], C.finite, C.length(2),
                                            doc="coefficients of d1, d2 in unmodeled_unstable (Fig. 8.18)")
    d1_freq: float = C.field(180.0 / math.pi, C.finite, doc="d1 = g1 x' sin(d1_freq x) (185; printed 180/pi)")
    deadzone: float = C.field(0.5, C.nonneg_finite, doc="deadzone half-width (V), d- = -d, d+ = d (160)")
    backlash_deg: float = C.field(0.1, C.nonneg_finite, doc="backlash half-width on the tilt (deg), m = 1 (162)")
    backlash_law: str = C.field("standard", C.one_of("standard", "printed"),
                                doc="backlash (161): standard (engaged output at the new input) or printed (at the "
                                    "previous input u(k), as (161) is written)")
    nonlinear_truth: str = C.field("table_8_2", C.one_of("table_8_1", "table_8_2"),
                                   doc="perturbed truth of the deadzone cases (see the module doc)")
    tilt_bound_deg: float = C.field(90.0, C.positive_finite, doc="|phi| above this counts as a fall (diverged)")
    state_bound: list[float] = C.field([100.0, 50.0, 1000.0, 1000.0], C.positive, C.length(4),
                                       doc="|x|, |x_dot|, -, |phi_dot| above these count as diverged (phi: tilt_bound_deg)")
    variants: list[str] = C.field(list(DEFAULT_VARIANTS),
                                  doc="further LQR + extra rows on the same seeds, each 'key=value; key=value' over "
                                      "the controller keys " + ", ".join(VARIANT_KEYS))
    chunk_seeds: int = C.field(250, C.positive, doc="seeds per compiled batch")

    def loads(self) -> list[Load]:
        n = steps_of(self.duration, self.dt)
        return [Load("the Monte Carlo", ("seeds", "duration"), self.seeds, n, saved=24 * n,
                     state=64 * self.n_hidden + 256)]

    def validate(self):
        if self.virtual_sign not in (1.0, -1.0):
            raise C.ConfigError("virtual_sign", "must be 1 or -1")
        for i, spec in enumerate(self.variants):
            try:
                variant_config(self, spec)
            except C.ConfigError as e:
                raise C.ConfigError(f"variants[{i}]", str(e)) from None
        if not self.cases:
            raise C.ConfigError("cases", "must name at least one case")
        for i, c in enumerate(self.cases):
            if c not in CASES:
                raise C.ConfigError(f"cases[{i}]", f"must be one of {', '.join(map(repr, CASES))}")
        if self.duration < 2 * self.dt:
            raise C.ConfigError("duration", f"must cover at least two samples (dt = {self.dt})")


def variant_config(cfg, spec: str):
    """``cfg`` with the overrides of one ``variants`` entry ('k1=10; virtual=printed') applied and checked."""
    data = C.to_dict(cfg)
    data["variants"] = []
    items = [t.strip() for t in spec.split(";") if t.strip()]
    if not items:
        raise C.ConfigError(repr(spec), "a variant needs at least one key=value")
    for item in items:
        k, v = C.parse_set(item)
        if k not in VARIANT_KEYS:
            raise C.ConfigError(k, f"a variant may set only {', '.join(VARIANT_KEYS)}")
        data[k] = v
    return C.from_dict(type(cfg), data)
