"""ifn-protection: optimal antiviral (Interferon-beta) protection at the onset of infection, thesis ch. 4.

The chapter is theory without numbers; this experiment checks it by Monte Carlo with intervals and goes past it:
1. the model (A1)–(A6): E[Z] = beta/eta and R0 = beta gamma / (eta (gamma + delta)) against the sample means of
   the simulated infected cells (every virion drawn: decay and entry clocks, Gaussian position at entry);
2. E[I] = R0 - int_A g (4.4) under many controls, Monte Carlo (common random numbers) against quadrature;
3. problem (P) for a target E[I] = target_R (V = R0 - target_R): F(r) (4.7) and r_bar (4.8) by bisection with a
   bracket from the quadrature's error bound, for a uniform cost, a cost growing with distance and a costly
   shell; Theorem 4.4.1 checked against the best ball over a time window and random perturbations of the level
   set, all tuned to the same V; the non-unique case (Corollary 4.4.2 fails) with a flat-ratio cost: the
   threshold switch over-shoots, several different sets and the stochastic response are all optimal;
4. §4.5: the cell-autonomous rule on a lattice of cells, per-cell thresholds for a varying cost, and a
   stochastic response of cells on the flat band;
5. E[I] differentiable in the threshold (quadrature and Rao–Blackwellised Monte Carlo): gradient against
   central differences, optax Adam to E[I] = target_R against the bisection answer;
6. generations: extinction probability by Monte Carlo against the offspring generating function's iterates and
   fixed point.
Units: time in hours, length in cell diameters (defaults: see the config's docs and docs/immune.md).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from jaxdip import config as C
from jaxdip import stats
import experiments.ifn_protection.figures as Fg
from jaxdip.runner.experiment import Experiment, Outcome, RunContext
from experiments.ifn_protection.problem import (f_curves, f_properties, flat_case, lattice_reference,
                                                       level_set_extent, num,
                                                       theorem_check)
import experiments.ifn_protection.report as R  # the module: its report() would shadow it as an attribute
from experiments.ifn_protection.per_seed import cells_data
from jaxdip.immune import quadrature as Q
from jaxdip.immune import tuning as Tn
from jaxdip.immune.autonomous import CellAutonomous, theta_of_r
from jaxdip.immune.branching import simulate_generations
from jaxdip.immune.controls import BallWindow, Indicator, LevelSet, NoControl, OffsetBallWindow
from jaxdip.immune.costs import Distance, Shell, Uniform
from jaxdip.immune.model import Infection, extinction_iterates, extinction_probability
from jaxdip.immune.sampling import CellSampler, simulate_cells
from jaxdip.resources import Load


@dataclass
class IfnProtectionConfig:
    seeds: int = C.field(131072, C.positive, doc="infected cells in the main Monte Carlo (~beta/eta virions each)")
    seed: int = C.field(0, C.nonneg, doc="base PRNG key")
    chunk: int = C.field(2048, C.positive, doc="cells per vmapped chunk")
    eta: float = C.field(1.0 / 12.0, C.positive_finite, doc="death rate of an infected cell (1/h): 12 h lifetime")
    beta: float = C.field(2.5, C.positive_finite, doc="virion production rate (1/h): mean burst beta/eta = 30")
    gamma: float = C.field(0.1, C.positive_finite, doc="cell entry rate of a free virion (1/h)")
    delta: float = C.field(0.9, C.positive_finite, doc="decay rate of a free virion (1/h): R0 = 3")
    diffusion: float = C.field(36.0, C.positive_finite,
                               doc="virion diffusion coefficient (cell diameters^2 / h; 1 um^2/s for 10 um cells)")
    dim: int = C.field(2, C.one_of(1, 2, 3), doc="dimension of the tissue (2: a monolayer)")
    target_R: float = C.field(1.0, C.positive_finite, doc="target E[I] = R_bar; V = R0 - R_bar")
    distance_scale: float = C.field(10.0, C.positive_finite, doc="cost 1 + (|x| / scale)^2")
    shell: list[float] = C.field([6.0, 10.0, 4.0], C.nonneg_finite, C.length(3),
                                 doc="costly shell: inner radius, outer radius, extra cost (h = 1 + extra there)")
    flat_excess: float = C.field(0.5, C.positive_finite,
                                 doc="flat-ratio cost: g-mass of the flat set = V + flat_excess (R0 - V)")
    tie_tol: float = C.field(1e-9, C.positive_finite, doc="tie band |log(g/h) - log r| of the stochastic response")
    quad_panels: int = C.field(16384, C.positive, doc="Simpson panels per segment for reported quadratures")
    bisect_panels: int = C.field(4096, C.positive, doc="panels inside searches (coarse bisection, perturbations)")
    ball_grid: int = C.field(40, C.positive, doc="grid points per axis of the ball-window search (in s0, s1)")
    ball_refine: int = C.field(2, C.nonneg, doc="refinements of that grid around its best point")
    perturbations: int = C.field(8, C.nonneg, doc="random perturbations of each level set")
    perturb_eps: float = C.field(1.0, C.positive_finite, doc="amplitude (nats) of the perturbing field")
    perturb_modes: int = C.field(3, C.positive, doc="cosine modes per axis of the perturbing field")
    offset_ball: list[float] = C.field([8.0, 6.0, 0.25, 2.0], C.nonneg_finite, C.length(4),
                                       doc="off-centre ball control: centre distance, radius, t0, t1")
    half_ball: list[float] = C.field([12.0, 0.0, 1.5], C.nonneg_finite, C.length(3),
                                     doc="half-ball indicator control {x_1 >= 0, |x| <= radius}: radius, t0, t1")
    cell_sizes: list[float] = C.field([1.0, 4.0], C.positive_finite,
                                      doc="lattice spacings of the cell-autonomous rule (cell diameters)")
    lattice_panels: int = C.field(2048, C.positive,
                                  doc="time panels of the lattice rule's quadrature (one switch per panel)")
    tune_steps: int = C.field(300, C.positive, doc="optax Adam steps")
    tune_lr: float = C.field(0.1, C.positive_finite, doc="Adam learning rate on log r (decays x0.01)")
    tune_batch: int = C.field(8192, C.positive, doc="entering virions per Monte Carlo tuning batch")
    tune_start: float = C.field(-1.0, C.finite, doc="start of tuning: log r_bar + this")
    generation_targets: list[float] = C.field([1.5, 1.0, 0.75], C.positive_finite,
                                              doc="E[I] of the level-set controls run for several generations")
    lineages: int = C.field(4096, C.positive, doc="independent infections in the generations Monte Carlo")
    generations: int = C.field(10, C.positive, doc="generations simulated")
    cap: int = C.field(200, C.positive, doc="a lineage reaching this many cells counts as surviving")

    def loads(self) -> list[Load]:
        """The big allocations: every cell's outputs (tau, Z, entries and one count per control; about
        13 + len(cell_sizes) controls) are kept, a chunk of cells holds its virion blocks, a generation holds up
        to lineages x cap cells, and a quadrature (up to 11 segments) or a tuning batch solves each level set's
        pieces by bisection at every node."""
        controls = 13 + len(self.cell_sizes)
        ray = 2 * 3 * 82
        return [
            Load("the Monte Carlo of infected cells", ("seeds",), self.seeds, 1, saved=3 + controls, state=0),
            Load("one chunk of infected cells", ("chunk",), self.chunk, 1, state=16 * (self.dim + 4) * controls),
            Load("a generation of the branching Monte Carlo", ("lineages", "cap"), self.lineages * self.cap, 1,
                 saved=4, state=0),
            Load("a quadrature", ("quad_panels",), 11 * (self.quad_panels + 1), 1, state=ray),
            Load("a Monte Carlo tuning batch", ("tune_batch",), self.tune_batch, 1, state=ray),
        ]

    def validate(self):
        if self.target_R >= self.beta * self.gamma / (self.eta * (self.gamma + self.delta)):
            raise C.ConfigError("target_R", "must be below R0 = beta gamma / (eta (gamma + delta))")
        if not self.shell[0] < self.shell[1]:
            raise C.ConfigError("shell", "inner radius must be below outer radius")
        if not (self.offset_ball[2] > 0 and self.offset_ball[2] < self.offset_ball[3]):
            raise C.ConfigError("offset_ball", "need 0 < t0 < t1")
        if not self.half_ball[1] < self.half_ball[2]:
            raise C.ConfigError("half_ball", "need t0 < t1")
        if self.flat_excess >= 1.0:
            raise C.ConfigError("flat_excess", "must be below 1 (the flat set's g-mass must stay below R0)")


def half_ball(t, x, p):
    """The indicator control {x_1 >= 0, |x| <= radius, t0 <= t < t1}, p = (radius, t0, t1)."""
    return (x[0] >= 0) & (jnp.sum(x * x) <= p[0] ** 2) & (t >= p[1]) & (t < p[2])


def make_model(cfg) -> Infection:
    return Infection(eta=cfg.eta, beta=cfg.beta, gamma=cfg.gamma, delta=cfg.delta, diffusion=cfg.diffusion,
                     dim=cfg.dim)


def run(cfg: IfnProtectionConfig, ctx: RunContext | None = None) -> Outcome:
    model = make_model(cfg)
    R0, EZ = num(model.R0), num(model.mean_burst)
    V = R0 - cfg.target_R
    key = jax.random.PRNGKey(cfg.seed)
    costs = {"uniform": Uniform(), "distance": Distance(cfg.distance_scale),
             "shell": Shell(*[float(v) for v in cfg.shell])}

    timing, t_last = {}, [time.perf_counter()]

    def lap(name):  # wall time of each stage: Outcome.timing, never results
        now = time.perf_counter()
        timing[f"{name}_s"] = round(now - t_last[0], 3)
        t_last[0] = now

    # ---- problem (P): thresholds, Theorem 4.4.1 against alternatives --------------------------------------
    checks = {name: theorem_check(model, cost, V, cfg, jax.random.fold_in(key, 100 + i))
              for i, (name, cost) in enumerate(costs.items())}
    checks["uniform"]["results"]["max_radius"] = level_set_extent(model, checks["uniform"]["threshold"].log_r)[1]
    lap("theorem")
    flat = flat_case(model, V, cfg, checks["uniform"])
    lap("flat_case")

    # ---- Monte Carlo of the infection under many controls (one pass, common random numbers) ---------------
    ob = cfg.offset_ball
    centre = jnp.zeros(cfg.dim).at[0].set(ob[0])
    offset = OffsetBallWindow(centre, ob[1], ob[2], ob[3])
    hb_r, hb_t0, hb_t1 = cfg.half_ball

    log_r_u = checks["uniform"]["threshold"].log_r
    controls = {
        "none": (NoControl(), (0.0, 0.0)),
        "level set, uniform h": (checks["uniform"]["level_set"], None),
        "best ball window, uniform h": (checks["uniform"]["ball"], None),
        "level set, distance h": (checks["distance"]["level_set"], None),
        "best ball window, distance h": (checks["distance"]["ball"], None),
        "level set, shell h": (checks["shell"]["level_set"], None),
        "best ball window, shell h": (checks["shell"]["ball"], None),
        "flat h: threshold switch": (flat["switch"], None),
        "flat h: stochastic response": (flat["stochastic"], (
            num(flat["results"]["sets"]["stochastic response (q on the flat set)"]["g"]),
            num(flat["F_at"].g_hi - flat["F_at"].g_lo) / 2)),
        "flat h: flat set after t_c": (flat["late"], None),
        "off-centre ball window": (offset, None),
        "half ball (indicator)": (Indicator(half_ball, jnp.asarray(cfg.half_ball)), BallWindow(hb_r, hb_t0, hb_t1)),
    }
    # the lattice rules' quadrature references (expected g-mass of the protected cells, with an error estimate)
    def lattice(rule, log_r):
        return rule, lattice_reference(model, rule, log_r, cfg.lattice_panels)

    # each lattice rule beside the continuum rule it approximates: compared paired, on the same virions
    partners = {f"cells of {a:g}: uniform h": "level set, uniform h" for a in cfg.cell_sizes}
    for a in cfg.cell_sizes:
        controls[f"cells of {a:g}: uniform h"] = lattice(
            CellAutonomous(Uniform(), theta_of_r(model, log_r_u), cell_size=float(a)), log_r_u)
    a0 = float(cfg.cell_sizes[0])
    log_r_d = checks["distance"]["threshold"].log_r
    partners[f"cells of {a0:g}: distance h (per-cell thresholds)"] = "level set, distance h"
    partners[f"cells of {a0:g}: flat h, stochastic"] = "flat h: stochastic response"
    controls[f"cells of {a0:g}: distance h (per-cell thresholds)"] = lattice(
        CellAutonomous(costs["distance"], theta_of_r(model, log_r_d), cell_size=a0), log_r_d)
    log_r_f = flat["threshold"].log_r
    controls[f"cells of {a0:g}: flat h, stochastic"] = lattice(
        CellAutonomous(flat["cost"], theta_of_r(model, log_r_f), cfg.tie_tol, flat["q"], cell_size=a0,
                       stochastic=True), log_r_f)
    lap("lattice_quadrature")
    names = list(controls)
    sampler = CellSampler(model, tuple(c for c, _ in controls.values()))
    out = simulate_cells(sampler, jax.random.fold_in(key, 1), cfg.seeds, chunk=cfg.chunk, progress=True,
                         desc="ifn-protection cells")
    Z, I = out["Z"].astype(np.float64), out["I"].astype(np.float64)
    virions = int(Z.sum())
    ez, ez_ci = stats.mean_ci(Z)
    entered = int(out["entered"].sum())
    px, px_ci = stats.wilson(entered, virions)
    p0, p0_ci = stats.wilson(int(np.sum(Z == 0)), cfg.seeds)
    model_res = {
        "E_Z_formula": EZ, "E_Z_mc": ez, "E_Z_ci95": ez_ci, "E_Z_in_ci": bool(ez_ci[0] <= EZ <= ez_ci[1]),
        "P_Z0_formula_geometric": num(model.eta / (model.eta + model.beta)), "P_Z0_mc": p0, "P_Z0_ci95": p0_ci,
        "entry_prob_formula": num(model.entry_prob), "entry_prob_mc": px, "entry_prob_ci95": px_ci,
        "virions": virions, "cells": cfg.seeds,
    }
    mc = {}
    for j, name in enumerate(names):
        ctrl, ref = controls[name]
        ref = ctrl if ref is None else ref
        m, ci = stats.mean_ci(I[:, j])
        row = {"E_I_mc": m, "E_I_ci95": ci, "int_g_mc": R0 - m, "int_g_ci95": [R0 - ci[1], R0 - ci[0]]}
        gb = None
        if isinstance(ref, tuple):
            gb = ref
        elif hasattr(ref, "profile"):
            g = Q.masses(model, ref, Uniform(), cfg.quad_panels)
            scale = 0.5 if name.startswith("half ball") else 1.0  # by symmetry: half of the ball's mass
            gb = (scale * num(g.g), scale * num(g.g_hi - g.g_lo) / 2)
        if gb is not None:
            e = R0 - gb[0]
            row.update({"E_I_quadrature": e, "quadrature_in_ci": bool(ci[0] <= e <= ci[1]),
                        "quadrature_error_bound": gb[1]})
        # a random pattern of responding cells is shared by the virions of one infection: not binomial per virion
        shared_pattern = isinstance(ctrl, CellAutonomous) and ctrl.stochastic and ctrl.cell_size > 0
        if gb is not None and not shared_pattern:
            # per entering virion: P(infects | enters) = 1 - int_A g / R0. Conditioning on the entries removes
            # the burst-size and entry noise that every control shares (common random numbers), leaving the
            # control's own (spatial) part; the count is binomial given the entries (independent virions)
            pe, pe_ci = stats.wilson(int(I[:, j].sum()), entered)
            pr = 1.0 - gb[0] / R0
            row.update({"P_infect_given_entry_mc": pe,
                        "P_infect_given_entry_ci95": pe_ci, "P_infect_given_entry_quadrature": pr,
                        "P_infect_given_entry_in_ci": bool(pe_ci[0] <= pr <= pe_ci[1])})
        mc[name] = row
    # the rows share their virions, so one unlucky draw moves them all; the paired difference of a lattice rule
    # and its continuum rule cancels that and tests what the lattice changes
    for name, partner in partners.items():
        j, jp = names.index(name), names.index(partner)
        dm, dci = stats.mean_ci(I[:, j] - I[:, jp])
        dq = mc[name]["E_I_quadrature"] - mc[partner]["E_I_quadrature"]
        mc[name].update({"paired_with": partner, "paired_difference_mc": dm, "paired_difference_ci95": dci,
                         "paired_difference_quadrature": dq, "paired_in_ci": bool(dci[0] <= dq <= dci[1])})
    mc_r0 = mc["none"]
    model_res.update({"R0_formula": R0, "R0_mc": mc_r0["E_I_mc"], "R0_ci95": mc_r0["E_I_ci95"],
                      "R0_in_ci": bool(mc_r0["E_I_ci95"][0] <= R0 <= mc_r0["E_I_ci95"][1])})
    offset_lambda = num(offset.max_lambda(model))

    lap("cells_monte_carlo")

    # ---- F(r): curves, monotone and upper semi-continuous numerically ---------------------------------------
    all_costs = {**costs, "flat": flat["cost"]}
    all_th = {**{k: v["threshold"] for k, v in checks.items()}, "flat": flat["threshold"]}
    curves = f_curves(model, all_costs, all_th, cfg.bisect_panels)

    lap("F_curves")

    # ---- differentiable E[I](r) and optax ---------------------------------------------------------------------
    unif = Uniform()
    x = num(log_r_u)
    eps = 1e-5
    kmc = jax.random.fold_in(key, 2)

    def slope_and_fd(**kw):
        g = num(Tn.progeny_and_slope(model, unif, x, **kw)[1])
        fd = (num(Tn.progeny_and_slope(model, unif, x + eps, **kw)[0])
              - num(Tn.progeny_and_slope(model, unif, x - eps, **kw)[0])) / (2 * eps)
        return g, fd

    g_quad, fd_quad = slope_and_fd(n=cfg.bisect_panels)
    g_mc, fd_mc = slope_and_fd(method="mc", key=kmc, n=cfg.tune_batch)
    tq = Tn.tune_threshold(model, unif, cfg.target_R, x + cfg.tune_start, steps=cfg.tune_steps, lr=cfg.tune_lr,
                           method="quadrature", n_quad=cfg.bisect_panels)
    tm = Tn.tune_threshold(model, unif, cfg.target_R, x + cfg.tune_start, steps=cfg.tune_steps, lr=cfg.tune_lr,
                           method="mc", key=jax.random.fold_in(key, 3), batch=cfg.tune_batch)
    tune_res = {
        "dEI_dlogr_autodiff_quadrature": g_quad, "dEI_dlogr_central_difference_quadrature": fd_quad,
        "dEI_dlogr_autodiff_mc": g_mc, "dEI_dlogr_central_difference_mc": fd_mc,
        "log_r_bar_bisection": x, "log_r_optax_quadrature": tq.log_r, "log_r_optax_mc": tm.log_r,
        "r_rel_error_quadrature": math.exp(tq.log_r - x) - 1.0, "r_rel_error_mc": math.exp(tm.log_r - x) - 1.0,
        "E_I_at_optax_mc_r": num(Tn.expected_progeny_quadrature(model, unif, tm.log_r, cfg.quad_panels)),
        "within_1_percent": bool(abs(math.exp(tm.log_r - x) - 1.0) < 0.01
                                 and abs(math.exp(tq.log_r - x) - 1.0) < 0.01),
    }

    lap("tuning")

    # ---- generations ------------------------------------------------------------------------------------------
    gen_res, gen_plot = {}, {}
    # "none" as a level set at r = inf (empty), so that one compiled sampler serves every generation run
    gen_controls = {f"{R0:g} (none)": (LevelSet(cost=unif, log_r=jnp.inf), R0)}
    for Rt in cfg.generation_targets:
        th = Q.threshold(model, unif, R0 - Rt, n=cfg.bisect_panels)
        Rq = R0 - num(Q.F(model, unif, th.log_r, cfg.quad_panels).g)
        gen_controls[f"{Rt:g}"] = (LevelSet(cost=unif, log_r=th.log_r), Rq)
    for i, (label, (ctrl, Rq)) in enumerate(gen_controls.items()):
        sim = simulate_generations(CellSampler(model, (ctrl,), thin=True), jax.random.fold_in(key, 10 + i),
                                   cfg.lineages, cfg.generations, cap=cfg.cap, chunk=cfg.chunk)
        iters = np.asarray(extinction_iterates(Rq, cfg.generations))
        ext = sim["extinct_by_generation"]
        inside = [e["extinct_ci95"][0] <= q <= e["extinct_ci95"][1] for e, q in zip(ext, iters)]
        off = sim["offspring"].astype(np.float64)
        om, oci = stats.mean_ci(off)
        z0, z0ci = stats.wilson(int(np.sum(off == 0)), off.size)
        gen_res[label] = {
            "E_I": Rq, "extinction_probability_fixed_point": num(extinction_probability(Rq)),
            "extinction_closed_form": min(1.0, 1.0 / Rq),
            "extinct_by_generation_mc": [e["extinct"] for e in ext],
            "extinct_by_generation_ci95": [e["extinct_ci95"] for e in ext],
            "extinct_by_generation_pgf": iters.tolist(), "pgf_in_ci": f"{sum(inside)} of {len(inside)}",
            "escaped": sim["escaped"], "cells_simulated": int(off.size),
            "offspring_mean_mc": om, "offspring_mean_ci95": oci, "offspring_P0_mc": z0, "offspring_P0_ci95": z0ci,
            "offspring_P0_geometric": 1.0 / (1.0 + Rq),
        }
        gen_plot[label] = (ext, iters)

    lap("generations")
    results = {
        "parameters": {"eta": cfg.eta, "beta": cfg.beta, "gamma": cfg.gamma, "delta": cfg.delta,
                       "diffusion": cfg.diffusion, "dim": cfg.dim, "target_R": cfg.target_R, "V": V},
        "model": model_res,
        "controls_mc": mc,
        "offset_ball_max_lambda": offset_lambda,
        "theorem": {k: v["results"] for k, v in checks.items()},
        "flat_case": flat["results"],
        "F_properties": f_properties(curves),
        "tuning": tune_res,
        "generations": gen_res,
    }
    figures = {
        "optimal_sets": Fg.fig_optimal_sets(model, checks, flat, costs),
        "F_of_r": Fg.fig_F(curves, V, all_th),
        "mc_vs_quadrature": Fg.fig_mc(mc, R0),
        "cost_at_equal_EI": Fg.fig_costs(checks, flat["results"]),
        "extinction": Fg.fig_extinction(gen_plot),
        "tuning": Fg.fig_tuning(tq, tm, x),
    }
    lap("figures")
    return Outcome(results=results, report=R.report(cfg, results), figures=figures, timing=timing,
                   per_seed=cells_data(Z, I, names, partners))


EXPERIMENT = Experiment(
    id="ifn-protection",
    title="Optimal antiviral protection (Interferon-β): (P), Theorem 4.4.1 and §4.5 by Monte Carlo",
    config_cls=IfnProtectionConfig,
    run=run,
    quick={"seeds": 4096, "quad_panels": 1024, "bisect_panels": 512, "ball_grid": 14, "ball_refine": 1,
           "perturbations": 2, "lattice_panels": 512, "lineages": 512, "generations": 6, "tune_steps": 100,
           "tune_batch": 2048,
           "generation_targets": [1.5, 1.0]},
    source="thesis ch. 4 (§4.3–4.5: (A1)–(A6), (4.1)–(4.8), Theorem 4.4.1, Corollary 4.4.2)",
    quick_cost_s=37, full_cost_s=194,
)
