"""dip-cpx-ldf's figures: one trial's velocity estimates (thesis Fig. 3.5) and the CPX gamma sweep."""

from __future__ import annotations

import numpy as np

from jaxdip.runner.results import floats
from jaxdip.plants import dip


def velocity_figure(cfg, tr, gamma_crit):
    import matplotlib.pyplot as plt

    i = dip.STATE_NAMES.index("theta_dot")
    t = np.arange(tr["x"].shape[0]) * cfg.dt
    win = t <= min(1.0, t[-1])
    fig, axes = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    ax = axes[0]
    ax.plot(t[win], tr["ldf"][win, i], lw=0.9, label="LDF")
    ax.plot(t[win], tr["cpx"][win, i], lw=0.9, label=f"CPX, gamma = {cfg.cpx_gamma:g}")
    ax.plot(t[win], tr["x"][win, i], "k", lw=1.2, label="truth")
    ax.set_ylabel("theta_dot (rad/s)")
    ax.legend(fontsize=8, loc="upper right")
    ax.set_title("one CPX-controlled trial: estimates of theta_dot from the same encoder readings (cf. Fig. 3.5)")
    ax = axes[1]
    ax.plot(t[win], tr["cpx_crit"][win, i], lw=0.7, color="C3", label=f"CPX, gamma = {gamma_crit:.0f} (criterion)")
    ax.plot(t[win], tr["x"][win, i], "k", lw=1.2, label="truth")
    ax.set_ylabel("theta_dot (rad/s)")
    ax.set_xlabel("time (s)")
    ax.legend(fontsize=8, loc="upper right")
    for a in axes:
        a.grid(alpha=0.3)
    return fig


def sweep_figure(cfg, sw, gamma_crit):
    import matplotlib.pyplot as plt

    g = np.asarray(sw["gamma"])
    v = floats(sw["theta_var"])
    ci = floats(sw["theta_var_ci95"])
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
    a1.fill_between(g, ci[:, 0], ci[:, 1], alpha=0.3)
    a1.plot(g, v, "o-", ms=3)
    a1.set_yscale("log")
    a1.set_ylabel("var theta (deg^2), non-diverged")
    a2.plot(g, sw["diverged_fraction"], "o-", ms=3, color="C3")
    a2.set_ylabel("diverged fraction")
    a2.set_ylim(-0.03, 1.03)
    a2.set_xlabel("CPX gamma")
    for a in (a1, a2):
        a.set_xscale("log")
        a.axvline(gamma_crit, color="k", ls="--", lw=1, label=f"Prop. 1.4.3 criterion {gamma_crit:.0f}")
        a.axvline(cfg.cpx_gamma, color="C2", ls=":", lw=1, label=f"paper's gamma {cfg.cpx_gamma:g}")
        a.grid(alpha=0.3, which="both")
    a1.legend(fontsize=8)
    a1.set_title(f"CPX gamma sweep: {sw['seeds']} seeds per gamma, {cfg.duration} s")
    return fig
