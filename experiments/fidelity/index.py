"""Generate ``docs/fidelity.md``: every table, figure and numeric claim of the documents -> its status.

    python -m experiments.fidelity.index --runs DIR [--readings docs/fidelity] [--out docs/fidelity.md]

DIR holds one folder per experiment with its ``metrics.json`` (the output of ``jaxdip reproduce [--quick] --out
DIR``, or of single ``jaxdip run <id> --out DIR/<id>`` runs). The claims are ``experiments/fidelity/claims.py``;
the readings rows are every ``*.json`` in ``--readings`` (written by the studies in ``experiments/fidelity/``).
Nothing is run here: the numbers are the runs' and the rows'. Each claim's status is one class of
``KIND_LABELS`` under the rules of ``VOCABULARY`` (printed at the top of the page):

- rows under its id (each given its support, and re-decided on its intervals where a threshold applies, by
  ``support.annotate``): the strongest support among the rows that hold, else not reproduced or
  undecided, the readings listed with their numbers and commands in the section "Readings";
- a claim that expects rows and has none: **readings pending** (with the default run's checks beside it);
- checks on the runs' results (``checks.evaluate``, on intervals where there are any): the weakest
  support among the claim's ``choices``, or **an ordering holds** for an ordering claim, when every check holds;
  else not reproduced / undecided;
- a test, an input table, or **not attempted** with why.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import sys
from dataclasses import dataclass

from experiments.fidelity import claims as FC
from experiments.fidelity import support as FS
from experiments.fidelity.checks import combine, evaluate, fmt, get, run_size  # noqa: F401  (the generator's API)
from experiments.fidelity.runs import ROOT
HOLDS = ("yes", "no", "undecided", "n/a")
# the classes of the status column, strongest first; each has one rule, stated at the top of the page (VOCABULARY)
KIND_LABELS = {"printed": "reproduced as printed", "supported": "reproduced under a reading the text supports",
               "ordering": "an ordering holds", "unprinted": "reproduced only with an unprinted value",
               "contradicts": "reproduced only against the text", "not reproduced": "not reproduced",
               "undecided": "undecided", "pending": "readings pending", "no run": "without a run",
               "test": "checked by a test", "input": "input tables", "not attempted": "not attempted"}
REPRODUCED = ("printed", "supported", "ordering", "unprinted", "contradicts")
VOCABULARY = (
    "*reproduced as printed*: every check holds on the default config, or a readings row holds, with the "
    "document's equations and values as printed and a printed number decided on our interval; "
    "*reproduced under a reading the text supports*: as before, but with a reading of something the text leaves "
    "open (the row says where); "
    "*an ordering holds* (weaker): the claim is checked only as an ordering on a metric we chose, not on a "
    "number the document prints (the row says what the ordering leaves out); "
    "*reproduced only with an unprinted value* / *only against the text*: it holds only with a value the "
    "document does not print (\"needs an unprinted value\") or with a reading that contradicts what it prints "
    "(\"contradicts the text\"); the row names it, and the number without it; "
    "*not reproduced*: a check fails, or no reading holds (every reading is listed with its numbers); "
    "*undecided*: a 95% interval straddles the claim's number, tolerance edge or threshold, or two intervals "
    "overlap (the row gives the run size that would decide it, from the half-width scaling as 1/sqrt(n)); "
    "*checked by a test*: a named test verifies it against an independent reference; *not attempted*: why not; "
    "*readings pending*: a study is expected and has written no row. "
    "A claim decided by readings takes the strongest class among the rows that hold; a row is as weak as the "
    "weakest of its choices (column *text* under Readings: printed, supported, unprinted, contradicts). A "
    "default-config claim takes the weakest class among the modelling choices it names. Tolerances are ours "
    "(the documents state none) and are written into each check.")
ROW_KEYS = ("claim", "reading", "what", "command", "ours", "document", "holds")


@dataclass
class Status:
    status: str  # one line
    kind: str  # reproduced | reading | not reproduced | undecided | pending | no run | test | input | not attempted
    ours: str = ""
    command: str = ""


def check_status(claim: FC.Claim, runs: dict[str, dict], quick: bool) -> Status:
    m = runs.get(claim.exp)
    command = f"`jaxdip run {claim.exp}{' --quick' if quick else ''}`"
    if m is None:
        return Status(f"no run of {claim.exp} in --runs", "no run", "", command)
    verdicts, texts = [], []
    for c in claim.checks:
        h, t = evaluate(c, m["results"], m.get("seeds"))
        verdicts.append(h)
        texts.append(f"{t} (**{h}**)")
    v = combine(verdicts)
    ours = "; ".join(texts) + "".join(
        f"; choice: {c.name} ({c.support}: {c.where}); without it: {c.without}" + _run_value(m, c.key)
        for c in claim.choices)
    command += f" ({m['seeds']} seeds)"
    if v != "yes":
        return Status(("not reproduced" if v == "no" else "undecided") + " (default config)",
                      "not reproduced" if v == "no" else "undecided", ours, command)
    kind = weakest(["printed"] + [c.support for c in claim.choices])
    return held_status(claim, kind, "default config", ours, command)


def _run_value(m: dict, key: str | None) -> str:
    if key is None:
        return ""
    try:
        return f" (this run: {fmt(get(m['results'], key))})"
    except KeyError:
        return f" (this run: key {key} absent)"


def weakest(supports: list[str]) -> str:
    return max(supports, key=FC.SUPPORT.index)


def held_status(claim: FC.Claim, support: str, how: str, ours: str, command: str) -> Status:
    """A claim that holds, classed by how far its reading departs from the text and whether it is only an
    ordering on a metric we chose."""
    if claim.ordering and support in ("printed", "supported"):
        return Status(f"an ordering holds ({how}): {claim.ordering}", "ordering", ours, command)
    label = {"printed": "reproduced as printed", "supported": "reproduced under a reading the text supports",
             "unprinted": "reproduced only with an unprinted value (needs an unprinted value)",
             "contradicts": "reproduced only against the text (contradicts the text)"}[support]
    return Status(f"{label} ({how})", support, ours, command)


def readings_status(rows: list[dict], claim: FC.Claim | None = None) -> Status:
    """Status of a claim from its readings rows (rows with holds "n/a" are shown but not counted): the strongest
    ``support`` among the rows that hold."""
    counted = [r for r in rows if r["holds"] != "n/a"]
    yes = [r for r in counted if r["holds"] == "yes"]
    if yes:
        best = min(FC.SUPPORT.index(r.get("support", "contradicts")) if r.get("support") in FC.SUPPORT
                   else len(FC.SUPPORT) - 1 for r in yes)
        top = [r for r in yes if r.get("support", "contradicts") == FC.SUPPORT[best]] or yes
        names = "; ".join(f"{r['reading']}" + (f" [{r['support_where']}]" if r.get("support_where") else "")
                          for r in top)
        how = f"reading {names}; {len(yes)} of {len(counted)} readings hold"
        st = held_status(claim or _NO_CLAIM, FC.SUPPORT[best], how, "; ".join(r["ours"] for r in top),
                         "<br>".join(f"`{r['command']}`" for r in top))
        return st
    n = len(counted)
    if not counted:
        return Status("readings pending (rows hold no verdict)", "pending")
    undecided = sum(r["holds"] == "undecided" for r in counted)
    if undecided == n:
        status, kind = f"undecided under {n} readings tried", "undecided"
    else:
        status, kind = f"not reproduced under {n} readings tried", "not reproduced"
        if undecided:
            status += f" ({undecided} undecided)"
    return Status(status + " (listed below)", kind, "; ".join(f"{r['reading']}: {r['ours']}" for r in counted[:1])
                  + (f"; ... {n - 1} more below" if n > 1 else ""), f"`{counted[0]['command']}` ...")


_NO_CLAIM = FC.Claim("paper:none-0", "", "", "", input=True)


def parent_of(row_id: str, known) -> str | None:
    """The inventory claim a row id names: itself, or the longest known id it extends with "-<part>" (a claim
    with several numbers is scored per part, e.g. ``stumfoll:table-8.3-param-lqr`` of ``stumfoll:table-8.3``)."""
    if row_id in known:
        return row_id
    best = None
    for k in known:
        if row_id.startswith(k + "-") and (best is None or len(k) > len(best)):
            best = k
    return best


def group_rows(rows_by_id: dict[str, list[dict]], known) -> tuple[dict[str, dict[str, list[dict]]], list[str]]:
    """claim -> {row id (the claim's own or a part's) -> rows}; and the row ids that name no known claim."""
    out: dict[str, dict[str, list[dict]]] = {}
    unknown = []
    for rid, rows in rows_by_id.items():
        parent = parent_of(rid, known)
        if parent is None:
            unknown.append(rid)
        else:
            out.setdefault(parent, {})[rid] = rows
    return out, sorted(unknown)


def parts_status(parts: dict[str, list[dict]], claim: FC.Claim | None = None,
                 default: Status | None = None) -> Status:
    """A claim scored in parts holds only if every part holds under some reading; it is as weak as its weakest
    part. ``default``: the default run's checks, one more part where the claim's own id has no rows (its rows
    then score other statements of it only)."""
    if len(parts) == 1 and default is None:
        return readings_status(next(iter(parts.values())), claim)
    sts = {pid: readings_status(rows) for pid, rows in parts.items()}
    if default is not None:
        sts[f"{claim.id}-default-run"] = default
    held = [pid for pid, st in sts.items() if st.kind in REPRODUCED]
    n_rows = sum(len([r for r in rows if r["holds"] != "n/a"]) for rows in parts.values())
    if len(held) == len(sts):
        kind = weakest([sts[pid].kind if sts[pid].kind in FC.SUPPORT else "printed" for pid in held])
        return held_status(claim or _NO_CLAIM, kind, f"all {len(sts)} parts hold, each under its reading(s), "
                           "listed below", "; ".join(f"{pid.split(':')[1]}: {sts[pid].ours}" for pid in held[:3]),
                           "see Readings")
    kind = "undecided" if all(st.kind in ("undecided", "pending") for st in sts.values()) else "not reproduced"
    part_names = ", ".join(pid.split(":")[1] for pid in held) or "none"
    ours = f"default run ({default.status}): {default.ours}" if default is not None else ""
    return Status(f"not reproduced: {len(held)} of {len(sts)} parts hold under some reading ({part_names}); "
                  f"{n_rows} readings rows tried (listed below)", kind, ours,
                  "see Readings" + (f"; {default.command}" if default is not None else ""))


def claim_status(claim: FC.Claim, rows, runs: dict[str, dict], quick: bool) -> Status:
    """``rows``: a list of rows of the claim, or {row id: rows} for a claim scored in parts."""
    if isinstance(rows, dict):
        if not rows:
            return claim_status(claim, [], runs, quick)
        default = check_status(claim, runs, quick) if claim.checks and claim.id not in rows else None
        return parts_status(rows, claim, default)
    if rows:
        return readings_status(rows, claim)
    if claim.readings:
        if claim.checks:
            s = check_status(claim, runs, quick)
            return Status(f"readings pending; default run: {s.status}", "pending", s.ours, s.command)
        return Status("readings pending", "pending")
    if claim.checks:
        return check_status(claim, runs, quick)
    if claim.test:
        return Status(f"checked by a test: {claim.test}", "test")
    if claim.input:
        return Status("input: the models use these values; nothing to reproduce", "input")
    return Status(f"not attempted: {claim.not_attempted}", "not attempted")


def load_rows(folder: str) -> tuple[dict[str, list[dict]], list[str]]:
    """Rows of every ``*.json`` in ``folder`` by claim id (each row gets ``file``); and the files read."""
    out: dict[str, list[dict]] = {}
    files = sorted(f for f in os.listdir(folder) if f.endswith(".json")) if os.path.isdir(folder) else []
    for name in files:
        with open(os.path.join(folder, name)) as fh:
            rows = json.load(fh)
        if not isinstance(rows, list):
            raise ValueError(f"{name}: not a list of rows")
        for i, r in enumerate(rows):
            missing = [k for k in ROW_KEYS if k not in r]
            if missing or r["holds"] not in HOLDS:
                raise ValueError(f"{name}: row {i}: missing {missing} or holds {r.get('holds')!r} not in {HOLDS}")
            a = FS.annotate(r)
            out.setdefault(a["claim"], []).append({**a, "file": name})
    return out, files


def load_runs(folder: str) -> tuple[dict[str, dict], bool]:
    """experiment id -> metrics.json of the runs in ``folder``; whether they are --quick runs (from reproduce's
    REPORT.md title; single runs are taken as full unless REPORT.md says quick)."""
    runs = {}
    for name in sorted(os.listdir(folder)):
        p = os.path.join(folder, name, "metrics.json")
        if os.path.isfile(p):
            with open(p) as fh:
                m = json.load(fh)
            runs[m.get("experiment", name)] = m
    quick = False
    report = os.path.join(folder, "REPORT.md")
    if os.path.isfile(report):
        with open(report) as fh:
            quick = "(quick)" in fh.readline()
    return runs, quick


def _cell(s: str) -> str:
    return s.replace("|", "\\|").replace("\n", " ")


def _anchor(cid: str) -> str:
    return "readings-" + re.sub(r"[^a-z0-9-]", "", cid.lower().replace(":", "-").replace(".", "-"))


def render(rows_by_claim: dict[str, list[dict]], files: list[str], runs: dict[str, dict], quick: bool,
           runs_label: str) -> str:
    claims = FC.CLAIMS
    known = FC.all_ids()
    grouped, unknown = group_rows(rows_by_claim, known)
    statuses = {c.id: claim_status(c, grouped.get(c.id, {}), runs, quick) for c in claims}
    counts: dict[str, int] = {}
    for s in statuses.values():
        counts[s.kind] = counts.get(s.kind, 0) + 1
    scale = ("`--quick` scale (each experiment's reduced run: few seeds, short horizons; see the `seeds` in the "
             "command column)" if quick else "the runs' own scale (full unless stated in the command column)")
    L = [
        "# Fidelity: what the documents claim and what jaxdip finds",
        "",
        "Generated by `python -m experiments.fidelity.index --runs DIR` (do not edit by hand) from the inventory "
        "`experiments/fidelity/claims.py`, the readings rows " + (", ".join(f"`docs/fidelity/{f}`" for f in files)
        or "(none)") + f" and the `metrics.json` of the runs in `{runs_label}`.",
        "",
        f"**Scale.** Numbers decided by checks on runs come from {scale}. Numbers from readings rows come from "
        "the readings studies at the scale stated in their own pages (`docs/fidelity/*.md`).",
        "",
        "**Status.** " + VOCABULARY,
        "",
        "Documents: " + "; ".join(f"**{k}** = {v}" for k, v in FC.DOCUMENTS.items()) + ".",
        "",
        "Summary: " + ", ".join(f"{counts[k]} {label}" for k, label in KIND_LABELS.items() if counts.get(k))
        + f" ({len(claims)} claims; {len(FC.QUALITATIVE)} figures qualitative, not scored).",
        "",
    ]
    for doc, title in FC.DOCUMENTS.items():
        L += [f"## {doc}: {title}", "",
              "| claim | where | the document claims | document's number | status | ours | command |",
              "|---|---|---|---|---|---|---|"]
        for c in claims:
            if c.doc != doc:
                continue
            s = statuses[c.id]
            status = s.status
            if c.id in grouped:
                status += f" ([readings](#{_anchor(c.id)}))"
            L.append("| " + " | ".join(_cell(x) for x in (
                f"`{c.id}`", c.where, c.claim + (f" *{c.notes}*" if c.notes else ""),
                c.document, f"**{status}**", s.ours, s.command)) + " |")
        L.append("")
    L += study_readings(grouped)
    L += ["## Qualitative figures, not scored", ""]
    L += [f"- `{q.id}`: {q.what}" for q in FC.QUALITATIVE]
    L += ["", "## Readings", ""]
    for c in claims:
        parts = grouped.get(c.id)
        if not parts:
            continue
        rows = [r for pr in parts.values() for r in pr]
        L += [f'<a id="{_anchor(c.id)}"></a>', "", f"### {c.id}", "",
              f"Document: {c.document}. Rows from " + ", ".join(sorted({f"`docs/fidelity/{r['file']}`" for r in rows}))
              + ".", ""]
        for pid, prs in parts.items():
            if len(parts) > 1 or pid != c.id:
                L += [f"Part `{pid}`: **{readings_status(prs).status}**", ""]
            L += ["| reading | text | what | ours | document | holds | command |", "|---|---|---|---|---|---|---|"]
            L += ["| " + " | ".join(_cell(x) for x in (
                r["reading"], f"{r.get('support', 'unclassified')}: {r.get('support_where', '')}", r["what"], r["ours"], r["document"],
                f"**{r['holds']}**" + (f" (study: {r['holds_study']}" + (f"; {r['holds_why']}" if r["holds_why"]
                                                                      else "") + ")" if "holds_study" in r else ""), f"`{r['command']}`")) + " |" for r in prs]
            L.append("")
    if unknown:
        L += ["## Rows whose claim id the inventory does not know", ""]
        L += [f"- `{k}` ({len(rows_by_claim[k])} rows in "
              + ", ".join(sorted({r['file'] for r in rows_by_claim[k]})) + ")" for k in unknown]
        L.append("")
    return "\n".join(L)


def study_readings(grouped: dict[str, dict[str, list[dict]]]) -> list[str]:
    """One consistent reading per study first (``FS.STUDIES``): how every claim of the study fares under it;
    then every reading against every claim, which shows the readings that exclude each other."""
    L = []
    for st in FS.STUDIES:
        rows = {cid: {r["reading"]: r for prs in grouped.get(cid, {}).values() for r in prs} for cid in st.claims}
        L += [f"## {st.title}: one reading for all its claims", "", st.text, "",
              "| claim | holds | ours |", "|---|---|---|"]
        L += ["| " + " | ".join(_cell(x) for x in (f"`{cid}`", f"**{rows[cid][st.reading]['holds']}**",
                                                  rows[cid][st.reading]["ours"])) + " |"
              for cid in st.claims if st.reading in rows[cid]]
        readings = list(dict.fromkeys(r for cid in st.claims for r in rows[cid]))
        L += ["", st.exclusive, "", "| reading | text | " + " | ".join(f"`{c}`" for c in st.claims) + " |",
              "|---|---|" + "---|" * len(st.claims)]
        for name in readings:
            first = next(rows[c][name] for c in st.claims if name in rows[c])
            L.append("| " + " | ".join(_cell(x) for x in (
                name, first["support"], *(rows[c][name]["holds"] if name in rows[c] else "" for c in st.claims)))
                + " |")
        L.append("")
    return L


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", required=True, help="folder of experiment runs (DIR/<id>/metrics.json)")
    ap.add_argument("--readings", default=os.path.join(ROOT, "docs", "fidelity"), help="folder of readings json")
    ap.add_argument("--out", default=os.path.join(ROOT, "docs", "fidelity.md"))
    ap.add_argument("--runs-label", default=None, help="how the runs folder is named in the page (default: the "
                    "reproduce command that makes it)")
    args = ap.parse_args(argv)
    if not os.path.isdir(args.runs):
        ap.error(f"--runs: {args.runs} is not a folder")
    runs, quick = load_runs(args.runs)
    if not runs:
        ap.error(f"--runs: no <id>/metrics.json under {args.runs}")
    rows, files = load_rows(args.readings)
    label = args.runs_label or f"jaxdip reproduce{' --quick' if quick else ''} --out DIR"
    text = render(rows, files, runs, quick, label)
    with open(args.out + ".tmp", "w") as fh:
        fh.write(text)
    os.replace(args.out + ".tmp", args.out)
    print("wrote", os.path.relpath(args.out, ROOT) if args.out.startswith(ROOT) else args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
