"""Output folders that never cost a user a file.

jaxdip writes a run into a temporary folder beside the destination and moves it into place only when complete.
Every folder it writes holds a marker file (``.jaxdip.json``) naming what wrote it and which files it wrote, so
a later run can tell its own output from a user's folder:

- a destination that does not exist, or an empty folder, is written;
- a previous run of the same experiment is replaced, and only the files that run wrote are removed;
- a jaxdip folder of another experiment is replaced only with ``force``;
- anything else (a file, a folder without the marker, a folder where the user added files) is refused.

``prepare`` runs every check and creates the temporary folder before any simulation is compiled, so a
destination that cannot be written is reported in seconds, not after the run.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from dataclasses import dataclass, field

MARKER = ".jaxdip.json"
PIDFILE = ".jaxdip-writing"  # inside a temporary folder while a live process fills it


class OutputError(ValueError):
    """An output destination jaxdip must not or cannot write; ``key`` names the flag that chose it."""

    def __init__(self, key: str, why: str):
        super().__init__(f"{key}: {why}")
        self.key = key
        self.why = why


def read_marker(folder: str) -> dict | None:
    """The marker of a jaxdip output folder, or None when ``folder`` is not one."""
    try:
        with open(os.path.join(folder, MARKER), encoding="utf-8") as fh:
            m = json.load(fh)
    except (OSError, ValueError):
        return None
    if not isinstance(m, dict) or m.get("tool") != "jaxdip" or not isinstance(m.get("files"), list):
        return None
    return m


def _shown(names: list[str], n: int = 3) -> str:
    more = f" and {len(names) - n} more" if len(names) > n else ""
    return ", ".join(sorted(names)[:n]) + more


def check_destination(path: str, owner: str, *, key: str = "--out", force: bool = False) -> None:
    """Raise OutputError unless writing ``owner``'s output at ``path`` loses nothing of the user's."""
    shown = path
    path = os.path.abspath(path)
    if os.path.islink(path):
        raise OutputError(key, f"{shown} is a symbolic link; give the folder itself")
    if os.path.exists(path) and not os.path.isdir(path):
        raise OutputError(key, f"{shown} exists and is a file, not a folder")
    if os.path.isdir(path):
        try:
            entries = os.listdir(path)
        except OSError as e:
            raise OutputError(key, f"cannot read {shown}: {e.strerror or e}") from None
        if entries:
            marker = read_marker(path)
            if marker is None:
                raise OutputError(key, f"{shown} exists and is not a jaxdip result folder ({len(entries)} entries); "
                                       "choose a new or empty folder")
            foreign = [e for e in entries if e != MARKER and e not in marker["files"]]
            if foreign:
                raise OutputError(key, f"{shown} holds files jaxdip did not write ({_shown(foreign)}); "
                                       "move them or choose another folder")
            if marker.get("owner") != owner and not force:
                raise OutputError(key, f"{shown} holds the results of {marker.get('owner')!r}, not {owner!r}; "
                                       "pass --force to replace them")
    _check_parent(path, shown, key)


def _check_parent(path: str, shown: str, key: str) -> None:
    """The nearest existing ancestor decides whether ``path`` can be made."""
    parent = os.path.dirname(path)
    while not os.path.exists(parent):
        parent = os.path.dirname(parent)
    if not os.path.isdir(parent):
        raise OutputError(key, f"cannot create {shown}: {parent} is a file")
    # try it: permission bits do not tell (root ignores them; read-only mounts and /proc refuse regardless)
    try:
        os.rmdir(tempfile.mkdtemp(prefix=".jaxdip-probe-", dir=parent))
    except OSError as e:
        raise OutputError(key, f"cannot write in {parent}: {e.strerror or e}") from None


@dataclass
class Staging:
    """A temporary folder beside the destination; ``commit`` moves its files into place."""

    dest: str
    owner: str
    tmp: str
    made: list[str] = field(default_factory=list)  # ancestors created for it, removed again if nothing lands
    committed: bool = False

    def commit(self) -> None:
        os.remove(os.path.join(self.tmp, PIDFILE))
        files = sorted(os.listdir(self.tmp))
        with open(os.path.join(self.tmp, MARKER), "w", encoding="utf-8") as fh:
            json.dump({"tool": "jaxdip", "owner": self.owner, "files": files}, fh, indent=1)
        if not os.path.exists(self.dest):
            os.rename(self.tmp, self.dest)
            self.committed = True
            return
        # the destination is empty or a previous run (checked again now: the user may have added files meanwhile);
        # files move one by one so the folder itself (perhaps the working directory) stays where it is
        old = read_marker(self.dest)
        check_destination(self.dest, self.owner, force=True)
        for name in files:
            os.replace(os.path.join(self.tmp, name), os.path.join(self.dest, name))
        for name in (old or {}).get("files", []):
            stale = os.path.join(self.dest, name)
            if name not in files and os.path.isfile(stale) and not os.path.islink(stale):
                os.remove(stale)
        os.replace(os.path.join(self.tmp, MARKER), os.path.join(self.dest, MARKER))
        os.rmdir(self.tmp)
        self.committed = True

    def discard(self) -> None:
        """Remove the temporary folder (and any ancestors made for it) unless the output was committed."""
        if self.committed:
            return
        shutil.rmtree(self.tmp, ignore_errors=True)
        for d in self.made:  # innermost first; only if still empty
            try:
                os.rmdir(d)
            except OSError:
                break


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _remove_abandoned(parent: str, base: str) -> None:
    """Temporary folders of runs that were killed (SIGKILL leaves no chance to clean up): ours by name and
    pid file, and their process is gone."""
    prefix = f".{base}.tmp-"
    for name in os.listdir(parent):
        d = os.path.join(parent, name)
        if not name.startswith(prefix) or not os.path.isdir(d) or os.path.islink(d):
            continue
        try:
            with open(os.path.join(d, PIDFILE)) as fh:
                pid = int(fh.read().strip())
        except (OSError, ValueError):
            continue
        if not _alive(pid):
            shutil.rmtree(d, ignore_errors=True)


def prepare(path: str, owner: str, *, key: str = "--out", force: bool = False) -> Staging:
    """Check the destination and create the temporary folder beside it (proving the place is writable)."""
    check_destination(path, owner, key=key, force=force)
    dest = os.path.abspath(path)
    parent = os.path.dirname(dest)
    made = []
    p = parent
    while not os.path.exists(p):
        made.append(p)
        p = os.path.dirname(p)
    try:
        os.makedirs(parent, exist_ok=True)
        _remove_abandoned(parent, os.path.basename(dest))
        tmp = tempfile.mkdtemp(prefix=f".{os.path.basename(dest)}.tmp-", dir=parent)
        with open(os.path.join(tmp, PIDFILE), "w") as fh:
            fh.write(str(os.getpid()))
    except OSError as e:
        for d in made:
            try:
                os.rmdir(d)
            except OSError:
                break
        raise OutputError(key, f"cannot write in {parent}: {e.strerror or e}") from None
    return Staging(dest, owner, tmp, made)


def check_file(path: str, is_ours, *, key: str = "--out") -> None:
    """Raise OutputError unless ``path`` is new or a file jaxdip wrote (``is_ours(text)``) in a writable folder."""
    shown = path
    path = os.path.abspath(path)
    if os.path.isdir(path):
        raise OutputError(key, f"{shown} is a folder; give a file name")
    if os.path.exists(path):
        try:
            with open(path, encoding="utf-8") as fh:
                ours = is_ours(fh.read(1 << 20))
        except (OSError, UnicodeDecodeError):
            ours = False
        if not ours:
            raise OutputError(key, f"{shown} exists and was not written by jaxdip; choose another name")
    _check_parent(path, shown, key)


def write_file_atomic(path: str, text: str) -> None:
    """Write one file by a temporary name and a rename, so a reader never sees half of it."""
    path = os.path.abspath(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{os.path.basename(path)}.tmp-", dir=os.path.dirname(path))
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise
