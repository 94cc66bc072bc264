"""ifn-protection, problem (P): thresholds r_bar, Theorem 4.4.1 against tuned competitors, the non-unique case,
F(r) curves. Called by ``ifn_protection.run``."""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np

from jaxdip.immune import alternatives as Al
from jaxdip.immune import quadrature as Q
from jaxdip.immune.autonomous import CellAutonomous, theta_of_r, tie_probability
from jaxdip.immune.controls import LevelSet, Window, breakpoints
from jaxdip.immune.costs import Flat, Uniform
from jaxdip.immune.lattice import lattice_mass


def num(x) -> float:
    return float(np.asarray(x))


def _masses_dict(ms: Q.Masses) -> dict:
    return {"g": num(ms.g), "g_bracket": [num(ms.g_lo), num(ms.g_hi)], "h": num(ms.h),
            "h_bracket": [num(ms.h_lo), num(ms.h_hi)]}


def refined_threshold(model, cost, V, cfg) -> Q.Threshold:
    """Coarse bisection over the whole range, then the reported one with fine panels in a narrow bracket."""
    coarse = Q.threshold(model, cost, V, n=cfg.bisect_panels)
    if cfg.quad_panels == cfg.bisect_panels:
        return coarse
    x = num(coarse.log_r)
    fine = Q.threshold(model, cost, V, n=cfg.quad_panels, lo=x - 0.05, hi=x + 0.05)
    for v in (fine.log_r, fine.log_r_lo, fine.log_r_hi):
        if abs(num(v) - x) > 0.049:
            raise RuntimeError("refined threshold left its bracket; raise bisect_panels")
    return fine


def theorem_check(model, cost, V, cfg, key):
    """Level set against the best ball window and perturbed level sets, all at g-mass V, costs under ``cost``."""
    th = refined_threshold(model, cost, V, cfg)
    ls = LevelSet(cost=cost, log_r=th.log_r)
    ball, ball_m = Al.best_ball_window(model, cost, V, grid=cfg.ball_grid, refine=cfg.ball_refine,
                                       n_quad=cfg.quad_panels)
    perts = Al.perturbations(model, cost, num(th.log_r), V, key, cfg.perturbations, modes=cfg.perturb_modes,
                             eps=cfg.perturb_eps, n_quad=cfg.bisect_panels)
    pert_m = [Q.masses(model, c, cost, cfg.quad_panels) for c, _ in perts]
    ls_m = th.at
    alts = [("ball", ball_m)] + [(f"perturbation {i}", m) for i, m in enumerate(pert_m)]
    # the level set wins by a margin beyond both quadrature brackets (rigorous where the brackets are)
    wins = [num(m.h_lo) > num(ls_m.h_hi) for _, m in alts]
    return {
        "threshold": th, "level_set": ls, "ball": ball, "perturbations": [c for c, _ in perts],
        "results": {
            "log_r_bar": num(th.log_r), "log_r_bar_bracket": [num(th.log_r_lo), num(th.log_r_hi)],
            "r_bar": math.exp(num(th.log_r)), "density_threshold_theta": math.exp(num(theta_of_r(model, th.log_r))),
            "level_set": _masses_dict(ls_m),
            "ball": {**_masses_dict(ball_m), "radius": num(ball.radius), "t0": num(ball.t0), "t1": num(ball.t1)},
            "perturbations": [_masses_dict(m) for m in pert_m],
            "perturbation_g_max_abs_error": max([abs(num(m.g) - V) for m in pert_m], default=0.0),
            "ball_extra_cost": num(ball_m.h) / num(ls_m.h) - 1.0,
            "perturbation_min_extra_cost": min([num(m.h) / num(ls_m.h) - 1.0 for m in pert_m], default=float("nan")),
            "protect_until_h": float(np.nanmax(np.asarray(breakpoints(model, ls)))),
            "level_set_cheapest": all(wins),
            "level_set_cheapest_count": f"{sum(wins)} of {len(wins)}",
        },
    }


def flat_case(model, V, cfg, uniform_check):
    """Non-unique case: h = max(1, g / r_f) with int_{g >= r_f} g = V + flat_excess (R0 - V)."""
    R0 = num(model.R0)
    V_flat = V + cfg.flat_excess * (R0 - V)
    log_rf = num(refined_threshold(model, Uniform(), V_flat, cfg).log_r)
    cost = Flat(log_r=log_rf)
    th = refined_threshold(model, cost, V, cfg)
    n = cfg.quad_panels
    F_at = Q.F(model, cost, th.log_r, n)
    F_after = Q.F(model, cost, th.log_r + 1e-6, n)
    F_before = Q.F(model, cost, th.log_r - 1e-6, n)
    q = num(tie_probability(Q.F(model, cost, th.log_r + 2 * cfg.tie_tol, n).g, F_at.g, V))
    switch = LevelSet(cost=cost, log_r=th.log_r)
    stochastic = LevelSet(cost=cost, log_r=th.log_r, stochastic=True, tie_tol=cfg.tie_tol, tie_prob=q)
    inner = uniform_check["level_set"]  # {g >= r_bar of the uniform cost}: a subset of the flat set
    # the flat set after a time t_c, t_c chosen so that it holds V
    def late_mass(t_c):
        return Q.masses(model, Window(switch, t_c, jnp.inf), cost, cfg.bisect_panels).g

    tc = Q.bisect_host(lambda v: late_mass(jnp.asarray(v)), V, 0.0, 20.0 / float(model.k), xtol=1e-12)
    late = Window(switch, jnp.asarray(tc), jnp.asarray(jnp.inf))
    sets = {"threshold switch L_r_bar": switch, "stochastic response (q on the flat set)": stochastic,
            "uniform-cost level set (inner part)": inner, "flat set after t_c": late}
    ms = {k: Q.masses(model, c, cost, n) for k, c in sets.items() if k != "stochastic response (q on the flat set)"}
    # the stochastic response's expected masses: q on the flat set plus (1 - q) on the strict set {g/h > r_bar}
    # (a shell-weighted quadrature of the same thing is ``LevelSet(stochastic=True).shells``, tested separately)
    strict = Q.F(model, cost, th.log_r + 2 * cfg.tie_tol, n)
    ms["stochastic response (q on the flat set)"] = Q.Masses(*(q * a + (1 - q) * b for a, b in zip(F_at, strict)))
    optimal_cost = V / math.exp(num(th.log_r))
    res = {
        "log_r_flat": log_rf, "log_r_bar": num(th.log_r), "log_r_bar_bracket": [num(th.log_r_lo), num(th.log_r_hi)],
        "F_at_r_bar": num(F_at.g), "F_just_below_r_bar": num(F_before.g), "F_just_above_r_bar": num(F_after.g),
        "unique": bool(num(F_at.g_lo) <= V <= num(F_at.g_hi)), "tie_probability": q, "t_c": num(tc),
        "optimal_cost_V_over_r_bar": optimal_cost,
        "sets": {k: _masses_dict(m) for k, m in ms.items()},
    }
    return {"cost": cost, "threshold": th, "switch": switch, "stochastic": stochastic, "late": late, "q": q,
            "F_strict": strict, "F_at": F_at, "results": res}


def f_curves(model, costs: dict, th: dict, n: int, points: int = 81):
    out = {}
    for name, cost in costs.items():
        c = num(th[name].log_r)
        grid = np.sort(np.concatenate([np.linspace(c - 6.0, c + 4.0, points), [c, c - 1e-6, c + 1e-6]]))
        ms = [Q.F(model, cost, jnp.asarray(lr), n) for lr in grid]
        out[name] = (grid, *(np.array([num(getattr(m, k)) for m in ms]) for k in ("g", "g_lo", "g_hi")))
    return out


def f_properties(curves) -> dict:
    """Numerical monotonicity (no increase beyond the brackets) and left-continuity (USC) of F."""
    res = {}
    for name, (_, g, lo, hi) in curves.items():
        rises = np.diff(g)
        res[name] = {"max_increase": float(max(rises.max(), 0.0)),
                     "nonincreasing_within_brackets": bool(np.all(lo[1:] <= hi[:-1]))}
    return res


def level_set_extent(model, log_r) -> tuple[float, float]:
    """(t_max, largest radius) of the uniform-cost level set {g >= r}: rho*(t)^2 = 4 D t L(t)_+ with
    L(t) = log c - log r - k t - (d/2) log(4 pi D t), which vanishes at t_max."""
    t_max = float(np.nanmax(np.asarray(breakpoints(model, LevelSet(cost=Uniform(), log_r=jnp.asarray(log_r))))))
    t = np.linspace(1e-6, t_max, 4001)
    c, k, D, d = (num(v) for v in (model.c, model.k, model.diffusion, model.dim))
    L = math.log(c) - num(log_r) - k * t - d / 2 * np.log(4 * math.pi * D * t)
    return t_max, float(np.sqrt(np.max(4 * D * t * np.maximum(L, 0.0))))


def lattice_reference(model, rule: CellAutonomous, log_r, n_s: int) -> tuple[float, float]:
    """(int_A g, error estimate) of a cell-autonomous rule by quadrature (``immune.lattice``); a stochastic rule
    protects the tie band with probability q and the strict set {f > tol} always. Every rule here protects
    inside the uniform-cost level set at its own r (g/h <= g for h >= 1; min(g, r_f) <= g), so that set's
    extent, with margins, bounds the cells and times summed over (and the sum checks its edges)."""
    t_max, rho_max = level_set_extent(model, log_r)
    kw = {"reach": 1.5 * rho_max + 2.0 * rule.cell_size, "t_end": 1.5 * t_max, "n_s": n_s}
    theta, a = rule.log_theta, rule.cell_size
    if not rule.stochastic:
        return lattice_mass(model, rule.cost, theta, a, **kw)
    q, tol = num(rule.tie_prob), num(rule.tie_tol)
    band, band_err = lattice_mass(model, rule.cost, theta, a, offset=-tol, **kw)
    strict, strict_err = lattice_mass(model, rule.cost, theta, a, offset=tol, **kw)
    return q * band + (1 - q) * strict, q * band_err + (1 - q) * strict_err
