"""eki-dip's report and figure (a helper of experiments.eki_dip; the leading underscore keeps the registry from
looking for experiments here)."""

from __future__ import annotations

import numpy as np

from experiments import _eki_dip_variants as variants
from jaxdip.runner.results import fmt_ci
from jaxdip.runner.summaries import failure_lines


def figure(cfg, history, grad):
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 3.5))
    h_plot = np.exp(history[:, 0]) if cfg.log_performance else history[:, 0]
    ax.semilogy(np.arange(1, len(history) + 1), h_plot,
                label="EKI: ensemble mean" + (" (geometric) " if cfg.log_performance else " ") + "performance")
    if grad:
        sims_per_iter = cfg.ensemble * cfg.n_x0
        ax.semilogy(np.arange(1, cfg.grad_steps + 1) * cfg.grad_x0 / sims_per_iter,
                    np.exp(grad["loss_history"]), label="gradient: geometric-mean performance (x-axis: EKI-equivalent iterations)")
    ax.set_xlabel("iteration (J simulations each)")
    ax.set_ylabel("performance (2.24)")
    ax.legend(fontsize=8)
    ax.set_title("eki-dip search")
    return fig


def report(cfg, r, timing):
    j = r["judge"]
    lines = [
        f"Ensemble Kalman search ({cfg.variant}, {cfg.schedule} step) on the printed DIP: J = {cfg.ensemble}, up to {cfg.iterations} iterations "
        f"(stopped at {r['iterations']}), T = {cfg.T} s, t* = {cfg.t_star} s, gamma = {cfg.gamma}, state noise std "
        f"{cfg.noise_std} every {cfg.dt * 1e3:g} ms, its closed loops in {cfg.search_precision}. Wall time of the search: **{timing['search_wall_s']:.1f} s** on this "
        f"machine, CPU time {timing.get('search_cpu_s', float('nan')):.1f} s over its threads ({r['simulations']} closed-loop simulations of {cfg.T} s; the thesis used a 12-core cluster)."
        + (" Initial states drawn per member (Procedure 1)." if cfg.x0_draw == "per_member" else "")
        + (f" One free basis vector, its singular value fixed at {cfg.init_s[0]:g}." if cfg.free_vectors == 1
           else ""),
        "",
        f"- found P: basis rows {np.round(r['P_basis'], 4).tolist()}, singular values "
        f"{np.round(r['P_singular_values'], 1).tolist()}",
        f"- performance (2.24) over {cfg.eval_states} common initial states: start {r['performance_start']['mean']:.3g}"
        f" -> EKI {r['performance']['mean']:.3g} (failed {r['performance']['failed']})",
        f"- RP with gamma = {cfg.judge_gamma} from {cfg.seeds} random states in a ball of radius {cfg.judge_radius},"
        f" {cfg.judge_duration} s: stabilised fraction **{fmt_ci(r['stabilized_fraction'], r['stabilized_fraction_ci95'])}**"
        f", diverged {j['diverged']}",
        *failure_lines(j, cfg.seeds),
    ]
    g = r["gradient"]
    if g:
        lines += [
            "",
            f"Gradient search (Adam, {g['steps']} steps x {cfg.grad_x0} initial states = {g['simulations']} forward "
            f"simulations plus as many backward passes, {timing['gradient_search_wall_s']:.1f} s): performance {g['performance']['mean']:.3g}"
            f" (failed {g['performance']['failed']}); stabilised fraction "
            f"{fmt_ci(g['judge']['stabilized_fraction'], g['judge']['stabilized_fraction_ci95'])}.",
            f"EKI used {r['simulations']} simulations for {r['performance']['mean']:.3g}; the gradient search used "
            f"{g['simulations']} (x about 2 with backward passes) for {g['performance']['mean']:.3g}: "
            + ("it reaches the EKI's performance." if g["performance"]["mean"] <= r["performance"]["mean"] else
               f"it falls short by a factor {g['performance']['mean'] / r['performance']['mean']:.3g}."),
        ]
    if "variants" in r:
        lines += variants.table(cfg, r["variants"], timing.get("variants_wall_s", {}))
    return "\n".join(lines)
