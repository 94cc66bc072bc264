"""Typed experiment configs loaded from TOML and validated before anything compiles.

An experiment's config is a dataclass whose defaults are the documents' values. Each field may carry
``check`` metadata (see ``positive``, ``nonneg``, ...). ``load`` merges, in order: the defaults, the
experiment's ``--quick`` overrides, a TOML file, ``--seeds`` and ``--set key=value`` pairs (so what the user
wrote is never silently replaced by ``--quick``); then checks every key's type and constraint and the config's
own ``validate()``. Any problem raises ``ConfigError(key, why)``, which the CLI prints as one line
``error: <key>: <why>``.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import os
import types
import typing
from typing import Any

import tomllib

INT_MAX = 2**63 - 1
INT_MIN = -(2**63)


class ConfigError(ValueError):
    def __init__(self, key: str, why: str):
        super().__init__(f"{key}: {why}")
        self.key = key
        self.why = why


# ---- constraints ----------------------------------------------------------------------------------------


def _numbers(v):
    if isinstance(v, (list, tuple)):
        for e in v:
            yield from _numbers(e)
    elif isinstance(v, (int, float)) and not isinstance(v, bool):
        yield v


def positive(v):
    if any(not (x > 0) or math.isnan(x) for x in _numbers(v)):
        return "must be positive"


def nonneg(v):
    if any(not (x >= 0) or math.isnan(x) for x in _numbers(v)):
        return "must be non-negative"


def finite(v):
    if any(not math.isfinite(x) for x in _numbers(v)):
        return "must be finite"


def positive_finite(v):
    return finite(v) or positive(v)


def nonneg_finite(v):
    return finite(v) or nonneg(v)


def one_of(*choices):
    def check(v):
        if v not in choices:
            return f"must be one of {', '.join(map(repr, choices))}"

    return check


def length(n):
    def check(v):
        if len(v) != n:
            return f"must have {n} entries, got {len(v)}"

    return check


def field(default, *checks, doc: str = ""):
    """A config field with constraints; mutable defaults are copied per instance."""
    meta = {"checks": checks, "doc": doc}
    if isinstance(default, (list, dict)):
        import copy

        return dataclasses.field(default_factory=lambda: copy.deepcopy(default), metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


# ---- type checking ---------------------------------------------------------------------------------------


def _check_type(key: str, value: Any, tp) -> Any:
    origin = typing.get_origin(tp)
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(key, f"expected a number, got {type(value).__name__} {value!r}")
        return float(value)
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and value.is_integer():
                value = int(value)
            else:
                raise ConfigError(key, f"expected an integer, got {value!r}")
        if not INT_MIN <= value <= INT_MAX:
            # JAX keys, counters and shapes are 64-bit at most; a larger value would overflow deep inside a compile
            raise ConfigError(key, f"{value} is out of range (at most {INT_MAX})")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(key, f"expected true or false, got {value!r}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(key, f"expected a string, got {value!r}")
        return value
    if origin is list:
        (inner,) = typing.get_args(tp)
        if not isinstance(value, list):
            raise ConfigError(key, f"expected a list, got {value!r}")
        rows = [v for v in value if isinstance(v, list)]
        if rows and len(rows) != len(value):
            raise ConfigError(key, "mixes numbers and lists: give a flat list or a matrix (a list of rows)")
        if rows and len({len(r) for r in rows}) > 1:
            lens = [len(r) for r in rows]
            raise ConfigError(key, f"ragged matrix: rows have {', '.join(map(str, lens))} entries")
        return [_check_type(f"{key}[{i}]", v, inner) for i, v in enumerate(value)]
    if origin is typing.Union or origin is types.UnionType:  # e.g. list[float] | list[list[float]]: first that fits wins
        errors = []
        for option in typing.get_args(tp):
            try:
                return _check_type(key, value, option)
            except ConfigError as e:
                errors.append(e.why)
        raise ConfigError(key, " or ".join(dict.fromkeys(errors)))
    raise TypeError(f"unsupported config type {tp!r} for {key}")


def _hints(cls):
    return typing.get_type_hints(cls)


def from_dict(cls, data: dict, prefix: str = ""):
    """Build a config dataclass from nested dicts, checking keys, types and constraints."""
    fields = {f.name: f for f in dataclasses.fields(cls)}
    hints = _hints(cls)
    unknown = [k for k in data if k not in fields]
    if unknown:
        k = unknown[0]
        close = difflib.get_close_matches(k, fields, n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else f" (known keys: {', '.join(fields)})"
        raise ConfigError(prefix + k, "unknown key" + hint)
    kwargs = {}
    for name, f in fields.items():
        key = prefix + name
        tp = hints[name]
        if dataclasses.is_dataclass(tp):
            sub = data.get(name, {})
            if not isinstance(sub, dict):
                raise ConfigError(key, "expected a table")
            kwargs[name] = from_dict(tp, sub, key + ".")
            continue
        if name in data:
            value = _check_type(key, data[name], tp)
        else:
            value = f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default
        for check in f.metadata.get("checks", ()):
            why = check(value)
            if why:
                raise ConfigError(key, why)
        kwargs[name] = value
    cfg = cls(**kwargs)
    if hasattr(cfg, "validate"):
        cfg.validate()
    return cfg


def to_dict(cfg) -> dict:
    return dataclasses.asdict(cfg)


def _set_path(d: dict, dotted: str, value):
    parts = dotted.split(".")
    for p in parts[:-1]:
        d = d.setdefault(p, {})
        if not isinstance(d, dict):
            raise ConfigError(dotted, "is not a table")
    d[parts[-1]] = value


def parse_set(item: str):
    """``key=value`` with a TOML value (numbers, true/false, [lists], "strings"); bare words are strings."""
    if "=" not in item:
        raise ConfigError("--set", f"expects key=value, got {item!r}")
    key, raw = item.split("=", 1)
    key = key.strip()
    if not key or any(not part for part in key.split(".")):
        raise ConfigError("--set", f"expects key=value, got {item!r}")
    try:
        parsed = tomllib.loads(f"v = {raw}")
        # a value that smuggles in more TOML lines ("1\nseeds = 5") is not one value: keep it as text
        value = parsed["v"] if list(parsed) == ["v"] else raw
    except (tomllib.TOMLDecodeError, RecursionError):
        value = raw
    return key, value


def _merge(base: dict, over: dict):
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(base.get(k), dict):
            _merge(base[k], v)
        else:
            base[k] = v


MAX_CONFIG_BYTES = 1 << 20  # a config is a page of numbers; anything larger is the wrong file


def read_toml(path: str) -> dict:
    """A TOML file as a dict, every failure (missing, a folder, unreadable, binary, not TOML) a ConfigError."""
    try:
        if os.path.isdir(path):
            raise ConfigError("--config", f"{path} is a folder, not a TOML file")
        with open(path, "rb") as fh:
            raw = fh.read(MAX_CONFIG_BYTES + 1)
    except FileNotFoundError:
        raise ConfigError("--config", f"no such file: {path}") from None
    except OSError as e:
        raise ConfigError("--config", f"cannot read {path}: {e.strerror or e}") from None
    if len(raw) > MAX_CONFIG_BYTES:
        raise ConfigError("--config", f"{path} is larger than {MAX_CONFIG_BYTES // 1024} KiB: not a config file")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as e:
        raise ConfigError("--config", f"{path} is not UTF-8 text (byte {e.start}): not a TOML config") from None
    if "\x00" in text:
        raise ConfigError("--config", f"{path} holds NUL bytes: not a TOML config")
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ConfigError("--config", f"not valid TOML: {e}") from None
    except RecursionError:
        raise ConfigError("--config", "not valid TOML: nested too deeply") from None


# A written config.toml's table of run settings that change results besides the config (the compile effort):
# read back by ``run_table`` so that re-running a run's own config.toml gives the same last bits
RUN_TABLE = "jaxdip"
EFFORTS = ("fast", "balanced", "full")


def _run_table(data: dict) -> dict:
    run = data.pop(RUN_TABLE, {})
    if not isinstance(run, dict):
        raise ConfigError(RUN_TABLE, "must be a table")
    for k, v in run.items():
        if k != "compile_effort":
            raise ConfigError(f"{RUN_TABLE}.{k}", "unknown key (known: compile_effort)")
        if v not in EFFORTS:
            raise ConfigError(f"{RUN_TABLE}.{k}", f"must be one of {', '.join(EFFORTS)}")
    return run


def run_table(path: str | None) -> dict:
    """The ``[jaxdip]`` run settings of the config file at ``path`` (empty without one), validated."""
    return _run_table(read_toml(path)) if path is not None else {}


def load(cls, path: str | None = None, quick: dict | None = None, seeds: int | None = None,
         sets: list[str] | None = None):
    """Defaults <- ``--quick`` overrides <- the file at ``path`` <- ``seeds`` <- ``--set`` pairs, then validated.
    The file's ``[jaxdip]`` table holds run settings, not config keys (``run_table``)."""
    data = to_dict(cls())
    if quick:
        _merge(data, quick)
    if path is not None:
        file = read_toml(path)
        _run_table(file)
        _merge(data, file)
    if seeds is not None:
        data["seeds"] = seeds
    for item in sets or []:
        k, v = parse_set(item)
        _set_path(data, k, v)
    return from_dict(cls, data)


# ---- TOML output -----------------------------------------------------------------------------------------


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


def documented_toml(cfg, title: str = "", source: str = "") -> str:
    """A config as TOML with each key's doc as a comment above it (the format of configs/<id>.toml)."""
    lines = [f"# {title}"] if title else []
    if source:
        lines.append(f"# Reproduces: {source}")
    if lines:
        lines += ["# Defaults are the documents' values; edit a copy and pass it with --config FILE.", ""]
    for f in dataclasses.fields(cfg):
        doc = f.metadata.get("doc", "")
        if doc:
            lines.append(f"# {doc}")
        lines.append(f"{f.name} = {_toml_value(getattr(cfg, f.name))}")
    return "\n".join(lines) + "\n"
