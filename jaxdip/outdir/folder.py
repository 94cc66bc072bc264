"""What a destination folder is now, decided from the folder itself: new, empty, or a run jaxdip wrote.

Every candidate path comes from listing the folder (``os.scandir`` of a descriptor opened without following
links); a name is jaxdip's only if it is a regular file of this user, listed in a valid marker, with the
content hash the marker records. Nothing here writes; ``Verdict`` records what was seen, so a commit can tell
whether the destination is still exactly what was checked before the run.
"""

from __future__ import annotations

import errno
import os
import stat
from dataclasses import dataclass, field

from jaxdip.outdir.marker import MARKER, NotOurs, file_digest, read_marker, valid_name


class OutputError(ValueError):
    """An output destination jaxdip must not or cannot write; ``key`` names the flag that chose it."""

    def __init__(self, key: str, why: str):
        super().__init__(f"{key}: {why}")
        self.key = key
        self.why = why


def shown(text: str, limit: int = 80) -> str:
    """User-supplied text fit for a one-line message: control characters escaped, long text shortened."""
    s = "".join(c if c.isprintable() else repr(c)[1:-1] for c in str(text))
    return s if len(s) <= limit else s[: limit // 2 - 2] + "..." + s[-(limit // 2 - 1):]


def _names(names: list[str], n: int = 3) -> str:
    more = f" and {len(names) - n} more" if len(names) > n else ""
    return ", ".join(shown(x, 40) for x in sorted(names)[:n]) + more


def absolute(path: str, key: str) -> str:
    """``path`` made absolute (an OutputError where a relative path has no working directory to be under)."""
    try:
        return os.path.abspath(path)
    except OSError:
        raise OutputError(key, f"{shown(path)} is relative and the working directory no longer exists") from None


@dataclass(frozen=True)
class Verdict:
    """A destination as it was seen: ``kind`` is "new" (no such path), "empty" or "ours" (a jaxdip run)."""

    path: str
    kind: str
    ident: tuple[int, int] | None = None  # (st_dev, st_ino) of the existing folder
    mode: int | None = field(default=None, compare=False)  # its permission bits, given to the folder replacing it
    owner: str | None = None
    files: dict[str, str] = field(default_factory=dict)  # name -> sha256 of jaxdip's files present
    marker: str | None = None  # sha256 of the marker itself: any rewrite of it counts as a change


def open_dir(path: str) -> int:
    return os.open(path, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW | os.O_CLOEXEC)


def classify(path: str, owner: str, *, key: str = "--out", force: bool = False, label: str | None = None) -> Verdict:
    """The verdict on the absolute ``path``, or OutputError (one line) where writing there could cost the user a
    file. ``label`` is how the path is shown."""
    label = shown(label if label is not None else path)
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return Verdict(path, "new")
    except NotADirectoryError:
        return Verdict(path, "new")  # an ancestor is a file: the parent check names it
    except OSError as e:
        raise OutputError(key, f"cannot read {label}: {e.strerror or e}") from None
    if stat.S_ISLNK(st.st_mode):
        raise OutputError(key, f"{label} is a symbolic link; give the folder itself")
    if not stat.S_ISDIR(st.st_mode):
        what = "a file" if stat.S_ISREG(st.st_mode) else "a special file"
        raise OutputError(key, f"{label} exists and is {what}, not a folder")
    try:
        fd = open_dir(path)
    except OSError as e:
        raise OutputError(key, f"cannot read {label}: {e.strerror or e}") from None
    try:
        return _classify_open(fd, path, owner, key, force, label)
    finally:
        os.close(fd)


def _classify_open(fd: int, path: str, owner: str, key: str, force: bool, label: str) -> Verdict:
    st = os.fstat(fd)
    ident, mode = (st.st_dev, st.st_ino), stat.S_IMODE(st.st_mode)
    try:
        entries = [e.name for e in os.scandir(fd)]
    except OSError as e:
        raise OutputError(key, f"cannot read {label}: {e.strerror or e}") from None
    if not entries:
        return Verdict(path, "empty", ident, mode)
    try:
        found, listed = read_marker(fd)
        marker = file_digest(MARKER, fd)
    except NotOurs as e:
        n = len(entries)
        raise OutputError(key, f"{label} exists and is not a jaxdip result folder ({e}; {n} entr"
                               f"{'y' if n == 1 else 'ies'}); choose a new or empty folder") from None
    foreign, changed, odd, files = [], [], [], {}
    for name in entries:
        if name == MARKER:
            continue
        if name not in listed or not valid_name(name):
            foreign.append(name)
            continue
        try:
            digest = file_digest(name, fd)
        except NotOurs:
            odd.append(name)  # a folder, link or special file by a name jaxdip used: the user's now
            continue
        if digest != listed[name]:
            changed.append(name)
        else:
            files[name] = digest
    if foreign:
        raise OutputError(key, f"{label} holds files jaxdip did not write ({_names(foreign)}); "
                               "move them or choose another folder")
    if odd:
        raise OutputError(key, f"{label} holds entries jaxdip cannot have written (a link, folder, special or "
                               f"oversized file: {_names(odd)}); move them or choose another folder")
    if changed:
        raise OutputError(key, f"{label} holds files changed since jaxdip wrote them ({_names(changed)}); "
                               "move them or choose another folder")
    if found != owner and not force:
        raise OutputError(key, f"{label} holds the results of {found!r}, not {owner!r}; pass --force to replace them")
    return Verdict(path, "ours", ident, mode, found, files, marker)


def check_parent(path: str, label: str, key: str, *, must_exist: bool = False) -> None:
    """The nearest existing ancestor of ``path`` must be a folder this process can create entries in."""
    parent = os.path.dirname(path)
    if must_exist and not os.path.isdir(parent):
        why = "does not exist" if not os.path.lexists(parent) else "is not a folder"
        raise OutputError(key, f"cannot write {shown(label)}: its folder {shown(parent)} {why}")
    while not os.path.lexists(parent):
        parent = os.path.dirname(parent)
    if not os.path.isdir(parent):
        raise OutputError(key, f"cannot create {shown(label)}: {shown(parent)} is a file")
    # try it: permission bits do not tell (root ignores them; read-only mounts and /proc refuse regardless)
    probe = os.path.join(parent, f".jaxdip-probe-{os.getpid()}")
    try:
        os.mkdir(probe, 0o700)
    except FileExistsError:
        return
    except OSError as e:
        why = "the disk is full" if e.errno == errno.ENOSPC else (e.strerror or str(e))
        raise OutputError(key, f"cannot write in {shown(parent)}: {why}") from None
    os.rmdir(probe)
