"""Stumfoll Table 8.3 (twip-extra-control): extra control against LQR alone, per plant-side reading and law,
and the §8.2 summary claims (53.1% better than LQR, 37.3% better than the nominal system)."""

from __future__ import annotations

import json
import math
import shlex

import numpy as np

from experiments.fidelity.runs import command as _cmd, run as _run
from experiments.fidelity.twip_cells import inside, num_ci, row

THESIS_8_3 = {  # Table 8.3: perturbed LQR, perturbed LQR + extra, nominal system
    "param": (248.92, 123.07, 240.72),
    "unmodeled": (587.04, 235.35, 240.72),
    "deadzone": (358.42, 181.53, 326.10),
    "deadzone_backlash": (1451.9, 688.17, 1434.5),
}
TABLE_CASES = tuple(THESIS_8_3)
SYSTEMS = ("lqr", "extra", "nominal")
# the extra-control laws compared on the same seeds in every run (the main law is virtual = flat)
LAW_VARIANTS = ["virtual=printed", "virtual=printed; virtual_sign=-1.0", "virtual=effective", "k1=10.0"]
LAW_NAMES = {"main": "flat (93) via the flat output (default)", "virtual=printed": "(93) as printed",
             "virtual=printed; virtual_sign=-1.0": "(93) as printed, sign of A2^-1 reversed",
             "virtual=effective": "(93) with the effective gain A2 - B1 A4/B2", "k1=10.0": "flat, k1 = 10"}
# (name, what it reads, --set items): the plant-side readings of §8.2.3-§8.2.4
TRUTH_READINGS = [
    ("default", "deadzone cases on the Table 8.2 truth (the experiment's default), standard backlash", []),
    ("deadzone on Table 8.1", "§8.2.3 as written: the deadzone study 'removes the parameter uncertainty' "
     "(nonlinear_truth = table_8_1)", ["nonlinear_truth=table_8_1"]),
    ("printed backlash", "(161) as printed: the engaged branch at the previous input u(k)", ["backlash_law=printed"]),
    ("Table 8.1 + printed backlash", "both of the above", ["nonlinear_truth=table_8_1", "backlash_law=printed"]),
]


def _paired_mean(parts):
    """Mean of per-case (value, ci) pairs with the 95% half-widths combined as independent errors."""
    vals = np.array([p[0] for p in parts])
    half = np.array([(p[1][1] - p[1][0]) / 2 for p in parts])
    m, h = float(vals.mean()), float(np.sqrt(np.sum(half**2)) / len(parts))
    return m, (m - h, m + h)


def _ratio_ci(a, a_ci, b, b_ci):
    """1 - a/b with a delta-method 95% interval from the two intervals (treated as independent)."""
    sa, sb = (a_ci[1] - a_ci[0]) / 3.92, (b_ci[1] - b_ci[0]) / 3.92
    r = a / b
    s = r * math.sqrt((sa / a) ** 2 + (sb / b) ** 2)
    return 1 - r, (1 - r - 1.96 * s, 1 - r + 1.96 * s)


def table_8_3(args, workdir: str):
    seeds = None if args.quick else args.seeds
    runs = []
    variants = "variants=" + json.dumps(LAW_VARIANTS)
    for name, what, sets in TRUTH_READINGS:
        cases = list(TABLE_CASES) if not sets else ["deadzone", "deadzone_backlash"]
        if "backlash_law=printed" in sets and "nonlinear_truth=table_8_1" not in sets:
            cases = ["deadzone_backlash"]
        cmd = _cmd("twip-extra-control", [*sets, "cases=" + json.dumps(cases), variants], seeds, args.quick)
        runs.append((name, what, cmd, cases, _run(cmd, workdir)["results"]))
    n = runs[0][4]
    n_seeds = seeds or "--quick"
    L = [
        "## Table 8.3: extra control against LQR (§8.2)",
        "",
        f"Scale: {n_seeds} seeds per run (the experiment's full scale is 1000) of {n['horizon_s']:g} s at "
        f"{n['dt_s']:g} s ({n['score_terms']} score terms, as the thesis). Each seed draws the networks' random "
        "input weights and x0 (1 +- 0.1) per component (seed 0: (184)); the thesis reports one run per cell. Score "
        "= sum_k ||x_k - x_d,k|| (lower is better); means over the seeds that did not fall, with 95% intervals. "
        "A cell **holds** when the thesis's number lies inside our interval.",
        "",
        "Readings. Plant side (one run each, column `command`): the deadzone cases' truth (Table 8.2, our default, "
        "because Table 8.3 gives different scores to the perturbed-LQR and nominal columns, or Table 8.1 as §8.2.3 "
        "says), and the backlash law (standard, or (161) as printed). Controller side (the rows of every run, on "
        "the same seeds): " + "; ".join(f"`{k}`: {v}" for k, v in LAW_NAMES.items()) + ". The sign reversal is the "
        "only sign convention that changes the law: counting the tilt the other way reverses A2 and the effective "
        "gain together (tests/test_extra_control.py), so the printed law commands the wrong way in either "
        "convention.",
        "",
        "### Cells (main law)",
        "",
        "| reading | case | LQR ours | thesis | holds | LQR + extra ours | thesis | holds | nominal ours | thesis "
        "| holds | fell (LQR/extra/nominal) | command |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    rows = []
    for name, _what, cmd, cases, r in runs:
        for case in cases:
            c = r[case]
            cells = []
            for s, doc in zip(SYSTEMS, THESIS_8_3[case]):
                h = inside(doc, c[s]["score_ci95"])
                cells += [num_ci(c[s]["score_mean"], c[s]["score_ci95"]), f"{doc:g}", h]
                rows.append(row(f"stumfoll:table-8.3-{case}-{s}", name, f"Table 8.3 score, {case}, {s} "
                                 "(main law: flat)", shlex.join(cmd), num_ci(c[s]["score_mean"], c[s]["score_ci95"]),
                                 f"{doc:g}", h))
            L.append(f"| {name} | {case} | " + " | ".join(cells) + " | "
                     + "/".join(str(c[s]["diverged"]) for s in SYSTEMS) + f" | `{shlex.join(cmd)}` |")
    L += ["", "### Improvement over LQR alone, per law and reading", "",
          "Improvement = 1 - score(extra) / score(LQR), paired over the seeds where neither fell (95% interval); "
          "the thesis's single runs give " + ", ".join(
              f"{c} {100 * (1 - t[1] / t[0]):.1f}%" for c, t in THESIS_8_3.items()) + ". A law that falls in every "
          "seed has no score (n/a).", "",
          "| reading | law | " + " | ".join(TABLE_CASES) + " | seeds kept up (extra) |",
          "|---|---|" + "---|" * len(TABLE_CASES) + "---|"]
    claims = []
    for name, _what, cmd, cases, r in runs:
        for law in ["main", *LAW_VARIANTS]:
            cells, ups, parts, vs_nom = [], [], [], []
            for case in TABLE_CASES:
                if case not in cases:
                    cells.append("—")
                    continue
                c = r[case] if law == "main" else r[case]["variants"][law]
                if "improvement_paired_mean" in c:
                    cells.append(f"{100 * c['improvement_paired_mean']:.1f}% [{100 * c['improvement_paired_ci95'][0]:.1f}, "
                                 f"{100 * c['improvement_paired_ci95'][1]:.1f}]")
                    parts.append((c["improvement_paired_mean"], c["improvement_paired_ci95"]))
                    e = r[case]["extra"] if law == "main" else c
                    nom = r[case]["nominal"]
                    vs_nom.append(_ratio_ci(e["score_mean"], e["score_ci95"], nom["score_mean"], nom["score_ci95"]))
                else:
                    cells.append("n/a")
                up = r[case]["extra_bounded_fraction"] if law == "main" else c["bounded_fraction"]
                ups.append(f"{100 * up:.0f}%")
            L.append(f"| {name} | {LAW_NAMES[law]} | " + " | ".join(cells) + " | " + "/".join(ups) + " |")
            if len(cases) == len(TABLE_CASES):
                claims.append((name, law, cmd, parts, vs_nom))
    L += ["", "### The §8.2 summary claims", "",
          "\"The extra control ... performing on average 53.1% better than LQR control, and even 37.3% better than "
          "the optimal LQR controller for the linear, or nominal, system\" (mean over the four cases of Table 8.3). "
          "Ours: the mean of the four paired improvements (interval: the four half-widths combined as independent "
          "errors), and 1 - extra/nominal per case from the means (delta-method interval). Holds when our interval "
          "reaches the thesis's number (or beyond).", "",
          "| reading | law | mean improvement vs LQR | thesis | holds | mean improvement vs nominal | thesis | holds |",
          "|---|---|---|---|---|---|---|---|"]
    for name, law, cmd, parts, vs_nom in claims:
        full = len(parts) == len(TABLE_CASES)
        if full:
            m, ci = _paired_mean(parts)
            mn, cin = _paired_mean(vs_nom)
            h1 = "yes" if ci[1] >= 0.531 else "no"
            h2 = "yes" if cin[1] >= 0.373 else "no"
            a, b = f"{100 * m:.1f}% [{100 * ci[0]:.1f}, {100 * ci[1]:.1f}]", f"{100 * mn:.1f}% [{100 * cin[0]:.1f}, {100 * cin[1]:.1f}]"
        else:
            a = b = "n/a (falls)"
            h1 = h2 = "no"
        L.append(f"| {name} | {LAW_NAMES[law]} | {a} | 53.1% | {h1} | {b} | 37.3% | {h2} |")
        tag = "" if law == "main" else f" / {law}"
        rows.append(row("stumfoll:table-8.3-53pct", f"{name}{tag}", "mean improvement of LQR + extra over LQR, "
                         "Table 8.3's four cases", shlex.join(cmd), a, "53.1%", h1))
        rows.append(row("stumfoll:table-8.3-37pct", f"{name}{tag}", "mean improvement of LQR + extra over the "
                         "nominal system", shlex.join(cmd), b, "37.3%", h2))
    return L, rows
