"""twip-dmso's side of the results: per-seed metrics summarised over seeds (``summarize``), the figures, the
thesis's findings (§8.1) checked on the summaries, the scoring readings the fidelity page reads
(``uncertainty_readings``, ``comparison_readings``, ``uncertainty_ratio_readings``), and the report. The runs
themselves are ``jaxdip.experiments.twip_dmso``."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from jaxdip import stats
from jaxdip.plants import twip
from jaxdip.scenarios import twip_dmso as S

if TYPE_CHECKING:  # types only; twip_dmso imports this module
    from jaxdip.experiments.twip_dmso import CaseSpec, Trace, TwipDmsoConfig

STATES = twip.STATE_NAMES  # ("x", "x_dot", "phi", "phi_dot")
UNITS = ("m", "m/s", "rad", "rad/s")
UNCERTAIN_NAMES = ("x_dot", "phi_dot")
ESTIMATORS = S.ESTIMATORS
UNCERTAIN_ROWS = S.UNCERTAIN_ROWS
# the thesis's numbers the report compares against (§8.1.3: time to converge within the measurement noise)
THESIS_NOISE_TILT_RATE_CONVERGENCE = {"dmso": 0.15, "kf": 1.3}


# ---- summaries --------------------------------------------------------------------------------------------


def _per_state(values, ok, names=STATES):
    out, ci = {}, {}
    for j, n in enumerate(names):
        out[n], ci[n] = stats.mean_ci(values[:, j], ok)
    return out, ci


def summarize(m: dict, div: np.ndarray, est: str, spec: CaseSpec) -> dict:
    ok = ~div
    r = {"diverged": int(div.sum()), "seeds": int(len(div))}
    for key, name in (("rms", "rms_error"), ("rms_1s", "rms_error_first_1s"), ("rms_tail", "rms_error_tail")):
        r[name], r[name + "_ci95"] = _per_state(m[key], ok)
    r["peak_error_first_1s"], r["peak_error_first_1s_ci95"] = _per_state(m["peak_1s"], ok)
    r["logmean_error_tail"], r["logmean_error_tail_ci95"] = _per_state(m["logmean_tail"], ok)
    r["convergence_time_s"], r["convergence_time_s_ci95"] = _per_state(m["conv"], ok)
    r["convergence_time_s_median"] = {n: float(np.median(m["conv"][ok, j])) if ok.any() else float("nan")
                                      for j, n in enumerate(STATES)}
    r["converged_fraction"] = {n: float(m["converged"][ok, j].mean()) if ok.any() else float("nan")
                               for j, n in enumerate(STATES)}
    r["seed0"] = {"rms_error": dict(zip(STATES, m["rms"][0].tolist())),
                  "rms_error_first_1s": dict(zip(STATES, m["rms_1s"][0].tolist())),
                  "convergence_time_s": dict(zip(STATES, m["conv"][0].tolist()))}
    if est == "dmso":
        r["uncertainty_rms_error"], r["uncertainty_rms_error_ci95"] = _per_state(m["unc_rms_err"], ok,
                                                                                 UNCERTAIN_NAMES)
        r["uncertainty_rms"], _ = _per_state(m["unc_rms"], ok, UNCERTAIN_NAMES)
        rel = m["unc_rms_err"] / np.maximum(m["unc_rms"], 1e-300)
        r["uncertainty_rel_error"], r["uncertainty_rel_error_ci95"] = _per_state(rel, ok, UNCERTAIN_NAMES)
        rel = m["unc_rms_err_settled"] / np.maximum(m["unc_rms_settled"], 1e-300)
        r["uncertainty_rel_error_settled"], r["uncertainty_rel_error_settled_ci95"] = _per_state(rel, ok,
                                                                                                 UNCERTAIN_NAMES)
        r["uncertainty_readings"] = uncertainty_readings(m, ok)
        for p in ("10", "25"):
            r[f"uncertainty_convergence_time_s_{p}pct"], r[f"uncertainty_convergence_time_s_{p}pct_ci95"] = (
                _per_state(m[f"unc_conv_{p}"], ok, UNCERTAIN_NAMES))
    return r


def _safe_div(a, b):
    return a / np.maximum(b, 1e-300)


# How far fhat is from f: the scoring choices a reader of "errors up to 25%" (Fig. 8.4) or "two orders of
# magnitude more accurate" (Fig. 8.11) may mean, per seed from ``seed_metrics``' u_* arrays.
UNCERTAINTY_METRICS = {
    "rel_rms": lambda m: _safe_div(m["u_rms_err"], m["u_rms"]),
    "rel_rms_settled": lambda m: _safe_div(m["u_rms_err_settled"], m["u_rms_settled"]),
    "peak_over_peak": lambda m: _safe_div(m["u_peak_err"], m["u_peak"]),
    "peak_over_peak_settled": lambda m: _safe_div(m["u_peak_err_settled"], m["u_peak"]),
    "rms_over_peak_settled": lambda m: _safe_div(m["u_rms_err_settled"], m["u_peak"]),
    "mean_abs_rel_settled": lambda m: _safe_div(m["u_mae_settled"], m["u_ma_settled"]),
    "median_pointwise_settled": lambda m: m["u_median_pointwise_settled"],
    "rms_error": lambda m: m["u_rms_err"],
    "rms_error_settled": lambda m: m["u_rms_err_settled"],
    "peak_error_settled": lambda m: m["u_peak_err_settled"],
}


def uncertainty_readings(m: dict, ok: np.ndarray) -> dict:
    """{f reading: {metric: {row: mean over seeds}, metric_ci95: ...}} (``S.F_READINGS``, ``UNCERTAINTY_METRICS``)."""
    out = {}
    for i, fr in enumerate(S.F_READINGS):
        d = {}
        for name, fn in UNCERTAINTY_METRICS.items():
            d[name], d[name + "_ci95"] = _per_state(np.asarray(fn(m))[:, i], ok, UNCERTAIN_NAMES)
        out[fr] = d
    return out


# ---- figures ----------------------------------------------------------------------------------------------


def _time(T, dt):
    return np.arange(T) * dt


def fig_states(name, traces, dt):
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(4, 1, figsize=(7, 8), sharex=True)
    for est, tr in traces.items():
        t = _time(tr.x.shape[0], dt)
        for j, ax in enumerate(axes):
            ax.plot(t, tr.x[:, j], lw=1.2, label=f"true ({est} loop)")
            ax.plot(t, tr.xhat[:, j], lw=0.9, ls="--", label=f"{est} estimate")
    for j, ax in enumerate(axes):
        ax.set_ylabel(f"{STATES[j]} ({UNITS[j]})")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7, ncol=2)
    axes[-1].set_xlabel("time (s)")
    axes[0].set_title(f"twip-dmso {name}: states and estimates (seed 0)")
    fig.tight_layout()
    return fig


def fig_errors(name, traces, dt, t_max=1.0, log=False):
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(4, 1, figsize=(7, 8), sharex=True)
    for est, tr in traces.items():
        T = tr.x.shape[0] if log else min(tr.x.shape[0], int(round(t_max / dt)) + 1)
        t = _time(T, dt)[1:]  # from sample 1: at sample 0 every estimator still holds the initial guess
        e = tr.xhat[1:T] - tr.x[1:T]
        for j, ax in enumerate(axes):
            if log:
                ax.semilogy(t, np.abs(e[:, j]) + 1e-16, lw=0.8, label=est)
            else:
                ax.plot(t, e[:, j], lw=1.0, label=est)
    for j, ax in enumerate(axes):
        ax.set_ylabel(f"{'|e|' if log else 'e'} {STATES[j]} ({UNITS[j]})")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    axes[-1].set_xlabel("time (s)")
    what = "log |estimation error| over the run" if log else f"estimation error, first {t_max:g} s"
    axes[0].set_title(f"twip-dmso {name}: {what} (seed 0)")
    fig.tight_layout()
    return fig


def fig_uncertainty(name, tr: Trace, dt):
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 1, figsize=(7, 5), sharex=True)
    t = _time(tr.f.shape[0], dt)
    for j, ax in enumerate(axes):
        ax.plot(t, tr.f[:, j], lw=1.2, label="f (153): x_{k+1} - F x_k - G u_k")
        ax.plot(t, tr.fhat[:, j], lw=0.9, ls="--", label="DMSO estimate W^T phi")
        ax.set_ylabel(f"f, {UNCERTAIN_NAMES[j]} row ({UNITS[UNCERTAIN_ROWS[j]]})")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    axes[-1].set_xlabel("time (s)")
    axes[0].set_title(f"twip-dmso {name}: uncertainty and its DMSO estimate (seed 0)")
    fig.tight_layout()
    return fig

# ---- the thesis's findings, checked ---------------------------------------------------------------------


def _ratio(a, b):
    return float(a / b) if b and np.isfinite(a) and np.isfinite(b) else float("nan")


KF_READINGS = ("kf", "kf_printed", "kf_posterior")


def findings(r: dict) -> dict:
    """The thesis's claims of §8.1, checked against each KF reading that was run."""
    out = {}
    for case in ("nominal", "param", "noise"):
        if case not in r:
            continue
        dm = r[case]["dmso"]
        c = {}
        for kfr in KF_READINGS:
            if kfr not in r[case]:
                continue
            kf = r[case][kfr]
            c[kfr] = {
                "dmso_converges_first": {s: bool(dm["convergence_time_s"][s] < kf["convergence_time_s"][s])
                                         for s in STATES},
                "first_1s_rms_ratio_kf_over_dmso": {s: _ratio(kf["rms_error_first_1s"][s],
                                                              dm["rms_error_first_1s"][s]) for s in STATES},
                "kf_ends_better_tilt_rate": bool(kf["rms_error_tail"]["phi_dot"] < dm["rms_error_tail"]["phi_dot"]),
                "tail_rms_ratio_kf_over_dmso": {s: _ratio(kf["rms_error_tail"][s], dm["rms_error_tail"][s])
                                                for s in STATES},
                **comparison_readings(dm, kf),
            }
        if case != "noise":
            c["dmso_tracks_f_within_25pct"] = {
                "run": bool(max(dm["uncertainty_rel_error"].values()) <= 0.25),
                "settled": bool(max(dm["uncertainty_rel_error_settled"].values()) <= 0.25)}
        out[case] = c
    if "param" in r and "param_dt_fine" in r:
        imp = {}
        for est in ("dmso",) + KF_READINGS:
            if est in r["param"] and est in r["param_dt_fine"]:
                imp[est] = {s: _ratio(r["param"][est]["rms_error"][s], r["param_dt_fine"][est]["rms_error"][s])
                            for s in STATES}
        unc = {s: _ratio(r["param"]["dmso"]["uncertainty_rms_error"][s],
                         r["param_dt_fine"]["dmso"]["uncertainty_rms_error"][s]) for s in UNCERTAIN_NAMES}
        out["dt_fine"] = {"rms_error_ratio_coarse_over_fine": imp,
                          "geometric_mean_ratio": {e: float(np.exp(np.mean(np.log(list(v.values())))))
                                                   for e, v in imp.items()},
                          "uncertainty_rms_error_ratio_coarse_over_fine": unc,
                          "uncertainty_readings": {c: uncertainty_ratio_readings(r[c], r["param_dt_fine"])
                                                   for c in ("param", "param_gamma_variant") if c in r}}
    if "param" in r and "param_gamma_variant" in r:
        a = r["param"]["dmso"]
        b = r["param_gamma_variant"]["dmso"]
        out["gamma_variant"] = {
            "uncertainty_rms_error_ratio_gamma_over_variant": {s: _ratio(a["uncertainty_rms_error"][s],
                                                                         b["uncertainty_rms_error"][s])
                                                               for s in UNCERTAIN_NAMES},
            "settled_rel_error": {"gamma": a["uncertainty_rel_error_settled"],
                                  "variant": b["uncertainty_rel_error_settled"]}}
        # Fig. 8.9's "in .1 seconds as compared to .25 seconds", timed per seed with a stated band
        for p in ("10", "25"):
            k = f"uncertainty_convergence_time_s_{p}pct"
            out["gamma_variant"][f"convergence_time_s_{p}pct"] = {
                "gamma": a[k], "gamma_ci95": a[k + "_ci95"], "variant": b[k], "variant_ci95": b[k + "_ci95"]}
    return out


def _means(d: dict, names) -> dict:
    v = np.array([d[s] for s in names], dtype=float)
    geo = float(np.exp(np.mean(np.log(v)))) if np.all(v > 0) else float("nan")
    return {"geometric": geo, "arithmetic": float(np.mean(v))}


def comparison_readings(dm: dict, kf: dict) -> dict:
    """The scoring choices of 'the DMSO is better / converges faster' (Figs. 8.2, 8.6, 8.7) for one KF output:
    who is lower per state under first-second RMS and peak, KF / DMSO ratios per state with their geometric and
    arithmetic means over all states and over the two uncertain rows, and who is lower on a log plot's tail."""
    out = {}
    for key, tag in (("rms_error_first_1s", "first_1s_rms"), ("peak_error_first_1s", "first_1s_peak"),
                     ("rms_error", "run_rms")):
        ratio = {s: _ratio(kf[key][s], dm[key][s]) for s in STATES}
        out[f"dmso_smaller_{tag}"] = {s: bool(dm[key][s] < kf[key][s]) for s in STATES}
        out[f"{tag}_ratio_kf_over_dmso"] = ratio
        out[f"{tag}_ratio_means"] = {"all": _means(ratio, STATES), "uncertain": _means(ratio, UNCERTAIN_NAMES)}
    out["kf_lower_log_tail_tilt_rate"] = bool(kf["logmean_error_tail"]["phi_dot"]
                                              < dm["logmean_error_tail"]["phi_dot"])
    return out


def uncertainty_ratio_readings(coarse: dict, fine: dict) -> dict:
    """Coarse / fine ratios of the DMSO's uncertainty-error metrics (Fig. 8.11), per row and their means; the
    absolute ones also per unit time (f / dt: a per-step f shrinks with dt by itself)."""
    a, b = coarse["dmso"]["uncertainty_readings"]["one_step"], fine["dmso"]["uncertainty_readings"]["one_step"]
    out = {"gamma": {"coarse": coarse["gamma"], "fine": fine["gamma"]}}
    for name in ("rms_error", "rms_error_settled", "peak_error_settled", "rel_rms", "rel_rms_settled"):
        ratio = {s: _ratio(a[name][s], b[name][s]) for s in UNCERTAIN_NAMES}
        out[name] = {**ratio, **_means(ratio, UNCERTAIN_NAMES)}
        if not name.startswith("rel"):
            k = fine["dt"] / coarse["dt"]
            ratio = {s: v * k for s, v in ratio.items()}
            out[name + "_per_unit_time"] = {**ratio, **_means(ratio, UNCERTAIN_NAMES)}
    return out


def _g(v, digits=3):
    return f"{v:.{digits}g}" if isinstance(v, (int, float)) and np.isfinite(v) else "n/a"


def _case_table(res: dict, ests) -> list[str]:
    lines = ["| estimator | quantity | " + " | ".join(f"{s} ({u})" for s, u in zip(STATES, UNITS)) + " |",
             "|---|---|" + "---|" * len(STATES)]
    for est in ests:
        if est not in res:
            continue
        e = res[est]
        for key, lab in (("rms_error", "RMS error, run"), ("rms_error_first_1s", "RMS error, first 1 s"),
                         ("rms_error_tail", "RMS error, tail"), ("convergence_time_s", "convergence time (s)")):
            lines.append(f"| {est} | {lab} | " + " | ".join(_g(e[key][s]) for s in STATES) + " |")
        lines.append(f"| {est} | converged fraction | " + " | ".join(_g(e["converged_fraction"][s])
                                                                     for s in STATES) + " |")
    return lines


def report(cfg: TwipDmsoConfig, r: dict) -> str:
    lines = [
        "DMSO (3), (4), (6) with K_MSO = diag(" + ", ".join(map(str, cfg.dmso_K)) + f"), Gamma = {cfg.dmso_gamma}, "
        "phi = [1, tanh(x_i)], B_MSO on the x_dot and phi_dot rows, against the discrete KF with Q, R, P0 of "
        f"(176)-(178); LQR (150) with R = {cfg.lqr_R}, Q = diag{tuple(cfg.lqr_Q)}, saturated at +-{cfg.u_max} V; "
        f"x0 = {cfg.x0} [m, m/s, deg, deg/s], estimates from zero, {cfg.duration} s. Means over seeds (95% "
        "intervals in metrics.json). `kf` is the KF's one-step prediction (the DMSO's information, see the "
        "module docstring); `kf_posterior` uses one more measurement; `kf_printed` is (170) as printed.",
        "",
    ]
    for case, res in r.items():
        if case == "findings":
            continue
        lines += [f"## {case} ({res['section']})", "",
                  f"Truth {res['truth']}, sensors {res['sensors']}, dt = {res['dt']} s, Gamma = {res['gamma']}, "
                  f"{res['seeds']} seeds (initial-state spread {res['init_spread']}); convergence band "
                  + ", ".join(f"{s} {_g(v)}" for s, v in res["band"].items()) + f"; tail = last {cfg.tail_s} s.",
                  ""]
        lines += _case_table(res, ESTIMATORS)
        dm = res["dmso"]
        lines += ["", "DMSO uncertainty: RMS(fhat - f) over the run "
                  + ", ".join(f"{s} {_g(dm['uncertainty_rms_error'][s])} (RMS f {_g(dm['uncertainty_rms'][s])})"
                              for s in UNCERTAIN_NAMES)
                  + "; relative over the run "
                  + ", ".join(f"{s} {_g(dm['uncertainty_rel_error'][s])}" for s in UNCERTAIN_NAMES)
                  + f", after {cfg.settle_s} s "
                  + ", ".join(f"{s} {_g(dm['uncertainty_rel_error_settled'][s])}" for s in UNCERTAIN_NAMES)
                  + f". Diverged: dmso {dm['diverged']}"
                  + "".join(f", {e} {res[e]['diverged']}" for e in ESTIMATORS[1:] if e in res) + ".", ""]
    lines += ["## The thesis's findings", ""] + findings_text(r)
    return "\n".join(lines)


def _verdict(ok: bool) -> str:
    return "holds" if ok else "does not hold"


def findings_text(r: dict) -> list[str]:
    f = r["findings"]
    out = []
    for case in ("nominal", "param", "noise"):
        if case not in f:
            continue
        c = f[case]
        dm = r[case]["dmso"]
        out.append(f"**{case}**")
        out.append("")
        for kfr in KF_READINGS:
            if kfr not in c:
                continue
            kf = r[case][kfr]
            cc = c[kfr]
            first = [s for s, v in cc["dmso_converges_first"].items() if v]
            out.append(f"- vs `{kfr}`: DMSO converges first in {len(first)}/4 states ({', '.join(first) or 'none'});"
                       " convergence times DMSO / KF: "
                       + ", ".join(f"{s} {_g(dm['convergence_time_s'][s])} / {_g(kf['convergence_time_s'][s])} s"
                                   for s in STATES)
                       + "; first-second RMS ratio KF/DMSO: "
                       + ", ".join(f"{s} {_g(v)}" for s, v in cc["first_1s_rms_ratio_kf_over_dmso"].items())
                       + f". KF ends better on the tilt rate: {_verdict(cc['kf_ends_better_tilt_rate'])} "
                       f"(tail RMS of phi_dot KF {_g(kf['rms_error_tail']['phi_dot'])} vs DMSO "
                       f"{_g(dm['rms_error_tail']['phi_dot'])} rad/s).")
        if case == "noise":
            kf = r[case]["kf"]
            out.append(f"- thesis (§8.1.3): the tilt rate converges in {THESIS_NOISE_TILT_RATE_CONVERGENCE['dmso']} s "
                       f"(DMSO) vs {THESIS_NOISE_TILT_RATE_CONVERGENCE['kf']} s (KF); here, medians over seeds, "
                       f"DMSO {_g(dm['convergence_time_s_median']['phi_dot'])} s, "
                       + ", ".join(f"{k} {_g(r[case][k]['convergence_time_s_median']['phi_dot'])} s"
                                   for k in KF_READINGS if k in r[case]) + ".")
        if "dmso_tracks_f_within_25pct" in c:
            v = c["dmso_tracks_f_within_25pct"]
            out.append("- DMSO tracks f within about 25%: relative RMS error over the run "
                       + ", ".join(f"{s} {_g(x)}" for s, x in dm["uncertainty_rel_error"].items())
                       + f" ({_verdict(v['run'])}); after the first {r[case].get('settle_s', '')} s "
                       + ", ".join(f"{s} {_g(x)}" for s, x in dm["uncertainty_rel_error_settled"].items())
                       + f" ({_verdict(v['settled'])}).")
        out.append("")
    if "dt_fine" in f:
        g = f["dt_fine"]["geometric_mean_ratio"]
        u = f["dt_fine"]["uncertainty_rms_error_ratio_coarse_over_fine"]
        out.append("**dt = 0.001 s** (thesis: both estimators about 10x better, the uncertainty about 100x): RMS "
                   "error ratio dt 0.01 / dt 0.001, geometric mean over the states: "
                   + ", ".join(f"{e} {_g(x)}" for e, x in g.items())
                   + "; uncertainty RMS error ratio " + ", ".join(f"{s} {_g(x)}" for s, x in u.items()) + ".")
        out.append("")
    if "gamma_variant" in f:
        v = f["gamma_variant"]["uncertainty_rms_error_ratio_gamma_over_variant"]
        st = f["gamma_variant"]["settled_rel_error"]
        out.append("**Gamma = 0.5** (Fig. 8.9; thesis: smaller uncertainty error, converged in 0.1 s instead of "
                   "0.25 s): uncertainty RMS error ratio Gamma 0.1 / Gamma 0.5 "
                   + ", ".join(f"{s} {_g(x)}" for s, x in v.items()) + "; settled relative error "
                   + ", ".join(f"{s} {_g(st['gamma'][s])} -> {_g(st['variant'][s])}" for s in UNCERTAIN_NAMES) + ".")
    return out
