"""The eki-dip search bench at toy scale: its counts agree with the run they describe."""

import numpy as np
import pytest

from jaxdip.bench.eki_search import measure


@pytest.mark.slow  # 7-10 s (three toy searches and four judges compiled); a bench smoke test
def test_eki_search_bench_counts_and_profile():
    out = measure({"ensemble": 4, "T": 0.1, "t_star": 0.05, "iterations": 4, "chunk": 2, "seeds": 4,
                   "eval_states": 2, "judge_duration": 0.1, "early_stop": False}, profile_chunks=2)
    assert out["profile"]["iteration_s"] > 0
    fixed, adaptive = out["fixed"], out["data_misfit"]
    assert fixed["iterations"] == 4 and fixed["evaluations"] == 16  # the budget, J = 4 members each
    assert 1 <= adaptive["iterations"] <= 4 and adaptive["evaluations"] == 4 * adaptive["iterations"]
    for r in (out["start"], fixed, adaptive):
        assert 0.0 <= r["stabilized_fraction"] <= 1.0 and np.isfinite(r["performance"])
