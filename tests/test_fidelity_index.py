"""The generator of docs/fidelity.md (experiments/fidelity_index.py): its status logic on a synthetic inventory
and synthetic rows, and that the committed readings rows name claims the inventory knows."""

import importlib.util
import json
import os
import re
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
EXP = os.path.join(ROOT, "experiments")
READINGS = os.path.join(ROOT, "docs", "fidelity")


def _load(name):
    if EXP not in sys.path:
        sys.path.insert(0, EXP)
    spec = importlib.util.spec_from_file_location(name, os.path.join(EXP, f"{name}.py"))
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod  # dataclasses look their module up there
    spec.loader.exec_module(mod)
    return mod


FI = _load("fidelity_index")
FC = FI.FC


def row(claim, reading, holds, ours="1.0"):
    return {"claim": claim, "reading": reading, "what": "w", "command": f"jaxdip run x --set r={reading}",
            "ours": ours, "document": "d", "holds": holds}


def test_a_holding_row_gives_reproduced_under_that_reading():
    s = FI.readings_status([row("paper:table-1", "A", "no", "2.0"), row("paper:table-1", "B", "yes", "3.0"),
                            row("paper:table-1", "C", "undecided")])
    assert s.kind == "reading"
    assert s.status.startswith("reproduced under reading B ")
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
    assert s.kind == "pending" and s.status == "readings pending; default run: reproduced (default config)"
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
    assert ev(rule="close", key="a", value=1.04, tol=0.05) == "yes"
    assert ev(rule="close", key="a", value=1.06, tol=0.05) == "no"
    assert ev(rule="close", key="b", other="a", tol=0.5) == "no"  # |2 - 1| > 0.5 * 1
    assert ev(rule="in_ci", key="a", value=1.09) == "yes"
    assert ev(rule="in_ci", key="a", value=1.2) == "no"
    assert ev(rule="in_ci", key="sub/x", value=3.2, ci="cis/x") == "yes"
    assert ev(rule="ratio_ge", key="b", other="a", value=2.0) == "yes"
    assert ev(rule="ratio_ge", key="b", other="a", value=2.1) == "no"
    assert ev(rule="ge", key="a", value=1.0) == "yes" and ev(rule="le", key="a", value=0.5) == "no"
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
    assert FI.parts_status(parts).kind == "reading"


def test_lorenz_rows_agree_with_their_own_intervals_and_with_lorenz_md():
    fid = _load("fidelity")
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
    assert "reproduced under reading A" in text
    assert "## Rows whose claim id the inventory does not know" in text and "`paper:table-99`" in text
