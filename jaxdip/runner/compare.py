"""``jaxdip compare A B``: two result folders' ``results``, statistic by statistic.

Every leaf of ``results`` (dotted path, list entries by index: ``gamma_sweep.theta_var[3]``) is one statistic;
its ``<name>_ci95`` sibling, where there is one, is its 95% interval and part of it. Each statistic is put in the
first class that fits:

- ``identical``: the same value (and interval) to the last bit;
- ``equal``: numbers within ``atol + rtol * max(|a|, |b|)`` (the interval's ends too);
- ``within interval`` / ``significantly different``: numbers with an interval on both sides are tested for a
  difference of means. With per-seed samples of the statistic in both folders (``per_seed`` hands them in) the
  test is Welch's two-sample t-test on them; otherwise a two-sample z-test on the standard errors the intervals
  imply, ``se = (hi - lo) / (2 * 1.96)``, so ``z = |a - b| / sqrt(se_a^2 + se_b^2)``. The p-values of all tested
  statistics are corrected together by Holm's step-down method, so that the chance of flagging any statistic
  when none differs is at most ``alpha`` (0.05): a run with other seeds differs in every statistic, and dozens
  of uncorrected 5% tests would flag a few by chance. Rejected: ``significantly different``; else ``within
  interval``;
- ``differs``: different, with nothing to judge the difference by (a count, a criterion, a single trial's
  figure, a word, an interval of zero width);
- ``missing``: on one side only.

The exit status (``status``): 0 when no statistic is significantly different, differs or is missing (identical,
equal and within-interval ones only), 1 otherwise, 2 when the folders cannot be compared (unreadable, not
jaxdip results, or of different experiments).
"""

from __future__ import annotations

import json
import math
import os
import tomllib
from dataclasses import dataclass
from typing import Any, Callable

from jaxdip.stats import Z95, welch, z_pvalue

CI = "_ci95"
IDENTICAL, EQUAL, WITHIN, SIGNIFICANT, DIFFERS, MISSING = (
    "identical", "equal", "within interval", "significantly different", "differs", "missing")
KINDS = (IDENTICAL, EQUAL, WITHIN, SIGNIFICANT, DIFFERS, MISSING)
FAILING = (SIGNIFICANT, DIFFERS, MISSING)


class CompareError(ValueError):
    """A folder that cannot be compared; ``key`` is the folder as given."""

    def __init__(self, key: str, why: str):
        super().__init__(f"{key}: {why}")
        self.key, self.why = key, why


@dataclass
class Finding:
    path: str
    kind: str
    a: Any = None
    b: Any = None
    a_ci: list | None = None
    b_ci: list | None = None
    p: float | None = None  # the test's p-value before correction
    test: str = ""  # "welch" (per-seed samples) or "z" (the intervals' standard errors)


def read_metrics(folder: str) -> dict:
    """metrics.json of a result folder, or a ``CompareError`` saying why not."""
    path = os.path.join(folder, "metrics.json")
    if not os.path.isdir(folder):
        raise CompareError(folder, "no such folder" if not os.path.lexists(folder) else "not a folder")
    try:
        with open(path) as fh:
            m = json.load(fh)
    except FileNotFoundError:
        raise CompareError(folder, "holds no metrics.json: not a jaxdip result folder") from None
    except (OSError, ValueError) as e:
        raise CompareError(folder, f"cannot read metrics.json ({getattr(e, 'strerror', None) or e})") from None
    if not isinstance(m, dict) or not isinstance(m.get("results"), dict) or "experiment" not in m:
        raise CompareError(folder, "metrics.json has no experiment and results: not a jaxdip result folder")
    return m


def _number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _interval(v) -> bool:
    return isinstance(v, list) and len(v) == 2 and all(_number(c) for c in v)


def leaves(obj, path: str = "") -> dict[str, tuple[Any, list | None]]:
    """Every statistic of ``results`` by path, with its interval (None without one)."""
    out: dict[str, tuple[Any, list | None]] = {}

    def put(p, v, ci):
        if isinstance(v, dict):
            out.update(leaves(v, f"{p}."))
        elif isinstance(v, list) and not _interval(ci):
            per = ci if isinstance(ci, list) and len(ci) == len(v) else [None] * len(v)
            for i, (e, c) in enumerate(zip(v, per)):
                put(f"{p}[{i}]", e, c)
        else:
            out[p] = (v, ci if _interval(ci) else None)

    if isinstance(obj, dict):
        for k, v in obj.items():
            if k.endswith(CI) and k[: -len(CI)] in obj:
                continue  # its statistic carries it
            put(f"{path}{k}", v, obj.get(f"{k}{CI}"))
    else:
        put(path.rstrip("."), obj, None)
    return out


def _close(a, b, rtol: float, atol: float) -> bool:
    return abs(a - b) <= atol + rtol * max(abs(a), abs(b))


def classify(path: str, a, b, rtol: float, atol: float,
             samples: tuple[Any, Any] | None = None) -> Finding:
    """One statistic's finding before the correction (a tested one is ``within interval`` with its p-value)."""
    (va, ca), (vb, cb) = a, b
    f = Finding(path, DIFFERS, va, vb, ca, cb)
    if va == vb and ca == cb and type(va) is type(vb):
        f.kind = IDENTICAL
    elif _number(va) and _number(vb) and _close(va, vb, rtol, atol) and (
            (ca is None and cb is None) or (ca is not None and cb is not None
                                            and all(_close(x, y, rtol, atol) for x, y in zip(ca, cb)))):
        f.kind = EQUAL
    elif samples is not None:
        f.kind, f.test = WITHIN, "welch"
        f.p = welch(*samples)[2]
    elif _number(va) and _number(vb) and ca is not None and cb is not None:
        se2 = ((ca[1] - ca[0]) / (2 * Z95)) ** 2 + ((cb[1] - cb[0]) / (2 * Z95)) ** 2
        if se2 > 0:
            f.kind, f.test = WITHIN, "z"
            f.p = z_pvalue(abs(va - vb) / math.sqrt(se2))
    return f


def holm(findings: list[Finding], alpha: float) -> None:
    """Holm's step-down correction over the tested findings: those it rejects become significantly different."""
    tested = sorted((f for f in findings if f.p is not None), key=lambda f: f.p)
    m = len(tested)
    for i, f in enumerate(tested):
        if f.p > alpha / (m - i):
            break
        f.kind = SIGNIFICANT


def compare(a: dict, b: dict, *, rtol: float = 1e-9, atol: float = 0.0, alpha: float = 0.05,
            samples: Callable[[str], tuple[Any, Any] | None] = lambda path: None) -> list[Finding]:
    """The findings for every statistic of the ``results`` dicts ``a`` and ``b``, in ``a``'s order then ``b``'s
    extra ones; ``samples(path)`` gives both folders' per-seed values of a statistic where both have them."""
    la, lb = leaves(a), leaves(b)
    out = []
    for path in list(la) + [p for p in lb if p not in la]:
        if path not in la or path not in lb:
            v = la.get(path, lb.get(path))
            out.append(Finding(path, MISSING, *((v[0], None, v[1], None) if path in la else (None, v[0], None, v[1]))))
        else:
            out.append(classify(path, la[path], lb[path], rtol, atol, samples(path)))
    holm(out, alpha)
    return out


def status(findings: list[Finding]) -> int:
    """0 when nothing is significantly different, differs or is missing; else 1."""
    return int(any(f.kind in FAILING for f in findings))


def _value(v, ci) -> str:
    text = "-" if v is None else (f"{v:.6g}" if _number(v) else json.dumps(v)[:40])
    return text + (f" [{ci[0]:.4g}, {ci[1]:.4g}]" if ci is not None else "")


def line(f: Finding) -> str:
    """The finding as one line: ``path: kind: a vs b (test)``."""
    where = {"welch": "Welch t-test on the per-seed values", "z": "z-test on the intervals"}.get(f.test, "")
    test = f" ({where}, p = {f.p:.3g})" if f.p is not None else ""
    if f.kind == MISSING:
        return f"{f.path}: missing in {'B' if f.b is None else 'A'}"
    return f"{f.path}: {f.kind}: {_value(f.a, f.a_ci)} vs {_value(f.b, f.b_ci)}{test}"


def summary(findings: list[Finding]) -> str:
    counts = {k: sum(f.kind == k for f in findings) for k in KINDS}
    return f"{len(findings)} statistics: " + ", ".join(f"{n} {k}" for k, n in counts.items())


PROVENANCE = ("seeds", "scale", "dtype", "backend", "devices", "jax_version", "compile_effort")


def _flat(d: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in d.items():
        out.update(_flat(v, f"{prefix}{k}.") if isinstance(v, dict) else {f"{prefix}{k}": v})
    return out


def context(a_dir: str, b_dir: str, ma: dict, mb: dict, limit: int = 8) -> list[str]:
    """What besides the results differs: provenance, and the config keys of the two config.toml (where read)."""
    notes = [f"{k}: {ma.get(k)!r} vs {mb.get(k)!r}" for k in PROVENANCE if ma.get(k) != mb.get(k)]
    configs = []
    for d in (a_dir, b_dir):
        try:
            with open(os.path.join(d, "config.toml"), "rb") as fh:
                configs.append(_flat(tomllib.load(fh)))
        except (OSError, tomllib.TOMLDecodeError):
            configs.append(None)
    ca, cb = configs
    if ca is not None and cb is not None:
        diff = [k for k in list(ca) + [k for k in cb if k not in ca] if ca.get(k) != cb.get(k)]
        notes += [f"config {k}: {json.dumps(ca.get(k))} vs {json.dumps(cb.get(k))}" for k in diff[:limit]]
        if len(diff) > limit:
            notes.append(f"config: {len(diff) - limit} more keys differ")
    return notes
