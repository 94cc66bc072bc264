"""The float32 study's comparison of two result dicts (jaxdip.bench.float32), checked on hand-made results."""

import math

from jaxdip.bench.float32 import compare, interval_statistics, table


R64 = {"a": 1.0, "a_ci95": [0.8, 1.2], "states": {"x": {"var": 2.0, "var_ci95": [1.0, 3.0], "n": 5}},
       "error_mean": 0.5, "error_ci95": [0.4, 0.6], "settle": float("nan"), "settle_ci95": [float("nan")] * 2,
       "label": "text", "flag_ci95": [0, 1]}


def test_interval_statistics_pairs_values_with_their_intervals():
    s = interval_statistics(R64)
    assert s["a"] == (1.0, 0.8, 1.2)
    assert s["states.x.var"] == (2.0, 1.0, 3.0)
    assert s["error_mean"] == (0.5, 0.4, 0.6)  # "error_ci95" beside "error_mean"
    assert "flag" not in s and "label" not in s and math.isnan(s["settle"][0])


def test_compare_inside_overlap_and_z():
    r32 = {**R64, "a": 1.1, "a_ci95": [0.9, 1.3], "states": {"x": {"var": 3.5, "var_ci95": [3.2, 3.8]}},
           "error_mean": 0.5, "error_ci95": [0.4, 0.6]}
    rows = {r["statistic"]: r for r in compare(R64, r32)}
    assert "settle" not in rows  # NaN in both: undefined alike, not compared
    a = rows["a"]
    assert a["inside"] and a["overlap"] and math.isclose(a["z"], 0.1 / 0.2)
    v = rows["states.x.var"]
    assert not v["inside"] and not v["overlap"] and math.isclose(v["z"], 1.5)
    assert rows["error_mean"]["z"] == 0.0
    nan32 = {**R64, "a": float("nan")}
    assert not {r["statistic"]: r for r in compare(R64, nan32)}["a"]["inside"]


def test_table_marks_safe_only_without_misses():
    rec = {"experiment": "x", "seeds": 4, "statistics": 2, "outside": 0, "disjoint": 0, "max_z": 0.5,
           "cpu_ratio_f32_f64": 0.7, "safe": True}
    line = table([rec]).splitlines()[-1]
    assert line == "| x | 4 | 2 | 0 | 0 | 0.50 | 0.70 | yes |"
