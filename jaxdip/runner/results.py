"""What an experiment may write: the check that its results and report hold no NaN, inf or null, the ``NA``
placeholder for a position without a value, and the formatting of a value and its 95% interval for a report."""

from __future__ import annotations

import math
import re

import numpy as np


def fmt_ci(v, ci, digits=4, missing: str = "n/a") -> str:
    """A mean and its 95% interval; ``missing`` where there is no mean (no seed to average over)."""
    if _missing(v):
        return missing
    if ci is None or _missing(ci) or any(_missing(c) for c in ci):
        return f"{v:.{digits}g}"
    return f"{v:.{digits}g} [{ci[0]:.{digits}g}, {ci[1]:.{digits}g}]"


# ---- what may be written ----------------------------------------------------------------------------------

# a number that is not one, as Python, NumPy, JSON or a format string spell it ("nan%", "-inf", "None")
_NOT_A_NUMBER = re.compile(r"(?<![\w.])(?:(?i:nan%?|[-+]?inf(?:inity)?)|null|None)(?![\w])")


class ResultError(ValueError):
    """An experiment produced a value that cannot be written (NaN, inf or None): a defect of the experiment,
    which must report a count, a failures block or a word instead. ``key`` is where it is."""

    def __init__(self, key: str, why: str):
        super().__init__(f"{key}: {why}")
        self.key, self.why = key, why


NA = "n/a"  # in a list whose positions mean something (one entry per gamma, say): no value at this position


def _missing(v) -> bool:
    if hasattr(v, "tolist") and not isinstance(v, (list, dict)):
        v = v.tolist()
    if isinstance(v, (list, tuple)):
        return bool(v) and all(_missing(e) for e in v)
    return v is None or v == NA or (isinstance(v, float) and not math.isfinite(v))


def na(v):
    """``v`` with every NaN, inf or None in it (a number, or a list of them) replaced by ``NA``."""
    if isinstance(v, (list, tuple)):
        return [na(e) for e in v]
    return NA if _missing(v) else v


def floats(v) -> np.ndarray:
    """A list written with ``na`` back as floats (NaN where it says ``NA``), for figures."""
    if isinstance(v, (list, tuple)):
        return np.asarray([floats(e) for e in v], dtype=float)
    return np.asarray(np.nan if _missing(v) else v, dtype=float)


def drop_missing(obj):
    """``obj`` without the statistics that could not be computed: a dict entry that is NaN, inf or None (or a
    list of nothing else, such as the interval of a mean over no seed) is left out. A NaN among numbers in a
    list is kept, for ``check_writable`` to refuse: the list's positions mean something."""
    if isinstance(obj, dict):
        return {k: drop_missing(v) for k, v in obj.items() if not _missing(v)}
    if isinstance(obj, (list, tuple)):
        return [drop_missing(v) for v in obj]
    return obj


def fmt(v, spec: str = ".4g", missing: str = "n/a") -> str:
    """``format(v, spec)``, or ``missing`` for a value that is absent, NaN or infinite."""
    return missing if _missing(v) else format(v, spec)


def unwritable(obj, key: str = "results") -> list[str]:
    """The keys (dotted, lists by index) under which ``obj`` holds NaN, inf or None, or a string spelling one."""
    if isinstance(obj, dict):
        return [k for name, v in obj.items() for k in unwritable(v, f"{key}.{name}")]
    if isinstance(obj, (list, tuple)):
        return [k for i, v in enumerate(obj) for k in unwritable(v, f"{key}[{i}]")]
    if hasattr(obj, "tolist"):
        return unwritable(obj.tolist(), key)
    if obj is None or (isinstance(obj, float) and not math.isfinite(obj)):
        return [key]
    if isinstance(obj, str) and _NOT_A_NUMBER.fullmatch(obj.strip()):
        return [key]
    return []


def check_writable(results: dict, report: str) -> None:
    """Refuse to write ``results`` or ``report`` holding NaN, inf or None (a ``ResultError`` naming the first
    key, or the report's line). When every seed of a run diverges there is nothing to average: an experiment
    leaves the statistic out and says so in its ``failures`` block, it never writes a placeholder."""
    bad = unwritable(results)
    if bad:
        more = f" (and {len(bad) - 1} more)" if len(bad) > 1 else ""
        raise ResultError(bad[0], f"is not a finite number{more}; the experiment must leave it out or say why")
    for i, line in enumerate(report.splitlines(), 1):
        if m := _NOT_A_NUMBER.search(line):
            raise ResultError(f"report.md line {i}", f"writes {m.group(0)!r}: {line.strip()[:80]}")
