"""rwp-bias's figures (the paper's Figs. 3-6) and its report: the tables of parts (a)-(d) and the paper's claims
checked, from the results ``experiments.rwp_bias.run`` computes."""

from __future__ import annotations

import math

from jaxdip.scenarios.rwp import REC

PAPER = {"ep2": -1.43, "thetar_dot": 138.0, "lowpass_0.05_settle": 60.0, "s_M": 0.36}


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
                 f"{chk.get('max_eig_Mm', 0):.3g}, {chk.get('max_eig_MM', 0):.3g}); s_M = {_f(lm['s_M'], fmt='.4f')} (paper ≈ 0.36); "
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
                   f"{'feasible' if lm['feasible'] else 'not feasible'} with c0 = {lm['c0']:g}, s_M = {_f(lm['s_M'], fmt='.3f')}; "
                   f"largest feasible μ {_f(lm['mu_max'])}. **{'Holds' if lm['feasible'] else 'Does not hold'}.**")
    return out
