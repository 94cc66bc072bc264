"""Where a run's numbers came from: the command, jaxdip's version and git commit, the packages, the devices, the
config's hash and the seeds' key. metrics.json holds it as its ``provenance`` block, every PNG as text chunks,
per_seed.nc as global attributes, and report.md ends with the command that regenerates the folder."""

from __future__ import annotations

import hashlib
import os
import shlex
import subprocess
from importlib import metadata

import jax

PACKAGES = ("jax", "jaxlib", "numpy", "equinox", "optax")


def _version(name: str) -> str:
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return "not installed"


def git_state(where: str | None = None) -> dict:
    """``{"commit": sha, "dirty": bool}`` of the checkout jaxdip is imported from; empty when it is not one (an
    installed wheel) or git is not there."""
    where = where or os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    try:
        top = subprocess.run(["git", "-C", where, "rev-parse", "--show-toplevel", "HEAD"], capture_output=True,
                             text=True, timeout=10)
        if top.returncode != 0:
            return {}
        root, commit = top.stdout.split()
        if os.path.realpath(root) != os.path.realpath(where):
            return {}  # jaxdip lies inside some other repository, whose commit says nothing about it
        dirty = subprocess.run(["git", "-C", where, "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=10)
        return {"commit": commit, "dirty": bool(dirty.stdout.strip())}
    except (OSError, subprocess.SubprocessError, ValueError):
        return {}


def regenerate_command(exp_id: str, out_dir: str) -> str:
    """The command that writes this folder again from its own resolved config (which records the seeds, the
    quick overrides and the compile effort)."""
    out = shlex.quote(out_dir)
    return f"jaxdip run {exp_id} --config {out}/config.toml --out {out} --force"


def provenance_block(exp_id: str, cfg, config_text: str, out_dir: str, command: str | None) -> dict:
    """metrics.json's ``provenance``: everything a figure's reader needs to know where it came from."""
    import jaxdip

    block = {
        "command": command or regenerate_command(exp_id, out_dir),
        "regenerate": regenerate_command(exp_id, out_dir),
        "jaxdip_version": jaxdip.__version__,
        **{f"git_{k}": v for k, v in git_state().items()},
        "packages": {name: _version(name) for name in PACKAGES},
        "devices": [str(d) for d in jax.devices()],
        "config_sha256": hashlib.sha256(config_text.encode()).hexdigest(),
    }
    if hasattr(cfg, "seed"):
        block["seeds_key"] = f"PRNGKey({cfg.seed})"  # the config's base key; Monte Carlo seed i: fold_in(key, i)
    return block


def png_metadata(block: dict) -> dict:
    """PNG text chunks of ``block`` (matplotlib's ``savefig(metadata=...)``): one per entry, as text."""
    import json

    return {"Software": f"jaxdip {block['jaxdip_version']}",
            **{f"jaxdip:{k}": v if isinstance(v, str) else json.dumps(v) for k, v in block.items()}}
