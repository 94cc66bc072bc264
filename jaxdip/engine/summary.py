"""``summary``: a Monte Carlo result as mean, 95% interval and failure count per metric, by state name.

``jd.summary(sol, plant)`` takes what ``jd.monte_carlo`` returns (a ``Solution`` stacked over seeds, or any pytree
of per-seed metrics with a ``result=`` array of ``jd.RESULTS`` codes) and reduces every metric over the seeds
that did not fail: the seeds whose result is not ``RESULTS.ok`` are masked out of every mean and interval and
counted instead. Intervals are Student's t (``jaxdip.stats.t_interval``): exact for normal per-seed values and the
normal interval's 1.96 as the seed count grows. The reduction runs on the host (NumPy), after the run: it is for
reporting, not for differentiating (take the mean of the metric yourself under ``jax.grad``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, Optional, Union

import jax
import numpy as np

from jaxdip.engine import checks
from jaxdip.engine.simulate import RESULTS
from jaxdip.stats import t_interval

from jaxdip._public import public_dir

__all__ = ["MetricSummary", "Summary", "summary"]
__dir__ = public_dir(globals())


class MetricSummary:
    """One metric over the live seeds: ``mean``, ``lo``, ``hi`` (the interval), ``n`` (live seeds) and ``failed``
    (seeds masked out), arrays of the metric's per-seed shape (with a sweep: leading sweep axes). Indexed by a
    state name (or an int) along its last axis where that axis has one entry per state: ``s["error"]["phi"]``."""

    def __init__(self, mean, lo, hi, n, failed, names: Optional[tuple[str, ...]] = None, label: str = "metric"):
        self.mean, self.lo, self.hi, self.n, self.failed, self.label = mean, lo, hi, n, failed, label
        # names label the last axis only where it has one entry per name (a scalar metric has no states)
        self.names = names if names is not None and np.ndim(mean) >= 1 and np.shape(mean)[-1] == len(names) else None

    @property
    def ci(self) -> tuple[np.ndarray, np.ndarray]:
        return self.lo, self.hi

    def __getitem__(self, key: Union[str, int]) -> MetricSummary:
        if isinstance(key, str):
            if self.names is None:
                raise KeyError(f"this metric has no state axis to index by name (per-seed shape {np.shape(self.mean)})")
            if key not in self.names:
                raise KeyError(f"no state {key!r}; states are {self.names}")
            label = f"{self.label}[{key}]"
            key = self.names.index(key)
        elif np.ndim(self.mean) == 0:
            raise IndexError("a scalar metric has no components")
        else:
            label = f"{self.label}[{self.names[key] if self.names else key}]"
        pick = lambda a: a[..., key] if np.ndim(a) == np.ndim(self.mean) else a
        return MetricSummary(pick(self.mean), pick(self.lo), pick(self.hi), pick(self.n), self.failed, label=label)

    def _rows(self, label: str) -> list[str]:
        if np.ndim(self.mean) == 0:
            return [f"{label:<24} {float(self.mean):12.5g}   [{float(self.lo):.5g}, {float(self.hi):.5g}]   "
                    f"{int(self.n)} of {int(self.n) + int(np.sum(self.failed))} seeds"]
        if self.names is not None and np.ndim(self.mean) == 1:
            return [row for i, name in enumerate(self.names) for row in self[i]._rows(f"{label}[{name}]")]
        return [f"{label:<24} shape {np.shape(self.mean)}: mean {np.array2string(np.asarray(self.mean), precision=4)}"]

    def __repr__(self) -> str:
        return "\n".join(self._rows(self.label))


class Summary(Mapping):
    """Metric path (``"theta"``, ``"x.mean"``: dict keys and attribute names joined by dots) -> ``MetricSummary``.
    ``seeds``: the seed count; ``failed``: seeds masked (per sweep entry with a sweep); ``codes``: the count per
    ``RESULTS`` name."""

    def __init__(self, metrics: dict[str, MetricSummary], seeds: int, failed, codes: dict[str, Any]):
        self._metrics, self.seeds, self.failed, self.codes = metrics, seeds, failed, codes

    def __getitem__(self, key: str) -> MetricSummary:
        try:
            return self._metrics[key]
        except KeyError:
            raise KeyError(f"no metric {key!r}; metrics are {list(self._metrics)}") from None

    def __iter__(self):
        return iter(self._metrics)

    def __len__(self) -> int:
        return len(self._metrics)

    def __repr__(self) -> str:
        head = f"{self.seeds} seeds, failed {self.failed} ({', '.join(f'{k} {v}' for k, v in self.codes.items())})"
        return "\n".join([head, f"{'metric':<24} {'mean':>12}   95% interval"]
                         + [row for k, m in self._metrics.items() for row in m._rows(k)])


def _path(keys) -> str:
    parts = []
    for k in keys:
        part = getattr(k, "key", getattr(k, "name", getattr(k, "idx", None)))
        parts.append(str(part))
    return ".".join(parts) or "metric"


def _state_names(names) -> Optional[tuple[str, ...]]:
    if names is None:
        return None
    names = getattr(names, "state_names", names)  # a plant, or the names themselves
    if isinstance(names, str) or not isinstance(names, Sequence) or not all(isinstance(s, str) for s in names):
        raise checks.ArgumentTypeError(f"summary: names must be a plant or a sequence of state names, got {names!r}")
    return tuple(names)


def summary(sol: Any, names: Any = None, *, result: Any = None, axis: int = 0, level: float = 0.95) -> Summary:
    """Mean, ``level`` interval and failure count of every metric of a Monte Carlo result, over the seeds (``axis``;
    with a ``sweep=``, the seeds are axis 1) that ended ``RESULTS.ok``.

    ``sol``: a ``Solution`` from ``jd.monte_carlo`` (its ``metrics`` and ``result``), or a pytree of per-seed
    metrics with ``result=`` the per-seed codes (None: no seed failed). ``names``: a plant (its ``state_names``) or
    the names, to index a metric's last axis by state: ``jd.summary(sol, plant)["error"]["theta2"].mean``.
    """
    if result is None and hasattr(sol, "metrics") and hasattr(sol, "result"):
        sol, result = sol.metrics, sol.result
    checks.check_int("summary", "axis", axis)
    checks.check_real("summary", "level", level)
    if checks.shape_of(level) != () or not 0.0 < float(level) < 1.0:
        checks.fail("summary", f"level must be a number in (0, 1) (0.95: a 95% interval), got {level!r}")
    if sol is None:
        checks.fail("summary", "the result has no metrics (pass metrics= to jd.Rollout or jd.simulate)")
    state_names = _state_names(names)
    leaves = jax.tree_util.tree_flatten_with_path(sol)[0]
    if not leaves:
        checks.fail("summary", "the result has no metrics (pass metrics= to jd.Rollout or jd.simulate)")
    for keys, leaf in leaves:
        # a leaf that is not numbers (a label, an object) or has no seeds axis would fail inside NumPy
        checks.check_real("summary", f"metric {_path(keys)!r}", leaf)
        if not -len(checks.shape_of(leaf)) <= axis < len(checks.shape_of(leaf)):
            checks.fail("summary", f"metric {_path(keys)!r} must have a seeds axis {axis} (a Monte Carlo result), "
                                   f"got shape {checks.fmt_shape(checks.shape_of(leaf))}")
    seeds = np.shape(leaves[0][1])[axis]
    codes = np.zeros((seeds,), np.int32) if result is None else np.asarray(result)
    if codes.ndim == 0 or codes.shape[axis] != seeds:
        checks.fail("summary", f"result must have {seeds} seeds along axis {axis}, got shape {codes.shape}")
    ok = codes == RESULTS.ok
    failed = np.sum(~ok, axis=axis)
    out = {}
    for keys, leaf in leaves:
        mean, lo, hi, n = t_interval(leaf, ok, axis=axis, level=level)
        out[_path(keys)] = MetricSummary(mean, lo, hi, n, failed, state_names, label=_path(keys))
    count = lambda c: int(np.sum(codes == c)) if codes.ndim == 1 else np.sum(codes == c, axis=axis)
    return Summary(out, seeds, failed if np.ndim(failed) else int(failed), {c.name: count(c) for c in RESULTS})
