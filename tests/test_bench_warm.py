"""The warm-start breakdown's arithmetic (the subprocess runs themselves are timings: docs/performance.md)."""

import numpy as np

from jaxdip.bench.warm import _union, table


def test_union_of_nested_and_overlapping_spans_against_a_grid():
    rng = np.random.default_rng(0)
    starts = rng.uniform(0, 10, 30)
    spans = [(a, a + d) for a, d in zip(starts, rng.uniform(0, 2, 30))]
    spans += [(1.0, 1.5), (1.1, 1.2), (11.5, 12.0)]  # nested (a jit traced inside another) and disjoint
    grid = np.linspace(0, 13, 1_300_001)
    covered = np.zeros_like(grid, bool)
    for a, b in spans:
        covered |= (grid >= a) & (grid < b)
    assert abs(_union(spans) - covered.mean() * 13) < 1e-4
    assert _union([]) == 0.0


def test_table_totals_each_column():
    counts = ("programs", "hits", "stored", "ordinary")
    cols = ("process", "import", "trace", "lower", "compile", *counts, "run", "write")
    rows = [{"id": f"e{i}", "warm": {c: (i + 1) * (3 if c in counts else 0.5) for c in cols}} for i in range(3)]
    rows = [{**r, "warm": {c: int(v) if c in counts else v for c, v in r["warm"].items()}} for r in rows]
    last = table(rows, "warm").strip().splitlines()[-1]
    assert last == "| **total** | " + " | ".join("18" if c in counts else "3.00" for c in cols) + " |"
