"""Single output files (``bench --out``'s JSON and figure, ``reproduce``'s REPORT.md) and the user's umask."""

from __future__ import annotations

import os
import stat
import tempfile
from typing import Callable

from jaxdip.outdir.folder import OutputError, absolute, check_parent, shown

_MAX_READ = 1 << 20


def umask() -> int:
    """The process's umask, read without changing it where Linux tells it (``/proc/self/status``)."""
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    old = os.umask(0o022)  # the portable way sets it to read it; put it straight back
    os.umask(old)
    return old


def read_own(path: str) -> bytes | None:
    """The bytes of ``path`` if it is a regular file of this user no larger than 1 MiB, else None; never
    follows a link or blocks on a FIFO."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError:
        return None
    with os.fdopen(fd, "rb") as fh:
        st = os.fstat(fh.fileno())
        if not stat.S_ISREG(st.st_mode) or st.st_uid != os.geteuid() or st.st_size > _MAX_READ:
            return None
        return fh.read(_MAX_READ)


def check_file(path: str, is_ours: Callable[[bytes], bool], *, key: str = "--out",
               parent_must_exist: bool = False, label: str | None = None) -> None:
    """Raise OutputError unless ``path`` is new or a file jaxdip wrote (``is_ours(content)``), in a folder this
    process can write (with ``parent_must_exist``, one that exists now)."""
    label = path if label is None else label
    path = absolute(path, key)
    if os.path.lexists(path):
        if os.path.isdir(path) and not os.path.islink(path):
            raise OutputError(key, f"{shown(label)} is a folder; give a file name")
        data = read_own(path)
        if data is None or not is_ours(data):
            raise OutputError(key, f"{shown(label)} exists and was not written by jaxdip (or was changed since); "
                                   "choose another name")
    check_parent(path, label, key, must_exist=parent_must_exist)


def write_file_atomic(path: str, data: str | bytes) -> None:
    """Write one file by a temporary name and a rename, so a reader never sees half of it; the file gets the
    user's umask (a temporary file is made private)."""
    path = os.path.abspath(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{os.path.basename(path)}.tmp-", dir=os.path.dirname(path))
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data.encode("utf-8") if isinstance(data, str) else data)
            os.fchmod(fh.fileno(), 0o666 & ~umask())
        os.replace(tmp, path)
    except BaseException:
        if os.path.lexists(tmp):
            os.remove(tmp)
        raise
