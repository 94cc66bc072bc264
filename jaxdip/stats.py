"""Summary statistics over Monte Carlo seeds, with 95% intervals.

Means use the normal approximation (mean +- 1.96 s / sqrt(n)), which is what "95% interval over seeds" means
at the hundreds-to-thousands of seeds we run; fractions use the Wilson score interval, which stays inside
[0, 1] and is honest at 0 or n successes.
"""

from __future__ import annotations

import math

import numpy as np

Z95 = 1.959963984540054


def mean_ci(values, mask=None):
    """(mean, [lo, hi]) over the entries of ``values`` selected by ``mask`` (NaN when none are)."""
    v = np.asarray(values, dtype=np.float64)
    if mask is not None:
        v = v[np.asarray(mask, dtype=bool)]
    v = v[np.isfinite(v)]
    n = v.size
    if n == 0:
        return float("nan"), [float("nan"), float("nan")]
    m = float(v.mean())
    if n == 1:
        return m, [m, m]
    half = Z95 * float(v.std(ddof=1)) / math.sqrt(n)
    return m, [m - half, m + half]


def wilson(k: int, n: int):
    """Wilson 95% interval for a binomial fraction k / n."""
    if n == 0:
        return float("nan"), [float("nan"), float("nan")]
    p = k / n
    z2 = Z95**2
    denom = 1 + z2 / n
    centre = (p + z2 / (2 * n)) / denom
    half = Z95 * math.sqrt(p * (1 - p) / n + z2 / (4 * n * n)) / denom
    return p, [max(0.0, centre - half), min(1.0, centre + half)]


def with_ci(name: str, values, mask=None) -> dict:
    m, ci = mean_ci(values, mask)
    return {name: m, f"{name}_ci95": ci}
