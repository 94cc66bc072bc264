"""lorenz-mhe's figures: the error per trial of each method, and one trial's xL estimates."""

from __future__ import annotations

import numpy as np

from jaxdip.scenarios.lorenz_mhe import METHODS

LABELS = {"cpx": "CPX", "scpx": "SCPX", "ekf": "EKF", "ekf2": "EKF2"}


def figures(cfg, per_trial: dict, rec) -> dict:
    import matplotlib.pyplot as plt

    fig1, ax = plt.subplots(figsize=(8, 4))
    data, labels = [], []
    for m in METHODS:
        e, ex = per_trial[m]
        data += [e, ex]
        labels += [f"{LABELS[m]} e", f"{LABELS[m]} ex"]
    ax.boxplot([d if len(d) else [np.nan] for d in data], tick_labels=labels, showfliers=True)
    ax.set_ylabel("time-averaged error")
    ax.set_title(f"lorenz-mhe: error per trial ({cfg.seeds} trials; cf. thesis Fig. 1.1)")
    ax.grid(alpha=0.3)
    plt.setp(ax.get_xticklabels(), rotation=30)

    t, (xl, cpx_l, scpx_l, ekf_l, ekf2_l) = rec
    fig2, ax = plt.subplots(figsize=(9, 3.5))
    ax.plot(t, xl, "k", lw=1.4, label="true xL")
    ax.plot(t, scpx_l, lw=0.9, label="SCPX")
    ax.plot(t, ekf_l, lw=0.9, label="EKF")
    ax.set_xlabel("time")
    ax.set_ylabel("xL")
    ax.set_title(f"trial {cfg.figure_trial}: SCPX and EKF estimates of xL (cf. thesis Fig. 1.2)")
    ax.legend(loc="upper right", fontsize=8)
    ax.grid(alpha=0.3)
    return {"errors_per_method": fig1, "xL_scpx_vs_ekf": fig2}
