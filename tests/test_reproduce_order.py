"""The parallel reproduction hands out the longest experiments first: by the time each took in the last
reproduction with the same cache, where one was recorded, else by its estimate. The record is a small JSON file
in the cache folder; a damaged one only loses the ordering."""

from __future__ import annotations

import json
import types

from jaxdip import reproduce_pool as P


def _reg(**costs):
    return [(name, types.SimpleNamespace(quick_cost_s=c)) for name, c in costs.items()]


def test_learned_times_order_the_work_and_estimates_fill_in():
    reg = _reg(a=30.0, b=20.0, c=10.0, d=5.0)
    assert [r[0] for r in P.work_order(reg, "quick_cost_s", {})] == ["a", "b", "c", "d"]
    # warm, a took 2 s and d 9 s; b has no record (its estimate of 20 s still puts it first)
    learned = {"a": 2.0, "c": 3.0, "d": 9.0}
    assert [r[0] for r in P.work_order(reg, "quick_cost_s", learned)] == ["b", "d", "c", "a"]


def test_times_are_recorded_per_scale_and_merged(tmp_path):
    path = str(tmp_path / P.TIMES)
    assert P.last_times(path, "quick") == {}  # none yet
    P.record_times(path, "quick", {"a": 1.23456, "b": 2.0})
    P.record_times(path, "full", {"a": 100.0})
    P.record_times(path, "quick", {"b": 3.0})  # a run of b alone keeps a's
    assert P.last_times(path, "quick") == {"a": 1.235, "b": 3.0}
    assert P.last_times(path, "full") == {"a": 100.0}
    assert P.last_times(None, "quick") == {}  # --no-compile-cache: nothing read ...
    P.record_times(None, "quick", {"a": 1.0})  # ... nor written


def test_a_damaged_record_only_loses_the_order(tmp_path):
    path = tmp_path / P.TIMES
    for text in ("not json", "[1, 2]", json.dumps({"quick": [1]}), json.dumps({"quick": {"a": "slow", "b": True,
                                                                                           "c": -1, "d": 2.0}})):
        path.write_text(text)
        got = P.last_times(str(path), "quick")
        assert got == ({"d": 2.0} if "slow" in text else {})
        P.record_times(str(path), "quick", {"e": 1.0})  # rewritten whole
        assert P.last_times(str(path), "quick")["e"] == 1.0
    P.record_times(str(tmp_path / "missing" / P.TIMES), "quick", {"a": 1.0})  # a folder that is not there: no error
