"""twip-extra-control: LQR + two-layer-network extra control against LQR alone on the TWIP (Stumfoll §8.2).

Closed loop per sample (``jaxdip.scenarios.twip_extra``, run by ``jd.monte_carlo``): the true state -> tilt output (backlash (161) on phi in the
``deadzone_backlash`` case, identity otherwise) -> passthrough estimator -> controller
(``jaxdip.control.extra_control``: u = sat(u_nom + u_e), or LQR alone with u_e switched off) -> deadzone (160)
on the voltage in the deadzone cases -> the nonlinear TWIP (72)-(73) plus the unmodeled accelerations d1, d2
of (185) over dt by RK4 sub-steps.

Design (all systems): the discrete LQR (``jaxdip.control.twip_lqr``) on the nominal linear model (79) with
Table 8.1, R = 1, Q = diag(1, 1, 0.1, 0.1) (180)-(181); desired trajectory (182)-(183) with x2d = 0.1 m/s,
x1d(0) = 0, x3d and u_d from the same nominal model; every control signal clipped at +-11.1 V.

Cases (results keys) and the three systems of each (Table 8.3's columns):
  param               truth Table 8.2                                   (§8.2.1)
  unmodeled           truth Table 8.2 + d1 = 1/2 x' sin(180 x/pi), d2 = 1/4 x'^2 (185)   (§8.2.2)
  unmodeled_unstable  as unmodeled with the gains 1/2 -> 3/4 and 1/4 -> 2/5 (Fig. 8.18)
  deadzone            truth ``nonlinear_truth`` (Table 8.2 by default, see below) + deadzone +-0.5 V (§8.2.3)
  deadzone_backlash   as deadzone + backlash +-0.1 deg, m = 1, on the tilt the controller sees (§8.2.4)
  systems: lqr = perturbed truth, LQR; extra = perturbed truth, LQR + extra control; nominal = Table 8.1 truth
  without unmodeled dynamics, LQR (the "nominal system optimal control"), with the case's deadzone/backlash.

Decisions: (185)'s d1, d2 are added to x'' and phi'' of the nonlinear plant, as they enter (87); "sin(180x/pi)"
is taken as printed (frequency ``d1_freq`` = 180/pi rad/m); "gains 3/4 and 2/5" replace the coefficients 1/2 and
1/4 of d1 and d2. §8.2.3 says the deadzone study "removes the parameter uncertainty", but Table 8.3 then gives
different scores to the perturbed-LQR (358.42) and nominal (326.10) columns, which would be equal if both
plants were Table 8.1; we therefore keep Table 8.2 as the perturbed truth there (``nonlinear_truth``).

The extra control's main law is the "flat" variant of ``jaxdip.control.extra_control`` (virtual control through
the flat output, derived because (93) as printed commands the tilt with the wrong sign and every seed falls) with
the thesis's numbers (k1 = k2 = 2.5, gamma = 0.1, sigma = 0.01). ``variants`` runs further LQR + extra rows on the
same seeds, each changing a few controller keys: by default the printed law, the networks switched off
(gamma = 0: what the networks contribute) and k1 = 10 (from a grid over k1 on 100 seeds: the smallest of 2.5,
5, 7.5, 10 that kept every unmodeled_unstable seed up with room to spare).

Score (Table 8.3): sum over the samples k = 0 .. N-1 (N = duration/dt, default 20 s at 0.01 s: 2000 terms) of
the Euclidean norm ||x_k - x_d,k|| of the true state's difference from the desired trajectory (mixed units
m, m/s, rad, rad/s, as in the thesis). Seeds: seed i draws the networks' random input weights V1, V2 and, for
i > 0, the initial state x0 * (1 + U(-s, s)) per component (seed 0 starts at (184)); the three systems of a
case share each seed's x0 and V. A seed whose |phi| passes ``tilt_bound_deg`` or whose state leaves the bounds
is diverged; scores are averaged over the others. improvement = 1 - mean(extra) / mean(lqr).

Every case, system and variant is the same loop structure with other numbers: one ``monte_carlo`` sweep.
``jaxdip.scenarios.twip_extra.scores_at`` gives the scores as a differentiable function of the controller's
parameters (k1, k2, learning rates; gradient checked against finite differences in tests/test_extra_control.py).
"""

from __future__ import annotations

import math

import jax
import numpy as np

import jaxdip as jd
from jaxdip import stats
from jaxdip.control.extra_control import ExtraControl, desired_state
from jaxdip.runner.experiment import Experiment, Outcome, RunContext
from jaxdip.runner.per_seed import PerSeed, fraction_of, mean_of
from experiments.twip_extra_control.config import (DEG, FIGS, STATES, SYSTEMS, THESIS,
                                                          TwipExtraControlConfig, variant_config)
from jaxdip.scenarios import twip_extra as S
from jaxdip.scenarios.twip_initial import thesis_x0


# ---- building the scenario (jaxdip.scenarios.twip_extra) ---------------------------------------------------


def controller(cfg: TwipExtraControlConfig) -> ExtraControl:
    return S.controller(dt=cfg.dt, lqr_Q=cfg.lqr_Q, lqr_R=cfg.lqr_R, v_d=cfg.v_d, k1=cfg.k1, k2=cfg.k2,
                        n_hidden=cfg.n_hidden, b=cfg.b, gamma=cfg.gamma, sigma=cfg.sigma, u_max=cfg.u_max,
                        v_scale=cfg.v_scale, feedforward=cfg.feedforward, tau_d=cfg.tau_d, virtual=cfg.virtual,
                        virtual_sign=cfg.virtual_sign)


def build_loop(cfg: TwipExtraControlConfig, case: str, system: str) -> jd.Loop:
    return S.loop(case, system, controller(cfg), dt=cfg.dt, substeps=cfg.substeps, d_gains=cfg.d_gains,
                  d_gains_unstable=cfg.d_gains_unstable, d1_freq=cfg.d1_freq, deadzone=cfg.deadzone,
                  backlash_deg=cfg.backlash_deg, nonlinear_truth=cfg.nonlinear_truth, backlash_law=cfg.backlash_law,
                  tilt_bound_deg=cfg.tilt_bound_deg, state_bound=cfg.state_bound)


def n_steps(cfg: TwipExtraControlConfig) -> int:
    return int(round(cfg.duration / cfg.dt))


def rows(cfg: TwipExtraControlConfig) -> list[tuple[str, str]]:
    """(case, system or variant) of every loop the study runs; one structure, hence one sweep."""
    return [(case, name) for case in cfg.cases for name in (*SYSTEMS, *cfg.variants)]


def build(cfg: TwipExtraControlConfig):
    """(trial recording the figures' trace, sweep over every row): one structure for all rows."""
    vcfgs = {spec: variant_config(cfg, spec) for spec in cfg.variants}
    loops = [build_loop(cfg, case, name) if name in SYSTEMS else build_loop(vcfgs[name], case, "extra")
             for case, name in rows(cfg)]
    return S.scored(loops[0], thesis_x0(cfg.x0), cfg.init_spread, n_steps(cfg), save=S.trace), S.sweep_of(loops)


def simulate(cfg: TwipExtraControlConfig, progress: bool = False):
    """{row: (scores, diverged)} over the seeds, and {row: seed-0 trace}: every row in one sweep, one compiled
    program (seed 0 starts at x0 and keeps its trace: ``index=True, detail=...``)."""
    run, sweep = build(cfg)
    (sc, dv), tr = jd.monte_carlo(run, jax.random.PRNGKey(cfg.seed), cfg.seeds, sweep=sweep, chunk=cfg.chunk_seeds,
                                  index=True, detail=S.split_trace, progress=progress, desc="twip-extra-control")
    sc, dv = np.asarray(sc), np.asarray(dv)
    out, traces = {}, {}
    for j, row in enumerate(rows(cfg)):
        out[row] = (sc[j], dv[j])
        traces[row] = {k: np.asarray(v[j]) for k, v in tr.items()}
    return out, traces


def versus_lqr(s, d, lqr_s, lqr_d) -> dict:
    """improvement = 1 - mean score / LQR's (each over its own non-diverged seeds), and its paired form over the
    seeds where neither diverged."""
    out = {"improvement": 1.0 - stats.mean_ci(s, ~d)[0] / stats.mean_ci(lqr_s, ~lqr_d)[0]}
    ok = ~d & ~lqr_d
    if ok.any():
        out["improvement_paired_mean"], out["improvement_paired_ci95"] = stats.mean_ci(1.0 - s[ok] / lqr_s[ok])
    return out


def summarize_case(scores: dict, divs: dict) -> dict:
    out = {}
    for sysname in SYSTEMS:
        s, d = scores[sysname], divs[sysname]
        m, ci = stats.mean_ci(s, ~d)
        med = float(np.median(s[~d])) if (~d).any() else float("nan")
        frac, fci = stats.wilson(int(d.sum()), len(d))
        out[sysname] = {"score_mean": m, "score_ci95": ci, "score_median": med, "score_seed0": float(s[0]),
                        "diverged": int(d.sum()), "diverged_fraction": frac, "diverged_fraction_ci95": fci}
    out.update(versus_lqr(scores["extra"], divs["extra"], scores["lqr"], divs["lqr"]))
    ok = ~divs["lqr"] & ~divs["extra"]
    if ok.any():
        out["extra_better_fraction"] = float(np.mean(scores["extra"][ok] < scores["lqr"][ok]))
    out["extra_bounded_fraction"] = float(np.mean(~divs["extra"]))
    out["lqr_diverged_fraction"] = float(np.mean(divs["lqr"]))
    return out


def fig_case(case, traces: dict, cfg):
    import matplotlib.pyplot as plt

    n = traces["lqr"]["x"].shape[0]
    t = np.arange(n) * cfg.dt
    xd = np.asarray(desired_state(controller(cfg), t))
    scale = (1.0, 1.0, 1 / DEG, 1 / DEG)
    units = ("m", "m/s", "deg", "deg/s")
    labels = {"lqr": "Perturbed system", "extra": "Perturbed system with ue", "nominal": "Nominal system"}
    fs, fsn = FIGS[case]
    fig, axes = plt.subplots(4, 1, figsize=(7, 8), sharex=True)
    for j, ax in enumerate(axes):
        for sysname in SYSTEMS:
            ax.plot(t, traces[sysname]["x"][:, j] * scale[j], lw=1.0, label=labels[sysname])
        ax.plot(t, xd[:, j] * scale[j], "k--", lw=0.8, label="desired")
        ax.set_ylabel(f"{STATES[j]} ({units[j]})")
        ax.grid(alpha=0.3)
    lim = 5 * max(abs(cfg.x0[2]), 1.0)
    axes[2].set_ylim(-lim, lim)
    axes[0].legend(fontsize=7, loc="best")
    axes[0].set_title(f"{case}: states, seed 0 (cf. Fig. {fs})")
    axes[-1].set_xlabel("time (s)")
    fig2, ax = plt.subplots(figsize=(7, 3.2))
    ax.plot(t, traces["nominal"]["u"], lw=1.0, label="optimal control (nominal system)")
    ax.plot(t, traces["extra"]["u_nom"], lw=1.0, label="nominal control u_nom")
    ax.plot(t, traces["extra"]["u_e"], lw=1.0, label="extra control u_e")
    ax.plot(t, traces["extra"]["u"], lw=1.0, label="total control")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("V")
    ax.set_title(f"{case}: control signals, seed 0 (cf. Fig. {fsn})")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    return fig, fig2


def summarize_variant(s, d, lqr_s, lqr_d) -> dict:
    m, ci = stats.mean_ci(s, ~d)
    return {"score_mean": m, "score_ci95": ci, "diverged": int(d.sum()), "bounded_fraction": float(np.mean(~d)),
            **versus_lqr(s, d, lqr_s, lqr_d)}


def per_seed(cfg: TwipExtraControlConfig, res: dict) -> PerSeed:
    """Each seed's score and divergence per case and system or variant, and its paired improvement over the
    perturbed LQR: what ``summarize_case`` and ``summarize_variant`` average."""
    d = PerSeed(coords={"case": list(cfg.cases), "system": list(SYSTEMS), "variant": list(cfg.variants)})
    grid = lambda names, i: np.stack([np.stack([res[(c, n)][i] for n in names], 1) for c in cfg.cases], 1)
    i_lqr, i_extra = SYSTEMS.index("lqr"), SYSTEMS.index("extra")
    sc, dv = grid(SYSTEMS, 0), grid(SYSTEMS, 1)  # (seed, case, system)
    lqr_s, lqr_d = sc[:, :, i_lqr, None], dv[:, :, i_lqr, None]
    score = "the seed's score (the sum over the periods of the distance to the desired state)"
    dims, at = ("seed", "case", "system"), "{case}.{system}."
    d.add("ok", dims, ~dv, "1", "the seed stayed within tilt_bound_deg and state_bound, and finite")
    d.add("diverged", dims, dv, "1", "the seed diverged", **fraction_of(at + "diverged_fraction"))
    d.add("score", dims, sc, "1", score, **mean_of(at + "score_mean", "ok", at + "score_ci95"))
    with np.errstate(divide="ignore", invalid="ignore"):
        d.add("paired_ok", ("seed", "case"), ~dv[:, :, i_extra] & ~lqr_d[:, :, 0], "1", "neither extra nor lqr diverged")
        d.add("improvement_paired", ("seed", "case"), 1.0 - sc[:, :, i_extra] / lqr_s[:, :, 0], "1",
              "1 - extra's score / lqr's, the same seed", **mean_of("{case}.improvement_paired_mean", "paired_ok",
                                                                    "{case}.improvement_paired_ci95"))
        if cfg.variants:
            vs, vd = grid(cfg.variants, 0), grid(cfg.variants, 1)
            dims, at = ("seed", "case", "variant"), "{case}.variants.{variant}."
            d.add("variant_ok", dims, ~vd, "1", "the variant's seed did not diverge")
            d.add("variant_score", dims, vs, "1", score, **mean_of(at + "score_mean", "variant_ok", at + "score_ci95"))
            d.add("variant_paired_ok", dims, ~vd & ~lqr_d, "1", "neither the variant nor lqr diverged")
            d.add("variant_improvement_paired", dims, 1.0 - vs / lqr_s, "1", "1 - the variant's score / lqr's",
                  **mean_of(at + "improvement_paired_mean", "variant_paired_ok", at + "improvement_paired_ci95"))
    return d


def run(cfg: TwipExtraControlConfig, ctx: RunContext | None = None, progress: bool = True) -> Outcome:
    res, traces = simulate(cfg, progress)
    results, figures = {}, {}
    for case in cfg.cases:
        scores = {s: res[(case, s)][0] for s in SYSTEMS}
        divs = {s: res[(case, s)][1] for s in SYSTEMS}
        results[case] = summarize_case(scores, divs)
        results[case]["variants"] = {spec: summarize_variant(*res[(case, spec)], scores["lqr"], divs["lqr"])
                                     for spec in cfg.variants}
        fs, fc = fig_case(case, {s: traces[(case, s)] for s in SYSTEMS}, cfg)
        figures[f"twip-extra-{case}-states"] = fs
        figures[f"twip-extra-{case}-control"] = fc
    figures["twip-extra-variants"] = fig_variants(cfg, results)
    imps = [results[c]["improvement"] for c in cfg.cases if c in THESIS]
    results["mean_improvement_table_cases"] = float(np.mean(imps)) if imps else float("nan")
    fell = {f"{case}/{name}": int(res[(case, name)][1].sum()) for case, name in rows(cfg) if res[(case, name)][1].any()}
    if fell:  # seeds that left tilt_bound_deg or state_bound (or became non-finite), per case and controller
        results["failures"] = {"diverged": fell, "of_seeds": cfg.seeds, "tilt_bound_deg": cfg.tilt_bound_deg,
                               "state_bound": list(cfg.state_bound)}
    results["horizon_s"] = cfg.duration
    results["dt_s"] = cfg.dt
    results["score_terms"] = n_steps(cfg)
    return Outcome(results=results, report=report(cfg, results), figures=figures, per_seed=per_seed(cfg, res))


def fig_variants(cfg, r):
    """Improvement over LQR alone and fraction of seeds kept up, per case, for the main law and every variant."""
    import matplotlib.pyplot as plt

    rows = [(f"{cfg.virtual} (main)", lambda c: r[c]["improvement"], lambda c: r[c]["extra_bounded_fraction"])]
    for spec in cfg.variants:
        rows.append((spec, lambda c, sp=spec: r[c]["variants"][sp]["improvement"],
                     lambda c, sp=spec: r[c]["variants"][sp]["bounded_fraction"]))
    rows.append(("LQR alone", lambda c: 0.0, lambda c: 1.0 - r[c]["lqr_diverged_fraction"]))
    cases = list(cfg.cases)
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.8))
    w = 0.8 / len(rows)
    xs = np.arange(len(cases))
    for j, (name, imp, up) in enumerate(rows):
        off = xs - 0.4 + (j + 0.5) * w
        axes[0].bar(off, [100 * np.nan_to_num(imp(c), nan=0.0) for c in cases], w, label=name)
        for c, case in enumerate(cases):  # no score to show: every seed fell
            if not np.isfinite(imp(case)):
                axes[0].text(off[c], 1, "all fell", rotation=90, fontsize=6, ha="center", va="bottom")
        axes[1].bar(off, [100 * up(c) for c in cases], w, label=name)
    for c, case in enumerate(cases):
        if case in THESIS:
            th = 100 * (1 - THESIS[case]["extra"] / THESIS[case]["lqr"])
            axes[0].plot([c - 0.4, c + 0.4], [th, th], "k--", lw=1, label="thesis" if c == 0 else None)
    axes[0].set_ylabel("improvement over LQR (%)")
    axes[0].set_title("1 - mean score / LQR's (non-diverged seeds)")
    axes[1].set_ylabel("seeds kept up (%)")
    axes[1].set_title(f"bounded over {cfg.duration:g} s, {cfg.seeds} seeds")
    for ax in axes:
        ax.set_xticks(xs, cases, rotation=20, fontsize=8)
        ax.axhline(0, color="k", lw=0.5)
        ax.grid(alpha=0.3, axis="y")
    axes[1].set_ylim(0, 105)
    axes[0].set_ylim(-60, 70)
    axes[0].legend(fontsize=7, loc="lower left")
    return fig


def _g(v, d=4):
    return "n/a" if v is None or (isinstance(v, float) and not math.isfinite(v)) else f"{v:.{d}g}"


def report(cfg: TwipExtraControlConfig, r: dict) -> str:
    out = [f"Score = sum over k = 0..{n_steps(cfg) - 1} of ||x_k - x_d,k|| ({cfg.duration:g} s at dt = {cfg.dt:g} s), "
           f"mean [95% interval] over the non-diverged of {cfg.seeds} seeds (network input weights and "
           f"x0 * (1 +- {cfg.init_spread:g}) vary; seed 0 = the thesis's x0). Thesis: one run per cell.", "",
           "| case | LQR (ours) | LQR (thesis) | LQR + extra (ours) | LQR + extra (thesis) | nominal (ours) "
           "| nominal (thesis) | improvement ours / thesis | diverged LQR / extra / nominal |",
           "|---|---|---|---|---|---|---|---|---|"]
    for case in cfg.cases:
        c = r[case]
        th = THESIS.get(case, {})
        cells = []
        for s in SYSTEMS:
            cells.append(f"{_g(c[s]['score_mean'])} [{_g(c[s]['score_ci95'][0])}, {_g(c[s]['score_ci95'][1])}]")
            cells.append(_g(th.get(s)))
        th_imp = 1 - th["extra"] / th["lqr"] if th else None
        out.append(f"| {case} | " + " | ".join(cells) + f" | {_g(c['improvement'], 3)} / {_g(th_imp, 3)} | "
                   + " / ".join(str(c[s]["diverged"]) for s in SYSTEMS) + " |")
    out += ["", f"Mean improvement over the thesis's four cases: ours {_g(r['mean_improvement_table_cases'], 3)}, "
            f"thesis 0.531 (its 53.1%). Main extra control: virtual = {cfg.virtual}, k1 = {cfg.k1:g}, "
            f"k2 = {cfg.k2:g}, gamma = {cfg.gamma}.", ""]
    if "failures" in r:
        f = r["failures"]
        out += [f"Diverged seeds (of {f['of_seeds']}; |tilt| over {f['tilt_bound_deg']:g} deg or a state over "
                f"its bound): " + ", ".join(f"{k} {v}" for k, v in f["diverged"].items())
                + "; scores are over the others, n/a where none is left.", ""]
    for case in cfg.cases:
        c = r[case]
        extra_best = c["extra"]["score_mean"] < min(c["lqr"]["score_mean"], c["nominal"]["score_mean"])
        line = (f"- {case}: extra control best of the three: {'yes' if extra_best else 'no'}; "
                f"extra better than LQR in {_g(100 * c.get('extra_better_fraction', float('nan')), 3)}% of seeds; "
                f"LQR diverged in {_g(100 * c['lqr_diverged_fraction'], 3)}%, LQR + extra bounded in "
                f"{_g(100 * c['extra_bounded_fraction'], 3)}% of seeds.")
        out.append(line)
    if cfg.variants:
        out += ["", "Variants of the extra control on the same seeds (`variants`; each changes only the listed keys "
                    "of the main law):", "",
                "| case | variant | score mean [95%] | improvement vs LQR (paired [95%]) | bounded |",
                "|---|---|---|---|---|"]
        for case in cfg.cases:
            for spec, v in r[case]["variants"].items():
                pair = (f" ({_g(v['improvement_paired_mean'], 3)} [{_g(v['improvement_paired_ci95'][0], 3)}, "
                        f"{_g(v['improvement_paired_ci95'][1], 3)}])" if "improvement_paired_mean" in v else "")
                out.append(f"| {case} | `{spec}` | {_g(v['score_mean'])} [{_g(v['score_ci95'][0])}, "
                           f"{_g(v['score_ci95'][1])}] | {_g(v['improvement'], 3)}{pair} | "
                           f"{_g(100 * v['bounded_fraction'], 3)}% |")
    return "\n".join(out)


EXPERIMENT = Experiment(
    id="twip-extra-control",
    title="TWIP: two-layer-network extra control for unmatched uncertainty vs LQR",
    config_cls=TwipExtraControlConfig,
    run=run,
    quick={"seeds": 8, "duration": 10.0, "chunk_seeds": 8},
    source="Stumfoll MS thesis §6.2 (eqs. 86-114) and §8.2 (eqs. 179-185, Table 8.3, Figs. 8.15-8.23)",
    quick_cost_s=6, full_cost_s=116,
)
