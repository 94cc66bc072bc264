"""The ensemble Kalman experiments' variant table (helpers of experiments.eki_examples and experiments.eki_dip; the
leading underscore keeps the registry from looking for experiments here).

A table is a set of config readings (changes to the experiment's config, by row key such as ``eki_fixed``) run
inside one experiment beside its main search: ``run_readings`` runs them, the rows go to ``results["variants"]``
and their wall times to ``timing["variants_wall_s"]`` (never to ``results``: they depend on the machine's load),
and ``variants_table`` writes the report's rows, the thesis's fixed-step EKI marked.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Callable, Sequence

REFERENCE = "eki_fixed"  # the thesis's reading: perturbed-observation EKI with the fixed step dt = 1


def run_readings(cfg, readings: dict[str, dict], one: Callable) -> tuple[dict, dict]:
    """Row and wall time per reading: ``one(key, changed config) -> (row dict, wall seconds)``, in the order of
    ``readings`` (the changed config is ``dataclasses.replace(cfg, **readings[key])``)."""
    rows, walls = {}, {}
    for key, changes in readings.items():
        rows[key], walls[key] = one(key, dataclasses.replace(cfg, **changes))
    return rows, walls


def fraction(name: str) -> Callable:
    """A column: ``row[name]`` with its 95% interval ``row[name + '_ci95']`` (a dash when the row has none)."""

    def cell(key, row, wall):
        if row.get(name) is None:
            return "-"
        lo, hi = row[f"{name}_ci95"]
        return f"{row[name]:.3f} [{lo:.3f}, {hi:.3f}]"

    return cell


def wall_time(key, row, wall) -> str:
    """A column: the row's wall time (s)."""
    return f"{wall:.1f}" if wall is not None and math.isfinite(wall) else "-"


def variants_table(intro: str, rows: dict, walls: dict, columns: Sequence[tuple[str, Callable]]) -> list[str]:
    """The report's lines: ``intro``, then a markdown table with one row per entry of ``rows`` and one column per
    ``(header, cell(key, row, wall) -> str)``; the first column names the reading, the thesis's marked."""
    if not rows:
        return []
    lines = ["", intro, "", "| reading | " + " | ".join(h for h, _ in columns) + " |",
             "|---" * (len(columns) + 1) + "|"]
    for key, row in rows.items():
        name = key.replace("_", " ") + (" (thesis)" if key == REFERENCE else "")
        lines.append(f"| {name} | " + " | ".join(cell(key, row, walls.get(key)) for _, cell in columns) + " |")
    return lines
