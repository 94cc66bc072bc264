"""Integration choice per experiment: what fewer RK4 sub-steps change in each experiment's own results.

    python -m experiments.fidelity.integration_choice [--runs DIR] [--only ID,ID] [--out docs/integration.json]

For every experiment whose plant is integrated with RK4 sub-steps, runs ``jaxdip run <id> --quick --set
<key>=<value>`` for the candidate values (child processes, the exact commands) beside a reference run with 10
sub-steps (``--runs``: a ``jaxdip reproduce --quick`` folder whose run of that experiment has 10; else run
here) and compares every numeric ``results`` entry that has a 95% interval (a ``<name>_ci95`` sibling, or
``<stem>_ci95`` for ``<stem>_mean``): the change divided by the interval's half-width (what the Monte Carlo
resolves), and the largest relative change of any numeric entry. RK4's error falls as h^4, so the difference
to the reference is the candidate's own integration error to within ~1e-4 of itself (for smooth loops).

The decision rule (docs/performance.md): a default moves to a cheaper value only when no interval-carrying
entry moves by more than 1% of its half-width at the --quick scale (so by less than ~6% of the half-width of
the full runs, whose intervals are ~5.6x narrower), and no decision (a boolean, a count of failures) flips.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shlex
import sys
import tempfile
import tomllib

from jaxdip.messages import unknown
from experiments.fidelity.runs import ROOT, command, run

# experiment -> [(config key, candidate value, what it means)]
CANDIDATES = {
    "dip-controllers": [("substeps", 1, "one RK4 step per 1 ms period"), ("substeps", 2, "two")],
    "dip-cpx-ldf": [("substeps", 1, "one RK4 step per 1 ms period"), ("substeps", 2, "two")],
    "tune": [("substeps", 1, "one RK4 step per period"), ("substeps", 2, "two")],
    "twip-extra-control": [("substeps", 1, "one RK4 step per 10 ms period"), ("substeps", 2, "two (5 ms)")],
    "rwp-bias": [("substeps", 1, "one RK4 step per 2 ms period (plant)"), ("substeps", 2, "two (plant)"),
                 ("observer_substeps", 1, "one RK4 step per period (observers)"),
                 ("observer_substeps", 2, "two (observers)")],
}
SKIP = ("wall", "timing")
REFERENCE = 10  # sub-steps of the reference run (RK4's error at 10 is ~1e-4 of its error at 1)
# twip-dmso is not a candidate: its `rk4_step` (1 ms) is one step length for every case, and its dt = 0.001
# case (Fig. 8.10-8.11) needs it no longer than the period; a per-period count would be a new key


def _leaves(o, path=""):
    if isinstance(o, dict):
        for k, v in o.items():
            if any(s in k for s in SKIP):
                continue
            yield from _leaves(v, f"{path}/{k}")
    elif isinstance(o, list):
        for i, v in enumerate(o):
            yield from _leaves(v, f"{path}[{i}]")
    else:
        yield path, o


def compare(base: dict, new: dict) -> dict:
    """Changes of ``new``'s results against ``base``'s: in units of the base's 95% half-widths, relative, and
    the non-numeric entries (booleans, strings, counts) that differ."""
    b, n = dict(_leaves(base)), dict(_leaves(new))
    worst_ci, worst_ci_key, worst_rel, worst_rel_key, flips, missing = 0.0, None, 0.0, None, [], []
    for key, bv in b.items():
        if key not in n:
            missing.append(key)
            continue
        nv = n[key]
        if isinstance(bv, bool) or not isinstance(bv, (int, float)) or isinstance(bv, int) and isinstance(nv, int):
            if bv != nv:
                flips.append(f"{key}: {bv!r} -> {nv!r}")
            continue
        if nv is None or bv is None or (isinstance(nv, float) and math.isnan(nv)) or math.isnan(bv):
            if not (nv is None and bv is None) and not (isinstance(nv, float) and math.isnan(nv) and math.isnan(bv)):
                flips.append(f"{key}: {bv!r} -> {nv!r}")
            continue
        d = abs(nv - bv)
        rel = d / max(abs(bv), abs(nv), 1e-300)
        if d > 1e-14 and rel > worst_rel:
            worst_rel, worst_rel_key = rel, key
        # the sibling interval: ".../name" -> ".../name_ci95[0]", "[1]"
        stem = key[:-5] if key.endswith("_mean") else key  # "score_mean" has its interval in "score_ci95"
        lo, hi = b.get(f"{key}_ci95[0]", b.get(f"{stem}_ci95[0]")), b.get(f"{key}_ci95[1]", b.get(f"{stem}_ci95[1]"))
        if isinstance(lo, (int, float)) and isinstance(hi, (int, float)) and hi > lo:
            r = d / ((hi - lo) / 2)
            if r > worst_ci:
                worst_ci, worst_ci_key = r, key
    return {"max_change_in_half_widths": worst_ci, "at": worst_ci_key, "max_rel_change": worst_rel,
            "rel_at": worst_rel_key, "flips": flips, "missing": missing}


def acceptable(row: dict) -> bool:
    """The decision rule of the module docstring."""
    return row["max_change_in_half_widths"] <= 0.01 and not row["flips"] and not row["missing"]


def markdown(rows: list[dict]) -> str:
    L = ["# Integration choice per experiment", "",
         "Generated by `python -m experiments.fidelity.integration_choice` (do not edit by hand). Each row: one "
         "`jaxdip run <id> --quick` with fewer RK4 sub-steps, compared with the run at 10 sub-steps (the default when measured) entry "
         "by entry. *Change* is the largest change of a result that carries a 95% interval, in units of that "
         "interval's half-width; *relative* the largest relative change of any number (interval bounds "
         "included); *flips* the decisions and counts that changed. A cheaper value is acceptable when no "
         "interval-carrying result moves by more than 1% of its half-width and nothing flips.", "",
         "| experiment | setting | what | change (half-widths) | where | relative | flips | acceptable | command |",
         "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        flips = "; ".join(r["flips"][:3]) + (f" (+{len(r['flips']) - 3})" if len(r["flips"]) > 3 else "")
        L.append(f"| {r['experiment']} | {r['key']} = {r['value']} | {r['what']} | "
                 f"{r['max_change_in_half_widths']:.2g} | `{r['at']}` | {r['max_rel_change']:.2g} | "
                 f"{flips or 'none'} | {'yes' if acceptable(r) else 'no'} | `{r['command']}` |")
    return "\n".join(L) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", default=None, help="a `jaxdip reproduce --quick` folder with the default runs")
    ap.add_argument("--only", default=",".join(CANDIDATES))
    ap.add_argument("--out", default=os.path.join(ROOT, "docs", "integration.json"))
    args = ap.parse_args(argv)
    ids = [i for i in args.only.split(",") if i]
    bad = [i for i in ids if i not in CANDIDATES]
    if bad:
        ap.error(f"--only: {unknown('experiment', bad, CANDIDATES)}")
    rows = json.load(open(args.out)) if os.path.exists(args.out) else []
    rows = [r for r in rows if r["experiment"] not in ids]
    work = tempfile.mkdtemp(prefix="jaxdip-integration-")
    for exp in ids:
        keys = sorted({k for k, _, _ in CANDIDATES[exp]})
        base = None
        if args.runs and os.path.exists(os.path.join(args.runs, exp, "config.toml")):
            with open(os.path.join(args.runs, exp, "config.toml"), "rb") as fh:
                cfg = tomllib.load(fh)
            if all(cfg.get(k) == REFERENCE for k in keys):  # a default run that is the reference itself
                with open(os.path.join(args.runs, exp, "metrics.json")) as fh:
                    base = json.load(fh)["results"]
        if base is None:
            base = run(command(exp, [f"{k}={REFERENCE}" for k in keys], None, True), work)["results"]
        for key, value, what in CANDIDATES[exp]:
            cmd = command(exp, [f"{key}={value}"], None, True)
            new = run(cmd, work)["results"]
            c = compare(base, new)
            row = {"experiment": exp, "key": key, "value": value, "what": what, "command": shlex.join(cmd), **c}
            rows.append(row)
            print(f"{exp} {key}={value}: {c['max_change_in_half_widths']:.3g} half-widths at {c['at']}; "
                  f"rel {c['max_rel_change']:.3g} at {c['rel_at']}; flips {c['flips'][:3]}", flush=True)
            with open(args.out, "w") as fh:
                json.dump(rows, fh, indent=1)
            with open(os.path.splitext(args.out)[0] + ".md", "w") as fh:
                fh.write(markdown(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
