"""``jaxdip config``: an experiment's default config as documented TOML, printed (``jaxdip config <id>``) or
written for every experiment (``jaxdip config --write DIR``, the repository's ``configs/``).

The config dataclasses in code are the one source of each default, its constraint and its doc; the
``configs/<id>.toml`` files are generated from them by ``jaxdip config --write configs`` and never edited by
hand (tests/test_cli.py fails on a stale one and names this command). A file there is replaced only when it is
one this command wrote (it starts with its experiment's title line and the generated-file line below).
"""

from __future__ import annotations

import os
from typing import Callable

from jaxdip import config as C
from jaxdip import outdir
from jaxdip.cli_errors import emit, error

GENERATED = ("Generated from the defaults in code by `jaxdip config --write configs` (not edited here): pass an "
             "edited copy with --config FILE.")


def default_toml(exp) -> str:
    """``configs/<id>.toml`` of the experiment ``exp``: its config's defaults, each key's doc above it."""
    return C.documented_toml(exp.config_cls(), f"{exp.id}: {exp.title}", exp.source, GENERATED)


def _written_by_us(exp_id: str):
    def is_ours(data: bytes) -> bool:
        lines = data.decode("utf-8", "replace").splitlines()
        return bool(lines) and lines[0].startswith(f"# {exp_id}: ") and f"# {GENERATED}" in lines[:3]

    return is_ours


def write_all(folder: str) -> list[str]:
    """Write ``<folder>/<id>.toml`` for every registered experiment (the folder is made if missing); every
    target is checked before the first is written, so a refusal leaves the folder as it was."""
    from jaxdip.runner import registry

    exps = sorted(registry().items())
    paths = [os.path.join(folder, f"{exp_id}.toml") for exp_id, _ in exps]
    os.makedirs(folder, exist_ok=True)
    for (exp_id, _), path in zip(exps, paths):
        outdir.check_file(path, _written_by_us(exp_id), key="--write", parent_must_exist=True)
    for (_, exp), path in zip(exps, paths):
        outdir.write_file_atomic(path, default_toml(exp))
    return paths


def cmd_config(args, unknown: Callable[[str, KeyError], int]) -> int:
    """The command's exit status; ``unknown(id, KeyError)`` reports an id the registry does not know."""
    from jaxdip.runner import get

    if args.write is not None:
        if args.id is not None:
            return error("--write", "writes every experiment's file: give no id")
        try:
            paths = write_all(args.write)
        except outdir.OutputError as e:
            return error(e.key, e.why)
        except OSError as e:
            return error("--write", f"cannot write {outdir.shown(args.write)}: {e.strerror or e}")
        emit(f"config: wrote {len(paths)} files to {args.write}")
        return 0
    if args.id is None:
        return error("config", "give an experiment id, or --write DIR")
    try:
        exp = get(args.id)
    except KeyError as e:
        return unknown(args.id, e)
    emit(default_toml(exp), end="")
    return 0
