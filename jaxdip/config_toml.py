"""Configs written as TOML: a run's resolved ``config.toml`` and the documented defaults of ``configs/<id>.toml``
(``jaxdip config <id>``). Re-exported by ``jaxdip.config``."""

from __future__ import annotations

import dataclasses
import math


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        if math.isnan(v):
            return "nan"
        return repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(e) for e in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def to_toml(d: dict, header: str = "") -> str:
    lines = [header] if header else []
    tables = []
    for k, v in d.items():
        if isinstance(v, dict):
            tables.append((k, v))
        else:
            lines.append(f"{k} = {_toml_value(v)}")
    for name, t in tables:
        lines.append("")
        lines.append(f"[{name}]")
        for k, v in t.items():
            lines.append(f"{k} = {_toml_value(v)}")
    return "\n".join(lines) + "\n"


def documented_toml(cfg, title: str = "", source: str = "", note: str = "") -> str:
    """A config as TOML with each key's doc as a comment above it (the format of configs/<id>.toml, written by
    ``jaxdip config --write``): ``title``, ``source`` and ``note`` head it as comment lines."""
    lines = [f"# {title}"] if title else []
    if source:
        lines.append(f"# Reproduces: {source}")
    if note:
        lines.append(f"# {note}")
    if lines:
        lines.append("")
    for f in dataclasses.fields(cfg):
        doc = f.metadata.get("doc", "")
        if doc:
            lines.append(f"# {doc}")
        lines.append(f"{f.name} = {_toml_value(getattr(cfg, f.name))}")
    return "\n".join(lines) + "\n"
