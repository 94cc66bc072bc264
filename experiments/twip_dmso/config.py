"""twip-dmso's config: the thesis's §8.1 settings (cases, periods, gains, the sensors of Table 7.1) and the
readings' switches."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from jaxdip import config as C
from jaxdip.resources import Load, steps_of

INF = float("inf")
CASES = ("nominal", "param", "noise")


@dataclass
class TwipDmsoConfig:
    seeds: int = C.field(1000, C.positive, doc="Monte Carlo seeds of the noisy case (sensor-noise draws)")
    det_seeds: int = C.field(64, C.positive,
                             doc="initial states per noiseless case (seed 0 is the thesis's x0, eq. 179)")
    seed: int = C.field(0, C.nonneg, doc="base PRNG key")
    cases: list[str] = C.field(list(CASES), doc="which of nominal, param (with its variants), noise to run")
    duration: float = C.field(20.0, C.positive_finite, doc="simulated time (s)")
    dt: float = C.field(0.01, C.positive_finite, doc="sample period of sensors, estimators and control (s)")
    dt_fine: float = C.field(0.001, C.positive_finite, doc="the param case's small-step variant (s)")
    duration_fine: float = C.field(20.0, C.positive_finite, doc="simulated time of the small-step variant (s)")
    rk4_step: float = C.field(0.001, C.positive_finite, doc="largest RK4 sub-step of the true plant (s)")
    x0: list[float] = C.field([1.0, 0.3, 10.0, 1.0], C.finite, C.length(4),
                              doc="true initial state [m, m/s, deg, deg/s] (179)")
    init_spread: float = C.field(0.2, C.nonneg_finite,
                                 doc="noiseless cases: seed i > 0 starts at x0 * (1 + U(-s, s)) per component")
    noise_init_spread: float = C.field(0.0, C.nonneg_finite, doc="the same for the noisy case (0: x0 always)")
    lqr_Q: list[float] = C.field([10.0, 10.0, 1e-5, 1e-4], C.nonneg_finite, C.length(4),
                                 doc="LQR state weights on [x, x_dot, phi, phi_dot] (152)")
    lqr_R: float = C.field(1000.0, C.positive_finite, doc="LQR input weight (151)")
    u_max: float = C.field(11.1, C.positive_finite, doc="motor voltage saturation (V), §7.5.1")
    dmso_K: list[float] | list[list[float]] = C.field([1.0, 1.0, 1.0, 1.0], C.finite,
                                                      doc="K_MSO: 4 diagonal entries or a 4x4 matrix (174)")
    dmso_gamma: float = C.field(0.1, C.nonneg_finite, doc="DMSO adaptation rate Gamma (175)")
    dmso_gamma_variant: float = C.field(0.5, C.nonneg_finite, doc="Gamma of the param case's variant (Fig. 8.9)")
    dt_fine_gamma: str = C.field("gamma", C.one_of("gamma", "variant"),
                                 doc="Gamma of the small-step variant (Figs. 8.10-8.11): dmso_gamma, or "
                                     "dmso_gamma_variant (the text comes to dt = 0.001 s after Fig. 8.9's Gamma)")
    basis_scale: list[float] = C.field([1.0, 1.0, 1.0, 1.0], C.finite, C.length(4),
                                       doc="s in the basis phi = [1, tanh(s_i x_i)] (thesis: 1)")
    kf_Q: list[float] = C.field([1e-4, 1e-2, 1e-4, 1e-2], C.nonneg_finite, C.length(4),
                                doc="KF process noise covariance diagonal (176)")
    kf_R: list[float] = C.field([1e-6, 1e-5, 4e-6, 2e-5], C.positive_finite, C.length(4),
                                doc="KF measurement noise covariance diagonal (177)")
    kf_P0: float = C.field(0.01, C.positive_finite, doc="KF initial covariance P0 = this * I (178)")
    kf_readings: bool = C.field(True, doc="also run the KF's posterior and printed readings (see module doc)")
    tilt_var: float = C.field(4.0397e-6, C.nonneg_finite,
                              doc="Table 7.1 tilt-angle white-noise variance (rad^2; printed 'rad')")
    tilt_bias_var: float = C.field(1.8929e-7, C.nonneg_finite,
                                   doc="Table 7.1 tilt walking-bias driving intensity (rad^2/s; printed 'rad/s')")
    tilt_tau: float = C.field(2160.0, C.positive_finite, doc="Table 7.1 tilt walking-bias time constant (s)")
    gyro_var: float = C.field(0.0012, C.nonneg_finite,
                              doc="Table 7.1 gyro white-noise variance ((deg/s)^2; printed 'deg/s')")
    gyro_bias_var: float = C.field(1.0986e-4, C.nonneg_finite,
                                   doc="Table 7.1 gyro walking-bias driving intensity ((deg/s)^2/s; printed 'deg/s^2')")
    gyro_tau: float = C.field(1610.0, C.positive_finite, doc="Table 7.1 gyro walking-bias time constant (s)")
    encoder_quantum: float = C.field(0.000147, C.nonneg_finite, doc="encoder position step (m), §7.4")
    encoder_gradient: str = C.field("exact", C.one_of("exact", "straight_through"),
                                    doc="derivative of the encoder quantiser: its exact a.e. 0, or 1 (gradients only)")
    bias_start: str = C.field("zero", C.one_of("zero", "stationary"),
                              doc="walking biases start at zero (removed at start-up, §4.3) or stationary")
    cf_alpha: float = C.field(0.99, C.nonneg_finite, doc="complementary filter weight alpha (37)")
    cf_init: str = C.field("accel", C.one_of("accel", "zero"),
                           doc="complementary filter starts at the first accelerometer tilt or at 0")
    band_noiseless: list[float] = C.field([1e-3, 1e-3, 1e-4, 1e-3], C.positive, C.length(4),
                                          doc="convergence band |error| per state, noiseless cases [m, m/s, rad, "
                                              "rad/s]")
    band_noise: list[float] = C.field([5e-4, 3e-2, 4e-3, 6e-3], C.positive, C.length(4),
                                      doc="convergence band, noisy case: about 5x the RMS measurement error after "
                                          "start-up (position one step ahead, velocity, CF tilt, gyro)")
    tail_s: float = C.field(5.0, C.positive_finite, doc="'ends better': RMS error over the last tail_s seconds")
    settle_s: float = C.field(0.25, C.nonneg_finite,
                              doc="settled relative uncertainty error is measured after this (s; thesis: the "
                                  "estimate converges in 0.25 s)")
    tilt_bound_deg: float = C.field(90.0, C.positive_finite, doc="|phi| above this counts as a fall (diverged)")
    chunk_seeds: int = C.field(64, C.positive, doc="seeds per compiled batch")

    def loads(self) -> list[Load]:
        # only the cases that run count: the noisy case at dt, the noiseless ones up to the small-step variant
        n = steps_of(self.duration, self.dt)
        nd = max(n, steps_of(self.duration_fine, self.dt_fine)) if "param" in self.cases else n
        det = {"nominal", "param"} & set(self.cases)
        return [Load("the Monte Carlo", ("seeds", "duration"), self.seeds if "noise" in self.cases else 0, n,
                     saved=48 * n),
                Load("the deterministic cases", ("det_seeds", "duration"), self.det_seeds if det else 0, nd,
                     saved=48 * nd)]

    def validate(self):
        for i, c in enumerate(self.cases):
            if c not in CASES:
                raise C.ConfigError(f"cases[{i}]", f"must be one of {', '.join(map(repr, CASES))}")
        if not self.cases:
            raise C.ConfigError("cases", "must name at least one case")
        K = np.asarray(self.dmso_K, dtype=float)
        if K.shape not in ((4,), (4, 4)):
            raise C.ConfigError("dmso_K", f"must be 4 diagonal entries or a 4x4 matrix, got shape {K.shape}")
        for name, dur, dt in (("duration", self.duration, self.dt), ("duration_fine", self.duration_fine,
                                                                     self.dt_fine)):
            if dur < 2 * dt:
                raise C.ConfigError(name, f"must cover at least two samples (dt = {dt})")
        if self.tail_s > self.duration:
            raise C.ConfigError("tail_s", f"must not exceed duration ({self.duration})")
        for name in ("dt", "dt_fine"):
            h = getattr(self, name)
            if self.rk4_step > h * (1 + 1e-9):
                raise C.ConfigError("rk4_step", f"must not exceed {name} ({h})")
