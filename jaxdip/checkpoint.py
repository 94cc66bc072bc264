"""Atomic checkpoints of pytrees (ensembles, PRNG keys, optimiser states, histories) as .npz files.

A checkpoint is written to a temporary name and renamed, so a run killed mid-write leaves the previous
checkpoint intact. It stores a fingerprint of whatever the caller says must match (for an experiment: the
resolved config, the compile effort, the dtype, the jaxdip version and the device count), so a resume with a
different run is refused instead of silently mixing runs. It also stores the token of the run that wrote it
(``owning``), so a finished run removes only a checkpoint it wrote or resumed from.

Every way a file can fail to be a checkpoint (not a regular file, not a zip, a meta record that is not
JSON, leaves missing or of another shape or dtype) raises ``CheckpointError``, a ``ValueError`` naming the
file, never a library's traceback.
"""

from __future__ import annotations

import contextlib
import contextvars
import hashlib
import json
import os
import stat
import zipfile
from typing import Iterator

import jax
import numpy as np


class CheckpointError(ValueError):
    """A file that cannot be resumed from: damaged, truncated or not a checkpoint at all."""


class CheckpointMismatch(CheckpointError):
    """A checkpoint that does not belong to the run trying to resume from it."""


def fingerprint(obj) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()[:16]


class _Owner:
    def __init__(self, token: str, run: dict | None):
        self.token, self.run = token, run
        self.adopted: set[str] = set()  # tokens of the checkpoints this run resumed from


_owner: contextvars.ContextVar[_Owner | None] = contextvars.ContextVar("jaxdip_checkpoint_owner", default=None)


@contextlib.contextmanager
def owning(token: str, run: dict | None = None) -> Iterator[_Owner]:
    """Checkpoints saved in this block record ``token`` as their writer (and ``run``, what the run was, so a
    refused resume can say what differs); those loaded in it are adopted by it."""
    o = _Owner(token, run)
    reset = _owner.set(o)
    try:
        yield o
    finally:
        _owner.reset(reset)


def save(path: str, tree, fingerprint_: str = "", **meta):
    """Write ``tree`` to ``path`` atomically. With ``jax.distributed`` only process 0 writes (every process
    holds the same state; a resume reads the file on every process, so it must be on a shared file system)."""
    if jax.process_index() != 0:
        return
    leaves, _ = jax.tree_util.tree_flatten(tree)
    arrays = {f"leaf_{i}": np.asarray(x) for i, x in enumerate(leaves)}
    owner = _owner.get()
    record = {"fingerprint": fingerprint_, "n": len(leaves), **meta}
    if owner is not None:
        record["owner"] = owner.token
        if owner.run is not None:
            record["run"] = owner.run
    arrays["__meta__"] = np.frombuffer(json.dumps(record, default=str).encode(), dtype=np.uint8)
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    tmp = f"{path}.{os.getpid()}.tmp.npz"  # per process: two writers never interleave in one temporary file
    try:
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)
        os.replace(tmp, path)
    finally:
        if os.path.lexists(tmp):
            os.remove(tmp)


def read_meta(path: str) -> dict:
    """The meta record of the checkpoint at ``path`` (a CheckpointError if it has none that can be read)."""
    with _open(path) as z:
        return _meta(path, z)


@contextlib.contextmanager
def _open(path: str):
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        raise CheckpointError(f"no checkpoint at {path}") from None
    except OSError as e:
        raise CheckpointError(f"cannot read checkpoint {path}: {e.strerror or e}") from None
    if not stat.S_ISREG(st.st_mode):  # a FIFO would block the reader, a link may point anywhere
        raise CheckpointError(f"checkpoint {path} is not a regular file")
    try:
        z = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as e:
        # numpy's own text would suggest loading with pickle: never for a file that may come from anywhere
        raise CheckpointError(f"checkpoint {path} is damaged or truncated: not an .npz archive "
                              f"({type(e).__name__})") from None
    if not isinstance(z, np.lib.npyio.NpzFile):
        raise CheckpointError(f"checkpoint {path} is not an .npz archive")
    try:
        yield z
    finally:
        z.close()


def _array(path: str, z, name: str) -> np.ndarray:
    try:
        a = z[name]
        if not isinstance(a, np.ndarray):  # a member that is not an .npy array (np.load gives its raw bytes)
            raise ValueError("not an array")
        return a
    except KeyError:
        raise CheckpointError(f"checkpoint {path} is damaged: it has no {name}") from None
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, RuntimeError) as e:
        raise CheckpointError(f"checkpoint {path} is damaged or truncated: {name} cannot be read "
                              f"({type(e).__name__})") from None


def _meta(path: str, z) -> dict:
    raw = _array(path, z, "__meta__")
    try:
        if raw.dtype != np.uint8 or raw.ndim != 1:
            raise ValueError("not bytes")
        meta = json.loads(bytes(raw).decode())
    except (ValueError, UnicodeDecodeError, TypeError, RecursionError):
        raise CheckpointError(f"checkpoint {path} is damaged: its meta record is not JSON") from None
    n = meta.get("n") if isinstance(meta, dict) else None
    if not isinstance(n, int) or isinstance(n, bool) or n < 0 or not isinstance(meta.get("fingerprint", ""), str):
        raise CheckpointError(f"checkpoint {path} is damaged: its meta record is not one jaxdip writes")
    return meta


def load(path: str, like, fingerprint_: str = ""):
    """Restore a pytree shaped like ``like``; returns (tree, meta).

    Every leaf must have the dtype and number of dimensions of ``like``'s, and its shape, except that a leaf
    of ``like`` whose first dimension is 0 accepts any length along it (a history that grows with the run).
    Raises ``CheckpointMismatch`` for another run's checkpoint, ``CheckpointError`` for a damaged one."""
    like_leaves, treedef = jax.tree_util.tree_flatten(like)
    with _open(path) as z:
        meta = _meta(path, z)
        if fingerprint_ and meta.get("fingerprint") != fingerprint_:
            raise CheckpointMismatch(f"checkpoint {path} was written by a run with a different config")
        if meta["n"] != len(like_leaves):
            raise CheckpointMismatch(f"checkpoint {path} does not match the expected state structure")
        leaves = [_array(path, z, f"leaf_{i}") for i in range(meta["n"])]
    for i, (got, want) in enumerate(zip(leaves, like_leaves)):
        want_shape, want_dtype = np.shape(want), np.asarray(want).dtype
        same = got.ndim == len(want_shape) and (
            got.shape == want_shape or (want_shape and want_shape[0] == 0 and got.shape[1:] == want_shape[1:]))
        if not same or got.dtype != want_dtype:
            raise CheckpointError(f"checkpoint {path} is damaged: leaf {i} is {got.dtype}{list(got.shape)}, "
                                  f"expected {want_dtype}{list(want_shape)}")
    owner = _owner.get()
    if owner is not None and isinstance(meta.get("owner"), str):
        owner.adopted.add(meta["owner"])
    return jax.tree_util.tree_unflatten(treedef, [jax.numpy.asarray(x) for x in leaves]), meta


def remove_own(path: str, owner: _Owner) -> bool:
    """Remove the checkpoint at ``path`` if ``owner``'s run wrote it or resumed from it; True if removed.

    A checkpoint another run keeps at the same name (one that started later with the same config, say) or a
    file that is not a checkpoint is left where it is."""
    try:
        meta = read_meta(path)
    except CheckpointError:
        return False
    if meta.get("owner") not in {owner.token, *owner.adopted}:
        return False
    os.remove(path)
    return True
