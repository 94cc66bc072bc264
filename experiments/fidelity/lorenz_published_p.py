"""Fidelity readings: run each plausible reading of a document's claim and write what it gives.

    python -m experiments.fidelity.lorenz_published_p [--quick] [--seeds N] [--only lorenz,published_p]
                                                      [--check-commands] [--runs DIR] [--docs DIR] [--json-only]

Writes ``docs/fidelity/lorenz.md`` (thesis §1.6, Fig. 1.1-1.2) and ``docs/fidelity/published_p.md`` (thesis
(3.6)), and beside each the same rows as JSON (``lorenz.json``, ``published_p.json``: one row per claim and reading,
the format ``experiments/fidelity/index.py`` reads). ``--json-only`` writes only the JSON without running
anything: the Lorenz rows are read back from the committed ``lorenz.md`` tables, the published-P rows are
recomputed in-process (both cheap). Every Lorenz row is one ``jaxdip run lorenz-mhe ...`` command, run as a child process exactly as
printed in the table, its ``metrics.json`` read back. The published-P rows are the linearised closed loop of
(2.14) under each reading (``jaxdip.theory.published_p``), computed in-process; ``--check-commands`` also runs
each one-at-a-time row's ``jaxdip run dip-controllers --quick ...`` command and checks that its metrics.json
reports the same number.

Scale: ``--seeds`` trials of the full 20 time units per Lorenz reading (default 50, the thesis's number);
``--quick`` passes ``--quick`` to every run (16 trials, 2 time units) to check the pipeline.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import shlex
import sys
import tempfile
from dataclasses import replace

import jaxdip  # noqa: F401  (float64)
from jaxdip.messages import listing, unknown
from experiments.fidelity.runs import ROOT, command as _cmd, run as _run

METHODS = ("cpx", "scpx", "ekf", "ekf2")
LABELS = {"cpx": "CPX", "scpx": "SCPX", "ekf": "EKF", "ekf2": "EKF2"}

# (name, what it says, --set items without the alignment)
LORENZ_READINGS = [
    ("printed", "std, per sample (as printed: sigma is a standard deviation, noise added at every sample)", []),
    ("eps variance", "measurement sigmas are variances (std sqrt 5, EKF2 sqrt 10)", ["eps_reading=variance"]),
    ("eta variance", "state-noise sigmas are variances (std sqrt 0.1, EKF2 sqrt 0.005)", ["eta_reading=variance"]),
    ("both variance", "both sigmas are variances", ["eps_reading=variance", "eta_reading=variance"]),
    ("EKF Q per unit time", "data as printed; EKFs' Q = sigma^2 h (continuous-discrete filter)",
     ["ekf_eta_time=unit_time"]),
    ("data per unit time", "data's state noise a diffusion (std sigma sqrt(h) per sample); EKFs' Q = sigma^2",
     ["eta_time=unit_time"]),
    ("both per unit time", "data a diffusion and EKFs' Q = sigma^2 h (consistent continuous-discrete)",
     ["eta_time=unit_time", "ekf_eta_time=unit_time"]),
]
ALIGNMENTS = ("filtered", "prediction")


def _fmt(v: float, ci) -> str:
    return f"{v:.4g} [{ci[0]:.4g}, {ci[1]:.4g}]"


def _below(r: dict, a: str, b: str, key: str) -> str:
    """'yes' if a's 95% interval lies entirely below b's, 'no' if entirely above, else 'undecided'."""
    ca, cb = r[a][f"{key}_ci95"], r[b][f"{key}_ci95"]
    if any(math.isnan(x) for x in (*ca, *cb)):
        return "undecided"
    return "yes" if ca[1] < cb[0] else "no" if ca[0] > cb[1] else "undecided"


def _all(vs: list[str]) -> str:
    return "yes" if all(v == "yes" for v in vs) else "no" if "no" in vs else "undecided"


def lorenz_claims(r: dict) -> dict[str, str]:
    """The thesis's four statements about Fig. 1.1-1.2, judged from 95% intervals."""
    return {
        "C1": _all([_below(r, m, "ekf", "mean_norm_error") for m in ("cpx", "scpx")]),
        "C2": _all([_below(r, "scpx", m, "mean_xL_error") for m in ("cpx", "ekf", "ekf2")]),
        "C3": _below(r, "ekf2", "ekf", "mean_xL_error"),
        "C4": _below(r, "scpx", "ekf", "mean_xL_error_at_extrema"),
    }


CLAIMS = {
    "C1": "both proximal methods (CPX, SCPX) have a smaller mean norm error e than the EKF",
    "C2": "SCPX has the smallest mean x_L error e_xL of the four",
    "C3": "EKF2 (tuned for x_L) has a smaller e_xL than the EKF",
    "C4": "SCPX recovers the extrema of x_L more closely than the EKF (x_L error where |x_L| > 15)",
}

# the inventory's ids (experiments/fidelity/claims.py) of the four statements
CLAIM_IDS = {"C1": "thesis:fig-1.1-norm", "C2": "thesis:fig-1.1-xL", "C3": "thesis:claim-1.6-ekf2",
             "C4": "thesis:fig-1.2"}
# what each statement compares: (results key, methods shown), and the document's side of it
CLAIM_NUMBERS = {"C1": ("mean_norm_error", ("cpx", "scpx", "ekf")),
                 "C2": ("mean_xL_error", METHODS),
                 "C3": ("mean_xL_error", ("ekf2", "ekf")),
                 "C4": ("mean_xL_error_at_extrema", ("scpx", "ekf"))}
CLAIM_DOCUMENT = {"C1": "CPX and SCPX below the EKF in e (Fig. 1.1 ordering; no number printed)",
                  "C2": "SCPX lowest e_xL of the four (Fig. 1.1 ordering; no number printed)",
                  "C3": "EKF2 (sigma_eta 0.005, sigma_eps 10) tuned for a better x_L fit than the EKF (no number)",
                  "C4": "SCPX closer than the EKF at the extrema of x_L (Fig. 1.2; no number printed)"}
KEY_SHORT = {"mean_norm_error": "e", "mean_xL_error": "e_xL", "mean_xL_error_at_extrema": "e_xL(|x_L|>15)"}


def lorenz_rows(readings: list[tuple[str, str, str, dict, dict]]) -> list[dict]:
    """JSON rows from (name, alignment, command, claims {C1..C4: yes/no/undecided}, numbers {key: {method:
    (value, lo, hi)}}) per reading: one row per claim and reading."""
    rows = []
    for name, align, command, claims, numbers in readings:
        for c, cid in CLAIM_IDS.items():
            key, methods = CLAIM_NUMBERS[c]
            ours = f"{KEY_SHORT[key]}: " + ", ".join(
                f"{LABELS[m]} {_fmt(numbers[key][m][0], numbers[key][m][1:])}" for m in methods)
            rows.append({"claim": cid, "reading": f"{name} ({align})", "what": CLAIMS[c], "command": command,
                         "ours": ours, "document": CLAIM_DOCUMENT[c], "holds": claims[c]})
    return rows


def _numbers(r: dict) -> dict:
    return {key: {m: (r[m][key], *r[m][f"{key}_ci95"]) for m in METHODS} for key in KEY_SHORT}


def lorenz_rows_from_markdown(text: str) -> list[dict]:
    """The Lorenz rows rebuilt from a committed lorenz.md (its claims table and its three number tables), so that
    the JSON of results computed before the JSON existed needs no rerun."""
    titles = {"Mean norm error e": "mean_norm_error", "Mean x_L error e_xL": "mean_xL_error",
              "x_L error where |x_L| > 15": "mean_xL_error_at_extrema"}
    claims, numbers, order, section = {}, {}, [], None
    num = r"(-?[0-9.e+-]+|nan) \[(-?[0-9.e+-]+|nan), (-?[0-9.e+-]+|nan)\]"
    for line in text.splitlines():
        if line.startswith("## "):
            section = line[3:].strip()
        elif line.startswith("### "):
            section = titles.get(line[4:].strip())
        if not line.startswith("| ") or line.startswith("| reading"):
            continue
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if section == "Claims per reading":
            key = (cells[0], cells[1])
            claims[key] = dict(zip(CLAIM_IDS, cells[2:6]))
            order.append((key, cells[6].strip("`")))
        elif section in KEY_SHORT:
            for m, cell in zip(METHODS, cells[2:2 + len(METHODS)]):
                v = re.fullmatch(num, cell)
                if v is None:
                    raise ValueError(f"lorenz.md: cannot read {cell!r} in {section}")
                numbers.setdefault((cells[0], cells[1]), {}).setdefault(section, {})[m] = tuple(
                    float(x) for x in v.groups())
    if not order:
        raise ValueError("lorenz.md: no claims table found")
    return lorenz_rows([(k[0], k[1], cmd, claims[k], numbers[k]) for k, cmd in order])


def lorenz(args, workdir: str) -> tuple[str, list[dict]]:
    rows = []
    plan = [("printed", LORENZ_READINGS[0][1], [], "mixed")]
    plan += [(n, d, s, a) for a in ALIGNMENTS for (n, d, s) in LORENZ_READINGS]
    for name, desc, sets, align in plan:
        full_sets = sets + ([] if align == "mixed" else [f"alignment={align}"])
        cmd = _cmd("lorenz-mhe", full_sets, None if args.quick else args.seeds, args.quick)
        m = _run(cmd, workdir)
        rows.append((name, desc, align, cmd, m))
    seeds = rows[0][4]["seeds"]
    scale = "`--quick` (16 trials, 2 time units)" if args.quick else f"{seeds} trials of 20 time units each"
    L = [
        "# Fidelity: Lorenz MHE comparison (thesis §1.6, Fig. 1.1-1.2)",
        "",
        "Generated by `python -m experiments.fidelity.lorenz_published_p` (do not edit by hand). Scale: " + scale + " per reading "
        "(the thesis ran 50 trials); every row is one `jaxdip run` command (column `command`), its numbers the "
        "`results` of that run's metrics.json: means over trials with 95% intervals.",
        "",
        "The thesis prints no numbers for this study, only the ordering in Fig. 1.1 and these statements:",
        "",
        *[f"- **{k}**: {v}." for k, v in CLAIMS.items()],
        "",
        "A claim holds (**yes**) when every comparison it needs has the first 95% interval entirely below the "
        "second, fails (**no**) when one has it entirely above, and is **undecided** otherwise.",
        "",
        "Readings. The thesis writes eps_k ~ N(0, sigma_eps I), eta_k ~ N(0, sigma_eta I) and calls sigma a "
        "standard deviation: read as a variance, the std is sqrt(sigma) (for the data and for both EKFs' "
        "assumed values alike). The state noise is added at every sample; read as a diffusion, it has std "
        "sigma sqrt(h) per sample, and an EKF tuned per unit time uses Q = sigma^2 h. Alignment: the thesis "
        "scores CPX/SCPX on their one-step model predictions (x~_{k+2} = Phi x^_{k+1}); it does not say what the "
        "EKFs were scored on. `mixed` (the experiment's default) scores CPX/SCPX on predictions and the EKFs on "
        "filtered estimates; `filtered` scores every method on its estimate of x_k from y_0..y_k; `prediction` "
        "every method on its prediction of x_k made at k-1.",
        "",
        "## Claims per reading",
        "",
        "| reading | alignment | C1 | C2 | C3 | C4 | command |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, _desc, align, cmd, m in rows:
        c = lorenz_claims(m["results"])
        L.append(f"| {name} | {align} | {c['C1']} | {c['C2']} | {c['C3']} | {c['C4']} | `{shlex.join(cmd)}` |")
    L += ["", "Document's numbers: none printed (Fig. 1.1 shows the ordering only).", "", "## Numbers", ""]
    for key, title in (("mean_norm_error", "Mean norm error e"), ("mean_xL_error", "Mean x_L error e_xL"),
                       ("mean_xL_error_at_extrema", "x_L error where |x_L| > 15")):
        L += [f"### {title}", "", "| reading | alignment | " + " | ".join(LABELS[m] for m in METHODS)
              + " | diverged (C/S/E/E2) |", "|---|---|" + "---|" * len(METHODS) + "---|"]
        for name, _desc, align, _c, m in rows:
            r = m["results"]
            L.append(f"| {name} | {align} | " + " | ".join(_fmt(r[x][key], r[x][f"{key}_ci95"]) for x in METHODS)
                     + " | " + "/".join(str(r[x]["diverged"]) for x in METHODS) + " |")
        L.append("")
    L += ["## What each reading means", "", "| reading | per-sample noise levels it gives |", "|---|---|"]
    L += [f"| {n} | {d} |" for n, d, _ in LORENZ_READINGS]
    json_rows = lorenz_rows([(name, align, shlex.join(cmd), lorenz_claims(m["results"]), _numbers(m["results"]))
                             for name, _desc, align, cmd, m in rows])
    return "\n".join(L) + "\n", json_rows


def published_p(args, workdir: str) -> tuple[str, list[dict]]:
    import numpy as np

    from jaxdip.theory import published_p as pp

    oat = pp.one_at_a_time()
    rows = [(r, pp.max_real(r)) for r in oat]
    if args.check_commands:
        for r, v in rows:
            m = _run(_cmd("dip-controllers", pp.set_args(r), None, True), workdir)
            got = m["results"]["published_P"]["linearised_max_real_eig"]
            if abs(got - v) > 1e-9 * max(1.0, abs(v)):
                raise SystemExit(f"published P: {r.changes()}: jaxdip run gives {got}, the table {v}")
    every = pp.all_readings()
    vals = np.array([pp.max_real(r) for r in every])
    # Mw and gamma do not move the unstable poles (see the note written below): one row per group without them,
    # after checking that the group agrees
    groups: dict = {}
    for r, v in zip(every, vals):
        groups.setdefault(replace(r, Mw=pp.MW_ON, gamma=40.0), []).append(v)
    spread = max(max(g) - min(g) for g in groups.values())
    reps = list(groups)
    rep_vals = np.array([max(groups[r]) for r in reps])
    order = np.argsort(rep_vals)

    def cmd_of(r):
        return shlex.join(_cmd("dip-controllers", pp.set_args(r), None, True))

    def name_of(r):
        ch = r.changes()
        return ", ".join(f"{k} = {v:g}" if isinstance(v, float) else f"{k} = {v}" for k, v in ch.items()) or \
            "default (printed model, Mw on, [xc, alpha, theta], rad, relative theta, Gram-Schmidt, gamma 40)"

    def holds(v):
        return "yes" if v < 0 else "no"

    L = [
        "# Fidelity: the published P (thesis (3.6)) on the DIP model",
        "",
        "Generated by `python -m experiments.fidelity.lorenz_published_p` (do not edit by hand). The document's claim: the relaxed "
        "projection control (2.14) with P from (3.6) (v1, v2, s = 9.99e5, 3.37e4, the construction (2.20)) and "
        "gamma = 40 stabilises the DIP (simulated on the model (3.1), Fig. 3.3, and on the laboratory system, "
        "Table 3.1). The document prints no eigenvalue; the number checked here is the largest real part of the "
        "linearised closed loop at upright, A - B (B^T P B)^{-1} B^T P (gamma I + A): the claim can hold only "
        "where it is negative. Computed by `jaxdip.theory.published_p`; each row's command prints the same number "
        "as `results.published_P.linearised_max_real_eig` in its metrics.json"
        + (" (checked for every row below when this file was generated)." if args.check_commands else "."),
        "",
        "Readings (each a `jaxdip run dip-controllers` config key): the model's equations (`variant`), the cart "
        "weight Mw on or off (`Mw`), the state order of the vectors (`published_P_order`), a coordinate counted "
        "with the opposite sign (`published_P_flip`; these four cover every sign pattern, since reversing all "
        "coordinates changes nothing), theta relative or absolute (`published_P_angles`), units "
        "(`published_P_units`), how (2.20) turns (v, s) into P (`published_P_construction`), and gamma "
        "(`rp_gamma`: 40 in §3.2.2, 10 in the search of §3.2.1).",
        "",
        "## Each choice changed alone",
        "",
        "| reading | largest real part (1/s) | document | claim holds | command |",
        "|---|---|---|---|---|",
    ]
    for r, v in rows:
        L.append(f"| {name_of(r)} | {v:+.3f} | stabilising (< 0) | {holds(v)} | `{cmd_of(r)}` |")
    n_stable = int((vals < 0).sum())
    L += [
        "",
        f"## All {len(every)} combinations",
        "",
        f"{n_stable} of {len(every)} combinations give a stable linearised closed loop. Within each group that "
        f"differs only in Mw and gamma the largest real part agrees to {spread:.1e}; the {len(reps)} groups "
        f"({int((rep_vals < 0).sum())} stable), the ten with the smallest largest real part first (Mw on, "
        "gamma 40 in the command):",
        "",
        "| reading | largest real part (1/s) | claim holds | command |",
        "|---|---|---|---|",
    ]
    for i in order[:10]:
        r = reps[i]
        L.append(f"| {name_of(r)} | {rep_vals[i]:+.3f} | {holds(rep_vals[i])} | `{cmd_of(r)}` |")
    L += [
        "",
        "Invariances seen in the table and why: Mw and gamma do not move the unstable eigenvalue. The closed loop "
        "is (I - Pi) A - gamma Pi with the oblique projector Pi = B (B^T P B)^{-1} B^T P: gamma only sets the pole "
        "of the relaxation (-gamma, along B), and the other five poles are those of the dynamics on the surface "
        "B^T P x = 0, which do not see terms that act along the input direction. The cart's mass (hence Mw) and "
        "the motor's back-EMF damping enter the linearised model only through such matched terms. Likewise the "
        "choice of completion vectors in (2.20) cannot matter: with the remaining singular values 1, P = I + "
        "sum (s_i - 1) q_i q_i^T for the orthonormalised q_i.",
    ]
    L += ["", "The worst groups: " + "; ".join(f"{name_of(reps[i])}: {rep_vals[i]:+.1f}" for i in order[-3:][::-1])
          + "."]
    # JSON: the one-at-a-time rows and the ten best groups (the tables above), each reading once
    json_rows, seen = [], set()
    for r, v in [*rows, *((reps[i], rep_vals[i]) for i in order[:10])]:
        if name_of(r) in seen:
            continue
        seen.add(name_of(r))
        json_rows.append({"claim": "thesis:eq-3.6", "reading": name_of(r),
                          "what": "largest real part of the linearised closed loop (2.14) with P (3.6) at upright "
                                  "(negative: (3.6) stabilises the model locally)",
                          "command": cmd_of(r), "ours": f"{float(v):+.3f} 1/s", "document": "stabilising (< 0)",
                          "holds": holds(v)})
    return "\n".join(L) + "\n", json_rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="pass --quick to every run (a pipeline check)")
    ap.add_argument("--seeds", type=int, default=50, help="Lorenz trials per reading (default 50, as the thesis)")
    ap.add_argument("--only", default="lorenz,published_p", help="comma list of: lorenz, published_p")
    ap.add_argument("--check-commands", action="store_true",
                    help="also run each one-at-a-time published-P command and compare its number")
    ap.add_argument("--runs", default=None,
                    help="keep the runs' folders here and reuse finished ones (default: a temporary folder)")
    ap.add_argument("--docs", default=os.path.join(ROOT, "docs", "fidelity"), help="where the markdown goes")
    ap.add_argument("--json-only", action="store_true",
                    help="write only the JSON rows, running nothing: Lorenz from the committed lorenz.md in --docs, "
                         "published P recomputed in-process")
    args = ap.parse_args(argv)
    parts = [p.strip() for p in args.only.split(",") if p.strip()]
    bad = [p for p in parts if p not in ("lorenz", "published_p")]
    if bad or not parts:
        ap.error(f"--only: {unknown('part', bad, ['lorenz', 'published_p'])}" if bad
                 else f"--only: no part given{listing(['lorenz', 'published_p'])}")
    if args.seeds < 1:
        ap.error("--seeds: must be positive")
    os.makedirs(args.docs, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="jaxdip-fidelity-") as tmp:
        workdir = args.runs or tmp
        os.makedirs(workdir, exist_ok=True)
        for part in parts:
            path = os.path.join(args.docs, f"{part}.md")
            if args.json_only and part == "lorenz":
                with open(path) as fh:
                    text, rows = None, lorenz_rows_from_markdown(fh.read())
            elif args.json_only:
                text, rows = None, published_p(replace_args(args, check_commands=False), workdir)[1]
            else:
                text, rows = lorenz(args, workdir) if part == "lorenz" else published_p(args, workdir)
            outputs = [(os.path.join(args.docs, f"{part}.json"), json.dumps(rows, indent=1) + "\n")]
            if text is not None:
                outputs.append((path, text))
            for out, body in outputs:
                with open(out + ".tmp", "w") as fh:
                    fh.write(body)
                os.replace(out + ".tmp", out)
                print("wrote", os.path.relpath(out, ROOT))
    return 0


def replace_args(args: argparse.Namespace, **changes) -> argparse.Namespace:
    return argparse.Namespace(**{**vars(args), **changes})


if __name__ == "__main__":
    sys.exit(main())
