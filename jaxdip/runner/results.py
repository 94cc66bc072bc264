"""Pieces shared by experiments: initial-state samplers, weight matrices from config, band figures, summaries
over seeds with their failures, and the check that what an experiment writes holds no NaN, inf or null."""

from __future__ import annotations

import math
import re

import jax
import jax.numpy as jnp
import numpy as np

from jaxdip.config import ConfigError


def weight_matrix(key: str, value, n: int) -> np.ndarray:
    """A weight given as n diagonal entries or an n x n symmetric PSD matrix."""
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape == (n,):
        arr = np.diag(arr)
    elif arr.shape != (n, n):
        raise ConfigError(key, f"must be {n} diagonal weights or a {n}x{n} matrix, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ConfigError(key, "must be finite")
    if not np.allclose(arr, arr.T):
        raise ConfigError(key, "must be symmetric")
    if np.linalg.eigvalsh(arr).min() < -1e-12 * max(1.0, np.abs(arr).max()):
        raise ConfigError(key, "must be positive semi-definite")
    return arr


def ball_sampler(center, radius):
    """x0 uniform in the Euclidean ball of ``radius`` around ``center`` (radius 0: exactly the center)."""
    center = jnp.asarray(center, dtype=jnp.float64)
    n = center.shape[0]

    def sample(key):
        k1, k2 = jax.random.split(key)
        d = jax.random.normal(k1, (n,))
        d = d / jnp.linalg.norm(d)
        r = radius * jax.random.uniform(k2) ** (1.0 / n)
        return center + r * d

    return sample


def band_figure(t, series: dict, ylabel: str = "", title: str = ""):
    """Median and 5-95% envelope over seeds of each series (arrays shaped (seeds, time))."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(series), 1, figsize=(7, 2.4 * len(series)), sharex=True, squeeze=False)
    for ax, (name, arr) in zip(axes[:, 0], series.items()):
        arr = np.asarray(arr)
        if arr.shape[0] == 0:
            ax.set_title(f"{name}: no finite trajectory")
            continue
        lo, med, hi = np.quantile(arr, [0.05, 0.5, 0.95], axis=0)
        ax.fill_between(t, lo, hi, alpha=0.3, label="5-95% of seeds")
        ax.plot(t, med, lw=1.2, label="median")
        ax.axhline(0.0, color="k", lw=0.5)
        ax.set_ylabel(f"{name} {ylabel}".strip())
        ax.grid(alpha=0.3)
    if axes[0, 0].get_legend_handles_labels()[0]:  # an empty panel (no surviving seed) has nothing to label
        axes[0, 0].legend(loc="upper right", fontsize=8)
    axes[-1, 0].set_xlabel("time (s)")
    if title:
        axes[0, 0].set_title(title)
    fig.tight_layout()
    return fig


def trajectory_summary(res, state_names, stab_idx, stab_tol) -> dict:
    """Per-seed time averages of a Monte Carlo result, then means over the non-diverged seeds with 95% CIs.

    For every state: the time mean, time variance, mean |x| and variance of |x| (Table 3.1 reports the last
    two); the same for the input; the stabilised fraction (not diverged and max |x_i| over the loop's tail
    window below ``stab_tol`` for i in ``stab_idx``) with a Wilson interval; the diverged count.
    """
    from jaxdip import stats

    st = jax.tree_util.tree_map(np.asarray, res.carry.stats)
    diverged = np.asarray(res.carry.diverged)
    ok = ~diverged
    cnt = np.maximum(st.count, 1)[:, None]
    tmean, tabs, tsq = st.sum_x / cnt, st.sum_absx / cnt, st.sum_x2 / cnt
    stab = ok & np.all(st.tail_max_absx[:, list(stab_idx)] < stab_tol, axis=1)
    frac, ci = stats.wilson(int(stab.sum()), len(stab))
    out = {"stabilized_fraction": frac, "stabilized_fraction_ci95": ci, "diverged": int(diverged.sum()),
           "states": {}}
    for i, name in enumerate(state_names):
        out["states"][name] = {
            **stats.with_ci("mean", tmean[:, i], ok),
            **stats.with_ci("var", tsq[:, i] - tmean[:, i] ** 2, ok),
            **stats.with_ci("mean_abs", tabs[:, i], ok),
            **stats.with_ci("var_abs", tsq[:, i] - tabs[:, i] ** 2, ok),
        }
    u_mean = st.sum_u / cnt
    u_abs = st.sum_absu / cnt
    u_sq = st.sum_u2 / cnt
    out["u"] = {**stats.with_ci("mean_abs", u_abs[:, 0], ok), **stats.with_ci("var", u_sq[:, 0] - u_mean[:, 0] ** 2, ok),
                **stats.with_ci("var_abs", u_sq[:, 0] - u_abs[:, 0] ** 2, ok)}
    return out


def failure_summary(sol, state_names, dt: float, bound) -> dict:
    """How the failed trajectories of a ``jaxdip.monte_carlo`` Solution failed, from the engine's result codes.

    Counts per code, the time of the first bad state (min / median / max over the failed seeds), the norm of
    that state, and for out-of-bounds failures which state crossed its bound first (the component furthest
    beyond its bound, relative to the bound). Empty when no trajectory failed.
    """
    from jaxdip.engine import RESULTS

    code = np.asarray(sol.result)
    failed = code != RESULTS.ok
    if not failed.any():
        return {}
    t_fail = np.asarray(sol.final.failed_at)[failed] * dt
    x_fail = np.asarray(sol.final.failed_x)[failed]
    oob = code[failed] == RESULTS.out_of_bounds
    bound = np.broadcast_to(np.asarray(bound, dtype=float), x_fail.shape[1:])
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.where(np.isfinite(bound), np.abs(x_fail) / bound, 0.0)
    first = np.argmax(ratio, axis=1)
    crossed = {name: int(np.sum(oob & (first == i))) for i, name in enumerate(state_names)}
    finite = np.all(np.isfinite(x_fail), axis=1)
    norms = np.linalg.norm(x_fail[finite], axis=1)
    return {
        "nonfinite": int(np.sum(code == RESULTS.nonfinite)),
        "out_of_bounds": int(np.sum(oob)),
        "time_to_failure_s": {"min": float(t_fail.min()), "median": float(np.median(t_fail)),
                              "max": float(t_fail.max())},
        "state_norm_at_failure_median": float(np.median(norms)) if norms.size else None,
        "bound_crossed_first": {k: v for k, v in crossed.items() if v},
    }


def failure_lines(r: dict, seeds: int) -> list[str]:
    """Report lines for ``failure_summary``'s block (``r["failures"]``); none when nothing failed."""
    f = r.get("failures") or {}
    if not f:
        return []
    n = f["nonfinite"] + f["out_of_bounds"]
    head = f"all {seeds} seeds diverged" if n == seeds else f"{n} of {seeds} seeds diverged"
    t = f["time_to_failure_s"]
    lines = [f"- **{head}**: {f['out_of_bounds']} left the state bound, {f['nonfinite']} became non-finite; "
             f"first bad state at t = {t['min']:.3g} / {t['median']:.3g} / {t['max']:.3g} s (min / median / max)"]
    if f["bound_crossed_first"]:
        crossed = ", ".join(f"{k} in {v}" for k, v in f["bound_crossed_first"].items())
        lines.append(f"- bound crossed: {crossed}; median norm of the first bad state "
                     f"{f['state_norm_at_failure_median']:.3g}")
    if n == seeds:
        lines.append("- no seed survived, so there are no per-seed statistics to report (nothing to average)")
    return lines


def diverged_counts(results: dict, key: str = "diverged", where: str = "") -> dict:
    """{dotted path: count} of every non-zero ``key`` count in ``results`` (nested dicts): the failures block of
    an experiment whose parts each count their diverged seeds."""
    out = {}
    for k, v in results.items():
        path = f"{where}.{k}" if where else str(k)
        if isinstance(v, dict):
            out.update(diverged_counts(v, key, path))
        elif k == key and isinstance(v, int) and not isinstance(v, bool) and v > 0:
            out[where or key] = v
    return out


def loop_summary(sol, state_names, stab_idx, stab_tol, *, dt: float | None = None, bound=None) -> dict:
    """``trajectory_summary`` for a ``jaxdip.monte_carlo`` Solution whose metrics are ``{"x": Moments("x"),
    "u": Moments("u"), "tail": Window(MaxAbs("x"), ...)}``: the same quantities, keys and formulas.

    Statistics are over the seeds that did not fail; when every seed failed they are left out (no NaN or
    null), and with ``dt`` and ``bound`` a ``failures`` block says how the seeds failed."""
    from jaxdip import stats
    from jaxdip.engine import RESULTS

    m = jax.tree_util.tree_map(np.asarray, sol.metrics)
    failed = np.asarray(sol.result) != RESULTS.ok
    ok = ~failed
    stab = ok & np.all(m["tail"][:, list(stab_idx)] < stab_tol, axis=1)
    frac, ci = stats.wilson(int(stab.sum()), len(stab))
    out = {"stabilized_fraction": frac, "stabilized_fraction_ci95": ci, "diverged": int(failed.sum()), "states": {}}
    if dt is not None and failed.any():
        out["failures"] = failure_summary(sol, state_names, dt, np.inf if bound is None else bound)
    if not ok.any():
        return out
    x, u = m["x"], m["u"]
    for i, name in enumerate(state_names):
        out["states"][name] = {**stats.with_ci("mean", x["mean"][:, i], ok), **stats.with_ci("var", x["var"][:, i], ok),
                               **stats.with_ci("mean_abs", x["mean_abs"][:, i], ok),
                               **stats.with_ci("var_abs", x["var_abs"][:, i], ok)}
    out["u"] = {**stats.with_ci("mean_abs", u["mean_abs"][:, 0], ok), **stats.with_ci("var", u["var"][:, 0], ok),
                **stats.with_ci("var_abs", u["var_abs"][:, 0], ok)}
    return out


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
