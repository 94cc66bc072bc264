"""``jaxdip compare A B``: two result folders' ``results``, statistic by statistic.

Every leaf of ``results`` (dotted path, list entries by index: ``gamma_sweep.theta_var[3]``) is one statistic;
its ``<name>_ci95`` sibling, where there is one, is its 95% interval and part of it. Each statistic is put in the
first class that fits:

- ``identical``: the same value (and interval) to the last bit;
- ``equal``: numbers within ``atol + rtol * max(|a|, |b|)`` (the interval's ends too);
- ``within interval`` / ``significantly different``: numbers with an interval on both sides are tested for a
  difference. Where both folders hold ``per_seed.nc`` (``jaxdip run --per-seed``) and it names the per-seed
  values a statistic summarises (``per_seed_samples``), the test uses them: Welch's two-sample t-test for a mean,
  the pooled two-proportion z-test for a fraction of seeds. Otherwise a two-sample z-test on the standard errors
  the intervals imply, ``se = (hi - lo) / (2 * 1.96)``, so ``z = |a - b| / sqrt(se_a^2 + se_b^2)``. The p-values of all tested
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

import itertools
import json
import math
import os
import re
import tomllib
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

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
    test: str = ""  # "welch" or "proportion" (per-seed samples), or "z" (the intervals' standard errors)


def read_metrics(folder: str) -> dict:
    """metrics.json of a result folder, or a ``CompareError`` saying why not."""
    path = os.path.join(folder, "metrics.json")
    if not os.path.isdir(folder):
        raise CompareError(folder, "no such folder" if not os.path.lexists(folder) else "not a folder")
    try:
        with open(path) as fh:
            m = json.load(fh)
    except FileNotFoundError:
        from jaxdip.runner.sweep import SWEEP_MARKER

        if os.path.exists(os.path.join(folder, SWEEP_MARKER)):
            raise CompareError(folder, "is a sweep: compare its points, points/<key=value,...>") from None
        raise CompareError(folder, "holds no metrics.json: not a jaxdip result folder") from None
    except (OSError, ValueError) as e:
        raise CompareError(folder, f"cannot read metrics.json ({getattr(e, 'strerror', None) or e})") from None
    if not isinstance(m, dict) or not isinstance(m.get("results"), dict) or "experiment" not in m:
        raise CompareError(folder, "metrics.json has no experiment and results: not a jaxdip result folder")
    return m


MEAN, FRACTION = "mean_ci95", "fraction_wilson"  # per_seed.nc's ``statistic`` attribute (docs/data.md)


def _path(results: dict, parts: list[str]) -> str | None:
    """The ``leaves`` path of the statistic at ``parts`` (keys, list indices as digits) in ``results``; None where
    there is none."""
    v, path = results, ""
    for part in parts:
        if isinstance(v, list) and part.isdigit() and int(part) < len(v):
            v, path = v[int(part)], f"{path}[{part}]"
        elif isinstance(v, dict) and part in v:
            v, path = v[part], f"{path}.{part}" if path else part
        else:
            return None
    return path


def per_seed_samples(folder: str, results: dict) -> dict[str, tuple[str, np.ndarray]]:
    """The per-seed values behind the statistics of ``results`` (the folder's own), from the folder's
    ``per_seed.nc`` (docs/data.md): path (as ``leaves`` names it) -> (``mean_ci95`` and the finite values of the
    seeds the mean is over, or ``fraction_wilson`` and every seed's truth). Empty without the file, or where it
    cannot be read (the ``data`` extra missing, a damaged file): the statistics are then tested on their
    intervals."""
    path = os.path.join(folder, "per_seed.nc")
    if not os.path.isfile(path):
        return {}
    from jaxdip import dataset

    try:
        ds = dataset.read(path)
    except (ImportError, OSError, ValueError):
        return {}
    out = {}
    for name in ds.data_vars:
        var = ds[name]
        template, statistic = var.attrs.get("summarised_as"), var.attrs.get("statistic")
        if template is None or statistic not in (MEAN, FRACTION):
            continue
        named = re.findall(r"\{(\w+)\}", template)
        others = [d for d in var.dims[1:] if d not in named]  # the first dimension is the seeds
        if any(var.sizes[d] != 1 for d in others):
            continue  # not one statistic per label of the named dimensions
        var = var.isel({d: 0 for d in others})
        over = ds[var.attrs["over"]] if var.attrs.get("over") in ds else None
        for labels in itertools.product(*(ds[d].values.tolist() for d in named)):
            where = dict(zip(named, labels))
            # split first: a label may hold dots of its own
            key = _path(results, [part.format(**where) for part in template.split(".")])
            if key is None:
                continue  # a statistic over no seed, left out of results
            values = np.asarray(var.sel(where).values)
            if statistic == FRACTION:
                out[key] = (FRACTION, values.astype(bool))
                continue
            if over is not None:
                values = values[np.asarray(over.sel({k: w for k, w in where.items() if k in over.dims}).values,
                                           dtype=bool)]
            out[key] = (MEAN, values[np.isfinite(values)].astype(np.float64))
    return out


def proportion_pvalue(k1: int, n1: int, k2: int, n2: int) -> float:
    """Two-sided p-value of the pooled two-proportion z-test of k1/n1 against k2/n2 (1 when both are 0 or 1)."""
    pooled = (k1 + k2) / (n1 + n2)
    var = pooled * (1 - pooled) * (1 / n1 + 1 / n2)
    return 1.0 if var == 0 else z_pvalue((k1 / n1 - k2 / n2) / math.sqrt(var))


def sample_test(a: tuple[str, np.ndarray], b: tuple[str, np.ndarray]) -> tuple[str, float] | None:
    """(test, p) on two folders' per-seed values of one statistic; None where they do not allow one."""
    (kind, x), (kind_b, y) = a, b
    if kind != kind_b:
        return None
    if kind == FRACTION and x.size and y.size:
        return "proportion", proportion_pvalue(int(x.sum()), x.size, int(y.sum()), y.size)
    if kind == MEAN and x.size >= 2 and y.size >= 2:
        return "welch", welch(x, y)[2]
    return None


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


def classify(path: str, a, b, rtol: float, atol: float, samples: tuple[str, float] | None = None) -> Finding:
    """One statistic's finding before the correction (a tested one is ``within interval`` with its p-value);
    ``samples``: the per-seed test's name and p-value, where both folders have the statistic's per-seed values."""
    (va, ca), (vb, cb) = a, b
    f = Finding(path, DIFFERS, va, vb, ca, cb)
    if va == vb and ca == cb and type(va) is type(vb):
        f.kind = IDENTICAL
    elif _number(va) and _number(vb) and _close(va, vb, rtol, atol) and (
            (ca is None and cb is None) or (ca is not None and cb is not None
                                            and all(_close(x, y, rtol, atol) for x, y in zip(ca, cb)))):
        f.kind = EQUAL
    elif samples is not None:
        f.kind, (f.test, f.p) = WITHIN, samples
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
            samples: Callable[[str], tuple[str, float] | None] = lambda path: None) -> list[Finding]:
    """The findings for every statistic of the ``results`` dicts ``a`` and ``b``, in ``a``'s order then ``b``'s
    extra ones; ``samples(path)``: the per-seed test's (name, p-value) where both folders allow one."""
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
    where = {"welch": "Welch t-test on the per-seed values", "proportion": "two-proportion z-test on the seeds",
             "z": "z-test on the intervals"}.get(f.test, "")
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
