"""The scale of a run, stated in its outputs: a ``--quick`` run's report opens with one generated line naming
what its quick overrides changed (seeds, duration, ...) against the full run's defaults, and why its numbers
differ from the full run's (the README quotes those); metrics.json says ``"scale": "quick"`` beside, never
inside, ``results``, so the results of a run do not depend on how its scale is described. A run whose own
values of those keys (``--seeds 100``) differ from the defaults says so the same way (``"custom"``).

The line is made here from the ``Experiment``'s ``quick`` overrides and its config class's defaults, never
written by an experiment, so every experiment's quick report says it the same way.
"""

from __future__ import annotations

import dataclasses
import re
import typing
from typing import Any

QUICK, CUSTOM, FULL = "quick", "custom", "full"  # metrics.json's "scale"


def _flat(d: dict, prefix: str = "") -> dict[str, Any]:
    out = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(_flat(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


def _field_doc(cls, dotted: str) -> str:
    """The ``doc`` of a (possibly nested) config field, "" when there is none."""
    *tables, name = dotted.split(".")
    for t in tables:
        cls = typing.get_type_hints(cls).get(t)
        if not isinstance(cls, type) or not dataclasses.is_dataclass(cls):
            return ""
    f = {f.name: f for f in dataclasses.fields(cls)}.get(name)
    return f.metadata.get("doc", "") if f is not None else ""


UNITS = ("s", "ms", "min", "h", "Hz", "m", "rad")  # a doc's closing "(s)" is a unit; "(c)" or "(n)" is not


def _unit(doc: str) -> str:
    """The unit a field's doc ends with, "(s)" or "(h)", as " s"; "" for a doc without one."""
    m = re.search(r"\(([^()]*)\)\s*$", doc)
    return f" {m.group(1)}" if m and m.group(1) in UNITS else ""


def _value(v, unit: str = "") -> str:
    if isinstance(v, float):
        return f"{v:g}{unit}"
    return f"{v}{unit}"


def quick_changes(exp, cfg) -> list[tuple[str, Any, Any]]:
    """(key, this run's value, the full run's default) for every key of ``exp.quick`` whose value in ``cfg``
    (the resolved config) differs from the config class's default: what makes this run smaller."""
    if not exp.quick or not dataclasses.is_dataclass(cfg):  # a config without quick overrides has one scale
        return []
    full = _flat(dataclasses.asdict(exp.config_cls()))
    used = _flat(dataclasses.asdict(cfg))
    return [(k, used[k], full[k]) for k in _flat(exp.quick) if k in used and used[k] != full.get(k)]


def scale(exp, cfg, quick: bool = False) -> str:
    """How the run's size compares with the full run's, from its resolved config: ``"full"`` when every key the
    quick overrides touch has its default; ``"quick"`` with ``--quick`` (``quick``) or a config that holds every
    quick override (a quick run's own config.toml run again); ``"custom"`` for other values of those keys
    (``--seeds 100``)."""
    if not quick_changes(exp, cfg):
        return FULL
    used = _flat(dataclasses.asdict(cfg))
    return QUICK if quick or all(used.get(k) == v for k, v in _flat(exp.quick).items()) else CUSTOM


def scale_line(exp, cfg, kind: str) -> str:
    """The line that opens the report of a run at ``kind`` (``scale``'s) scale: what differs from the full
    run's config, and what that means for its numbers; "" for a full run."""
    if kind == FULL:
        return ""
    parts = []
    for key, v, d in quick_changes(exp, cfg):
        unit = _unit(_field_doc(exp.config_cls, key))
        parts.append(f"{key} {_value(v, unit)} (full run: {_value(d, unit)})")
    head, why = (("**Quick scale** (the `--quick` overrides)", "smaller") if kind == QUICK
                 else ("**Changed scale**", "different"))
    return (f"{head}: {', '.join(parts)}. Its numbers differ from the full run's (`jaxdip run {exp.id}`) "
            f"because of the {why} scale.")
