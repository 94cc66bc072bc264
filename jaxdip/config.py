"""Typed experiment configs loaded from TOML and validated before anything compiles.

An experiment's config is a dataclass whose defaults are the documents' values: the one source of each key's
default, type, constraint (``check`` metadata: ``positive``, ``nonneg``, ...) and doc. ``configs/<id>.toml`` is
generated from it (``jaxdip config --write configs``; a test fails on a stale file), not read by a run: a TOML
cannot hold the types and constraints, and an installed package has no configs/ folder (docs/config.md).

``load`` merges, in order: the defaults, the experiment's ``--quick`` overrides, a TOML file, ``--seeds`` and
``--set key=value`` pairs (so what the user wrote is never silently replaced by ``--quick``); then checks every
key's type and constraint and the config's own ``validate()``. Any problem raises ``ConfigError(key, why)``, which the CLI prints as one line
``error: <key>: <why>``.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import os
import stat
import sys
import types
import typing
from typing import Any

import tomllib

from jaxdip.config_toml import documented_toml, to_toml  # noqa: F401  (part of this module's interface)
from jaxdip.messages import shown, suggestion
from jaxdip.xla_flags import EFFORTS

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
            return f"must be one of {', '.join(map(repr, choices))}{suggestion(v, choices, known=None)}"

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
        return dataclasses.field(default_factory=lambda: copy.deepcopy(default), metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


# ---- type checking ---------------------------------------------------------------------------------------


def _check_type(key: str, value: Any, tp) -> Any:
    origin = typing.get_origin(tp)
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(key, f"expected a number, got {type(value).__name__} {shown(value)}")
        try:
            value = float(value)
        except OverflowError:  # an integer beyond every float
            raise ConfigError(key, f"{shown(value, 24)} is out of range for a float") from None
        if math.isnan(value):
            raise ConfigError(key, "is not a number (nan)")
        if 0 < abs(value) < sys.float_info.min:
            # subnormal: too small for any quantity here, and every ratio with it overflows
            raise ConfigError(key, f"{value!r} is too small to compute with (below {sys.float_info.min:.3g})")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and value.is_integer():
                value = int(value)
            else:
                raise ConfigError(key, f"expected an integer, got {shown(value)}")
        if not INT_MIN <= value <= INT_MAX:
            # JAX keys, counters and shapes are 64-bit at most; a larger value would overflow deep inside a compile
            raise ConfigError(key, f"{shown(value, 24)} is out of range (at most {INT_MAX})")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(key, f"expected true or false, got {shown(value)}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(key, f"expected a string, got {shown(value)}")
        return value
    if origin is list:
        (inner,) = typing.get_args(tp)
        if not isinstance(value, list):
            raise ConfigError(key, f"expected a list, got {shown(value)}")
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


def from_dict(cls, data: dict, prefix: str = ""):
    """Build a config dataclass from nested dicts, checking keys, types and constraints."""
    fields = {f.name: f for f in dataclasses.fields(cls)}
    hints = typing.get_type_hints(cls)
    unknown = [k for k in data if k not in fields]
    if unknown:
        k = unknown[0]
        raise ConfigError(prefix + k, "unknown key" + suggestion(k, fields, "known keys"))
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
    _computable(cfg)
    return cfg


_ARITHMETIC = (OverflowError, ZeroDivisionError, FloatingPointError, MemoryError)


def _numeric_fields(cfg, prefix: str = ""):
    for f in dataclasses.fields(cfg):
        v = getattr(cfg, f.name)
        if dataclasses.is_dataclass(v):
            yield from _numeric_fields(v, f"{prefix}{f.name}.")
        else:
            for x in _numbers(v):
                yield prefix + f.name, x


def _extremity(x) -> float:
    """How far a finite number is from everyday magnitudes, in decades."""
    return abs(math.log10(abs(x))) if x else 0.0


def _computable(cfg) -> None:
    """The config's own ``validate()`` and its resource estimate (``loads()``): every number they derive from the
    values (a period count from a duration and a step, a memory estimate) must be computable. One that
    overflows is a ConfigError naming the most extreme value, the one a user would change."""
    try:
        if hasattr(cfg, "validate"):
            cfg.validate()
        if hasattr(cfg, "loads"):
            cfg.loads()
    except _ARITHMETIC as e:
        key, value, _ = most_extreme(cfg)
        raise ConfigError(key, f"{shown(value, 24)} is out of range: a number computed from it does not fit "
                               f"({type(e).__name__})") from None


def most_extreme(cfg) -> tuple[str, float, float]:
    """(key, value, decades from 1) of the config's number furthest from everyday magnitudes: the likeliest
    cause when arithmetic on the values fails. Infinities are left out (a field that allows one means "no
    bound"). ``("config", 0.0, 0.0)`` for a config without numbers."""
    finite = [(k, x) for k, x in _numeric_fields(cfg) if not math.isinf(x)]
    ranked = sorted(((k, x, _extremity(x)) for k, x in finite), key=lambda kxe: kxe[2], reverse=True)
    return ranked[0] if ranked else ("config", 0.0, 0.0)


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
        raise ConfigError("--set", f"expects key=value, got {shown(item)}")
    key, raw = item.split("=", 1)
    key = key.strip()
    if not key or any(not part for part in key.split(".")):
        raise ConfigError("--set", f"expects key=value, got {shown(item)}")
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
    """A TOML file as a dict, every failure (missing, a folder, a FIFO or device, unreadable, binary, not TOML) a
    ConfigError. Only a regular file is opened: reading a FIFO would wait for a writer forever, a device
    would never end."""
    shown_path = shown(path, 120)[1:-1]
    try:
        st = os.stat(path)
        if stat.S_ISDIR(st.st_mode):
            raise ConfigError("--config", f"{shown_path} is a folder, not a TOML file")
        if not stat.S_ISREG(st.st_mode):
            kind = next((name for test, name in ((stat.S_ISFIFO, "a FIFO"), (stat.S_ISSOCK, "a socket"))
                         if test(st.st_mode)), "a device")
            raise ConfigError("--config", f"{shown_path} is {kind}, not a TOML file")
        # O_NONBLOCK: should the name have become a FIFO since the stat, opening it still does not wait
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOCTTY", 0))
        with os.fdopen(fd, "rb") as fh:
            if not stat.S_ISREG(os.fstat(fh.fileno()).st_mode):
                raise ConfigError("--config", f"{shown_path} is not a regular file, not a TOML file")
            raw = fh.read(MAX_CONFIG_BYTES + 1)
    except ConfigError:
        raise
    except FileNotFoundError:
        raise ConfigError("--config", f"no such file: {shown_path}") from None
    except OSError as e:
        raise ConfigError("--config", f"cannot read {shown_path}: {e.strerror or e}") from None
    except ValueError:  # a path with a NUL character
        raise ConfigError("--config", f"not a valid path: {shown_path}") from None
    if len(raw) > MAX_CONFIG_BYTES:
        raise ConfigError("--config", f"{shown_path} is larger than {MAX_CONFIG_BYTES // 1024} KiB: not a config file")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as e:
        raise ConfigError("--config", f"{shown_path} is not UTF-8 text (byte {e.start}): not a TOML config") from None
    if "\x00" in text:
        raise ConfigError("--config", f"{shown_path} holds NUL bytes: not a TOML config")
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ConfigError("--config", f"not valid TOML: {e}") from None
    except RecursionError:
        raise ConfigError("--config", "not valid TOML: nested too deeply") from None


# A written config.toml's table of run settings that change results besides the config (the compile effort):
# read back by ``run_table`` so that re-running a run's own config.toml gives the same last bits
RUN_TABLE = "jaxdip"


def _run_table(data: dict) -> dict:
    run = data.pop(RUN_TABLE, {})
    if not isinstance(run, dict):
        raise ConfigError(RUN_TABLE, "must be a table")
    for k, v in run.items():
        if k != "compile_effort":
            raise ConfigError(f"{RUN_TABLE}.{k}", "unknown key" + suggestion(k, ["compile_effort"], "known keys"))
        if v not in EFFORTS:
            raise ConfigError(f"{RUN_TABLE}.{k}", f"must be one of {', '.join(EFFORTS)}"
                                                  + suggestion(v, EFFORTS, known=None))
    return run


def run_table(path: str | None) -> dict:
    """The ``[jaxdip]`` run settings of the config file at ``path`` (empty without one), validated."""
    return _run_table(read_toml(path)) if path is not None else {}


def check_layer(cls, layer: dict, prefix: str = "") -> None:
    """Each key of one layer of a config (a file, ``--seeds``, one ``--set``) checked on its own: known, of the
    right type, within its constraints, so that a value a later layer replaces is still refused when wrong.
    (Checks across keys, ``validate()``, apply to the merged config only.)"""
    fields = {f.name: f for f in dataclasses.fields(cls)}
    hints = typing.get_type_hints(cls)
    for name, value in layer.items():
        f = fields.get(name)
        if f is None:
            from_dict(cls, {name: value}, prefix)  # raises the unknown-key error with its suggestion
            continue
        key = prefix + name
        if dataclasses.is_dataclass(hints[name]):
            if not isinstance(value, dict):
                raise ConfigError(key, "expected a table")
            check_layer(hints[name], value, key + ".")
            continue
        value = _check_type(key, value, hints[name])
        for check in f.metadata.get("checks", ()):
            why = check(value)
            if why:
                raise ConfigError(key, why)


def load(cls, path: str | None = None, quick: dict | None = None, seeds: int | None = None,
         sets: list[str] | None = None):
    """Defaults <- ``--quick`` overrides <- the file at ``path`` <- ``seeds`` <- ``--set`` pairs, then validated.
    The file's ``[jaxdip]`` table holds run settings, not config keys (``run_table``)."""
    data = to_dict(cls())
    if quick:
        _merge(data, quick)
    if path is not None:
        layer = read_toml(path)
        _run_table(layer)
        check_layer(cls, layer)
        _merge(data, layer)
    if seeds is not None:
        try:
            check_layer(cls, {"seeds": seeds})
        except ConfigError as e:
            raise ConfigError("--seeds", e.why) from None
        data["seeds"] = seeds
    for item in sets or []:
        k, v = parse_set(item)
        _set_path(data, k, v)  # first: a key under a value that is no table is refused as such
        layer: dict = {}
        _set_path(layer, k, v)
        check_layer(cls, layer)
    try:
        return from_dict(cls, data)
    except ConfigError as e:
        # a check across keys that names seeds: the flag set it
        if seeds is not None and e.key == "seeds":
            raise ConfigError("--seeds", e.why) from None
        raise
