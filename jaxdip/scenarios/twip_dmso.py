"""The TWIP estimation study of Stumfoll §8.1: the DMSO and the Kalman filter, each closing its own loop.

Closed loop per sample: sensors (``TwipSensors``: §7.4 with the complementary filter on the tilt, or y = x) ->
estimator -> discrete LQR (149)-(152) on the estimate, clipped at +-u_max inside the controller (so the u_{k-1}
an estimator is given is the voltage applied) -> the nonlinear TWIP (72)-(73) over dt by RK4 sub-steps. The
estimators and the LQR use the nominal linear model (79) with Table 8.1 discretised exactly (148).

Estimators (``estimator``): dmso (``DMSO``, a one-step predictor), kf (``KalmanFilter`` handing out its prior:
the DMSO's information), kf_posterior (its posterior), kf_printed ((170) as printed: updated with the previous
sample's measurement). Each closes its own loop: the controller acts on that estimator's estimate, so the
estimators are not fed the same measurements and a ``FanOut`` (one driving, the others listening) would
compare something else than the thesis does.

A trial (``Trial``) records the whole trajectory inside the compiled program and reduces it to the per-seed
metrics of the study (``seed_metrics``), with the DMSO's fhat taken from its ``aux``; only seed 0's trace
leaves the program (``monte_carlo(..., detail=split_trace)``).
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import jaxdip as jd
from jaxdip.control.feedback import SaturatedFeedback
from jaxdip.control.twip_lqr import TwipDesign, twip_dlqr
from jaxdip.estimators.dmso import DMSO, DMSOAux, selection_matrix
from jaxdip.estimators.kf import KalmanFilter
from jaxdip.estimators.wrappers import DelayedMeasurement, Prior
from jaxdip.plants import twip
from jaxdip.scenarios.twip_initial import Spread, exact_first
from jaxdip.sim.twip_sensors import DEG, TwipSensors

ESTIMATORS = ("dmso", "kf", "kf_posterior", "kf_printed")
UNCERTAIN_ROWS = (1, 3)  # B_MSO (173): the x_dot and phi_dot rows
# how each KF reading is taken from the one filter: its prior (the DMSO's information), its posterior, or (170) as
# printed, the update fed the previous sample's y (C xhat0 = 0 before the first)
KF_READING = {"kf": Prior, "kf_posterior": lambda kf: kf, "kf_printed": lambda kf: DelayedMeasurement(kf, jnp.zeros(4))}


def design(dt: float, lqr_Q=(10.0, 10.0, 1e-5, 1e-4), lqr_R=1000.0) -> TwipDesign:
    return twip_dlqr(twip.TWIP(), lqr_Q, lqr_R, dt)


def _diag(v):
    a = np.asarray(v, dtype=np.float64)
    return np.diag(a) if a.ndim == 1 else a


def estimator(name: str, d: TwipDesign, *, dmso_K=(1.0, 1.0, 1.0, 1.0), dmso_gamma=0.1,
              basis_scale=(1.0, 1.0, 1.0, 1.0), kf_Q=(1e-4, 1e-2, 1e-4, 1e-2), kf_R=(1e-6, 1e-5, 4e-6, 2e-5),
              kf_P0=0.01):
    """One of ``ESTIMATORS`` on the design's (F, G): the DMSO with K_MSO (174), Gamma (175), or the KF with the
    Q, R, P0 of (176)-(178); estimates start at zero."""
    if name == "dmso":
        return DMSO.thesis(d.F, d.G, selection_matrix(4, UNCERTAIN_ROWS), K=_diag(dmso_K), Gamma=dmso_gamma,
                           basis_scale=basis_scale)
    if name not in KF_READING:
        raise ValueError(f"unknown estimator {name!r}; choose one of {ESTIMATORS}")
    return KF_READING[name](KalmanFilter(d.F, d.G, jnp.eye(4), jnp.asarray(_diag(kf_Q)), jnp.asarray(_diag(kf_R)),
                                         kf_P0 * jnp.eye(4), jnp.zeros(4)))


def sensors(dt: float, noisy: bool, *, tilt_var=4.0397e-6, tilt_bias_var=1.8929e-7, tilt_tau=2160.0,
            gyro_var=0.0012, gyro_bias_var=1.0986e-4, gyro_tau=1610.0, encoder_quantum=0.000147,
            encoder_gradient="exact", bias_start="zero", cf_alpha=0.99, cf_init="accel") -> TwipSensors:
    """Table 7.1's sensors (printed units read as in ``jaxdip.sim.twip_sensors.table_7_1``) with the
    complementary filter, or (``noisy=False``) y = x with the same structure."""
    return TwipSensors.table_7_1(
        dt, tilt_white_std=math.sqrt(tilt_var), tilt_gm_sigma=math.sqrt(tilt_bias_var), tilt_gm_tau=tilt_tau,
        gyro_white_std=math.sqrt(gyro_var) * DEG, gyro_gm_sigma=math.sqrt(gyro_bias_var) * DEG,
        gyro_gm_tau=gyro_tau, encoder_quantum=encoder_quantum, cf_alpha=cf_alpha, ideal=0.0 if noisy else 1.0,
        stationary_start=bias_start == "stationary", straight_through=encoder_gradient == "straight_through",
        cf_init_from_angle=cf_init == "accel")


def loop(est, sens: TwipSensors, d: TwipDesign, *, truth="8.2", rk4_step=0.001, u_max=11.1,
         tilt_bound_deg=90.0) -> jd.Loop:
    """The loop of one estimator (``estimator(...)``) on the truth of Table ``truth``; RK4 sub-steps of at
    most ``rk4_step``; |phi| above ``tilt_bound_deg`` counts as a fall."""
    dt = sens.dt
    substeps = max(1, int(math.ceil(dt / rk4_step - 1e-9)))
    return jd.Loop(plant=twip.TWIP.table(truth), sensor=sens, estimator=est,
                   controller=SaturatedFeedback(d.K, -u_max, u_max), dt=dt, substeps=substeps,
                   state_bound=[math.inf, math.inf, tilt_bound_deg * DEG, math.inf])


# ---- one trial ------------------------------------------------------------------------------------------------


def record(sample: jd.Sample) -> dict:
    """Per period: x, the estimate, u, y, and the DMSO's fhat_{k-1} (zeros for the other estimators)."""
    a = sample.aux.estimator
    fhat = a.fhat if isinstance(a, DMSOAux) else jnp.zeros(len(UNCERTAIN_ROWS))
    return {"x": sample.x, "xhat": sample.xhat, "u": sample.u[0], "y": sample.y, "fhat": fhat}


# The f of (153) read three ways (``F_READINGS``): x_dt,k+1 of the linear model (148) from the true state
# (the one-step mismatch, the default), from the estimate the DMSO hands out, or run free from x_0 with the
# applied inputs (x_dt as its own trajectory; unstable open loop, so it drifts from the truth).
F_READINGS = ("one_step", "estimated", "open_loop")


def _open_loop(x0, u, F, G):
    def step(z, uk):
        return F @ z + G[:, 0] * uk, z

    return jax.lax.scan(step, x0, u)[1]


def trace(rec: dict, F, G) -> dict:
    """The recorded trajectory with f_k = B^T (x_{k+1} - F x_k - G u_k) (153) and fhat_k aligned to it;
    ``f_readings`` stacks B^T f_k under each of ``F_READINGS`` (shape (3, T - 1, 2))."""
    rows = list(UNCERTAIN_ROWS)
    x, u = rec["x"], rec["u"]
    lin = lambda z: z @ F.T + u[:-1, None] @ G.T  # noqa: E731
    f = x[1:] - lin(x[:-1])
    f_est = x[1:] - lin(rec["xhat"][:-1])
    f_ol = x[1:] - _open_loop(x[0], u, F, G)[1:]
    return {**rec, "f": f[:, rows], "fhat": rec["fhat"][1:],
            "f_readings": jnp.stack([f[:, rows], f_est[:, rows], f_ol[:, rows]])}


def seed_metrics(tr: dict, band, dt: float, tail_s: float, settle_s: float) -> dict:
    """Per-seed metrics. Error RMS values skip sample 0, where dmso, kf and kf_printed all hand out the common
    initial guess (zero) before any measurement has reached them.

    ``peak_1s``: largest |error| over samples 1..1 s; ``logmean_tail``: mean of log10 |error| over the tail
    (what a log plot such as Figs. 8.3 and 8.7 shows as the lower line). ``u_*``: the uncertainty estimate
    against f under each of ``F_READINGS`` (shape (3, 2)): RMS of fhat - f and of f over the run and after
    ``settle_s``, the largest |fhat - f| over the run and after ``settle_s``, the largest |f|, the mean |fhat - f|
    and |f| after ``settle_s`` and the median of the pointwise ratio |fhat - f| / |f| after ``settle_s``;
    ``unc_conv_<p>``: the time after which |fhat - f| stays within p% of the row's largest |f| (Fig. 8.9 prints
    convergence times without a band, so two bands are kept)."""
    T = tr["x"].shape[0]
    err = tr["xhat"] - tr["x"]
    n1 = min(T, int(round(1.0 / dt)) + 1)
    nt = min(T - 1, int(round(tail_s / dt)))
    ns = min(T - 2, int(round(settle_s / dt)))
    rms = lambda a, ax=0: jnp.sqrt(jnp.mean(a**2, axis=ax))  # noqa: E731
    outside = jnp.abs(err) > band
    idx = jnp.arange(T)[:, None]
    last_out = jnp.max(jnp.where(outside, idx, -1), axis=0)
    dev = tr["fhat"] - tr["f"]
    fr = tr["f_readings"]
    dr = tr["fhat"][None] - fr
    tiny = jnp.finfo(err.dtype).tiny
    peak_f = jnp.max(jnp.abs(tr["f"]), axis=0)

    def unc_conv(frac):
        # dev[i] is at sample i + 1 (f needs the next state), so the first sample inside for good is last + 2
        last = jnp.max(jnp.where(jnp.abs(dev) > frac * peak_f, jnp.arange(dev.shape[0])[:, None], -1), axis=0)
        return (last + 2) * dt

    return {
        "unc_conv_10": unc_conv(0.10), "unc_conv_25": unc_conv(0.25),
        "rms": rms(err[1:]), "rms_1s": rms(err[1:n1]), "rms_tail": rms(err[T - nt:]),
        "peak_1s": jnp.max(jnp.abs(err[1:n1]), axis=0),
        "logmean_tail": jnp.mean(jnp.log10(jnp.abs(err[T - nt:]) + tiny), axis=0),
        "conv": (last_out + 1) * dt, "converged": last_out < T - 1,
        "unc_rms_err": rms(dev), "unc_rms": rms(tr["f"]),
        "unc_rms_err_settled": rms(dev[ns:]), "unc_rms_settled": rms(tr["f"][ns:]),
        "u_rms_err": rms(dr, 1), "u_rms": rms(fr, 1),
        "u_rms_err_settled": rms(dr[:, ns:], 1), "u_rms_settled": rms(fr[:, ns:], 1),
        "u_peak_err": jnp.max(jnp.abs(dr), axis=1), "u_peak_err_settled": jnp.max(jnp.abs(dr[:, ns:]), axis=1),
        "u_peak": jnp.max(jnp.abs(fr), axis=1),
        "u_mae_settled": jnp.mean(jnp.abs(dr[:, ns:]), axis=1), "u_ma_settled": jnp.mean(jnp.abs(fr[:, ns:]), axis=1),
        "u_median_pointwise_settled": jnp.median(jnp.abs(dr[:, ns:]) / (jnp.abs(fr[:, ns:]) + tiny), axis=1),
    }


class Trial(eqx.Module):
    """One seed: (``seed_metrics``, diverged, the trace). ``F``, ``G``: the model of (153).

    Called as ``trial(key, i)`` (``jd.monte_carlo(..., index=True)``): seed 0 starts at the sampler's x0 itself,
    the others at its spread. ``DETAIL`` keeps the trace of the run's first seed only."""

    rollout: jd.Rollout
    F: jax.Array = jd.param()
    G: jax.Array = jd.param()
    band: jax.Array = jd.param()
    tail_s: float = eqx.field(default=5.0, static=True)
    settle_s: float = eqx.field(default=0.25, static=True)

    def __call__(self, key, i):
        r = exact_first(self.rollout, key, i)
        sol = r(key)
        tr = trace(sol.saved, self.F, self.G)
        m = seed_metrics(tr, self.band, r.loop.dt, self.tail_s, self.settle_s)
        return m, sol.result != jd.RESULTS.ok, tr


def split_trace(out):
    """``monte_carlo(detail=...)`` for a ``Trial``: ((metrics, diverged) per seed, the trace)."""
    return (out[0], out[1]), out[2]


def trial(lp: jd.Loop, d: TwipDesign, x0, spread, steps: int, band, *, tail_s=5.0, settle_s=0.25) -> Trial:
    return Trial(jd.Rollout(lp, Spread(x0, spread), steps, save=record), d.F, d.G, band, tail_s, settle_s)


class RmsError(eqx.Module):
    """The tuning loss of one seed: mean over the four states of the RMS estimation error over samples
    1..T-1, and whether the seed fell (differentiable in every leaf of the loop)."""

    rollout: jd.Rollout

    def __call__(self, key):
        sol = self.rollout(key)
        return jnp.mean(sol.metrics["rms"]), sol.result != jd.RESULTS.ok


def _error(sample):
    return sample.xhat - sample.x


def rms_error(lp: jd.Loop, x0, steps: int) -> RmsError:
    """``RmsError`` from x0 (the noisy case starts every seed there)."""
    from jaxdip.engine.metrics import RMS, Window

    return RmsError(jd.Rollout(lp, Spread(x0, 0.0), steps, metrics={"rms": Window(RMS(_error), start=1)}))
