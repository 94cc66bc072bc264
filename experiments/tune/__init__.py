"""tune: gradient-based tuning of estimator and controller hyperparameters (``jaxdip.tune``).

For a target (``--set target=...``: ``cpx``, ``rwp``, ``dmso``, ``rp``, ``extra``) the experiment tunes the
hyperparameters on one set of seeds by gradient (optax Adam on log-parameters, forward-mode derivatives through
the whole closed loop), evaluates them on a disjoint held-out set of seeds, and compares with the documents'
values and with a random search given the same number of closed-loop simulations (also converted to
evaluation-equivalents with the measured cost of a gradient step).

cpx: gamma of CPX on the DIP stabilisation task of ``dip-cpx-ldf`` (the scenario ``jaxdip.scenarios.dip_cpx_ldf``);
loss per seed = time variance of alpha plus that of theta (deg^2) + ``divergence_penalty`` if it diverged.
The encoders quantise, so one sample path's loss is piecewise constant in gamma with jumps (finite differences
of it measure the jumps); ``smoothing = "straight_through"`` differentiates the quantiser as the identity
(the sensors' ``straight_through``), ``"none"`` uses the exact pathwise derivative (round' = 0).

rwp, dmso, rp, extra: see ``RWPTarget``, ``DMSOTarget`` (Gamma and diag K_MSO on the noisy TWIP case of
``twip-dmso``; ``smoothing`` picks that experiment's ``encoder_gradient``), ``RPTarget`` (gamma of (2.14) on the
DIP with a fixed LQR-derived P), ``ExtraTarget`` (k1, k2 and the four learning rates of the TWIP extra control on
the ``unmodeled`` case, Table 8.3's score); ``smoothing`` does not apply to rp and extra: no quantiser.

Held-out scenarios. The tuning seeds run the target's nominal scenario; every held-out seed draws its own
(``ScenarioDraw``): the initial state, the constant sensor bias and the disturbance's size are each scaled by
1 + U(-s, s) with s = ``heldout_x0_spread``, ``heldout_bias_spread``, ``heldout_disturbance_spread`` (default
0.5 each; 0 everywhere gives the tuning scenario with new noise only, the behaviour before these keys). Which
leaves each kind scales is the target's ``scenario_leaves``; a kind a target lacks is not drawn.

The config is in ``experiments.tune.config``, the targets in ``jaxdip.scenarios.tune_targets`` and the scenario draw in
``jaxdip.scenarios.heldout``; this module runs and reports.
"""

from __future__ import annotations

import jax
import numpy as np
import optax

from jaxdip import checkpoint as ckpt
from jaxdip import program_cache
from jaxdip import config as C
from jaxdip import stats
from jaxdip.runner.experiment import Experiment, Outcome, RunContext
from jaxdip.runner.per_seed import PerSeed, mean_of
from jaxdip.runner.results import fmt_ci
from experiments.tune.config import HELDOUT_OFFSET, TuneConfig
from jaxdip.scenarios.tune_targets import make_target
from jaxdip.tune import random_search, tune

# ---- run ----------------------------------------------------------------------------------------------------


def _scalar(theta):
    return {k: float(v) if np.ndim(v) == 0 else np.asarray(v, dtype=float).tolist() for k, v in theta.items()}


def run(cfg: TuneConfig, ctx: RunContext | None = None, progress: bool = True) -> Outcome:
    import time

    t_all = time.perf_counter()
    tg = make_target(cfg)
    key = jax.random.PRNGKey(cfg.seed)
    tune_seeds = np.arange(cfg.seeds)
    held_seeds = HELDOUT_OFFSET + np.arange(cfg.heldout_seeds)
    J_tune = tg.objective(tune_seeds, smooth=cfg.smoothing == "straight_through")
    # forward values are the same; no gradient needed. Through the program cache: a warm run skips their traces
    J_eval = program_cache.jit(tg.objective(tune_seeds, smooth=False), "J_eval")
    held_obj = tg.objective(held_seeds, smooth=False, scenarios=cfg.scenario_spreads())
    held = program_cache.jit(held_obj.per_seed)
    held_div = program_cache.jit(held_obj.diverged) if held_obj.diverged is not None else None

    res = tune(J_tune, tg.paper, key, steps=cfg.steps, lr=cfg.lr, spec=tg.spec, clip=cfg.clip,
               optimizer=optax.rprop(cfg.lr) if cfg.optimizer == "rprop" else None,
               common_random_numbers=cfg.crn, early_stop_patience=cfg.patience or None,
               checkpoint_path=ctx.checkpoint_path if ctx else None, resume=bool(ctx and ctx.resume),
               fingerprint=ctx.fingerprint if ctx else ckpt.fingerprint(C.to_dict(cfg)), progress=progress, desc=f"tune {cfg.target}",
               mode=cfg.mode)
    sims_grad = res.steps * cfg.seeds
    # random search with the same number of closed-loop simulations, on the same seeds and key
    rs = random_search(lambda th: J_eval(th, key), tg.sample, res.steps, jax.random.fold_in(key, 7),
                       progress=progress, desc=f"random search {cfg.target}")
    best_rs = rs.loss
    hit = np.nonzero(np.minimum.accumulate(res.loss_history) <= best_rs)[0]
    sims_to_rs_best = int((hit[0] + 1) * cfg.seeds) if hit.size else None
    rs_sims_to_best = int((int(np.argmin(rs.losses)) + 1) * cfg.seeds)
    # a forward-mode step carries one tangent per unconstrained coordinate through the same trajectories, so it
    # costs more than one plain evaluation; its measured steady-state price (compilation excluded) converts the
    # gradient's simulation count into evaluation-equivalents, the currency of the random search
    sw, ew = res.step_wall[1:], rs.eval_wall[1:]
    sw, ew = sw[np.isfinite(sw)], ew[np.isfinite(ew)]
    step_cost = float(np.median(sw) / np.median(ew)) if sw.size and ew.size else float("nan")

    t0 = time.perf_counter()
    evals, per_seed, fell = {}, {}, {}
    for name, th in (("paper", tg.paper), ("tuned", res.theta), ("random_search", rs.theta)):
        per_seed[name] = np.asarray(held(th, key))
        evals[name] = stats.mean_ci(per_seed[name])
        if held_div is not None:
            fell[name] = np.asarray(held_div(th, key))
            evals[name] += (int(np.sum(fell[name])),)
    diff = stats.mean_ci(per_seed["tuned"] - per_seed["paper"])  # paired: the same held-out seeds' noise
    data = heldout_data(cfg, held_seeds, per_seed, fell)
    eval_wall = time.perf_counter() - t0
    land = [float(J_eval(th, key)) for th in tg.grid(cfg.landscape_points)]
    grid = [float(th[tg.param]) for th in tg.grid(cfg.landscape_points)]

    paper_ci, tuned_ci = evals["paper"][1], evals["tuned"][1]
    out = {
        "paper_value": _scalar(tg.paper), "tuned_value": _scalar(res.theta),
        "random_search_value": _scalar(rs.theta),
        "loss_paper": evals["paper"][0], "loss_paper_ci95": paper_ci,
        "loss_tuned": evals["tuned"][0], "loss_tuned_ci95": tuned_ci,
        "loss_random_search": evals["random_search"][0], "loss_random_search_ci95": evals["random_search"][1],
        **({f"heldout_diverged_{n}": evals[n][2] for n in evals} if held_div is not None else {}),
        "heldout_scenario_spreads": {k: v for k, v in cfg.scenario_spreads().items() if k in tg.scenario_leaves},
        "tuned_below_paper_nonoverlapping": bool(tuned_ci[1] < paper_ci[0]),
        "loss_tuned_minus_paper": diff[0], "loss_tuned_minus_paper_ci95": diff[1],
        "simulations_used": sims_grad, "random_search_simulations": int(res.steps * cfg.seeds),
        "tuning_loss_best": res.loss, "random_search_tuning_loss_best": best_rs,
        "gradient_simulations_to_reach_random_search_best": sims_to_rs_best,
        "random_search_simulations_to_its_best": rs_sims_to_best,
        "steps": res.steps, "stopped_early": res.stopped_early,
        "trajectory": {"loss": res.loss_history.tolist(),
                       **{k: np.asarray(v).tolist() for k, v in res.theta_history.items()},
                       "grad_norm": res.grad_norm_history.tolist()},
        "random_search_losses": rs.losses.tolist(),
        "random_search_samples": {k: np.asarray(v).tolist() for k, v in rs.samples.items()},
        "landscape": {tg.param: grid, "loss": land},
    }
    # measured time, and what is derived from it, is not a result: a resumed run must give identical results
    timing = {
        "wall_s": {"tune": res.wall_s, "random_search": rs.wall_s, "heldout_eval": eval_wall,
                   "total": time.perf_counter() - t_all},
        "gradient_step_cost_in_evaluations": step_cost,
        "gradient_evaluation_equivalents_to_reach_random_search_best":
            None if sims_to_rs_best is None else sims_to_rs_best * step_cost,
    }
    if hasattr(tg, "describe"):
        out.update(tg.describe())
    results = {cfg.target: out}
    figures = {"tune_" + cfg.target: figure(cfg, tg, out)}
    return Outcome(results=results, report=report(cfg, out, timing), figures=figures,
                   timing={cfg.target: timing}, per_seed=data)


def heldout_data(cfg, held_seeds, losses: dict, fell: dict) -> PerSeed:
    """The held-out evaluation's per-seed losses at each value (paper, tuned, random search): the per-seed part of
    the results. The searches themselves (loss histories, the random search's samples) are not per-seed
    aggregates: they stay in metrics.json."""
    names, at = list(losses), f"{cfg.target}."
    data = PerSeed(coords={"heldout_seed": held_seeds, "theta": names})
    data.add("heldout_loss", ("heldout_seed", "theta"), np.stack([losses[n] for n in names], 1), "1",
             f"held-out loss of the seed ({cfg.target}) at each value", **mean_of(at + "loss_{theta}", None))
    data.add("loss_tuned_minus_paper", ("heldout_seed",), losses["tuned"] - losses["paper"], "1",
             "the tuned value's held-out loss minus the paper's, the same seed", **mean_of(at + "loss_tuned_minus_paper", None))
    if fell:
        data.add("heldout_diverged", ("heldout_seed", "theta"), np.stack([fell[n] for n in names], 1), "1",
                 "the seed diverged at this value")
    return data


def figure(cfg, tg, r):
    import matplotlib.pyplot as plt

    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4))
    L = np.asarray(r["trajectory"]["loss"])
    a1.plot(np.arange(1, len(L) + 1) * cfg.seeds, L, "o-", ms=3, label="gradient (Adam), J at each step")
    rsl = np.asarray(r["random_search_losses"])
    a1.plot(np.arange(1, len(rsl) + 1) * cfg.seeds, np.minimum.accumulate(rsl), "s--", ms=3,
            label="random search, best so far")
    a1.set_xlabel("closed-loop simulations (tuning seeds x steps)")
    a1.set_ylabel("J on the tuning seeds")
    a1.set_title(f"{cfg.target}: J against optimiser steps ({cfg.seeds} seeds/step)")
    a1.legend(fontsize=8)
    p = tg.param
    a2.plot(r["landscape"][p], r["landscape"]["loss"], "o-", ms=3, label="J (tuning seeds)")
    a2.axvline(r["paper_value"][p], color="C2", ls=":", label=f"paper {r['paper_value'][p]:.4g}")
    a2.axvline(r["tuned_value"][p], color="C3", ls="--", label=f"tuned {r['tuned_value'][p]:.4g}")
    a2.set_xscale("log")
    if min(r["landscape"]["loss"]) > 0:  # rp's loss is a log already
        a2.set_yscale("log")
    a2.set_xlabel(p)
    a2.set_ylabel("J")
    a2.set_title(f"loss landscape along {p}")
    a2.legend(fontsize=8)
    for a in (a1, a2):
        a.grid(alpha=0.3, which="both")
    return fig


def report(cfg, r, timing) -> str:
    p = list(r["paper_value"])
    num = lambda v: f"{v:.5g}" if np.ndim(v) == 0 else "[" + ", ".join(f"{x:.4g}" for x in v) + "]"
    fmt = lambda d: ", ".join(f"{k} = {num(v)}" for k, v in d.items())
    g = r["gradient_simulations_to_reach_random_search_best"]
    n_tan = sum(int(np.size(v)) for v in r["paper_value"].values())
    lines = [
        f"Target {cfg.target}: tuned {', '.join(p)} on {cfg.seeds} seeds ({cfg.duration} s each, "
        f"{'common random numbers' if cfg.crn else 'resampled keys'}, {'Adam lr' if cfg.optimizer == 'adam' else 'Rprop initial step'} {cfg.lr} on "
        f"log-parameters, clip {cfg.clip}, {cfg.mode}-mode derivatives, quantiser derivative: "
        f"{cfg.smoothing if cfg.target in ('cpx', 'rwp', 'dmso') else 'n/a, no quantiser'}); {r['steps']} steps"
        f"{' (stopped early)' if r['stopped_early'] else ''}. Held-out: {cfg.heldout_seeds} disjoint seeds, "
        + (("each drawing its scenario: " + ", ".join(f"{k} x (1 + U(-{v:g}, {v:g}))"
                                                    for k, v in r["heldout_scenario_spreads"].items() if v > 0)
            + " (the tuning seeds keep the nominal scenario).")
           if any(v > 0 for v in r["heldout_scenario_spreads"].values()) else "in the tuning scenario."),
        "",
        "| | value | held-out loss (95% interval) |",
        "|---|---|---|",
        f"| paper | {fmt(r['paper_value'])} | {fmt_ci(r['loss_paper'], r['loss_paper_ci95'])} |",
        f"| gradient-tuned | {fmt(r['tuned_value'])} | {fmt_ci(r['loss_tuned'], r['loss_tuned_ci95'])} |",
        f"| random search ({r['random_search_simulations']} sims) | {fmt(r['random_search_value'])} | "
        f"{fmt_ci(r['loss_random_search'], r['loss_random_search_ci95'])} |",
        "",
        *([f"Held-out seeds diverged (each counted with the penalty {cfg.divergence_penalty:g}): paper "
           f"{r['heldout_diverged_paper']}, tuned {r['heldout_diverged_tuned']}, random search "
           f"{r['heldout_diverged_random_search']} of {cfg.heldout_seeds}.", ""]
          if "heldout_diverged_paper" in r else []),
        f"Tuned below paper with non-overlapping intervals: {'yes' if r['tuned_below_paper_nonoverlapping'] else 'no'}"
        f"; paired difference tuned - paper on the same held-out seeds: "
        f"{fmt_ci(r['loss_tuned_minus_paper'], r['loss_tuned_minus_paper_ci95'])}."
        f" Best tuning-seed loss: gradient {r['tuning_loss_best']:.5g}, random search "
        f"{r['random_search_tuning_loss_best']:.5g}; the gradient run "
        f"{f'reached the random search best after {g} simulations' if g is not None else 'did not reach the random search best within its budget'}"
        f", the random search found it after "
        f"{r['random_search_simulations_to_its_best']}. A gradient step (one forward-mode pass per seed carrying "
        f"{n_tan} tangent{'s' if n_tan > 1 else ''}) cost "
        f"{timing['gradient_step_cost_in_evaluations']:.3g}x a plain evaluation in wall time (medians, compilation "
        f"excluded), so in evaluation-equivalents the gradient run needed "
        f"{'n/a' if g is None else format(timing['gradient_evaluation_equivalents_to_reach_random_search_best'], '.4g')}"
        f" simulations to reach the random search's best.",
    ]
    return "\n".join(lines)


EXPERIMENT = Experiment(
    id="tune",
    title="Gradient-based tuning of estimator and controller hyperparameters",
    config_cls=TuneConfig,
    run=run,
    quick={"seeds": 4, "heldout_seeds": 16, "duration": 0.5, "steps": 6, "landscape_points": 5},
    source="the documents' hyperparameter values (CPX gamma = 150, paper §5) against gradient tuning",
    resumable=True,
    quick_cost_s=18, full_cost_s=56,
)
