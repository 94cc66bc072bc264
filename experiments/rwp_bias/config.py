"""rwp-bias's config: the paper's Table 1-2 values, the parts' horizons and seeds, the readings' switches."""

from __future__ import annotations

from dataclasses import dataclass


from jaxdip import config as C
from jaxdip.resources import Load, steps_of
from jaxdip.runner.experiment import precision_field

INF = float("inf")


def _gain3(v):
    return C.length(3)(v)


@dataclass
class RwpBiasConfig:
    seeds: int = C.field(1000, C.positive, doc="Monte Carlo seeds of part (a) (no bias)")
    seed: int = C.field(0, C.nonneg, doc="base PRNG key")
    dt: float = C.field(0.002, C.positive_finite, doc="sample period (s), 500 Hz in Table 1")
    substeps: int = C.field(10, C.positive, doc="RK4 sub-steps per period for the plant")
    observer_substeps: int = C.field(10, C.positive, doc="RK4 sub-steps per period for the continuous observers")
    hold: str = C.field("foh", C.one_of("foh", "zoh"),
                        doc="measurement between samples inside the observers: linear (foh) or last sample (zoh)")
    K: list[float] = C.field([-582.0, -83.0, -1.2], C.finite, _gain3,
                             doc="LQR gains on [theta, theta', theta_r'] (Table 2)")
    homd_pendulum: list[float] = C.field([5.0, 12.0, 0.9], C.positive_finite, _gain3,
                                         doc="[k_p1, k_p2, alpha_p] of (10) (Table 2)")
    homd_wheel: list[float] = C.field([5.0, 12.0, 0.9], C.positive_finite, _gain3,
                                      doc="[k_r1, k_r2, alpha_r] of (12) (Table 2)")
    luenberger_vref: list[float] = C.field([1.0, 10.0], C.positive_finite, C.length(2),
                                           doc="velocity steps (rad/s) at which L of (9) matches the HOMD rise time")
    luenberger_omega: list[float] = C.field([], C.positive_finite,
                                            doc="[omega_p, omega_r]: L of (9) with gains (omega k1, omega^2 k2) "
                                                "set directly (empty: matched to the HOMD's rise time)")
    current_limit: float = C.field(INF, C.positive, doc="|I| limit (A); the paper states none")
    observer_current: str = C.field("commanded", C.one_of("commanded", "applied"),
                                    doc="current in the observers' models under current_limit: the law's "
                                        "(commanded) or the clipped one (applied)")
    quantize: bool = C.field(True, doc="quantise the angles with the Table 1 resolutions")
    precision: str = precision_field()
    theta0: list[float] = C.field([0.1, 0.15], C.finite, doc="initial pendulum angles of part (a) (rad)")
    init_velocity_std: list[float] = C.field([0.01, 0.1], C.nonneg_finite, C.length(2),
                                             doc="std of the initial theta', theta_r' (rad/s)")
    no_bias_duration: float = C.field(5.0, C.positive_finite, doc="simulated time of part (a) (s)")
    settle_tol: float = C.field(0.005, C.positive_finite, doc="part (a) settle time: |theta| stays below this (rad)")
    stabilized_tol: list[float] = C.field([0.01, 2.0], C.positive_finite, C.length(2),
                                          doc="stabilised: |theta| (rad), |theta_r'| (rad/s) over the last second")
    bias: float = C.field(-0.08, C.finite, doc="sensor offset d of (6) (rad)")
    bias_theta0: float = C.field(0.1, C.finite, doc="initial pendulum angle of parts (b), (c) (rad)")
    bias_seeds: int = C.field(32, C.positive, doc="seeds of parts (b) and (c)")
    bias_duration: float = C.field(10.0, C.positive_finite, doc="simulated time of part (b) (s)")
    steady_window: float = C.field(2.0, C.positive_finite, doc="part (b): average over the last this many seconds")
    gamma_d: list[float] = C.field([0.05, 0.5], C.positive_finite, doc="gains of the low-pass observer (17)")
    lowpass_duration: float = C.field(120.0, C.positive_finite, doc="simulated time of the low-pass runs (s)")
    L0: float = C.field(0.01, C.positive_finite, doc="gain L0 of the reduced-order observer (21)/(24)")
    reduced_duration: float = C.field(30.0, C.positive_finite, doc="simulated time of the joint-observer run (s)")
    bias_settle_tol: float = C.field(0.05, C.positive_finite, doc="bias settled: |d_hat - d| <= this * |d|")
    gamma_check: list[float] = C.field([0.95, 1.05], C.positive_finite, C.length(2),
                                       doc="simulate law (18) at these multiples of gamma_d_bar")
    gamma_check_bias: float = C.field(-0.01, C.finite, doc="bias in the gamma_d_bar simulations (rad)")
    gamma_check_duration: float = C.field(150.0, C.positive_finite, doc="simulated time of those runs (s)")
    lmi_gamma: float = C.field(0.62, C.positive_finite, doc="gamma of (27)")
    lmi_mu: float = C.field(-0.2, C.finite, doc="mu of (27)")
    lmi_c0: float = C.field(0.9, C.positive_finite, doc="c0 of Assumption 2 (not given in the paper)")
    record_every: int = C.field(5, C.positive, doc="keep every n-th period for figures and settle times")

    def loads(self) -> list[Load]:
        every = self.record_every
        n_a = steps_of(self.no_bias_duration, self.dt)
        n_b = steps_of(max(self.bias_duration, self.lowpass_duration, self.reduced_duration,
                           self.gamma_check_duration), self.dt)
        return [Load("part (a)", ("seeds", "no_bias_duration", "record_every"), 2 * len(self.theta0) * self.seeds,
                     n_a, saved=8 * (n_a // every)),
                Load("the biased runs", ("bias_seeds", "lowpass_duration", "record_every"),
                     (len(self.gamma_d) + 2) * self.bias_seeds, n_b, saved=8 * (n_b // every))]

    def validate(self):
        for key in ("no_bias_duration", "bias_duration", "lowpass_duration", "reduced_duration",
                    "gamma_check_duration"):
            steps = int(round(getattr(self, key) / self.dt))
            if steps < 1:
                raise C.ConfigError(key, f"must be at least one period (dt = {self.dt})")
            if steps % self.record_every:
                raise C.ConfigError("record_every", f"must divide the number of periods of {key} ({steps})")
        for key in ("homd_pendulum", "homd_wheel"):
            a = getattr(self, key)[2]
            if not 0.5 < a <= 1.0:
                raise C.ConfigError(key, f"alpha must be in (0.5, 1], got {a}")
        if not self.lmi_c0 <= 1.0:
            raise C.ConfigError("lmi_c0", "must be in (0, 1]")
        if self.bias == 0.0:
            raise C.ConfigError("bias", "must be non-zero (parts (b)-(c) study a biased sensor)")
        if self.steady_window >= self.bias_duration:
            raise C.ConfigError("steady_window", "must be shorter than bias_duration")
        if not self.theta0:
            raise C.ConfigError("theta0", "needs at least one angle")
        if self.luenberger_omega and len(self.luenberger_omega) != 2:
            raise C.ConfigError("luenberger_omega", f"must be empty or have 2 entries, got {len(self.luenberger_omega)}")
        if not self.gamma_d:
            raise C.ConfigError("gamma_d", "needs at least one gain")


# ---- building loops ----------------------------------------------------------------------------------------
