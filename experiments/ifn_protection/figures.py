"""ifn-protection: the figures (titled and labelled for a reader who knows the biology, not the code)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxdip import program_cache
from jaxdip.immune.controls import breakpoints
from jaxdip.immune.costs import RadialCost


@program_cache.jit
def _raster(model, control, t, rho):
    """The indicator of a control on a (t, |x|) grid (x along the first axis)."""
    key = jax.random.PRNGKey(0)

    def at(tt, r):
        x = jnp.zeros(model.dim).at[0].set(r)
        return control.protected(model, tt, x, key, key)

    return jax.vmap(lambda tt: jax.vmap(lambda r: at(tt, r))(rho))(t)


PANEL_TITLES = {"uniform": "same cost everywhere", "distance": "cost grows with distance",
                "shell": "a costly ring around the infection", "flat": "flat signal: many optimal choices"}
TIME_LABEL = "hours since the infected cell burst"
DIST_LABEL = "distance from the infected cell (cell diameters)"


def fig_optimal_sets(model, checks, flat, costs):
    import matplotlib.pyplot as plt

    panels = [(k, checks[k]["level_set"], checks[k]["ball"], costs[k]) for k in checks]
    panels.append(("flat", flat["switch"], None, flat["cost"]))
    # the plot must hold every level set (they end where their own t_max is) and every disc
    ends = [np.nanmax(np.asarray(breakpoints(model, p[1]))) for p in panels]
    t_end = 1.08 * max(max(ends), *(float(b.t1) for _, _, b, _ in panels if b is not None))
    t = np.linspace(1e-4, t_end, 360)
    rho = np.linspace(0.0, 20.0, 240)
    fig, axes = plt.subplots(1, len(panels), figsize=(4.2 * len(panels), 5.0), sharey=True)
    for ax, (name, ls, ball, cost) in zip(axes, panels):
        ind = np.asarray(_raster(model, ls, jnp.asarray(t), jnp.asarray(rho))).astype(float)
        ax.contourf(t, rho, ind.T, levels=[0.5, 1.5], colors=["C0"], alpha=0.55)
        ax.contour(t, rho, ind.T, levels=[0.5], colors=["C0"], linewidths=1.0)
        ax.plot([], [], color="C0", lw=6, alpha=0.55, label="optimal: protect while virus density > threshold")
        if ball is not None:
            ax.plot([float(ball.t0), float(ball.t0), float(ball.t1), float(ball.t1)],
                    [0, float(ball.radius), float(ball.radius), 0], "C3", lw=1.5,
                    label="best fixed disc for a fixed time")
        if isinstance(cost, RadialCost) and float(cost.extra) > 0:
            ax.axhspan(float(cost.inner), float(cost.outer), color="C1", alpha=0.15,
                       label=f"ring where protection costs {1 + float(cost.extra):g}x")
        if name == "flat":
            sub = np.asarray(_raster(model, checks["uniform"]["level_set"], jnp.asarray(t), jnp.asarray(rho)))
            ax.contour(t, rho, sub.T.astype(float), levels=[0.5], colors=["k"], linewidths=1.0,
                       linestyles="--")
            ax.plot([], [], "k--", lw=1, label="one of many equally good subsets")
            ax.plot([], [], " ", label=f"(all of the shaded region over-protects;\n each cell in it responding with\n"
                                       f" probability {flat['q']:.2f} is also optimal)")
        ax.set_title(PANEL_TITLES.get(name, name))
        ax.set_xlabel(TIME_LABEL)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.16), frameon=False)
    axes[0].set_ylabel(DIST_LABEL)
    fig.suptitle("Which cells to protect, and when: each policy prevents the same number of infections")
    return fig


def fig_F(curves, V, th):
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.8, 4.2))
    for i, (name, (x, g, lo, hi)) in enumerate(curves.items()):
        ax.plot(np.exp(x), g, color=f"C{i}", label=PANEL_TITLES.get(name, name))
        ax.fill_between(np.exp(x), lo, hi, color=f"C{i}", alpha=0.3, lw=0)
        ax.axvline(float(np.exp(th[name].log_r)), color=f"C{i}", ls=":", lw=1)
    ax.axhline(V, color="k", lw=0.8, label=f"target: {V:g} infections prevented")
    ax.set_xscale("log")
    ax.set_xlabel("threshold r: infections prevented per cell-hour of protection at the region's edge")
    ax.set_ylabel("infections prevented per infected cell")
    ax.set_title("Protecting wherever the benefit/cost ratio exceeds r\n(dotted: the threshold that meets the target)",
                 fontsize=10)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    return fig


def fig_mc(mc, R0):
    """Left: E[I] by simulation and by formula (4.4). Right: the simulation's relative deviation from the formula
    (95%), per infected cell and per virion that enters a cell (which removes the noise all rows share)."""
    import matplotlib.pyplot as plt

    names = list(mc)
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(11, 0.32 * len(names) + 1.6), sharey=True,
                                  gridspec_kw={"width_ratios": [1, 1.2]})
    y = np.arange(len(names))[::-1]
    for yi, n in zip(y, names):
        r = mc[n]
        first = yi == y[0]
        ax.errorbar(r["E_I_mc"], yi, xerr=[[r["E_I_mc"] - r["E_I_ci95"][0]], [r["E_I_ci95"][1] - r["E_I_mc"]]],
                    fmt="o", color="C0", ms=3, capsize=2, label="simulation, 95% interval" if first else None)
        if "E_I_quadrature" not in r:
            continue
        ax.plot(r["E_I_quadrature"], yi, "x", color="C3", ms=7, label="formula (4.4)" if first else None)
        for key, ref, dy, col, lab in (("E_I", "E_I_quadrature", 0.15, "C0", "per infected cell"),
                                       ("P_infect_given_entry", "P_infect_given_entry_quadrature", -0.15, "C2",
                                        "per virion entering a cell")):
            if ref not in r or r[ref] <= 0:
                continue
            q = r[ref]
            m, (lo, hi) = r[key + "_mc"], r[key + "_ci95"]
            ax2.errorbar(100 * (m / q - 1), yi + dy, xerr=[[100 * (m - lo) / q], [100 * (hi - m) / q]], fmt="o",
                         color=col, ms=3, capsize=2, label=lab if first else None)
    ax.set_yticks(y, names, fontsize=7)
    ax.axvline(R0, color="k", lw=0.6)
    ax.set_xlabel("new infections caused by one infected cell (expected)")
    ax.set_title("Simulated infections against the formula", fontsize=10)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    ax2.axvline(0.0, color="C3", lw=1)
    ax2.set_xlabel("simulation / formula - 1 (%), 95% interval")
    ax2.legend(fontsize=8)
    ax2.grid(alpha=0.3)
    return fig


def fig_costs(checks, flat_res):
    """Protection used by each policy that brings E[I] to the target, relative to the optimal policy's (for the
    flat signal, to the least possible, V / r_bar; its threshold switch over-shoots the target)."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 5.2))
    labels = list(checks) + ["flat"]
    for i, name in enumerate(checks):
        r = checks[name]["results"]
        base = r["level_set"]["h"]
        ax.bar(i - 0.2, 1.0, 0.35, color="C0", label="optimal (threshold on virus density)" if i == 0 else None)
        ax.bar(i + 0.2, r["ball"]["h"] / base, 0.35, color="C3",
               label="best fixed disc for a fixed time" if i == 0 else None)
        p = [m["h"] / base for m in r["perturbations"]]
        ax.plot([i] * len(p), p, "k.", ms=5, label="random variations of the optimum" if i == 0 and p else None)
    j = len(checks)
    base = flat_res["optimal_cost_V_over_r_bar"]
    names = {"threshold switch L_r_bar": "all cells above threshold (over-shoots)",
             "stochastic response (q on the flat set)": "each such cell with probability q",
             "uniform-cost level set (inner part)": "an inner part of that region",
             "flat set after t_c": "that region after a delay"}
    for k, (n, m) in enumerate(flat_res["sets"].items()):
        ax.bar(j - 0.3 + 0.15 * k, m["h"] / base, 0.14, color=f"C{4 + k}", label=names.get(n, n))
    ax.set_xticks(range(len(labels)), [PANEL_TITLES.get(n, n).replace(" (", "\n(").replace(": ", ":\n")
                                       for n in labels], fontsize=8)
    ax.set_ylabel("cost of the protection (cell-hours, each weighted\nby its cost h), relative to the optimal policy")
    ax.set_title("Protection needed to bring new infections to the target", fontsize=10)
    ax.axhline(1.0, color="k", lw=0.6)
    ax.legend(fontsize=7, ncol=2, loc="upper center", bbox_to_anchor=(0.5, -0.16), frameon=False)
    ax.grid(alpha=0.3, axis="y")
    return fig


def fig_extinction(gen_plot):
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 4))
    for i, (label, (ext, iters)) in enumerate(gen_plot.items()):
        g = np.arange(1, len(ext) + 1)
        m = np.array([e["extinct"] for e in ext])
        lo = m - np.array([e["extinct_ci95"][0] for e in ext])
        hi = np.array([e["extinct_ci95"][1] for e in ext]) - m
        ax.errorbar(g, m, yerr=[lo, hi], fmt="o", color=f"C{i}", ms=3, capsize=2,
                    label=f"{label} new infections per cell")
        ax.plot(g, iters, "-", color=f"C{i}", lw=1)
    ax.set_xlabel("generation of infected cells")
    ax.set_ylabel("probability the infection has died out")
    ax.set_title("Will the infection die out? (dots: simulation, 95%; lines: theory)", fontsize=10)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    return fig


def fig_tuning(tq, tm, x):
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 3.8))
    ax.plot(np.exp(tq.trace_log_r), label="gradient steps on the formula")
    ax.plot(np.exp(tm.trace_log_r), label="gradient steps on simulated virions", alpha=0.8)
    ax.axhline(float(np.exp(x)), color="k", ls="--", lw=1, label="threshold found by bisection")
    ax.set_yscale("log")
    ax.set_xlabel("optimiser step (Adam)")
    ax.set_ylabel("threshold r (infections prevented\nper cell-hour at the edge)")
    ax.set_title("Learning the threshold from the target alone", fontsize=10)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    return fig
