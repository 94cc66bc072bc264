"""The generator of docs/fidelity.md (experiments/fidelity/index.py): its status logic on a synthetic inventory
and synthetic rows, and that the committed readings rows name claims the inventory knows."""

import json
import os
import re
import subprocess
import sys

import pytest

from experiments.fidelity import index as FI
from experiments.fidelity import lorenz_published_p as fid

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
READINGS = os.path.join(ROOT, "docs", "fidelity")

FC = FI.FC


def row(claim, reading, holds, ours="1.0"):
    return {"claim": claim, "reading": reading, "what": "w", "command": f"jaxdip run x --set r={reading}",
            "ours": ours, "document": "d", "holds": holds}


def test_a_holding_row_gives_reproduced_under_that_reading():
    s = FI.readings_status([row("paper:table-1", "A", "no", "2.0"), row("paper:table-1", "B", "yes", "3.0"),
                            row("paper:table-1", "C", "undecided")])
    assert s.kind == "contradicts"  # a row without a support field counts as the weakest
    assert s.status.startswith("reproduced only against the text") and "reading B" in s.status
    assert "1 of 3" in s.status and s.ours == "3.0" and "r=B" in s.command


def test_no_holding_row_gives_not_reproduced_under_n_readings():
    s = FI.readings_status([row("paper:table-1", "A", "no"), row("paper:table-1", "B", "undecided"),
                            row("paper:table-1", "C", "n/a")])
    assert s.kind == "not reproduced"
    assert s.status.startswith("not reproduced under 2 readings tried (1 undecided)")  # n/a is not counted
    s = FI.readings_status([row("paper:table-1", "A", "undecided"), row("paper:table-1", "B", "undecided")])
    assert s.kind == "undecided" and s.status.startswith("undecided under 2 readings")


def test_claim_without_rows_is_pending_and_rows_take_precedence_over_checks():
    c = FC.Claim("paper:table-1", "w", "c", "d", exp="e", checks=(FC.Check("e", "true", "ok", "ok"),),
                 readings=True)
    runs = {"e": {"seeds": 3, "results": {"ok": True}}}
    s = FI.claim_status(c, [], runs, quick=True)
    assert s.kind == "pending" and s.status == "readings pending; default run: reproduced as printed (default config)"
    assert s.command == "`jaxdip run e --quick` (3 seeds)"
    s = FI.claim_status(c, [row(c.id, "A", "no")], runs, quick=True)
    assert s.kind == "not reproduced" and "1 readings tried" in s.status
    bare = FC.Claim("thesis:thm-1.3.2", "w", "c", "d", readings=True)
    assert FI.claim_status(bare, [], {}, quick=False).status == "readings pending"


def test_check_rules_against_hand_computed_verdicts():
    res = {"a": 1.0, "a_ci95": [0.9, 1.1], "b": 2.0, "b_ci95": [1.8, 2.2], "c": 1.05, "c_ci95": [1.0, 1.2],
           "flag": False, "lst": {"v": [5.0, 7.0]}, "none": None, "sub": {"x": 3.0}, "cis": {"x": [2.5, 3.5]}}

    def ev(**kw):
        return FI.evaluate(FC.Check("e", label="l", **kw), res)[0]

    assert ev(rule="below", key="a", other="b") == "yes"  # [0.9, 1.1] entirely below [1.8, 2.2]
    assert ev(rule="below", key="b", other="a") == "no"
    assert ev(rule="below", key="a", other="c") == "undecided"  # overlapping intervals
    assert ev(rule="below", key="lst/v/0", other="lst/v/-1") == "yes"  # points, list indices
    assert ev(rule="close", key="a", value=1.0, tol=0.1) == "yes"  # [0.9, 1.1] inside the band [0.9, 1.1]
    assert ev(rule="close", key="a", value=1.04, tol=0.05) == "undecided"  # band [0.988, 1.092] cuts [0.9, 1.1]
    assert ev(rule="close", key="a", value=1.5, tol=0.05) == "no"  # band [1.425, 1.575] clear of it
    assert ev(rule="close", key="b", other="a", tol=0.5) == "no"  # |2 - 1| > 0.5 * 1
    assert ev(rule="in_ci", key="a", value=1.09) == "yes"
    assert ev(rule="in_ci", key="a", value=1.2) == "no"
    assert ev(rule="in_ci", key="sub/x", value=3.2, ci="cis/x") == "yes"
    # ratio intervals [1.8/1.1, 2.2/0.9] = [1.64, 2.44]
    assert ev(rule="ratio_ge", key="b", other="a", value=1.6) == "yes"
    assert ev(rule="ratio_ge", key="b", other="a", value=2.0) == "undecided"
    assert ev(rule="ratio_ge", key="b", other="a", value=2.5) == "no"
    assert ev(rule="ratio_ge", key="sub/x", other="lst/v/0", value=0.6) == "yes"  # points: 3/5
    assert ev(rule="ge", key="a", value=0.9) == "yes" and ev(rule="le", key="a", value=0.5) == "no"
    assert ev(rule="ge", key="a", value=1.0) == "undecided"  # the point on the threshold, the interval across
    assert ev(rule="false", key="flag") == "yes" and ev(rule="true", key="flag") == "no"
    assert ev(rule="ge", key="none", value=1.0) == "undecided"  # a null result decides nothing
    assert ev(rule="ge", key="missing/key", value=1.0) == "undecided"
    assert FI.combine(["yes", "undecided"]) == "undecided" and FI.combine(["undecided", "no"]) == "no"


def test_bad_checks_and_claims_are_refused():
    with pytest.raises(ValueError):
        FC.Check("e", "below", "a", "l")  # below needs other
    with pytest.raises(ValueError):
        FC.Check("e", "close", "a", "l", value=1.0)  # close needs tol
    with pytest.raises(ValueError):
        FC.Claim("book:table-1", "w", "c", "d", input=True)  # unknown document
    with pytest.raises(ValueError):
        FC.Claim("paper:table-1", "w", "c", "d", input=True, not_attempted="x")  # two ways to decide


def test_inventory_ids_unique_and_every_committed_row_names_a_known_claim():
    known = FC.all_ids()  # raises on duplicates
    rows, files = FI.load_rows(READINGS)
    assert "lorenz.json" in files and "published_p.json" in files
    grouped, unknown = FI.group_rows(rows, known)
    assert not unknown, f"rows name claims the inventory does not know: {unknown}"
    scored = FC.by_id()
    assert all(scored[k].readings or scored[k].checks for k in grouped), "rows for a claim decided otherwise"


def test_a_claim_in_parts_holds_only_when_every_part_holds():
    def row(cid, reading, holds):
        return {"claim": cid, "reading": reading, "what": "w", "command": "c", "ours": "1", "document": "1",
                "holds": holds}

    known = {"stumfoll:table-8.3", "stumfoll:table-8.3x"}
    assert FI.parent_of("stumfoll:table-8.3-param-lqr", known) == "stumfoll:table-8.3"
    assert FI.parent_of("stumfoll:table-8.3x-a", known) == "stumfoll:table-8.3x"
    assert FI.parent_of("stumfoll:table-8.4-a", known) is None
    parts = {"stumfoll:table-8.3-a": [row("stumfoll:table-8.3-a", "r1", "yes")],
             "stumfoll:table-8.3-b": [row("stumfoll:table-8.3-b", "r1", "no"), row("stumfoll:table-8.3-b", "r2", "no")]}
    s = FI.parts_status(parts)
    assert s.kind == "not reproduced" and "1 of 2 parts" in s.status
    parts["stumfoll:table-8.3-b"][1]["holds"] = "yes"
    assert FI.parts_status(parts).kind == "contradicts"  # rows without a support field: the weakest
    for rows in parts.values():
        for r in rows:
            r["support"] = "printed"
    parts["stumfoll:table-8.3-a"][0]["support"] = "unprinted"
    assert FI.parts_status(parts).kind == "unprinted"  # as weak as its weakest part


def test_lorenz_rows_agree_with_their_own_intervals_and_with_lorenz_md():
    with open(os.path.join(READINGS, "lorenz.md")) as fh:
        rebuilt = fid.lorenz_rows_from_markdown(fh.read())
    with open(os.path.join(READINGS, "lorenz.json")) as fh:
        assert json.load(fh) == rebuilt  # the committed JSON is the committed markdown's
    # recompute each verdict from the intervals printed in the row: the first method(s) against the rest
    first = {"thesis:fig-1.1-norm": ("CPX", "SCPX"), "thesis:fig-1.1-xL": ("SCPX",),
             "thesis:claim-1.6-ekf2": ("EKF2",), "thesis:fig-1.2": ("SCPX",)}
    for r in rebuilt:
        ci = {m: (float(lo), float(hi)) for m, lo, hi in re.findall(r"(\w+) \S+ \[(\S+), (\S+)\]", r["ours"])}
        lows = first[r["claim"]]
        pairs = [(a, b) for a in lows for b in ci if b not in lows]
        verdicts = ["yes" if ci[a][1] < ci[b][0] else "no" if ci[a][0] > ci[b][1] else "undecided"
                    for a, b in pairs]
        expect = "yes" if all(v == "yes" for v in verdicts) else "no" if "no" in verdicts else "undecided"
        assert r["holds"] == expect, (r["reading"], r["claim"])


def test_render_lists_every_claim_and_unknown_row_ids(tmp_path):
    runs = {}
    rows = {"paper:table-1": [{**row("paper:table-1", "A", "yes"), "file": "x.json"}],
            "paper:table-99": [{**row("paper:table-99", "A", "no"), "file": "x.json"}]}
    text = FI.render(rows, ["x.json"], runs, quick=True, runs_label="R")
    for c in FC.CLAIMS:
        assert f"| `{c.id}` |" in text
    for q in FC.QUALITATIVE:
        assert f"- `{q.id}`:" in text
    assert "reading A" in text
    assert "## Rows whose claim id the inventory does not know" in text and "`paper:table-99`" in text


# ---- the status vocabulary of issue 30: classes by support, orderings, thresholds on intervals -------------


def _claim(**kw):
    base = dict(exp="e", checks=(FC.Check("e", "ge", "f", "fraction at least 0.95", value=0.95),))
    return FC.Claim("thesis:claim-9.9", "w", "c", "d", **{**base, **kw})


def test_a_threshold_is_decided_on_the_interval_with_the_run_size_that_would_decide_it():
    # the case the issue names: 0.969 [0.843, 0.995] against "at least 0.95" is undecided, not reproduced
    runs = {"e": {"seeds": 32, "results": {"f": 0.969, "f_ci95": [0.843, 0.995]}}}
    s = FI.claim_status(_claim(), [], runs, quick=True)
    assert s.kind == "undecided"
    # half-width on the threshold's side 0.126, distance 0.019: 32 (0.126 / 0.019)^2 = 1407.3 -> 1408 samples
    assert "about 1408 samples would decide it (now 32)" in s.ours
    runs["e"]["results"]["f_ci95"] = [0.955, 0.99]
    assert FI.claim_status(_claim(), [], runs, quick=True).kind == "printed"
    runs["e"]["results"].update(f=0.9, f_ci95=[0.85, 0.94])
    assert FI.claim_status(_claim(), [], runs, quick=True).kind == "not reproduced"
    assert FI.run_size(100, 0.5, 0.4, 0.6, 0.55).endswith("about 400 samples would decide it (now 100)")


def test_choices_and_orderings_weaken_a_default_config_claim():
    runs = {"e": {"seeds": 8, "results": {"f": 0.99}}}
    assert FI.claim_status(_claim(), [], runs, quick=False).kind == "printed"
    sup = FC.Choice("a", "supported", "§1 leaves it open", "0.5")
    con = FC.Choice("Mw on the cart", "contradicts", "§3.1.1 leaves it out", "29148")
    s = FI.claim_status(_claim(choices=(sup,)), [], runs, quick=False)
    assert s.kind == "supported" and "without it: 0.5" in s.ours
    s = FI.claim_status(_claim(choices=(sup, con)), [], runs, quick=False)
    assert s.kind == "contradicts" and "Mw on the cart" in s.ours and "29148" in s.ours
    s = FI.claim_status(_claim(ordering="RMS at two points only"), [], runs, quick=False)
    assert s.kind == "ordering" and "RMS at two points only" in s.status
    with pytest.raises(ValueError):
        FC.Choice("x", "maybe", "w", "n")


def test_readings_take_the_strongest_holding_row_and_a_row_the_weakest_of_its_choices():
    def sup(r, support):
        return {**r, "support": support, "support_where": "here"}

    c = _claim(readings=True)
    rows = [sup(row(c.id, "A", "yes"), "contradicts"), sup(row(c.id, "B", "yes"), "unprinted"),
            sup(row(c.id, "C", "no"), "printed")]
    s = FI.readings_status(rows, c)
    assert s.kind == "unprinted" and "reading B" in s.status and "2 of 3" in s.status
    rows[2]["holds"] = "yes"
    assert FI.readings_status(rows, c).kind == "printed"
    assert FI.readings_status(rows, _claim(readings=True, ordering="o")).kind == "ordering"
    # one row of several choices: Lagrangian model (contradicts) with the library's P (unprinted)
    assert FI.FS.support_of(row("thesis:table-3.1", "Lagrangian model, library P", "no"))[0] == "contradicts"
    assert FI.FS.support_of(row("thesis:table-3.1", "printed model, library P", "no"))[0] == "unprinted"
    assert FI.FS.support_of(row("thesis:table-3.1", "nothing known", "no"))[0] == "unclassified"


def test_a_row_whose_interval_straddles_its_threshold_is_undecided():
    r = row("stumfoll:fig-8.18", "default / k1=5.0 (not printed)", "yes",
            "LQR fell 0.42 [0.328, 0.518] (42/100); LQR + extra up 0.96 [0.902, 0.984] (96/100)")
    a = FI.FS.annotate(r)
    assert a["holds"] == "undecided" and a["holds_study"] == "yes" and a["support"] == "unprinted"
    # half-width 0.058 on the threshold's side, distance 0.01: 100 (0.058 / 0.01)^2 = 3364 seeds
    assert "about 3364 samples would decide it (now 100)" in a["holds_why"]
    r["ours"] = "LQR fell 0.42 [0.328, 0.518] (42/100); LQR + extra up 1 [0.963, 1] (100/100)"
    assert FI.FS.annotate(r)["holds"] == "yes"
    r["ours"] = "LQR fell 0.05 [0.01, 0.08] (5/100); LQR + extra up 1 [0.963, 1] (100/100)"
    assert FI.FS.annotate(r)["holds"] == "no"


def test_no_committed_row_is_reproduced_while_its_interval_straddles_its_threshold():
    rows, _ = FI.load_rows(READINGS)
    every = [r for rs in rows.values() for r in rs]
    assert not [r["reading"] for r in every if r["support"] == "unclassified"], "rows without a support class"
    checked = 0
    for r in every:
        for t in FI.FS.THRESHOLDS:
            if not FI.FS._applies(t.claim, r["claim"]) or (t.readings and not re.search(t.readings, r["reading"])):
                continue
            for m in re.finditer(t.pattern, r["ours"]):
                g = [float(x) for x in m.groups()]
                lo, hi = (g[1], g[2]) if len(g) == 3 else (g[0], g[0])
                checked += 1
                outside = (lo < t.value) if t.rule == "ge" else (hi > t.value) if t.rule == "le" \
                    else (lo < t.value or hi > t.upper)
                assert not (outside and r["holds"] == "yes"), (r["claim"], r["reading"], r["ours"])
    assert checked >= 100  # the thresholds reach the fig-8.18, EKI, 25%, Fig. 8.6 and Fig. 8.11 rows


def test_no_default_check_is_reproduced_while_its_interval_straddles_its_threshold():
    # every ge/le check of the inventory, fed an interval across its threshold, is undecided
    for c in FC.CLAIMS:
        for k in c.checks:
            if k.rule not in ("ge", "le"):
                continue
            res = {}
            cur = res
            steps = k.key.split("/")
            for st in steps[:-1]:
                cur = cur.setdefault(st, {})
            cur[steps[-1]] = k.value
            ci_path = (k.ci or f"{k.key}_ci95").split("/")
            cur = res
            for st in ci_path[:-1]:
                cur = cur.setdefault(st, {})
            cur[ci_path[-1]] = [k.value - 1.0, k.value + 1.0]
            assert FI.evaluate(k, res, 10)[0] == "undecided", (c.id, k.key)


def test_a_per_state_interval_is_found_beside_its_dict():
    res = {"kf": {"t": {"x": 4.4}, "t_ci95": {"x": [4.2, 4.6]}}, "dm": {"t": {"x": 0.5}, "t_ci95": {"x": [0.4, 0.6]}}}
    k = FC.Check("e", "ratio_ge", "kf/t/x", "l", value=5.0, other="dm/t/x")
    h, text = FI.evaluate(k, res)
    assert h == "yes" and "[7, 11.5]" in text  # [4.2 / 0.6, 4.6 / 0.4]
    assert FI.evaluate(FC.Check("e", "ratio_ge", "kf/t/x", "l", value=8.0, other="dm/t/x"), res)[0] == "undecided"


@pytest.mark.parametrize("first", ["claims_propositions", "claims"])
def test_the_propositions_are_appended_whichever_is_imported_first(first):
    # the inventory appends the propositions module's CLAIMS, whichever of the two a fresh interpreter (so the
    # inventory already loaded here is not reused) imports first
    code = (f"from experiments.fidelity import {first}; from experiments.fidelity import claims as FC, "
            "claims_propositions as FP; ids = [c.id for c in FC.CLAIMS]; last = FP.CLAIMS[-1].id; "
            "assert ids[-len(FP.CLAIMS):] == [c.id for c in FP.CLAIMS], ids[-3:]; "
            "assert last in FC.by_id() and len(ids) == len(set(ids))")
    subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT)
