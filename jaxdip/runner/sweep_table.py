"""A sweep's summary: each headline result against the swept values, as ``sweep.json``, ``sweep.md`` and one
figure per headline result.

A headline result is a number in a run's ``results`` (at any depth, named by its dotted path such as
``cpx.theta_var``) that has its 95% interval beside it (``<name>_ci95``): the statistics the experiments report
with intervals over seeds. Each has a row in the table, and a figure (error bars against the first swept key,
one line per value of the others) unless it is the same at every point (rendering is the slow part of a cheap
sweep, and a flat line says nothing the table does not). ``sweep.json`` also lists every other number of ``results`` (counts, criteria,
single-trial figures) per point, without an interval; lists (an experiment's own inner sweep) are left out.
"""

from __future__ import annotations

import io
import json
import math
import re
from typing import Any

from jaxdip.runner.results import fmt_ci

CI = "_ci95"


def _number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _interval(v) -> bool:
    return isinstance(v, list) and len(v) == 2 and all(_number(c) for c in v)


def scalars(results: dict, prefix: str = "") -> dict[str, tuple[float, list[float] | None]]:
    """Every number of ``results`` by dotted path, with its ``_ci95`` interval where it has one."""
    out = {}
    for k, v in results.items():
        path = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(scalars(v, f"{path}."))
        elif _number(v):
            ci = results.get(f"{k}{CI}")
            out[path] = (v, ci if _interval(ci) else None)
    return out


def table(per_point: list[dict]) -> dict:
    """``{path: {"value": [...], "ci95": [...], "headline": bool}}`` over the points, in the points' order
    (``None`` where a point lacks the statistic); headline: an interval at some point."""
    paths: list[str] = []
    for s in per_point:
        paths += [p for p in s if p not in paths]
    out = {}
    for p in paths:
        vals = [s.get(p, (None, None)) for s in per_point]
        out[p] = {"value": [v for v, _ in vals], "ci95": [c for _, c in vals],
                  "headline": any(c is not None for _, c in vals)}
    return out


def _axis_numbers(values: list[Any]) -> list[float] | None:
    return [float(v) for v in values] if all(_number(v) for v in values) else None


def figure(stat: str, rows: dict, axes: list[tuple[str, list[str]]], points: list[dict]):
    """The statistic against the first swept key, one line per combination of the others, with error bars."""
    from matplotlib.figure import Figure

    key = axes[0][0]
    fig = Figure(figsize=(6, 3.6))  # not pyplot's: nothing to close, and no global state between points
    ax = fig.add_subplot()
    fig.subplots_adjust(left=0.14, right=0.97, bottom=0.14, top=0.9)  # tight_layout renders twice
    groups: dict[str, list[int]] = {}
    for i, p in enumerate(points):
        label = ", ".join(f"{k}={p['texts'][k]}" for k, _ in axes[1:])
        groups.setdefault(label, []).append(i)
    xs_all = _axis_numbers([p["values"][key] for p in points])
    for label, idx in groups.items():
        xs = [xs_all[i] for i in idx] if xs_all else list(range(len(idx)))
        ys = [rows["value"][i] for i in idx]
        keep = [j for j, y in enumerate(ys) if y is not None]
        lo = [max(ys[j] - rows["ci95"][idx[j]][0], 0.0) if rows["ci95"][idx[j]] else 0.0 for j in keep]
        hi = [max(rows["ci95"][idx[j]][1] - ys[j], 0.0) if rows["ci95"][idx[j]] else 0.0 for j in keep]
        ax.errorbar([xs[j] for j in keep], [ys[j] for j in keep], yerr=[lo, hi], marker="o", capsize=3,
                    label=label or None)
    if xs_all is None:
        first = [points[i]["texts"][key] for i in next(iter(groups.values()))]
        ax.set_xticks(range(len(first)), first)
    elif min(xs_all) > 0 and max(xs_all) / min(xs_all) >= 100:
        ax.set_xscale("log")
    if len(groups) > 1:
        ax.legend(fontsize=8)
    ax.set_xlabel(key)
    ax.set_ylabel(stat)
    ax.set_title(f"{stat} (95% intervals)")
    ax.grid(alpha=0.3)
    return fig


def varies(row: dict) -> bool:
    """A headline result that is not the same at every point: it gets a figure (the others a table row only)."""
    return row["headline"] and len({json.dumps([v, c]) for v, c in zip(row["value"], row["ci95"])}) > 1


def figure_name(stat: str) -> str:
    return "sweep-" + re.sub(r"[^A-Za-z0-9._-]", "_", stat) + ".png"


def markdown(exp_id: str, axes: list[tuple[str, list[str]]], points: list[dict], rows: dict,
             compilations: list[int | None]) -> str:
    keys = [k for k, _ in axes]
    head = [f"# Sweep of {exp_id} over " + " x ".join(f"{k} ({len(v)} values)" for k, v in axes), "",
            f"{len(points)} points, each a complete run in points/<point>/. Headline results (those with a 95% "
            "interval over seeds), one column per point; sweep.json has every number of the results.", ""]
    cols = [",".join(f"{k}={p['texts'][k]}" for k in keys) for p in points]
    lines = ["| result | " + " | ".join(cols) + " |", "|---" * (len(cols) + 1) + "|"]
    for stat, r in rows.items():
        if r["headline"]:
            lines.append(f"| {stat} | " + " | ".join(fmt_ci(v, c, 4) if v is not None else "n/a"
                                                      for v, c in zip(r["value"], r["ci95"])) + " |")
    ran = [c for c in compilations if c is not None]
    comp = ("Programs built per point (this invocation; kept points are not run): "
            + ", ".join("kept" if c is None else str(c) for c in compilations)
            + (f"; {sum(ran)} in all." if ran else "."))
    figs = [f"![{stat}]({figure_name(stat)})" for stat, r in rows.items() if varies(r)]
    same = [stat for stat, r in rows.items() if r["headline"] and not varies(r)]
    note = [f"The same at every point, so without a figure: {', '.join(same)}.", ""] if same else []
    return "\n".join(head + lines + ["", comp, "", "## Figures", ""] + note + figs) + "\n"


def summary_files(exp_id: str, axes: list[tuple[str, list[str]]], points: list[dict], results: list[dict],
                  compilations: list[int | None], programs: list[dict]) -> dict[str, str | bytes]:
    """The sweep's summary files by name: sweep.json, sweep.md and one PNG per headline result. ``points``: per
    point its ``name``, ``texts`` and ``values`` (the swept keys' values as given and as read); ``results``:
    each point's metrics.json ``results``."""
    rows = table([scalars(r) for r in results])
    doc = {"experiment": exp_id, "swept": [{"key": k, "values": v} for k, v in axes],
           "points": [{"name": p["name"], "folder": f"points/{p['name']}", "values": p["values"]} for p in points],
           "table": rows,
           # not a result: a resumed sweep builds fewer programs than an uninterrupted one
           "compilations": {"per_point": compilations, "programs": programs,
                            "total": sum(c for c in compilations if c is not None)}}
    files: dict[str, str | bytes] = {"sweep.json": json.dumps(doc, indent=1) + "\n",
                                     "sweep.md": markdown(exp_id, axes, points, rows, compilations)}
    for stat, r in rows.items():
        if varies(r):
            fig = figure(stat, r, axes, points)
            buf = io.BytesIO()
            fig.savefig(buf, format="png", dpi=100)
            files[figure_name(stat)] = buf.getvalue()
    return files

