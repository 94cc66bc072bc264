"""The DIP readings of the ensemble Kalman search for P: thesis §3.2.1 (Procedure 1, eki-dip) and the nonlinear
example of §2.7.2 (eki-nonlinear)."""

from __future__ import annotations

import math
import shlex

from experiments.fidelity.dip_cells import num_ci, row, run_metrics
from experiments.fidelity.runs import command as _cmd


# ---- the ensemble search (thesis §3.2.1, Procedure 1) -----------------------------------------------------------

EKI_SCALE = ["ensemble=40", "iterations=100", "grad_steps=0", "eval_states=32"]
NOISE_VAR = f"noise_std={math.sqrt(5e-5)!r}"
EKI_READINGS = [
    ("default", "N(0, 5e-5) read as a std; one x0 (and noise) shared by the ensemble per iteration; two free "
     "vectors", []),
    ("noise variance", "N(0, 5e-5) read as a variance: std 7.07e-3 per period (search and judging)", [NOISE_VAR]),
    ("x0 per member", "each member draws its own x0 and noise (Procedure 1, steps 1-2)", ["x0_draw=per_member"]),
    ("noise variance, x0 per member", "noise read as a variance and x0 drawn per member", [NOISE_VAR, "x0_draw=per_member"]),
    ("one free vector", "the thesis's first search: v1 alone, s fixed at 1e6", ["free_vectors=1"]),
    ("one free vector, x0 per member", "one free vector (s = 1e6) and x0 drawn per member", ["free_vectors=1", "x0_draw=per_member"]),
]


def eki(args, workdir):
    seeds = None if args.quick else 200
    L = [
        "## Thesis §3.2.1: the ensemble Kalman search for P (Procedure 1)",
        "",
        "The thesis's claims: a search over P_{V,s} (2.20) with J = 80 for up to 1000 iterations found P that "
        "stabilise the model (3.1) in simulation; a first search with one free basis vector (its singular value "
        "fixed at 1e6) also found P stabilising in a neighbourhood of the origin in simulation (but not on the "
        "laboratory system). Reduced scale here: J = 40, at most 100 iterations (early stop as configured), no "
        "gradient search; the found P (ensemble mean) judged by relaxed projection (gamma = 40) from 200 random "
        "states within 0.03 of upright for 5 s. **holds**: yes when the stabilised fraction's 95% interval lies "
        "above 0.5, no when below.",
        "",
        "| reading | iterations | stabilised fraction | performance (2.24) start -> found | command |",
        "|---|---|---|---|---|",
    ]
    rows = []
    for name, what, sets in EKI_READINGS:
        cmd = _cmd("eki-dip", EKI_SCALE + sets, seeds, args.quick)
        m = run_metrics(cmd, workdir)
        r = m["results"]
        f, ci = r["stabilized_fraction"], r["stabilized_fraction_ci95"]
        holds = "yes" if ci[0] > 0.5 else "no" if ci[1] < 0.5 else "undecided"
        perf = f"{r['performance_start']['mean']:.3g} -> {r['performance']['mean']:.3g}"
        L.append(f"| {name} | {r['iterations']} | {num_ci(f, ci)} | {perf} | `{shlex.join(cmd)}` |")
        claim = "thesis:claim-3.2.1-one-vector" if "free_vectors=1" in sets else "thesis:procedure-1"
        rows.append(row(claim, name, "the ensemble search finds a P that stabilises the model in simulation; "
                         + what, cmd, f"stabilised fraction {num_ci(f, ci)} after "
                         f"{r['iterations']} iterations (J = 40)", "stabilising P found (no number printed)", holds))
    L += ["", "| reading | meaning |", "|---|---|"]
    L += [f"| {n} | {w} |" for n, w, _ in EKI_READINGS]
    L += ["", "Note. The starting ensemble has v1 from the LQR Riccati solution, a random v2 in v1-perp and B-perp, "
          "and s = [1e6, 1e4]: where its mean's "
          "performance (2.24) above is finite (below the failure value 1000), it already stabilised the "
          "evaluation states, and the row checks that the search keeps and improves a stabilising P, not that it "
          "finds one from an unstable start. Where both numbers are 1000, the starting mean and the found P "
          "scored the failure value on every evaluation state (the members' own histories were not checked): "
          "with the state "
          "noise read as a variance (std 7.07e-3 per state per 1 ms period) no judging trial stays up either: "
          "that noise level is beyond what "
          "these P (or the search from them) tolerate."]
    return L, rows


# ---- thesis §2.7.2: the search on the nonlinear example ---------------------------------------------------------

EKI_NL_SEEDS = 100
# (name, what it reads, --set items); every reading but the first runs the thesis's procedure (one ensemble)
EKI_NL_READINGS = [
    ("default --quick", "the default run: 10 searches of 80 iterations; the fraction of its one-ensemble searches "
     "(`stabilizing_fraction_single_ensemble`; the run's main search keeps the best of 8 restarts)", None),
    ("printed scale", "J = 100, K = 4, 250 iterations as printed, 100 searches", ["restarts=1"]),
    ("500 iterations", "'iterated until satisfactory performance measures were returned': twice as long",
     ["restarts=1", "iterations=500"]),
    ("objective noise as std", "yhat_1 ~ N(0, .002), yhat_2 ~ N(-.2, .01) read as standard deviations: "
     "R = diag(4e-6, 1e-4)", ["restarts=1", "R=[4e-06, 0.0001]"]),
    ("x0 per member", "each member draws its own x0 (Procedure 1, steps 1-2)", ["restarts=1", "x0_draw=per_member"]),
    ("initial spread 20x", "members drawn from N(0, 4 I) instead of N(0, 0.2 I), then normalised",
     ["restarts=1", "init_var=4.0"]),
    ("best member", "a search ends with its best final member (lowest mean y1 over 64 common initial states), "
     "not the ensemble mean", ["restarts=1", "final=best_member"]),
    ("stabilising near the origin", "the found P judged from initial states N(0, 0.1^2 I) instead of N(0, I)",
     ["restarts=1", "judge_std=0.1"]),
    ("K = 8", "8 steps per evaluation (the linear example's K)", ["restarts=1", "K=8"]),
]


def eki_nonlinear(args, workdir):
    L = [
        "## Thesis §2.7.2: the ensemble search on the nonlinear example",
        "",
        "The thesis: an ensemble of 100 vectors from N(0, 0.2), K = 4 steps from one random x0 ~ N(0, 1) per "
        "iteration, objectives yhat_1 ~ N(0, .002), yhat_2 ~ N(-.2, .01); \"after about 250 iterations the "
        "ensemble mean was v = [.9950, .1003]\" (one search). Ours: the fraction of independent searches (seeds "
        "1.. of the run) whose final v gives a P with which relaxed projection (gamma_k = 0.1 / ||x_k||^2) brings "
        "every one of 200 random initial states (N(0, judge_std^2 I)) within 1e-3 of the origin in 200 steps; "
        "Wilson 95% interval. **holds**: at least 0.9 (the default run's check). The alignment abs(cos) of search 0's "
        f"v with the thesis's is shown beside it. Scale: {EKI_NL_SEEDS} searches per reading (the default run's "
        "--quick: 10).",
        "",
        "| reading | searches ending stabilising | search 0: v (abs cos with the thesis's) | holds | command |",
        "|---|---|---|---|---|",
    ]
    rows = []
    for name, what, sets in EKI_NL_READINGS:
        if sets is None:
            cmd = _cmd("eki-nonlinear", [], None, True)
        else:
            cmd = _cmd("eki-nonlinear", sets, None if args.quick else EKI_NL_SEEDS, args.quick)
        r = run_metrics(cmd, workdir)["results"]
        key = "stabilizing_fraction_single_ensemble" if r["restarts"] > 1 else "stabilizing_fraction"
        f, ci = r[key], r[key + "_ci95"]
        holds = "yes" if f >= 0.9 else "no"
        v0 = f"[{r['v'][0]:.4f}, {r['v'][1]:.4f}] ({r['alignment_with_thesis_v']:.3f})"
        L.append(f"| {name} | {num_ci(f, ci)} | {v0} | {holds} | `{shlex.join(cmd)}` |")
        rows.append(row("thesis:claim-2.7.2-v", name, "searches with one ensemble ending stabilising, at least "
                         "0.9; " + what, cmd, f"{num_ci(f, ci)} of {r['search_seeds']} searches; search 0 v = {v0}",
                         "v = [.9950, .1003] after ~250 iterations (one search)", holds))
    L += ["", "| reading | meaning |", "|---|---|"] + [f"| {n} | {w} |" for n, w, _ in EKI_NL_READINGS]
    fr = {r["reading"]: r["ours"].split(" of ")[0] for r in rows}
    L += ["", "Note. Under the printed settings about half the searches end near the thesis's v (about 6 deg from "
          "x1) and the rest near a second direction (about 74 deg) that does not stabilise even the states near "
          f"the origin (judged from N(0, 0.1^2 I): {fr.get('stabilising near the origin', 'n/a')}): the ensemble "
          "settles in one of two basins depending on its initial draw, whatever the number of iterations "
          f"(500: {fr.get('500 iterations', 'n/a')}) or the end point taken (best member: "
          f"{fr.get('best member', 'n/a')}). Drawing x0 per member makes the wrong basin more likely "
          f"({fr.get('x0 per member', 'n/a')}), K = 8 less ({fr.get('K = 8', 'n/a')}). The members are normalised "
          "before the first update, so the initial spread (`init_var`) only rescales draws whose directions are "
          "uniform whatever the variance; the last-bit differences of the rescaled draws flip single searches "
          f"({fr.get('initial spread 20x', 'n/a')} against {fr.get('printed scale', 'n/a')}). The thesis's "
          "sentence describes one search; under every reading tried a single search lands in the stabilising "
          "basin with odds between about 1 in 8 and 2 in 3, never the 0.9 asked here."]
    return L, rows
