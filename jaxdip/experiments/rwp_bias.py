"""rwp-bias: velocity estimation and sensor-bias estimation on the reaction-wheel pendulum (Aranovskiy et al.).

Every part of the paper's §II-V, in simulation (plant (2)-(3), Table 1, current as input, 500 Hz, angle
quantisation of Table 1, law (8)/(23) with the Table 2 gains; continuous observers integrated with RK4 sub-steps
between samples, see ``jaxdip.estimators.continuous``):

(a) no bias: the Luenberger observer (9) against the differentiators (10)+(12) from theta(0) = 0.1 and 0.15 over
    many seeds (random quantisation phase of both encoders, small random initial velocities): Fig. 3;
(b) bias d = -0.08 with the differentiators alone: steady-state errors against (15)/(16): Fig. 4;
(c) the low-pass bias observer (17) with γ_d = 0.05 and 0.5, and the joint observer (24) with L0 = 0.01, under
    law (23): Figs. 5 and 6;
(d) Proposition 2's γ̄_d (Routh and eigenvalue routes, and sampled simulations just below/above it), and the
    matrix inequalities (27) with s_M (28) (needs the optional extra ``jaxdip[lmi]``; skipped with a reason
    otherwise).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

import jaxdip as jd
from jaxdip.resources import Load, steps_of
from jaxdip import config as C
from jaxdip import stats
from jaxdip.estimators import bias_observers as bo
from jaxdip.estimators import homd
from jaxdip.estimators import luenberger as lu
from jaxdip.experiments.base import Experiment, Outcome, RunContext
from jaxdip.experiments.common import diverged_counts
from jaxdip.plants import rwp
from jaxdip.scenarios import rwp as scenario
from jaxdip.scenarios.rwp import REC
from jaxdip.theory import rwp as T

INF = float("inf")
PAPER = {"ep2": -1.43, "thetar_dot": 138.0, "lowpass_0.05_settle": 60.0, "s_M": 0.36}


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


def homd_parameters(cfg):
    return homd.homd_params(pend=tuple(cfg.homd_pendulum), wheel=tuple(cfg.homd_wheel))


def luenberger_parameters(cfg):
    hp = homd_parameters(cfg)
    if cfg.luenberger_omega:
        wp, wr = cfg.luenberger_omega
        L = lu.decoupled_gain(hp.model, wp * hp.pend.k1, wp**2 * hp.pend.k2, wr * hp.wheel.k1, wr**2 * hp.wheel.k2)
        return lu.luenberger_params(L, hp.model), wp, wr
    L, wp, wr = lu.matched_gain(hp.model, hp.pend, hp.wheel, *cfg.luenberger_vref)
    return lu.luenberger_params(L, hp.model), wp, wr


def _obs(cfg):
    return {"dt": cfg.dt, "substeps": cfg.observer_substeps, "hold": cfg.hold}


def _loop_and_x0(r):
    return r.loop, r.x0


def simulate(cfg, cases, duration, n_seeds, desc, measured_velocities=False, quantize=None):
    """Every seed of the rwp loop (``jaxdip.scenarios.rwp``) for every case, in one compiled program.

    ``cases``: list of (engine estimator, bias d, theta0) sharing one structure. The cases' loops and initial
    state laws are stacked and swept (``jd.monte_carlo(..., sweep=...)``): every number of a case is a batched
    leaf, as in the stacked-params driver this replaced, so the quick results stay identical to the last bit.
    Returns (diverged, records) with leading axes (case, seed); records hold ``scenario.record`` of every
    ``cfg.record_every``-th period."""
    n_steps = int(round(duration / cfg.dt))
    q = cfg.quantize if quantize is None else quantize
    rollouts = [scenario.rollout(est, steps=n_steps, theta0=th0, velocity_std=cfg.init_velocity_std,
                                 save_every=cfg.record_every, dt=cfg.dt, substeps=cfg.substeps, K=cfg.K, d=d,
                                 current_limit=cfg.current_limit, measured_velocities=measured_velocities,
                                 quantize=q, observer_current=cfg.observer_current)
                for est, d, th0 in cases]
    stacked = jax.tree_util.tree_map(lambda *a: jnp.stack(a), *[_loop_and_x0(r) for r in rollouts])
    sol = jd.monte_carlo(rollouts[0], jax.random.PRNGKey(cfg.seed), n_seeds, sweep=(_loop_and_x0, stacked),
                         time_chunk=n_steps, progress=True,
                         desc=f"{desc} ({len(cases)} case(s) x {n_seeds} seeds x {n_steps} periods)")
    return np.asarray(sol.result != jd.RESULTS.ok), np.asarray(sol.saved)


# ---- metrics ----------------------------------------------------------------------------------------------------


def settle_times(values, t, tol):
    """Per row: the first recorded time after which |values| stays <= tol (NaN if it does not by the end)."""
    bad = np.abs(values) > tol
    any_bad = bad.any(axis=1)
    last_bad = bad.shape[1] - 1 - np.argmax(bad[:, ::-1], axis=1)
    idx = np.where(any_bad, last_bad + 1, 0)
    out = np.where(idx < bad.shape[1], t[np.minimum(idx, bad.shape[1] - 1)], np.nan)
    return out


def overshoot_after_reaching(err, sign_target):
    """max |err| after err first changes to the side of ``sign_target`` (0 if it never gets there): the
    oscillation amplitude of an estimate around its target (err = estimate - target, starting on the other side)."""
    reached = np.sign(err) == sign_target
    first = np.where(reached.any(axis=1), np.argmax(reached, axis=1), err.shape[1])
    mask = np.arange(err.shape[1])[None, :] >= first[:, None]
    return np.where(mask, np.abs(err), 0.0).max(axis=1)


def _stabilized(cfg, diverged, rec_tail):
    th_ok = np.abs(rec_tail[:, :, REC["theta"]]).max(axis=1) < cfg.stabilized_tol[0]
    w_ok = np.abs(rec_tail[:, :, REC["thetar_dot"]]).max(axis=1) < cfg.stabilized_tol[1]
    return ~diverged & th_ok & w_ok


def _tail(cfg, rec, seconds=1.0):
    n = max(1, int(round(seconds / (cfg.dt * cfg.record_every))))
    return rec[:, -n:, :]


def _times(cfg, rec):
    return np.arange(rec.shape[-2]) * cfg.dt * cfg.record_every


def part_a(cfg):
    """No bias: Luenberger (9) against the differentiators (10)+(12) from each theta0."""
    lp, wp, wr = luenberger_parameters(cfg)
    observers = {
        "luenberger": lu.LuenbergerObserver.of(lp, **_obs(cfg)),
        "homd": homd.HOMDObserver.of(homd_parameters(cfg), **_obs(cfg)),
    }
    out, curves = {}, {}
    for name, est in observers.items():
        out[name] = {}
        divs, recs = simulate(cfg, [(est, 0.0, th0) for th0 in cfg.theta0], cfg.no_bias_duration, cfg.seeds,
                              f"(a) {name}")
        for i, th0 in enumerate(cfg.theta0):
            rec = recs[i]
            div = divs[i]
            t = _times(cfg, rec)
            stab = _stabilized(cfg, div, _tail(cfg, rec))
            frac, ci = stats.wilson(int(stab.sum()), len(stab))
            st = np.where(stab, settle_times(rec[:, :, REC["theta"]], t, cfg.settle_tol), np.nan)
            # position variation past upright: the largest swing to the other side of the start
            under = np.maximum((-np.sign(th0) * rec[:, :, REC["theta"]]).max(axis=1), 0.0)
            maxI = np.abs(rec[:, :, REC["I"]]).max(axis=1)
            out[name][f"{th0:g}"] = {
                "stabilized_fraction": frac, "stabilized_fraction_ci95": ci,
                "diverged": int(div.sum()),
                **stats.with_ci("settle_time", st, stab),
                **stats.with_ci("undershoot", under, stab),
                **stats.with_ci("max_abs_current", maxI, stab),
            }
            curves[(name, th0)] = (t, rec[:8])
    out["luenberger_omega"] = {"pendulum": wp, "wheel": wr}
    return out, curves


def part_b(cfg):
    """Bias d with the differentiators alone: steady-state errors against (15) and (16)."""
    hp = homd_parameters(cfg)
    divs, recs = simulate(cfg, [(homd.HOMDObserver.of(hp, **_obs(cfg)), cfg.bias, cfg.bias_theta0)],
                          cfg.bias_duration, cfg.bias_seeds, "(b) bias, HOMD")
    rec = recs[0]
    ok = ~divs[0]
    tail = _tail(cfg, rec, cfg.steady_window)[ok]
    ep2 = float((tail[:, :, REC["xp2"]] - tail[:, :, REC["theta_dot"]]).mean())
    er2 = float((tail[:, :, REC["xr2"]] - tail[:, :, REC["thetar_dot"]]).mean())
    wdot = float(tail[:, :, REC["thetar_dot"]].mean())
    theta = float(tail[:, :, REC["theta"]].mean())
    a1 = float(T.a1(hp.model))
    kp1, kp2, ap = cfg.homd_pendulum
    kr1, kr2, ar = cfg.homd_wheel
    ep2_f = float(T.homd_steady_error(kp1, kp2, ap, a1, cfg.bias))
    er2_f = float(T.wheel_steady_error(kr1, kr2, ar, a1, cfg.bias))
    wdot_f = float(T.thetar_dot_biased_homd(cfg.K, cfg.bias, ep2_f, er2_f))
    out = {
        "ep2_sim": ep2, "ep2_formula": ep2_f, "ep2_rel_err": abs(ep2 - ep2_f) / abs(ep2_f),
        "er2_sim": er2, "er2_formula": er2_f,
        "thetar_dot_sim": wdot, "thetar_dot_formula": wdot_f,
        "thetar_dot_rel_err": abs(wdot - wdot_f) / abs(wdot_f),
        "thetar_dot_formula_7": float(T.thetar_dot_biased_feedback(cfg.K, cfg.bias)),
        "theta_sim": theta,
        "y_sim": float(tail[:, :, REC["y"]].mean()),
        "thetar_dot_std_over_seeds": float(tail[:, :, REC["thetar_dot"]].mean(axis=1).std()),
        "diverged": int((~ok).sum()),
        "paper_measured": {"ep2": PAPER["ep2"], "thetar_dot": PAPER["thetar_dot"]},
    }
    return out, (_times(cfg, rec), rec[:8])


def _bias_metrics(cfg, diverged, rec):
    t = _times(cfg, rec)
    dhat = rec[:, :, REC["y"]] - rec[:, :, REC["theta_hat"]]
    err = dhat - cfg.bias
    d_abs = abs(cfg.bias)
    settle = settle_times(err, t, cfg.bias_settle_tol * d_abs)
    osc = overshoot_after_reaching(err, np.sign(cfg.bias))
    # the wheel's swing back after its peak: a closed-loop oscillation shows as theta_r' changing sign
    w = rec[:, :, REC["thetar_dot"]]
    rows = np.arange(len(w))
    ipk = np.argmax(np.abs(w), axis=1)
    peak = np.abs(w[rows, ipk])
    later = np.arange(w.shape[1])[None, :] > ipk[:, None]
    swing = np.maximum(np.where(later, -np.sign(w[rows, ipk])[:, None] * w, -np.inf).max(axis=1), 0.0)
    err_tail = np.abs(_tail(cfg, err[:, :, None])[:, :, 0]).max(axis=1)
    stab = _stabilized(cfg, diverged, _tail(cfg, rec)) & (err_tail <= cfg.bias_settle_tol * d_abs)
    frac, ci = stats.wilson(int(stab.sum()), len(stab))
    ok = ~diverged
    return {
        "stabilized": bool(stab.all()), "stabilized_fraction": frac, "stabilized_fraction_ci95": ci,
        "diverged": int((~ok).sum()),
        "settle_time_nan_count": int(np.isnan(settle[ok]).sum()),
        **stats.with_ci("settle_time", settle, ok),
        **stats.with_ci("oscillation_amplitude", osc, ok),
        "oscillation_amplitude_rel": float(np.mean(osc[ok]) / d_abs) if ok.any() else float("nan"),
        **stats.with_ci("wheel_speed_peak", peak, ok),
        **stats.with_ci("wheel_speed_backswing", swing, ok),
        "dhat_final": float(dhat[ok, -1].mean()) if ok.any() else float("nan"),
    }, (t, rec[:8])


def part_c(cfg):
    hp = homd_parameters(cfg)
    out, curves = {}, {}
    divs, recs = simulate(cfg, [(bo.LowpassHOMD.of(bo.lowpass_params(hp, g), **_obs(cfg)), cfg.bias, cfg.bias_theta0)
                                for g in cfg.gamma_d], cfg.lowpass_duration, cfg.bias_seeds, "(c) low-pass")
    for i, g in enumerate(cfg.gamma_d):
        out[f"lowpass_{g:g}"], curves[f"lowpass_{g:g}"] = _bias_metrics(cfg, divs[i], recs[i])
    divs, recs = simulate(cfg, [(bo.JointObserver.of(bo.joint_params(hp, cfg.L0), **_obs(cfg)), cfg.bias,
                                 cfg.bias_theta0)], cfg.reduced_duration, cfg.bias_seeds, "(c) reduced-order")
    out["reduced_order"], curves["reduced_order"] = _bias_metrics(cfg, divs[0], recs[0])
    return out, curves


def growth_rate(t, err, window):
    """ln(envelope at the end / envelope at the start) / elapsed, envelope = max |err| over ``window`` seconds
    (the start window begins after one window, past the initial transient)."""
    n = max(2, int(round(window / (t[1] - t[0]))))
    a0 = np.abs(err[..., n:2 * n]).max(axis=-1)
    a1 = np.abs(err[..., -n:]).max(axis=-1)
    return np.log(a1 / a0) / (t[-n] - t[n])


def part_d(cfg):
    """γ̄_d of Proposition 2 (two routes, plus sampled simulations around it) and the LMIs (27)."""
    p = rwp.default_params()
    gb = T.gamma_bar_routh(p, cfg.K)
    ge = T.gamma_bar_eig(p, cfg.K)
    gammas = [f * gb.gamma_bar for f in cfg.gamma_check]
    divs, recs = simulate(cfg, [(bo.LowpassMeasured.of(bo.lowpass_measured_params(g), **_obs(cfg)),
                                 cfg.gamma_check_bias, 0.0) for g in gammas],
                          cfg.gamma_check_duration, 2, "(d) law (18) around gamma_d_bar",
                          measured_velocities=True, quantize=False)
    sims = {}
    for i, (f, g) in enumerate(zip(cfg.gamma_check, gammas)):
        rec = recs[i]
        t = _times(cfg, rec)
        err = rec[:, :, REC["y"]] - rec[:, :, REC["theta_hat"]] - cfg.gamma_check_bias  # d_hat - d
        div = bool(divs[i].any())
        rate = float(np.mean(growth_rate(t, err, 5.0))) if not div else float("inf")
        re = float(np.max(np.linalg.eigvals(np.asarray(T.lowpass_F(p, cfg.K, g))).real))
        sims[f"{f:g}"] = {"gamma_d": g, "growth_rate_sim": rate, "max_real_eig_F": re, "diverged": div,
                          "stable_sim": bool(not div and rate < 0)}
    kp, kr = cfg.homd_pendulum[:2], cfg.homd_wheel[:2]
    out = {
        "gamma_d_bar": gb.gamma_bar,
        "gamma_d_bar_detail": {
            "routh": gb.gamma_bar, "gamma_bar_1": gb.gamma_bar_1, "gamma_bar_2": gb.gamma_bar_2, "eig": ge,
            "routh_minus_eig": gb.gamma_bar - ge, "simulations": sims,
            "with_differentiators_alpha1": T.gamma_bar_lowpass_homd_linear(p, cfg.K, kp, kr),
            "slowest_eigs_with_differentiators_alpha1": {
                f"{g:g}": _slowest(T.lowpass_homd_linear_matrix(p, cfg.K, kp, kr, g)[0]) for g in cfg.gamma_d},
            "slowest_eigs_F": {f"{g:g}": _slowest(np.asarray(T.lowpass_F(p, cfg.K, g))) for g in cfg.gamma_d},
        },
    }
    out["lmi"] = lmi_part(cfg, p)
    return out


def _slowest(M):
    ev = np.linalg.eigvals(M)
    e = ev[np.argmax(ev.real)]
    return [float(e.real), float(abs(e.imag))]


def lmi_part(cfg, p):
    kp1, kp2, ap = cfg.homd_pendulum
    a1 = float(T.a1(p))
    base = {"L0": cfg.L0, "gamma": cfg.lmi_gamma, "mu": cfg.lmi_mu, "c0": cfg.lmi_c0,
            "s_M": T.s_M(cfg.lmi_mu, ap) if ap < 1 else INF, "paper_s_M": PAPER["s_M"]}
    if ap >= 1:
        return {**base, "feasible": None, "skipped": "alpha_p = 1: (26)-(28) are an expansion around alpha_p < 1"}
    if not T.have_cvxpy():
        return {**base, "feasible": None,
                "skipped": "cvxpy is not installed (pip install 'jaxdip[lmi]' for the LMI part)"}
    r = T.solve_lmi(cfg.L0, cfg.lmi_gamma, cfg.lmi_mu, kp1, kp2, ap, a1, cfg.lmi_c0)
    mu_max = T.mu_max(cfg.L0, cfg.lmi_gamma, kp1, kp2, ap, a1, cfg.lmi_c0, iters=20)
    chk = r.check._asdict() if r.check is not None else None
    return {**base, "feasible": r.feasible, "solver": r.solver, "status": r.status, "margin": r.margin,
            "check": chk, "C": r.C, "P": r.P, "mu_max": mu_max,
            "s_M_at_mu_max": T.s_M(mu_max, ap) if np.isfinite(mu_max) else None}


# ---- figures ------------------------------------------------------------------------------------------------


def _fig3(cfg, curves):
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, len(cfg.theta0), figsize=(5.5 * len(cfg.theta0), 7.5), squeeze=False, sharex=True)
    for j, th0 in enumerate(cfg.theta0):
        for name, ls in (("luenberger", "--"), ("homd", "-")):
            t, rec = curves[(name, th0)]
            label = "Luenberger (9)" if name == "luenberger" else "HOMD (10), (12)"
            axes[0, j].plot(t, rec[0, :, REC["theta"]], ls, label=label)
            axes[1, j].plot(t, rec[0, :, REC["xp2"]], ls, label=label)
            axes[2, j].plot(t, rec[0, :, REC["I"]], ls, label=label)
        axes[0, j].set_title(f"theta(0) = {th0:g} rad (seed 0)")
        axes[0, j].set_ylabel("theta (rad)")
        axes[1, j].set_ylabel("velocity estimate of theta' (rad/s)")
        axes[2, j].set_ylabel("current I (A)")
        axes[2, j].set_xlabel("time (s)")
        for ax in axes[:, j]:
            ax.grid(alpha=0.3)
        axes[0, j].legend(fontsize=8)
    fig.suptitle("Fig. 3: stabilisation with the differentiators (10), (12) and the Luenberger observer (9)")
    fig.tight_layout()
    return fig


def _fig4(cfg, curve, res_b):
    import matplotlib.pyplot as plt

    t, rec = curve
    fig, axes = plt.subplots(3, 1, figsize=(7, 7.5), sharex=True)
    axes[0].plot(t, rec[0, :, REC["y"]], label="measured y")
    axes[0].plot(t, rec[0, :, REC["theta"]], label="theta")
    axes[0].axhline(cfg.bias, color="k", lw=0.5)
    axes[0].set_ylabel("rad")
    axes[1].plot(t, rec[0, :, REC["xp2"]], label="x̂_p2")
    axes[1].plot(t, rec[0, :, REC["theta_dot"]], label="theta'")
    axes[1].axhline(res_b["ep2_formula"], color="k", ls=":", lw=1, label="(15)")
    axes[1].set_ylabel("rad/s")
    axes[2].plot(t, rec[0, :, REC["xr2"]], label="x̂_r2")
    axes[2].plot(t, rec[0, :, REC["thetar_dot"]], label="theta_r'")
    axes[2].axhline(res_b["thetar_dot_formula"], color="k", ls=":", lw=1, label="(16)")
    axes[2].set_ylabel("rad/s")
    axes[2].set_xlabel("time (s)")
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    axes[0].set_title(f"Fig. 4: law (8) with (10), (12) for d = {cfg.bias:g} (seed 0)")
    fig.tight_layout()
    return fig


def _fig_bias(cfg, items, title):
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(4, 1, figsize=(7, 9), sharex=False)
    for label, (t, rec) in items:
        dhat = rec[0, :, REC["y"]] - rec[0, :, REC["theta_hat"]]
        axes[0].plot(t, dhat, label=label)
        axes[1].plot(t, rec[0, :, REC["theta_hat"]], label=label)
        axes[2].plot(t, rec[0, :, REC["xr2"]], label=label)
        axes[3].plot(t, rec[0, :, REC["I"]], label=label, lw=0.6)
    axes[0].axhline(cfg.bias, color="k", lw=0.5)
    for ax, yl in zip(axes, ["(a) bias estimate d̂ (rad)", "(b) θ̂ = y - d̂ (rad)", "(c) x̂_r2 (rad/s)",
                             "(d) current I (A)"]):
        ax.set_ylabel(yl, fontsize=8)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    axes[-1].set_xlabel("time (s)")
    axes[0].set_title(title)
    fig.tight_layout()
    return fig


# ---- report ------------------------------------------------------------------------------------------------


def _f(v, ci=None, fmt=".4g"):
    if v is None:
        return "—"
    if isinstance(v, float) and not math.isfinite(v):
        return "n/a"
    s = format(v, fmt)
    if ci is not None and all(isinstance(c, float) and math.isfinite(c) for c in ci):
        s += f" [{format(ci[0], fmt)}, {format(ci[1], fmt)}]"
    return s


def report(cfg, r) -> str:
    nb, b, d = r["no_bias"], r["bias"], r["gamma_d_bar_detail"]
    L = []
    L.append(f"Plant (2)-(3) with Table 1, current input, {1 / cfg.dt:g} Hz, quantised angles "
             f"({'on' if cfg.quantize else 'off'}), K = {cfg.K}, HOMD [k1, k2, α] = {cfg.homd_pendulum} (pendulum) and "
             f"{cfg.homd_wheel} (wheel); continuous observers with {cfg.observer_substeps} RK4 sub-steps per period "
             f"({cfg.hold}); "
             + (f"current limit {cfg.current_limit:g} A." if math.isfinite(cfg.current_limit) else "no current limit."))
    L += ["", "## (a) No bias: Luenberger (9) vs differentiators (10), (12)", ""]
    om = nb["luenberger_omega"]
    L.append(f"L of (9): error dynamics two decoupled blocks s² + ω k1 s + ω² k2 with ω = {om['pendulum']:.3f} "
             f"(pendulum) and {om['wheel']:.3f} (wheel), matching the HOMD's 10-90% velocity rise time at steps of "
             f"{cfg.luenberger_vref[0]:g} and {cfg.luenberger_vref[1]:g} rad/s. {cfg.seeds} seeds per cell, "
             f"{cfg.no_bias_duration:g} s; settle time: |θ| stays below {cfg.settle_tol:g} rad; undershoot: largest swing "
             "past upright.")
    L += ["", "| observer | θ(0) | stabilised fraction | settle time (s) | undershoot (rad) | max \\|I\\| commanded (A) | diverged |",
          "|---|---|---|---|---|---|---|"]
    for name in ("luenberger", "homd"):
        for th0 in cfg.theta0:
            c = nb[name][f"{th0:g}"]
            L.append(f"| {name} | {th0:g} | {_f(c['stabilized_fraction'], c['stabilized_fraction_ci95'])} | "
                     f"{_f(c['settle_time'], c['settle_time_ci95'])} | {_f(c['undershoot'], c['undershoot_ci95'])} | "
                     f"{_f(c['max_abs_current'])} | {c['diverged']} |")
    L += ["", "## (b) Bias d = %g, differentiators only: steady state against (15), (16)" % cfg.bias, "",
          "| quantity | simulation | formula | relative difference | paper (measured) |", "|---|---|---|---|---|",
          f"| velocity error e_p2 (rad/s) | {_f(b['ep2_sim'])} | {_f(b['ep2_formula'])} (15) | "
          f"{_f(b['ep2_rel_err'], fmt='.2%')} | {PAPER['ep2']} |",
          f"| wheel velocity error e_r2 (rad/s) | {_f(b['er2_sim'])} | {_f(b['er2_formula'])} (-(15)) | | |",
          f"| θ̇_r (rad/s) | {_f(b['thetar_dot_sim'])} | {_f(b['thetar_dot_formula'])} (16) | "
          f"{_f(b['thetar_dot_rel_err'], fmt='.2%')} | {PAPER['thetar_dot']} |",
          f"| θ̇_r with exact velocities (rad/s) | | {_f(b['thetar_dot_formula_7'])} (7) | | |",
          f"| θ (rad) | {_f(b['theta_sim'])} | 0 | | ≈ 0 |", ""]
    L += ["## (c) Bias observers, d = %g" % cfg.bias, "",
          "| observer | settle time of d̂ (s) | oscillation amplitude of d̂ (rad) | wheel back-swing (rad/s) | "
          "stabilised |", "|---|---|---|---|---|"]
    for key in [f"lowpass_{g:g}" for g in cfg.gamma_d] + ["reduced_order"]:
        c = r[key]
        L.append(f"| {key} | {_f(c['settle_time'], c['settle_time_ci95'])} | "
                 f"{_f(c['oscillation_amplitude'])} ({_f(c['oscillation_amplitude_rel'], fmt='.1%')} of \\|d\\|) | "
                 f"{_f(c['wheel_speed_backswing'])} | {_f(c['stabilized_fraction'], c['stabilized_fraction_ci95'])} |")
    L += ["", f"Settle time: |d̂ − d| stays within {cfg.bias_settle_tol:.0%} of |d| (n/a: not by the end of "
          f"{cfg.lowpass_duration:g} s / {cfg.reduced_duration:g} s). Oscillation amplitude: largest |d̂ − d| after d̂ "
          "first reaches d (an overshoot; 0 for a monotone approach). Wheel back-swing: largest wheel speed of "
          "the opposite sign after its peak.", ""]
    L += ["## (d) Proposition 2 and the matrix inequalities (27)", "",
          f"- γ̄_d (Routh route) = **{d['routh']:.10g}** (γ̄_d,1 = {d['gamma_bar_1']:.6g} from b3 > 0, γ̄_d,2 = "
          f"{d['gamma_bar_2']:.10g} from the cubic); eigenvalues of F: {d['eig']:.10g}; difference "
          f"{d['routh_minus_eig']:.2e}.",
          ]
    for f, s in d["simulations"].items():
        L.append(f"- law (18), measured velocities, {f} × γ̄_d = {s['gamma_d']:.4g}: simulated growth rate "
                 f"{_f(s['growth_rate_sim'])} 1/s (largest Re eig F: {s['max_real_eig_F']:.4g}) → "
                 f"{'stable' if s['stable_sim'] else 'unstable'}.")
    L.append(f"- With the differentiators in the loop (the Fig. 5 setting), linearised at α = 1: stability limit "
             f"γ_d < {d['with_differentiators_alpha1']:.4g}; slowest eigenvalues (re, |im|): " + ", ".join(
                 f"γ_d = {g}: {v[0]:.3g} ± {v[1]:.3g}j" for g, v in d["slowest_eigs_with_differentiators_alpha1"].items())
             + "; Prop. 2's F (exact velocities): " + ", ".join(
                 f"γ_d = {g}: {v[0]:.3g} ± {v[1]:.3g}j" for g, v in d["slowest_eigs_F"].items()) + ".")
    lm = r["lmi"]
    if lm.get("skipped"):
        L.append(f"- LMIs (27): skipped: {lm['skipped']}. s_M (28) = {_f(lm['s_M'])}.")
    else:
        chk = lm["check"] or {}
        L.append(f"- LMIs (27) for L0 = {lm['L0']:g}, γ = {lm['gamma']:g}, μ = {lm['mu']:g}, c0 = {lm['c0']:g}: "
                 f"**{'feasible' if lm['feasible'] else 'not feasible'}** ({lm['solver']}, {lm['status']}, "
                 f"margin {lm['margin']:.3g} with trace P = 1; eigenvalue check: min eig P {chk.get('min_eig_P', 0):.3g}, "
                 f"min eig Q {chk.get('min_eig_Q', 0):.2g}, max eig of the two decrease expressions "
                 f"{chk.get('max_eig_Mm', 0):.3g}, {chk.get('max_eig_MM', 0):.3g}); s_M = {lm['s_M']:.4f} (paper ≈ 0.36); "
                 f"largest feasible μ = {_f(lm['mu_max'])} (s_M = {_f(lm['s_M_at_mu_max'])}); Ω = {{sᵀPs < {_f(lm['C'])}}}.")
    L += ["", "## The paper's claims", ""]
    L += claims(cfg, r)
    if "failures" in r:
        L += ["", "Diverged seeds (|θ| past π/2 or a non-finite state), per part: "
              + ", ".join(f"{k} {v}" for k, v in r["failures"]["diverged"].items())
              + "; statistics are over the other seeds, n/a where none is left."]
    return "\n".join(L)


def claims(cfg, r):
    nb, b = r["no_bias"], r["bias"]
    th_hi = f"{max(cfg.theta0):g}"
    lu_hi = nb["luenberger"][th_hi]["stabilized_fraction"]
    ho_hi = nb["homd"][th_hi]["stabilized_fraction"]
    lp = [r[f"lowpass_{g:g}"] for g in cfg.gamma_d]
    ro = r["reduced_order"]
    out = [
        f"- Steady-state errors under bias match (15)/(16): e_p2 {_f(b['ep2_sim'])} vs {_f(b['ep2_formula'])} "
        f"({_f(b['ep2_rel_err'], fmt='.2%')}), θ̇_r {_f(b['thetar_dot_sim'])} vs {_f(b['thetar_dot_formula'])} "
        f"({_f(b['thetar_dot_rel_err'], fmt='.2%')}); the paper measured −1.43 and ≈ 138. "
        + ("**Not judged**: every seed diverged." if not b["diverged"] < cfg.bias_seeds else
           f"**{'Holds' if max(b['ep2_rel_err'], b['thetar_dot_rel_err']) < 0.05 else 'Does not hold'}** "
           "(5% criterion)."),
        f"- The Luenberger observer loses the pendulum from θ(0) = {th_hi} where the HOMD holds it: stabilised "
        f"fractions {lu_hi:.3f} (Luenberger) and {ho_hi:.3f} (HOMD). "
        + ("**Holds.**" if (lu_hi < 0.5 <= ho_hi) else
           "**Not reproduced in simulation**: with the Table 1 model both observers are model-based, their error "
           "dynamics do not depend on the input, and both start exact in position, so the state feedback sees "
           "nearly the same estimates; the hardware difference must come from effects the model does not have."),
    ]
    th_lo = f"{min(cfg.theta0):g}"
    a_lu, a_ho = nb["luenberger"][th_lo], nb["homd"][th_lo]
    out.append(
        f"- From θ(0) = {th_lo} the differentiators stabilise faster and with smaller position variations (Fig. 3): "
        f"settle time {_f(a_ho['settle_time'])} s (HOMD) vs {_f(a_lu['settle_time'])} s (Luenberger), undershoot "
        f"{_f(a_ho['undershoot'])} vs {_f(a_lu['undershoot'])} rad. "
        + ("**Holds.**" if a_ho["settle_time"] < 0.95 * a_lu["settle_time"] else
           "**Not reproduced**: in simulation the two are within a few per cent of each other."))
    if len(lp) >= 2:
        slow, fast = lp[0], lp[-1]
        out.append(
            f"- γ_d = {cfg.gamma_d[0]:g} is slow (d̂ settles in {_f(slow['settle_time'])} s; paper ≈ 60 s) and "
            f"γ_d = {cfg.gamma_d[-1]:g} oscillates (settles in {_f(fast['settle_time'])} s with an overshoot of "
            f"{_f(fast['oscillation_amplitude_rel'], fmt='.0%')} of |d| and a wheel back-swing of "
            f"{_f(fast['wheel_speed_backswing'])} rad/s, against {_f(slow['oscillation_amplitude_rel'], fmt='.0%')} "
            f"and {_f(slow['wheel_speed_backswing'])} rad/s for γ_d = {cfg.gamma_d[0]:g}). Prop. 2 alone (exact "
            f"velocities) predicts no oscillation at {cfg.gamma_d[-1]:g} (γ̄_d = {r['gamma_d_bar']:.3g}); the "
            f"oscillation comes from the differentiators in the loop (α = 1 linearisation: limit "
            f"{r['gamma_d_bar_detail']['with_differentiators_alpha1']:.3g}).")
    faster = bool(lp) and all(not (c["settle_time"] <= ro["settle_time"]) for c in lp)  # NaN: never settled
    out.append(
        f"- The reduced-order observer (L0 = {cfg.L0:g}) is fast and stable: d̂ settles in {_f(ro['settle_time'])} s, "
        f"overshoot {_f(ro['oscillation_amplitude_rel'], fmt='.1%')} of |d|, stabilised fraction "
        f"{ro['stabilized_fraction']:.3f}. "
        f"**{'Holds' if ro['stabilized'] and faster else 'Does not hold'}** (faster than every low-pass gain "
        f"simulated, stable in every seed).")
    lm = r["lmi"]
    if not lm.get("skipped"):
        out.append(f"- (27) feasible for L0 = 0.01, γ = 0.62, μ = −0.2 with s_M ≈ 0.36: "
                   f"{'feasible' if lm['feasible'] else 'not feasible'} with c0 = {lm['c0']:g}, s_M = {lm['s_M']:.3f}; "
                   f"largest feasible μ {_f(lm['mu_max'])}. **{'Holds' if lm['feasible'] else 'Does not hold'}.**")
    return out


# ---- run --------------------------------------------------------------------------------------------------------


def run(cfg: RwpBiasConfig, ctx: RunContext | None = None) -> Outcome:
    a, curves_a = part_a(cfg)
    b, curve_b = part_b(cfg)
    c, curves_c = part_c(cfg)
    d = part_d(cfg)
    results = {"no_bias": a, "bias": b, **c, **d}
    if fell := diverged_counts(results):  # seeds that left |theta| < pi/2 or became non-finite, per part and cell
        results["failures"] = {"diverged": fell}
    lp_items = [(f"γ_d = {g:g}", curves_c[f"lowpass_{g:g}"]) for g in cfg.gamma_d]
    figures = {
        "rwp-fig3": _fig3(cfg, curves_a),
        "rwp-fig4": _fig4(cfg, curve_b, b),
        "rwp-fig5": _fig_bias(cfg, lp_items, f"Fig. 5: law (23) with (10), (12) and the low-pass observer (17), "
                                             f"d = {cfg.bias:g}"),
        "rwp-fig6": _fig_bias(cfg, [(f"L0 = {cfg.L0:g}", curves_c["reduced_order"])],
                              f"Fig. 6: law (23) with the joint observer (24), (12), d = {cfg.bias:g}"),
    }
    return Outcome(results=results, report=report(cfg, results), figures=figures)


EXPERIMENT = Experiment(
    id="rwp-bias",
    title="Reaction-wheel pendulum: homogeneous differentiators, bias propagation, bias observers",
    config_cls=RwpBiasConfig,
    run=run,
    quick={"seeds": 16, "no_bias_duration": 2.0, "bias_seeds": 2, "bias_duration": 6.0, "lowpass_duration": 20.0,
           "reduced_duration": 10.0, "gamma_check_duration": 40.0},
    source="Aranovskiy et al., IEEE Access 2020: (7), (9)-(28), Tables 1-2, Figs. 3-6",
    # The differentiators' switching amplifies last-bit differences into its quick numbers whatever changes
    # them (quick results at balanced moved up to 1e-3 relative against full, inside their intervals; its
    # 2-seed spread by 2.7 %); at fast they moved as much with a spread moved by 7 %. -O1 halves its compile.
    quick_effort="balanced",
)
