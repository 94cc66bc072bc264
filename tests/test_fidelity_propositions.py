"""The rows for the documents' numbered results (experiments/fidelity/claims_propositions.py): one row per
numbered proposition, lemma, theorem and corollary, each a test or not attempted, and every test it names
exists."""

import os
import re

from experiments.fidelity import claims as FC
from experiments.fidelity import claims_propositions as FP

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _cited_tests(text):
    """(path, function) pairs of a row's ``test`` text: 'path::name', then '::name' for more in the same file."""
    out, path = [], None
    for m in re.finditer(r"(tests/[\w/]+\.py)?::(\w+)", text):
        path = m.group(1) or path
        out.append((path, m.group(2)))
    return out


def test_every_numbered_result_has_one_row():
    inventory = [c.id for c in FC.CLAIMS]
    mine = {c.id: c for c in FP.CLAIMS}
    assert len(mine) == len(FP.CLAIMS)
    for c in FC.CLAIMS:  # the inventory may append these rows; then they must be these same rows
        if c.id in mine:
            assert c == mine[c.id]
    assert len(set(inventory)) == len(inventory)
    known = set(inventory) | set(mine)
    missing = [i for i in FP.NUMBERED if i not in known]
    assert not missing, missing
    assert set(mine) <= set(FP.NUMBERED)


def test_rows_are_tests_or_not_attempted_and_name_existing_tests():
    rows = list(FP.CLAIMS) + [c for c in FC.CLAIMS if c.id in FP.NUMBERED and c.test]
    for c in FP.CLAIMS:
        assert (c.test is None) != (c.not_attempted is None), c.id
        assert not c.checks and not c.readings and not c.input, c.id
    for c in rows:
        if not c.test:
            continue
        cited = _cited_tests(c.test)
        assert cited, c.id
        for path, name in cited:
            with open(os.path.join(ROOT, path)) as f:
                assert re.search(rf"^def {name}\(", f.read(), re.M), f"{c.id}: {path}::{name}"


def test_prop_1_5_2_cites_a_test_of_1_5_2():
    """The subspace bound's row cites the test of the bound, not the test of the recursion (Prop. 1.5.1)."""
    row = {c.id: c for c in FC.CLAIMS}["thesis:prop-1.5.2"]
    assert all("1_5_2" in name for _, name in _cited_tests(row.test))
