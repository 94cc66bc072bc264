"""Figures shared by experiments' reports."""

from __future__ import annotations

import numpy as np


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
    return fig
