"""ifn-protection: the report (a summary for biologists first, the technical tables after it)."""

from __future__ import annotations

import math

from jaxdip.runner.results import fmt_ci


def summary(cfg, r) -> list[str]:
    """The part for a reader who knows the biology and not the code: the answer, then the symbols in words."""
    p, th = r["parameters"], r["theorem"]
    R0, V, Rt = r["model"]["R0_formula"], p["V"], cfg.target_R
    u, d, s = th["uniform"], th["distance"], th["shell"]
    per = 1000.0 * V / u["level_set"]["h"]
    per_ball = 1000.0 * V / u["ball"]["h"]
    b = u["ball"]
    f = r["flat_case"]
    mc = r["controls_mc"]
    lat = {k: v.get("E_I_quadrature", float("nan")) for k, v in mc.items() if k.startswith("cells of")
           and "uniform" in k}
    lat_text = ", ".join(f"{e:.4f} with blocks of {k.split(':')[0].split()[-1]} x {k.split(':')[0].split()[-1]} "
                         "cell diameters" for k, e in lat.items())
    switch_extra = f["sets"]["threshold switch L_r_bar"]["h"] / f["optimal_cost_V_over_r_bar"] - 1
    return [
        "## Summary",
        "",
        f"**The optimal interferon response protects a cell exactly while the free virus around it is denser than "
        f"a threshold.** In this model one infected cell bursts and, with no protection, its virions go on to "
        f"infect R0 = {R0:g} other cells on average. To bring that down to {Rt:g} (preventing {V:g} infections per "
        f"infected cell) with the least antiviral state, every cell should be antiviral while the expected "
        f"density of free virions over it exceeds θ = {u['density_threshold_theta']:.3g} virions per cell area. "
        f"That protects a disc around the infected cell which grows to {u['max_radius']:.1f} cell diameters and "
        f"shrinks to nothing {u['protect_until_h']:.2f} h after the burst, and costs {u['level_set']['h']:.0f} "
        f"cell-hours of antiviral state: **{per:.2f} infections prevented per 1000 cell-hours**. The best simple "
        f"alternative, a fixed disc of radius {b['radius']:.1f} cell diameters protected "
        + (f"from the burst until {b['t1']:.2f} h" if b["t0"] < 0.005 else f"from {b['t0']:.2f} h to {b['t1']:.2f} h")
        + f" after it, needs {b['h']:.0f} cell-hours for the same effect "
        f"(**{per_ball:.2f} per 1000 cell-hours**): the threshold rule does the same job with "
        f"{100 * (1 - 1 / (1 + u['ball_extra_cost'])):.0f}% less protection.",
        "",
        f"When protecting a cell costs more the farther it is from the infection, or costs {1 + cfg.shell[2]:g}x on "
        f"a ring {cfg.shell[0]:g}–{cfg.shell[1]:g} cells away, the optimum raises each cell's virus threshold in proportion to its cost (it skips most of the "
        f"costly ring), and the best fixed disc needs {100 * d['ball_extra_cost']:.0f}% and "
        f"{100 * s['ball_extra_cost']:.0f}% more than the optimum. Cells that each sense the virus averaged over "
        f"themselves and switch on their own reach nearly the ideal: E[I] = {lat_text}, against {Rt:g} for the "
        f"ideal continuous response, so no central coordination is needed. Where the virus signal is flat over a "
        f"large region, a plain switch over-reacts (it prevents {f['F_at_r_bar']:.2f} infections instead of "
        f"{V:g}, at {100 * switch_extra:.0f}% more cost); cells in that region responding at random with "
        f"probability q = {f['tie_probability']:.2f} meet the target at the least cost, as the thesis suggests "
        "for the stochastic interferon responses seen in experiments.",
        "",
        "Every number above is computed from the model by quadrature and checked against simulations of "
        f"{r['model']['cells']} infected cells and {r['model']['virions']} virions (tables below).",
        "",
        "**What the symbols mean** (time in hours, length in cell diameters, ~10 µm; area in cell diameters², "
        "about one cell of a monolayer):",
        "",
        "| symbol | meaning | units | value here |",
        "|---|---|---|---|",
        "| t | time since the infected cell burst and released its virions | h | |",
        "| x, \\|x\\| | position in the tissue, distance from the infected cell | cell diameters | |",
        f"| η | death (burst) rate of an infected cell; it lives 1/η on average | 1/h | {cfg.eta:.4g} (lives {1 / cfg.eta:.3g} h) |",
        f"| β | rate at which an infected cell makes virions | virions/h | {cfg.beta:g} |",
        f"| E[Z] = β/η | virions released in one burst, on average | virions | {cfg.beta / cfg.eta:g} |",
        f"| γ | rate at which a free virion enters a cell | 1/h | {cfg.gamma:g} |",
        f"| δ | rate at which a free virion decays | 1/h | {cfg.delta:g} |",
        f"| D | diffusion coefficient of a virion | cell diameters²/h | {cfg.diffusion:g} (1 µm²/s) |",
        f"| d | dimension of the tissue | — | {cfg.dim} (a monolayer) |",
        f"| R0 | new infections caused by one infected cell, no protection | cells | {R0:g} |",
        "| E[I] | new infections caused by one infected cell under a protection policy | cells | |",
        f"| R̄ | the target for E[I]; V = R0 − R̄ infections must be prevented | cells | {Rt:g}; V = {V:g} |",
        "| A | the protection policy: the set of (time, place) where cells are antiviral | — | |",
        "| g(t, x) | infections prevented per cell area per hour by protecting (t, x) | 1/(cell diameter² h) | |",
        "| h(t, x) | cost of keeping (t, x) protected; 1 = one cell for one hour | 1/(cell diameter² h) | 1, or "
        "more with distance / on the ring |",
        "| ∫_A h | the cost of policy A | cell-hours (cost-weighted) | |",
        "| r, r̄ | threshold on g/h: infections prevented per cell-hour at the edge of the protected region; "
        "r̄ meets the target | infections per cell-hour | r̄ = " + f"{u['r_bar']:.3g} (same cost everywhere) |",
        "| θ = r/γ | the same threshold on the density of free virions a cell senses | virions per cell area | "
        f"{u['density_threshold_theta']:.3g} |",
        "| F(r) | infections prevented by protecting wherever g/h ≥ r | cells | F(r̄) = V |",
        "| q | probability that a cell in a region of flat signal responds | — | "
        f"{f['tie_probability']:.2f} |",
        "",
        "**Figures.** `optimal_sets`: which cells to protect and when, for each cost, with the best fixed disc; "
        "`cost_at_equal_EI`: the cost of each policy that prevents the same number of infections, relative to "
        "the optimum; `F_of_r`: infections prevented as the threshold is lowered; `mc_vs_quadrature`: simulations "
        "against the formula; `extinction`: the chance the infection dies out over generations of cells; "
        "`tuning`: finding the threshold by gradient descent from the target alone.",
        "",
        "**A misprint in the thesis.** In Step 2 of the proof of Theorem 4.4.1 the thesis writes "
        "∫_{E_A} h = ∫_{E_A} r̄·g on the tie set E_A = {g/h = r̄}; there h = g/r̄, so the difference of two "
        "costs is (1/r̄)(∫_A g − ∫_B g), not r̄(∫_A g − ∫_B g) (both are zero, so the theorem stands). The code "
        "follows the corrected form: in the non-unique case every optimal set costs V/r̄ (table 'non-unique "
        "case' below). The same line writes the union over r ≥ r̄ of L_r where the strict set (r > r̄) is meant.",
        "",
        "# Technical tables",
        "",
    ]


def report(cfg, r) -> str:
    p, m = r["parameters"], r["model"]
    L = summary(cfg, r) + [
        f"Infection model (A1)–(A6) in d = {cfg.dim}: eta = {cfg.eta:.4g}/h, beta = {cfg.beta:g}/h, gamma = "
        f"{cfg.gamma:g}/h, delta = {cfg.delta:g}/h, D = {cfg.diffusion:g} cell diameters²/h. Target E[I] = "
        f"{cfg.target_R:g}, so V = R0 - R̄ = {p['V']:.4g}. {m['cells']} infected cells, {m['virions']} virions, "
        "every virion drawn (decay and entry clocks, Gaussian position at entry). Intervals are 95% (normal "
        "approximation for means, Wilson for fractions); quadrature values (Simpson's rule between every time "
        "the set changes shape) carry a bracket from the panels' end values, rigorous for the level sets.",
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
        f"parameter {r['offset_ball_max_lambda']:.3g}). The cell-autonomous rules on a lattice are integrated "
        "cell by cell (each cell's switching times, then Gauss–Legendre; ± is the change from halving the time "
        "grid); their random-pattern row has no per-virion check (one infection's virions share its pattern).",
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
    L += ["", "**Lattice rules against the continuum rule they approximate**, paired on the same virions (the "
          "difference per infected cell; this cancels the noise every row shares):", "",
          "| lattice rule | continuum rule | E[I] difference, Monte Carlo [95%] | by quadrature | inside |",
          "|---|---|---|---|---|"]
    for n, row in r["controls_mc"].items():
        if "paired_with" in row:
            L.append(f"| {n} | {row['paired_with']} | "
                     f"{fmt_ci(row['paired_difference_mc'], row['paired_difference_ci95'], 5)} | "
                     f"{row['paired_difference_quadrature']:.5f} | {row['paired_in_ci']} |")
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
