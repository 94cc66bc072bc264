"""The eki-linear / eki-nonlinear reports' variant x schedule table (a helper of experiments.eki_examples; the
leading underscore keeps the registry from looking for experiments here)."""

from __future__ import annotations


def variants_table(cfg, r, timing) -> list[str]:
    """The report's variant x schedule rows, the thesis's fixed-step EKI first (wall times measured under
    whatever load the machine had, compilation included)."""
    if "variants" not in r:
        return []
    lines = ["", f"Variants ({cfg.compare_seeds} searches per row, seeds 1.., at most {cfg.iterations} iterations; "
             f"adaptive: the data-misfit controller, stopping at algorithmic time {cfg.adaptive_end:g}):", "",
             "| variant | schedule | stabilising fraction [95% CI] | mean iterations | mean forward evaluations "
             "| wall time (s) |", "|---|---|---|---|---|---|"]
    for key, row in r["variants"].items():
        variant, schedule = key.split("_")
        lo, hi = row["stabilizing_fraction_ci95"]
        ref = " (thesis)" if key == "eki_fixed" else ""
        lines.append(f"| {variant}{ref} | {schedule} | {row['stabilizing_fraction']:.3f} [{lo:.3f}, {hi:.3f}] | "
                     f"{row['mean_iterations']:.1f} | {row['mean_forward_evaluations']:.0f} | "
                     f"{timing.get('variants_wall_s', {}).get(key, float('nan')):.1f} |")
    return lines
