"""ifn-protection: the report (a summary for biologists first, the technical tables after it)."""

from __future__ import annotations

import math

from jaxdip.experiments.common import fmt_ci


def report(cfg, r) -> str:
    p, m = r["parameters"], r["model"]
    L = [
        f"Infection model (A1)–(A6) in d = {cfg.dim}: eta = {cfg.eta:.4g}/h, beta = {cfg.beta:g}/h, gamma = "
        f"{cfg.gamma:g}/h, delta = {cfg.delta:g}/h, D = {cfg.diffusion:g} cell diameters²/h. Target E[I] = "
        f"{cfg.target_R:g}, so V = R0 - R̄ = {p['V']:.4g}. {m['cells']} infected cells, {m['virions']} virions, "
        "every virion drawn (decay and entry clocks, Gaussian position at entry). Intervals are 95% (normal "
        "approximation for means, Wilson for fractions); quadrature values carry the bracket of the trapezoid rule.",
        "",
        "## The model",
        "",
        "| quantity | formula | Monte Carlo [95%] | inside |",
        "|---|---|---|---|",
        f"| E[Z] = β/η | {m['E_Z_formula']:.6g} | {fmt_ci(m['E_Z_mc'], m['E_Z_ci95'], 6)} | {m['E_Z_in_ci']} |",
        f"| P(Z = 0) = η/(η+β) (Z geometric) | {m['P_Z0_formula_geometric']:.5g} | "
        f"{fmt_ci(m['P_Z0_mc'], m['P_Z0_ci95'], 5)} | |",
        f"| P(τ_γ ≤ τ_δ) = γ/(γ+δ) | {m['entry_prob_formula']:.5g} | "
        f"{fmt_ci(m['entry_prob_mc'], m['entry_prob_ci95'], 5)} | |",
        f"| R0 = βγ/(η(γ+δ)) | {m['R0_formula']:.6g} | {fmt_ci(m['R0_mc'], m['R0_ci95'], 6)} | {m['R0_in_ci']} |",
        "",
        "## E[I] under controls: Monte Carlo against (4.4) by quadrature",
        "",
        "Same virions for every control (common random numbers). The half ball's reference is half the ball's "
        f"quadrature (symmetry); the off-centre ball's is the noncentral chi-square mixture (largest Poisson "
        f"parameter {r['offset_ball_max_lambda']:.3g}). Cell-autonomous rules on a lattice have no quadrature: "
        "compare them with the continuum level set they approximate.",
        "",
        "All controls see the same virions, so one fluctuation of the burst sizes or of the entry clocks moves "
        "every row the same way (compare the E[Z] and entry rows above). The last three columns remove it: "
        "P(infects | enters) = 1 - ∫_A g / R0 against the fraction of entering virions that infect (Wilson 95%; "
        "binomial given the entries).",
        "",
        "| control | E[I] Monte Carlo [95%] | E[I] quadrature (± bound) | inside | P(infects \\| enters) MC [95%] "
        "| 1 - ∫_A g / R0 | inside |",
        "|---|---|---|---|---|---|---|",
    ]
    for n, row in r["controls_mc"].items():
        q = (f"{row['E_I_quadrature']:.5f} (± {row['quadrature_error_bound']:.1e})" if "E_I_quadrature" in row
             else "—")
        c = (f"{fmt_ci(row['P_infect_given_entry_mc'], row['P_infect_given_entry_ci95'], 5)} | "
             f"{row['P_infect_given_entry_quadrature']:.5f} | {row['P_infect_given_entry_in_ci']}"
             if "P_infect_given_entry_mc" in row else "| |")
        L.append(f"| {n} | {fmt_ci(row['E_I_mc'], row['E_I_ci95'], 5)} | {q} | {row.get('quadrature_in_ci', '')} | "
                 f"{c} |")
    L += ["", "## Problem (P) and Theorem 4.4.1", "",
          "Each row: the level set L_r̄ and its competitors, all with ∫_A g = V; costs ∫_A h with the quadrature "
          "bracket. 'cheapest' counts competitors whose cost bracket lies wholly above the level set's.", "",
          "| h | r̄ [bracket] | ∫g of L_r̄ | ∫h of L_r̄ | best ball (ρ, t0, t1): ∫h | perturbations: least ∫h "
          "| extra cost ball / perturbation | cheapest |",
          "|---|---|---|---|---|---|---|---|"]
    for n, t in r["theorem"].items():
        b = t["ball"]
        pm = min([x["h"] for x in t["perturbations"]], default=float("nan"))
        L.append(
            f"| {n} | {t['r_bar']:.5g} [{math.exp(t['log_r_bar_bracket'][0]):.5g}, "
            f"{math.exp(t['log_r_bar_bracket'][1]):.5g}] | {t['level_set']['g']:.6f} | "
            f"{t['level_set']['h']:.2f} [{t['level_set']['h_bracket'][0]:.2f}, {t['level_set']['h_bracket'][1]:.2f}] "
            f"| ({b['radius']:.2f}, {b['t0']:.3f}, {b['t1']:.3f}): {b['h']:.2f} | {pm:.2f} | "
            f"{100 * t['ball_extra_cost']:.1f}% / {100 * t['perturbation_min_extra_cost']:.2f}% | "
            f"{t['level_set_cheapest_count']} |")
    L += ["", "Monte Carlo of the same sets: ∫_A g = R0 - E[I] (from the table above) — level sets: " + ", ".join(
        f"{k.split(', ')[1]}: {fmt_ci(v['int_g_mc'], v['int_g_ci95'], 5)}" for k, v in r["controls_mc"].items()
        if k.startswith("level set")) + f" (V = {p['V']:.4g}).", ""]
    f = r["flat_case"]
    L += ["### The non-unique case (flat g/h)", "",
          f"h = max(1, g / r_f) with log r_f = {f['log_r_flat']:.5f}: r̄ = r_f, F(r̄) = {f['F_at_r_bar']:.5f} "
          f"> V (F just below r̄ {f['F_just_below_r_bar']:.5f}, just above {f['F_just_above_r_bar']:.3g}): "
          f"Corollary 4.4.2's condition fails (unique: {f['unique']}). Every optimal set costs V / r̄ = "
          f"{f['optimal_cost_V_over_r_bar']:.3f}.", "",
          "| set | ∫g | ∫h |", "|---|---|---|"]
    for n, s in f["sets"].items():
        L.append(f"| {n} | {s['g']:.5f} | {s['h']:.3f} [{s['h_bracket'][0]:.3f}, {s['h_bracket'][1]:.3f}] |")
    L += ["", f"The stochastic response protects each point of the flat set with probability q = "
          f"{f['tie_probability']:.4f}; the late set starts at t_c = {f['t_c']:.4f} h.", ""]
    L += ["### F(r) numerically", ""]
    for n, fp in r["F_properties"].items():
        L.append(f"- h {n}: nonincreasing within brackets: {fp['nonincreasing_within_brackets']}, largest "
                 f"step up {fp['max_increase']:.2e}")
    L += ["", "## Differentiable E[I] and optax", ""]
    t = r["tuning"]
    L += [f"- dE[I]/dlog r at r̄: quadrature autodiff {t['dEI_dlogr_autodiff_quadrature']:.8f}, central "
          f"difference {t['dEI_dlogr_central_difference_quadrature']:.8f}; Monte Carlo (same {cfg.tune_batch} "
          f"virions) autodiff {t['dEI_dlogr_autodiff_mc']:.8f}, central difference "
          f"{t['dEI_dlogr_central_difference_mc']:.8f}",
          f"- optax Adam to E[I] = {cfg.target_R:g} from log r̄ {cfg.tune_start:+g}: quadrature log r = "
          f"{t['log_r_optax_quadrature']:.6f} (r off by {100 * t['r_rel_error_quadrature']:.4f}%), Monte Carlo "
          f"log r = {t['log_r_optax_mc']:.6f} (r off by {100 * t['r_rel_error_mc']:.3f}%, E[I] there "
          f"{t['E_I_at_optax_mc_r']:.4f}); bisection log r̄ = {t['log_r_bar_bisection']:.6f}. Within 1%: "
          f"{t['within_1_percent']}", ""]
    L += ["## Generations (level-set control around every infected cell)", "",
          "| E[I] | extinction: fixed point (closed form) | P(extinct by g = G) MC [95%] | G^G(0) | "
          "G^g(0) inside the MC interval | P(I = 0) MC vs 1/(1+R) | escaped |",
          "|---|---|---|---|---|---|---|"]
    for n, g in r["generations"].items():
        L.append(f"| {n} ({g['E_I']:.4f}) | {g['extinction_probability_fixed_point']:.4f} "
                 f"({g['extinction_closed_form']:.4f}) | "
                 f"{fmt_ci(g['extinct_by_generation_mc'][-1], g['extinct_by_generation_ci95'][-1])} | "
                 f"{g['extinct_by_generation_pgf'][-1]:.4f} | {g['pgf_in_ci']} | "
                 f"{fmt_ci(g['offspring_P0_mc'], g['offspring_P0_ci95'])} vs {g['offspring_P0_geometric']:.4f} | "
                 f"{g['escaped']} |")
    return "\n".join(L)
