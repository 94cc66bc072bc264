"""experiments/fidelity/integration_choice.py: the comparison of two runs' results in units of the 95% half-widths."""

import json
import os

from experiments.fidelity import integration_choice as ic

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_changes_are_measured_in_half_widths_of_the_reference_interval():
    base = {"a": {"var": 2.0, "var_ci95": [1.0, 3.0], "score_mean": 10.0, "score_ci95": [8.0, 12.0]},
            "n_failed": 0, "ok": True, "wall_s": 1.0}
    new = {"a": {"var": 2.1, "var_ci95": [1.1, 3.1], "score_mean": 10.5, "score_ci95": [8.0, 12.0]},
           "n_failed": 0, "ok": True, "wall_s": 9.0}
    c = ic.compare(base, new)
    # var moved 0.1 of a half-width 1; score_mean (interval in score_ci95) 0.5 of 2
    assert abs(c["max_change_in_half_widths"] - 0.25) < 1e-12 and c["at"] == "/a/score_mean"
    assert abs(c["max_rel_change"] - 0.1 / 1.1) < 1e-12 and c["rel_at"] == "/a/var_ci95[0]"
    assert c["flips"] == [] and c["missing"] == []  # wall times are not results
    assert not ic.acceptable({**c})


def test_a_flipped_decision_or_count_is_not_acceptable_however_small_the_change():
    base = {"x": 1.0, "x_ci95": [0.0, 2.0], "stabilized": True, "diverged": 0}
    for new, flip in (({**base, "stabilized": False}, "/stabilized: True -> False"),
                      ({**base, "diverged": 1}, "/diverged: 0 -> 1")):
        c = ic.compare(base, new)
        assert c["max_change_in_half_widths"] == 0.0 and c["flips"] == [flip] and not ic.acceptable(c)
    assert ic.acceptable(ic.compare(base, dict(base)))


def test_the_committed_table_follows_the_rule_and_the_defaults_follow_the_table():
    with open(os.path.join(ROOT, "docs", "integration.json")) as fh:
        rows = json.load(fh)
    from jaxdip.runner import registry

    reg = registry()
    # every default below the reference was measured acceptable at that very value
    lowered = {(r["experiment"], r["key"]) for r in rows
               if getattr(reg[r["experiment"]].config_cls(), r["key"]) < ic.REFERENCE}
    for exp, key in lowered:
        d = getattr(reg[exp].config_cls(), key)
        assert any(r["experiment"] == exp and r["key"] == key and r["value"] == d and ic.acceptable(r)
                   for r in rows), (exp, key, d)
    assert {("dip-controllers", "substeps"), ("dip-cpx-ldf", "substeps")} <= lowered
