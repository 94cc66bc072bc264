"""Fidelity readings, DIP side: paper Table 1 / thesis Table 3.2 (CPX vs LDF), thesis Table 3.1 (LQR / PS / RP),
the ensemble Kalman search of §3.2.1 (Procedure 1), and the claims of thesis ch. 1-2 a computation can check
(Thm 1.3.2 with (1.9), Prop. 1.4.1, Prop. 2.4.2).

    python -m experiments.fidelity.dip [--quick] [--seeds N] [--only cpx_ldf,controllers,eki,theory,eki_nonlinear]
                                       [--runs DIR] [--docs DIR]

Writes ``docs/fidelity/dip.md`` and ``docs/fidelity/dip.json`` (rows {claim, reading, what, command, ours,
document, holds}). Every row is one ``jaxdip run ...`` command, run as a child process exactly as printed, its
metrics.json read back; the theory rows' run is ``jaxdip run thesis-theory`` (``jaxdip.theory.proximal_growth``).

Scale (the machine is a shared 2-core CPU): ``--seeds`` trials per dip-cpx-ldf reading (default 100, the
experiment's full 6.5 s, no gamma sweep or single-trial figure), 2 x that per dip-controllers reading (5 s),
and the ensemble search at a reduced size (J = 40 members, at most 100 iterations, 200 judging trials, no
gradient search). ``eki_nonlinear`` (thesis §2.7.2): 100 searches per reading at the printed J = 100, K = 4,
250 iterations, one ensemble per search. ``--quick`` passes ``--quick`` to every run (a pipeline check; numbers
meaningless). Each part is a function ``(args, workdir) -> (markdown lines, rows)`` in ``dip_tables``,
``dip_search`` or ``dip_theory``; this module runs the chosen parts and merges them into the page.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile

import jaxdip  # noqa: F401  (float64)
from jaxdip.messages import listing, unknown
from experiments.fidelity.dip_search import eki, eki_nonlinear
from experiments.fidelity.dip_tables import controllers, cpx_ldf, cpx_ldf_notes
from experiments.fidelity.dip_theory import theory
from experiments.fidelity.runs import ROOT

PARTS = ("cpx_ldf", "controllers", "eki", "theory", "eki_nonlinear")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="pass --quick to every run (a pipeline check)")
    ap.add_argument("--seeds", type=int, default=100, help="trials per dip-cpx-ldf reading (dip-controllers: 2x)")
    ap.add_argument("--only", default=",".join(PARTS), help="comma list of: " + ", ".join(PARTS))
    ap.add_argument("--runs", default=None,
                    help="keep the runs' folders here and reuse finished ones (default: a temporary folder)")
    ap.add_argument("--docs", default=os.path.join(ROOT, "docs", "fidelity"), help="where dip.md/dip.json go")
    args = ap.parse_args(argv)
    parts = [p.strip() for p in args.only.split(",") if p.strip()]
    bad = [p for p in parts if p not in PARTS]
    if bad or not parts:
        ap.error(f"--only: {unknown('part', bad, PARTS)}" if bad else f"--only: no part given{listing(PARTS)}")
    if args.seeds < 2:
        ap.error("--seeds: must be at least 2")
    os.makedirs(args.docs, exist_ok=True)
    md_path, js_path = os.path.join(args.docs, "dip.md"), os.path.join(args.docs, "dip.json")
    # a partial run (--only) replaces its parts' rows and keeps the others'
    old_rows = json.load(open(js_path)) if os.path.isfile(js_path) else []
    sections, rows = {}, []
    with tempfile.TemporaryDirectory(prefix="jaxdip-fidelity-dip-") as tmp:
        workdir = args.runs or tmp
        os.makedirs(workdir, exist_ok=True)
        for part in parts:
            if part == "cpx_ldf":
                L, r, runs = cpx_ldf(args, workdir)
                L += cpx_ldf_notes(runs, r)
            else:
                L, r = {"controllers": controllers, "eki": eki, "theory": theory,
                        "eki_nonlinear": eki_nonlinear}[part](args, workdir)
            sections[part] = L
            rows += r
    kept = [x for x in old_rows if _part_of(x["claim"]) not in parts]
    all_rows = kept + rows
    md_old = open(md_path).read() if os.path.isfile(md_path) else ""
    text = _markdown(args, sections, md_old)
    for path, body in ((md_path, text), (js_path, json.dumps(all_rows, indent=1) + "\n")):
        with open(path + ".tmp", "w") as fh:
            fh.write(body)
        os.replace(path + ".tmp", path)
        print("wrote", os.path.relpath(path, ROOT))
    return 0


def _part_of(claim: str) -> str:
    """Which part of this script writes a row (from its claim id)."""
    if "table-1" in claim or "table-3.2" in claim:
        return "cpx_ldf"
    if "table-3.1" in claim:
        return "controllers"
    if "procedure-1" in claim or "3.2.1" in claim:  # sec-3.2.1, claim-3.2.1-one-vector
        return "eki"
    if claim.startswith("thesis:claim-2.7.2"):
        return "eki_nonlinear"
    return "theory"


MARK = "<!-- part: {} -->"


def _markdown(args, sections: dict, old: str) -> str:
    """The whole page: each part between markers, so a run of some parts keeps the others' text."""
    prev = {}
    for p in PARTS:
        m = MARK.format(p)
        if m in old:
            rest = old.split(m, 1)[1]
            prev[p] = rest.split("<!-- part:", 1)[0].strip("\n").splitlines()
    head = [
        "# Fidelity: the DIP (paper Table 1, thesis Tables 3.1-3.2, §3.2.1, ch. 1-2 claims)",
        "",
        "Generated by `python -m experiments.fidelity.dip` (do not edit by hand); the rows are also in "
        "`docs/fidelity/dip.json`. Every simulation row is one `jaxdip run` command (shown), its numbers the "
        "`results` of that run's metrics.json, with 95% intervals over trials. The scale is reduced (a shared "
        "2-core CPU): each section states its own." + (" **This page was generated with `--quick`: numbers are a "
                                                       "pipeline check only.**" if args.quick else ""),
        "",
    ]
    body = []
    for p in PARTS:
        L = sections.get(p, prev.get(p))
        if L:
            body += [MARK.format(p), *L, ""]
    return "\n".join(head + body) + "\n"


if __name__ == "__main__":
    sys.exit(main())
