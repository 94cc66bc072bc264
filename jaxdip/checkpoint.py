"""Atomic checkpoints of pytrees (ensembles, PRNG keys, optimiser states, histories) as .npz files.

A checkpoint is written to a temporary name and renamed, so a run killed mid-write leaves the previous
checkpoint intact. It stores a fingerprint of whatever the caller says must match (the config), so a resume
with a different config is refused instead of silently mixing runs.
"""

from __future__ import annotations

import hashlib
import json
import os

import jax
import numpy as np


class CheckpointMismatch(ValueError):
    """A checkpoint that does not belong to the run trying to resume from it."""


def fingerprint(obj) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()[:16]


def save(path: str, tree, fingerprint_: str = "", **meta):
    """Write ``tree`` to ``path`` atomically. With ``jax.distributed`` only process 0 writes (every process
    holds the same state; a resume reads the file on every process, so it must be on a shared file system)."""
    if jax.process_index() != 0:
        return
    leaves, treedef = jax.tree_util.tree_flatten(tree)
    arrays = {f"leaf_{i}": np.asarray(x) for i, x in enumerate(leaves)}
    arrays["__meta__"] = np.frombuffer(json.dumps({"fingerprint": fingerprint_, "n": len(leaves), **meta})
                                       .encode(), dtype=np.uint8)
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    tmp = path + ".tmp.npz"
    with open(tmp, "wb") as fh:
        np.savez(fh, **arrays)
    os.replace(tmp, path)


def load(path: str, like, fingerprint_: str = ""):
    """Restore a pytree shaped like ``like``; returns (tree, meta). Raises ValueError on a mismatch."""
    with np.load(path) as z:
        meta = json.loads(bytes(z["__meta__"]).decode())
        if fingerprint_ and meta.get("fingerprint") != fingerprint_:
            raise CheckpointMismatch(f"checkpoint {path} was written by a run with a different config")
        leaves = [z[f"leaf_{i}"] for i in range(meta["n"])]
    treedef = jax.tree_util.tree_structure(like)
    if treedef.num_leaves != len(leaves):
        raise CheckpointMismatch(f"checkpoint {path} does not match the expected state structure")
    return jax.tree_util.tree_unflatten(treedef, [jax.numpy.asarray(x) for x in leaves]), meta
