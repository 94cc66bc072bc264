"""The eki-dip search bench at toy scale: a profile per precision of the forward model."""

import pytest

from jaxdip.bench.eki_search import measure


@pytest.mark.slow  # two toy searches per precision compiled; a bench smoke test
def test_eki_search_bench_profiles_both_precisions():
    out = measure({"ensemble": 4, "T": 0.1, "t_star": 0.05, "chunk": 2, "early_stop": False}, chunks=2, rounds=1)
    for p in ("float64", "float32"):
        assert out[p]["iteration_s"] > 0 and out[p]["compile_s"] > 0
    assert out["speedup"] == out["float64"]["iteration_s"] / out["float32"]["iteration_s"]
