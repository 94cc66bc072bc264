"""The moves that put a finished run in place, each all-or-nothing, and the recovery of a killed one.

Linux's ``renameat2`` (through libc) gives two atomic moves: ``RENAME_NOREPLACE`` (a new destination appears
whole or not at all, never over something that appeared meanwhile) and ``RENAME_EXCHANGE`` (an existing folder
and the new one trade places in one step). Where exchange is unsupported, or the destination is the working
directory (which must stay where it is for the user's shell), files move one by one under a journal: old files
out into the staging folder, new ones in, marker last; a failure rolls back, and a run killed half-way is rolled
back (or, once every new file is in, forward) by the next run that looks at that destination.

A staging folder ("container") is ``.<dest name>.jaxdip-XXXXXX`` beside the destination, holding ``owner.pid``
(locked with ``flock`` by the live process: a lock that can be taken proves the owner dead, even after SIGKILL
and with its pid reused), ``new/`` (the run's output), and during a commit ``journal.json`` and ``old/``.
"""

from __future__ import annotations

import ctypes
import errno
import fcntl
import json
import os
import shutil
import stat
import time
from contextlib import contextmanager

from jaxdip.outdir.folder import shown
from jaxdip.outdir.marker import MARKER, NotOurs, file_digest, valid_name

PIDFILE = "owner.pid"
JOURNAL = "journal.json"
NEW, OLD = "new", "old"
_AT_FDCWD = -100
_NOREPLACE, _EXCHANGE = 1, 2


def container_prefix(dest: str) -> str:
    return f".{os.path.basename(dest)}.jaxdip-"


_libc = None


def _renameat2(src: str, dst: str, flags: int) -> None:
    global _libc
    if _libc is None:
        _libc = ctypes.CDLL(None, use_errno=True)
    fn = getattr(_libc, "renameat2", None)
    if fn is None:
        raise OSError(errno.ENOSYS, "renameat2 is not available")
    if fn(_AT_FDCWD, os.fsencode(src), _AT_FDCWD, os.fsencode(dst), flags) != 0:
        e = ctypes.get_errno()
        raise OSError(e, os.strerror(e), dst)


def rename_noreplace(src: str, dst: str) -> None:
    """Move ``src`` to ``dst`` unless ``dst`` exists (FileExistsError), atomically where the kernel can."""
    try:
        _renameat2(src, dst, _NOREPLACE)
    except OSError as e:
        if e.errno not in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP):
            raise
        if os.path.lexists(dst):  # the fallback's window between this test and the rename is not atomic
            raise FileExistsError(errno.EEXIST, "File exists", dst) from None
        os.rename(src, dst)


def exchange(a: str, b: str) -> bool:
    """Swap two folders in one step; False where the kernel or filesystem cannot (nothing moved then)."""
    try:
        _renameat2(a, b, _EXCHANGE)
    except OSError as e:
        if e.errno in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP):
            return False
        raise
    return True


@contextmanager
def locked(folder: str, timeout: float = 30.0):
    """Hold an exclusive ``flock`` on ``folder`` itself (no lock file is left behind): commits beside each other
    take turns. Where the filesystem has no flock the commit goes on unlocked."""
    try:
        fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    except OSError:
        yield
        return
    try:
        t_end = time.monotonic() + timeout
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() > t_end:
                    raise TimeoutError(f"another jaxdip run keeps {shown(folder)} locked") from None
                time.sleep(0.02)
            except OSError:
                break  # no flock here
        yield
    finally:
        os.close(fd)  # releases the lock


def write_json(path: str, obj: dict) -> None:
    """Write a small JSON file by a temporary name and a rename: a reader sees the old one or the new one."""
    tmp = path + ".part"
    with open(tmp, "w", encoding="utf-8") as fh:
        json.dump(obj, fh)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def owner_dead(container: str) -> bool:
    """True only when the container's owner lock can be taken: its process has ended."""
    try:
        fd = os.open(os.path.join(container, PIDFILE), os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError:
        return False
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            return False
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return True
    except OSError:
        return False
    finally:
        os.close(fd)


def digest_in(folder: str, name: str) -> str | None:
    fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW | os.O_CLOEXEC)
    try:
        return file_digest(name, fd)
    except NotOurs:
        return None
    finally:
        os.close(fd)


def swap_in_place(container: str, dest: str, old: dict[str, str], new: dict[str, str]) -> None:
    """Replace the files ``old`` of ``dest`` by the files ``new`` of ``container/new``, the folder itself staying.
    The marker is in both maps: out first, in last. Rolls back on any failure and re-raises."""
    write_json(os.path.join(container, JOURNAL), {"mode": "in-place", "dest": dest, "old": old, "new": new})
    os.makedirs(os.path.join(container, OLD), exist_ok=True)
    try:
        for name in [MARKER] * (MARKER in old) + sorted(n for n in old if n != MARKER):
            rename_noreplace(os.path.join(dest, name), os.path.join(container, OLD, name))
        for name in sorted(n for n in new if n != MARKER) + [MARKER]:
            rename_noreplace(os.path.join(container, NEW, name), os.path.join(dest, name))
    except BaseException:
        roll_back(container, dest, old, new)
        raise
    # committed: every new file is in. The journal stays until the old files are removed (by content), so a
    # kill before that leaves the next run a record of which files it may delete


def roll_back(container: str, dest: str, old: dict[str, str], new: dict[str, str]) -> None:
    """Undo a partial ``swap_in_place``: new files back out (only with their own content), old files back in."""
    for name in [MARKER] + sorted(n for n in new if n != MARKER):
        if name in new and not os.path.lexists(os.path.join(container, NEW, name)):
            if digest_in(dest, name) == new[name]:
                rename_noreplace(os.path.join(dest, name), os.path.join(container, NEW, name))
    for name in sorted(old):
        src = os.path.join(container, OLD, name)
        if os.path.lexists(src) and not os.path.lexists(os.path.join(dest, name)):
            rename_noreplace(src, os.path.join(dest, name))


def recover(parent: str, dest: str) -> None:
    """Finish or undo what runs killed while writing ``dest`` left beside it, and remove their staging folders;
    anything not provably a dead run's own is left alone. Call with ``parent`` locked."""
    prefix = container_prefix(dest)
    try:
        names = [n for n in os.listdir(parent) if n.startswith(prefix)]
    except OSError:
        return
    for name in names:
        c = os.path.join(parent, name)
        try:
            st = os.lstat(c)
        except OSError:
            continue
        if not stat.S_ISDIR(st.st_mode) or st.st_uid != os.geteuid():
            continue
        try:
            if not owner_dead(c):
                os.rmdir(c)  # only if empty: a run killed between creating it and taking its lock
                continue
            _recover_one(c, dest)
        except OSError:
            continue  # cannot finish it (the destination moved, a permission): left for a person to look at


def _only_output(c: str) -> bool:
    """A staging folder as ``prepare`` leaves it: the owner file and ``new/`` holding plain files only."""
    names = set(os.listdir(c))
    if not names <= {PIDFILE, NEW, OLD, JOURNAL + ".part"} or OLD in names and os.listdir(os.path.join(c, OLD)):
        return False
    if NEW not in names:
        return True
    d = os.path.join(c, NEW)
    return stat.S_ISDIR(os.lstat(d).st_mode) and all(
        stat.S_ISREG(os.lstat(os.path.join(d, n)).st_mode) for n in os.listdir(d))


def _journal(path: str) -> dict | None:
    """The journal exactly as jaxdip writes it, else None: its names are plain output names (or the marker),
    since recovery moves files by them."""
    try:
        with open(path, encoding="utf-8") as fh:
            j = json.load(fh)
    except (OSError, ValueError, RecursionError):
        return None
    if not isinstance(j, dict) or j.get("mode") not in ("exchange", "in-place") or not isinstance(j.get("dest"), str):
        return None
    for side in ("old", "new"):
        m = j.get(side)
        if not isinstance(m, dict) or not all(
                (n == MARKER or valid_name(n)) and isinstance(d, str) and len(d) == 64 for n, d in m.items()):
            return None
    return j


def _recover_one(c: str, dest: str) -> None:
    journal = os.path.join(c, JOURNAL)
    if not os.path.lexists(journal):
        if _only_output(c):
            shutil.rmtree(c, ignore_errors=True)  # killed before its commit began: only its own output is inside
        return
    j = _journal(journal)
    if j is None or j["dest"] != dest:
        return  # not what jaxdip writes: leave it for a person to look at
    old, new = j["old"], j["new"]
    if j["mode"] == "in-place" and any(os.path.lexists(os.path.join(c, NEW, n)) for n in new):
        roll_back(c, dest, old, new)  # killed before every new file was in: undo (else it had committed)
    remove_container(c, old, new)


def remove_container(c: str, old: dict[str, str], new: dict[str, str]) -> bool:
    """Remove a staging folder once its commit is over: inside are the run's new output or the folder it
    replaced, each removed only where its content is what jaxdip wrote; True if nothing was left."""
    for sub in (NEW, OLD):
        d = os.path.join(c, sub)
        if os.path.lexists(d) and not _remove_verified_any(d, old, new):
            return False
    for leftover in (JOURNAL, JOURNAL + ".part", PIDFILE):  # the journal last but one: it names what to delete
        try:
            os.unlink(os.path.join(c, leftover))
        except OSError:
            pass
    try:
        os.rmdir(c)
        return True
    except OSError:
        return False


def _remove_verified_any(folder: str, old: dict[str, str], new: dict[str, str]) -> bool:
    """Remove the files matching either map's content (a name may hold the old or the new version)."""
    try:
        names = os.listdir(folder)
    except OSError:
        return False
    for name in names:
        d = digest_in(folder, name) if (name in old or name in new) else None
        if d is not None and d in (old.get(name), new.get(name)):
            os.unlink(os.path.join(folder, name))
    try:
        os.rmdir(folder)
        return True
    except OSError:
        return False
