"""Summaries over Monte Carlo seeds for a report: means with 95% intervals over the seeds that did not fail, the
stabilised fraction with its Wilson interval, and how the failed seeds failed."""

from __future__ import annotations

import numpy as np


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


def loop_per_seed(sol, state_names, stab_idx, stab_tol, *, dt: float | None = None, state_units=None,
                  input_units: str = ""):
    """The per-seed arrays ``loop_summary`` reduces (a ``runner.per_seed.PerSeed``): the engine's result codes,
    failure times and final states (``jaxdip.engine.dataset.solution_variables``), the metrics ``x.*``, ``u.*``
    and ``tail``, and ``stabilized`` (ok, and the ``stab_idx`` states' tail maxima below ``stab_tol``), each
    labelled with the statistic of ``results`` it is summarised into. Saved samples are kept on (seed, time, ...)
    for a ``--per-seed trajectories`` run. ``state_units`` (one per state) become the coordinate ``state_units``
    that the state variables' ``units`` refer to; ``input_units``: those of u."""
    from jaxdip.engine.dataset import solution_variables
    from jaxdip.runner.per_seed import PerSeed, fraction_of, mean_of

    names = list(state_names)
    per_state, squared, u2 = "state_units", "state_units^2", f"{input_units}^2" if input_units else ""
    units = {"final_x": per_state, "x.mean": per_state, "x.mean_abs": per_state, "x.var": squared,
             "x.var_abs": squared, "x.mean_sq": squared, "tail": per_state, "u.mean": input_units,
             "u.mean_abs": input_units, "u.var": u2, "u.var_abs": u2, "u.mean_sq": u2, "x.count": "1", "u.count": "1"}
    out = PerSeed(solution_variables(sol, names, dt=dt, dims={"u": ("input",)}, units=units), {"state": names})
    if state_units is not None:
        out.coords["state_units"] = ("state", list(state_units))
    for stat in ("mean", "var", "mean_abs", "var_abs"):
        out.variables[f"x.{stat}"][2].update(mean_of(f"states.{{state}}.{stat}"))
    for stat in ("mean_abs", "var", "var_abs"):
        out.variables[f"u.{stat}"][2].update(mean_of(f"u.{stat}"))
    ok = out.variables["ok"][1]
    tail = out.variables["tail"][1]
    out.add("stabilized", ("seed",), ok & np.all(tail[:, list(stab_idx)] < stab_tol, axis=1), "1",
            f"ok, and max |{', '.join(names[i] for i in stab_idx)}| over the tail window below {stab_tol}",
            **fraction_of("stabilized_fraction"))
    return out


def loop_summary(sol, state_names, stab_idx, stab_tol, *, dt: float | None = None, bound=None,
                 per_seed=None) -> dict:
    """``trajectory_summary`` for a ``jaxdip.monte_carlo`` Solution whose metrics are ``{"x": Moments("x"),
    "u": Moments("u"), "tail": Window(MaxAbs("x"), ...)}``: the same quantities, keys and formulas, computed from
    ``loop_per_seed``'s arrays (``per_seed``, when the caller already has them).

    Statistics are over the seeds that did not fail; when every seed failed they are left out (no NaN or
    null), and with ``dt`` and ``bound`` a ``failures`` block says how the seeds failed."""
    from jaxdip import stats

    v = (per_seed or loop_per_seed(sol, state_names, stab_idx, stab_tol, dt=dt)).arrays()
    ok = v["ok"]
    failed = ~ok
    stab = v["stabilized"]
    frac, ci = stats.wilson(int(stab.sum()), len(stab))
    out = {"stabilized_fraction": frac, "stabilized_fraction_ci95": ci, "diverged": int(failed.sum()), "states": {}}
    if dt is not None and failed.any():
        out["failures"] = failure_summary(sol, state_names, dt, np.inf if bound is None else bound)
    if not ok.any():
        return out
    for i, name in enumerate(state_names):
        out["states"][name] = {**stats.with_ci("mean", v["x.mean"][:, i], ok), **stats.with_ci("var", v["x.var"][:, i], ok),
                               **stats.with_ci("mean_abs", v["x.mean_abs"][:, i], ok),
                               **stats.with_ci("var_abs", v["x.var_abs"][:, i], ok)}
    out["u"] = {**stats.with_ci("mean_abs", v["u.mean_abs"][:, 0], ok), **stats.with_ci("var", v["u.var"][:, 0], ok),
                **stats.with_ci("var_abs", v["u.var_abs"][:, 0], ok)}
    return out
