"""Summary statistics over Monte Carlo seeds, with 95% intervals.

``mean_ci``, what the experiments report, uses the normal approximation (mean +- 1.96 s / sqrt(n)), which is what
"95% interval over seeds" means at the hundreds-to-thousands of seeds they run; ``t_interval`` (``jd.summary``'s)
uses Student's t quantile instead, the same there and honest at a handful of seeds; fractions use the Wilson
score interval (``wilson``), which stays inside [0, 1] and is honest at 0 or n successes. Two samples are compared
by Welch's t-test (``welch``, p-values by ``t_pvalue``, for any positive degrees of freedom; ``z_pvalue`` for the
normal), as ``jaxdip compare`` does with per-seed data. Public as ``jd.stats``.
"""

from __future__ import annotations

import functools
import math
from statistics import NormalDist
from typing import Optional

import numpy as np
from numpy.typing import ArrayLike

from jaxdip._public import public_dir

__all__ = ["Z95", "mean_ci", "wilson", "with_ci", "t_quantile", "t_interval", "t_pvalue", "welch", "z_pvalue"]
__dir__ = public_dir(globals())

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


def _t_two_sided(t: float, df: int) -> float:
    # P(|T| < t) for Student's t with integer df, by the finite series of Abramowitz & Stegun 26.7.3-4 (exact up
    # to rounding): no SciPy at run time, and cheap enough for a bisection even at thousands of seeds.
    theta = math.atan(t / math.sqrt(df))
    c2 = math.cos(theta) ** 2
    if df % 2:
        term, acc = 1.0, 0.0
        if df > 1:
            term = math.cos(theta)
            acc = term
            for j in range(3, df - 1, 2):  # terms cos^j with the coefficients (2*4*...*(j-1)) / (1*3*...*j)
                term *= c2 * (j - 1) / j
                acc += term
        return 2 / math.pi * (theta + math.sin(theta) * acc) if df > 1 else 2 * theta / math.pi
    term, acc = 1.0, 1.0
    for j in range(2, df - 1, 2):  # terms cos^j with the coefficients (1*3*...*(j-1)) / (2*4*...*j)
        term *= c2 * (j - 1) / j
        acc += term
    return math.sin(theta) * acc


@functools.lru_cache(maxsize=1024)  # a summary asks for the same few (level, df) once per metric component
def t_quantile(level: float, df: int) -> float:
    """The two-sided Student-t critical value: P(|T| < t) = level for ``df`` degrees of freedom (1.96 as df grows)."""
    if not 0 < level < 1 or df < 1:
        raise ValueError(f"t_quantile: level must be in (0, 1) and df >= 1, got level={level}, df={df}")
    if df > 1000:
        # Cornish-Fisher expansion in 1/df (Abramowitz & Stegun 26.7.5): its error, of order z^11 / df^5, is below
        # float64 rounding here, where the series above would need df/2 terms per evaluation
        z = NormalDist().inv_cdf(0.5 + level / 2)
        g = ((z**3 + z) / 4, (5 * z**5 + 16 * z**3 + 3 * z) / 96, (3 * z**7 + 19 * z**5 + 17 * z**3 - 15 * z) / 384,
             (79 * z**9 + 776 * z**7 + 1482 * z**5 - 1920 * z**3 - 945 * z) / 92160)
        return z + sum(gi / df ** (i + 1) for i, gi in enumerate(g))
    lo, hi = 0.0, 1.0
    while _t_two_sided(hi, df) < level:
        hi *= 2
    for _ in range(100):  # bisection to the last bits: the CDF is monotone, and 100 halvings exhaust a float64
        mid = 0.5 * (lo + hi)
        if _t_two_sided(mid, df) < level:
            lo = mid
        else:
            hi = mid
        if hi - lo <= 4e-16 * hi:
            break
    return 0.5 * (lo + hi)


def t_interval(values: ArrayLike, mask: Optional[ArrayLike] = None, *, axis: int = 0,
               level: float = 0.95) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Student's t interval along ``axis`` (the seeds): ``(mean, lo, hi, n)``, arrays of the other axes' shape, with
    mean +- t s / sqrt(n), s the sample standard deviation of the ``n`` entries that ``mask`` selects (all when
    None; ``mask`` broadcasts against ``values`` from the left, so a per-seed mask selects whole seeds). The mean is
    NaN where none is selected, the interval where fewer than two are; non-finite selected values are kept, so
    they show instead of being dropped silently."""
    v = np.moveaxis(np.asarray(values, dtype=np.float64), axis, 0)
    if mask is None:
        keep = np.ones(v.shape, dtype=bool)
    else:
        keep = np.moveaxis(np.asarray(mask, dtype=bool), axis, 0)
        keep = np.broadcast_to(keep.reshape(keep.shape + (1,) * (v.ndim - keep.ndim)), v.shape)
    n = keep.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(keep, v, 0.0).sum(axis=0) / n
        var = np.where(keep, (v - mean) ** 2, 0.0).sum(axis=0) / (n - 1)
        t = np.vectorize(lambda k: t_quantile(level, int(k) - 1) if k > 1 else np.nan, otypes=[np.float64])(n)
        half = t * np.sqrt(var / n)
    return mean, mean - half, mean + half, n


def _betacf(a: float, b: float, x: float) -> float:
    # the continued fraction of the regularised incomplete beta function (modified Lentz), as in Numerical Recipes
    tiny, qab, qap, qam = 1e-300, a + b, a + 1.0, a - 1.0
    c, d = 1.0, 1.0 - qab * x / qap
    d = 1.0 / (d if abs(d) > tiny else tiny)
    h = d
    for m in range(1, 10_000):
        m2 = 2 * m
        for aa in (m * (b - m) * x / ((qam + m2) * (a + m2)), -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2))):
            d = 1.0 + aa * d
            d = 1.0 / (d if abs(d) > tiny else tiny)
            c = 1.0 + aa / c
            c = c if abs(c) > tiny else tiny
            h *= d * c
        if abs(d * c - 1.0) < 1e-15:
            break
    return h


def _betainc(a: float, b: float, x: float) -> float:
    if x <= 0.0 or x >= 1.0:
        return 0.0 if x <= 0.0 else 1.0
    ln = math.lgamma(a + b) - math.lgamma(a) - math.lgamma(b) + a * math.log(x) + b * math.log1p(-x)
    if x < (a + 1.0) / (a + b + 2.0):
        return math.exp(ln) * _betacf(a, b, x) / a
    return 1.0 - math.exp(ln) * _betacf(b, a, 1.0 - x) / b


def t_pvalue(t: float, df: float) -> float:
    """Two-sided p-value P(|T| >= |t|) of Student's t with ``df`` (> 0, not necessarily whole; infinite: the
    normal) degrees of freedom."""
    if not df > 0:
        raise ValueError(f"t_pvalue: df must be > 0, got {df}")
    if math.isinf(t):
        return 0.0
    if math.isinf(df):
        return z_pvalue(t)
    return _betainc(df / 2.0, 0.5, df / (df + t * t))


def z_pvalue(z: float) -> float:
    """Two-sided p-value P(|Z| >= |z|) of the standard normal."""
    return math.erfc(abs(z) / math.sqrt(2.0))


def welch(a: ArrayLike, b: ArrayLike) -> tuple[float, float, float]:
    """Welch's two-sample t-test of equal means without assuming equal variances: ``(t, df, p)``, p two-sided,
    df by the Welch-Satterthwaite formula. Both samples need two values; with both variances zero, p is 1 when
    the means agree and 0 when they do not."""
    x, y = np.asarray(a, dtype=np.float64).ravel(), np.asarray(b, dtype=np.float64).ravel()
    if x.size < 2 or y.size < 2:
        raise ValueError(f"welch: each sample needs at least two values, got {x.size} and {y.size}")
    vx, vy = x.var(ddof=1) / x.size, y.var(ddof=1) / y.size
    diff = float(x.mean() - y.mean())
    if vx + vy == 0.0:
        return (0.0 if diff == 0 else math.copysign(math.inf, diff)), math.inf, 1.0 if diff == 0 else 0.0
    t = diff / math.sqrt(vx + vy)
    df = (vx + vy) ** 2 / (vx**2 / (x.size - 1) + vy**2 / (y.size - 1))
    return t, df, t_pvalue(t, df)
