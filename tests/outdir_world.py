"""Helpers shared by the output-folder tests: write a run through the staging API, read a marker back, check
that a folder is one whole jaxdip run, and load ``jaxdip.outdir`` without importing JAX (for driver processes)."""

from __future__ import annotations

import hashlib
import json
import os
import sys
import types

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def light_import():
    """``jaxdip.outdir`` without ``jaxdip/__init__`` (which imports JAX): a driver process starts in ~50 ms."""
    if "jaxdip" not in sys.modules:
        pkg = types.ModuleType("jaxdip")
        pkg.__path__ = [os.path.join(ROOT, "jaxdip")]
        sys.modules["jaxdip"] = pkg
    import jaxdip.outdir

    return jaxdip.outdir


def write_run(path, owner, files, *, force=False):
    from jaxdip.outdir import prepare

    st = prepare(str(path), owner, force=force)
    try:
        for name, text in files.items():
            with open(os.path.join(st.tmp, name), "w") as fh:
                fh.write(text)
        st.commit()
    finally:
        st.discard()
    return st


def marker(folder) -> dict:
    with open(os.path.join(folder, ".jaxdip.json"), encoding="utf-8") as fh:
        return json.load(fh)


def sha(data) -> str:
    return hashlib.sha256(data.encode() if isinstance(data, str) else data).hexdigest()


def whole(folder) -> dict[str, str] | None:
    """The files of ``folder`` ({name: text}) if it is exactly one jaxdip run (every file listed in its marker
    with the recorded hash, nothing else), else None."""
    try:
        m = marker(folder)
        names = sorted(os.listdir(folder))
    except (OSError, ValueError):
        return None
    if names != sorted([".jaxdip.json", *m["files"]]):
        return None
    out = {}
    for name, digest in m["files"].items():
        with open(os.path.join(folder, name), "rb") as fh:
            data = fh.read()
        if sha(data) != digest:
            return None
        out[name] = data.decode("utf-8", "replace")
    return out
