"""A run's output folder from first check to commit: ``prepare`` before anything compiles, ``Staging.commit``
once every file is written, ``Staging.discard`` on every way out.

The commit holds a lock on the destination's parent, recovers what killed runs left there, and checks that the
destination is still exactly what ``prepare`` saw (same folder, same marker, same files). If it is not (a
second run committed first, the user added or edited a file, a name turned into a folder), the run stops with
one line and moves its finished output to a folder it names beside the destination, instead of replacing
anything.
"""

from __future__ import annotations

import errno
import fcntl
import os
import shutil
import tempfile
import time
from dataclasses import dataclass, field

from jaxdip.outdir import swap
from jaxdip.outdir.files import umask
from jaxdip.outdir.folder import OutputError, Verdict, absolute, check_parent, classify, open_dir, shown
from jaxdip.outdir.marker import MARKER, NotOurs, file_digest, marker_text, valid_name


def check_destination(path: str, owner: str, *, key: str = "--out", force: bool = False) -> Verdict:
    """Raise OutputError unless writing ``owner``'s output at ``path`` loses nothing of the user's; the verdict
    says what is there now (a killed run's half-done commit there is finished or undone first)."""
    dest = absolute(path, key)
    parent = os.path.dirname(dest)
    if os.path.isdir(parent):
        try:
            with swap.locked(parent):
                swap.recover(parent, dest)
        except TimeoutError as e:
            raise OutputError(key, str(e)) from None
    verdict = classify(dest, owner, key=key, force=force, label=path)
    check_parent(dest, path, key)
    return verdict


def _reason(e: OSError) -> str:
    return "the disk is full" if e.errno == errno.ENOSPC else (e.strerror or str(e))


@dataclass
class Staging:
    """A staging folder beside the destination; the run writes its files into ``tmp``."""

    dest: str
    owner: str
    verdict: Verdict
    container: str
    key: str = "--out"
    force: bool = False
    label: str = ""
    made: list[str] = field(default_factory=list)  # ancestors created for it, removed again if nothing lands
    committed: bool = False
    kept: str | None = None
    _lock_fd: int | None = None
    _moved: tuple[dict, dict] | None = None  # (old, new) digests once the commit has begun moving files

    @property
    def tmp(self) -> str:
        return os.path.join(self.container, swap.NEW)

    def _digests(self) -> dict[str, str]:
        fd = open_dir(self.tmp)
        try:
            names = os.listdir(fd)
            bad = [n for n in names if not valid_name(n)]
            if bad:
                raise ValueError(f"jaxdip tried to write outputs it cannot record: {bad[:3]}")
            return {n: file_digest(n, fd) for n in names}
        except NotOurs as e:
            raise ValueError(f"an output of the run is not a plain file: {e}") from None
        finally:
            os.close(fd)

    def commit(self) -> None:
        """Put the output in place, all or nothing; OutputError (one line) where it cannot."""
        label = shown(self.label or self.dest)
        try:
            new = self._digests()
            with open(os.path.join(self.tmp, MARKER), "x", encoding="utf-8") as fh:
                fh.write(marker_text(self.owner, new))
            new[MARKER] = swap.digest_in(self.tmp, MARKER)
        except OSError as e:
            raise OutputError(self.key, f"cannot write {label}: {_reason(e)}") from None
        parent = os.path.dirname(self.dest)
        try:
            with swap.locked(parent):
                swap.recover(parent, self.dest)
                try:
                    now = classify(self.dest, self.owner, key=self.key, force=self.force, label=self.label)
                except OutputError as e:
                    self._keep(shown(e.why.split(";")[0], 140))
                if now != self.verdict:
                    self._keep(f"{label} changed while this run was writing (another run or the user wrote there)")
                self._put(now, new)
        except TimeoutError as e:
            self._keep(str(e))
        except OSError as e:
            self._keep(f"cannot replace {label}: {_reason(e)}")
        self.committed = True
        self.discard()

    def _put(self, now: Verdict, new: dict[str, str]) -> None:
        self._moved = ({}, new)
        if now.kind == "new":
            os.chmod(self.tmp, 0o777 & ~umask())
            swap.rename_noreplace(self.tmp, self.dest)
            return
        old = dict(now.files)
        if now.marker is not None:
            old[MARKER] = now.marker
        self._moved = (old, new)
        os.chmod(self.tmp, now.mode)
        cwd = _cwd_ident()
        if cwd != now.ident:
            swap.write_json(os.path.join(self.container, swap.JOURNAL),
                            {"mode": "exchange", "dest": self.dest, "old": old, "new": new})
            if swap.exchange(self.tmp, self.dest):
                # the folder that was there is now ``tmp``: it must be what was checked, else swap back
                try:
                    was = classify(self.tmp, self.owner, key=self.key, force=True)
                except OutputError:
                    was = None
                if was is None or (was.ident, was.files, was.marker) != (now.ident, now.files, now.marker):
                    swap.exchange(self.tmp, self.dest)
                    raise OSError(errno.EBUSY, "it changed during the commit")
                return
        swap.swap_in_place(self.container, self.dest, old, new)

    def _keep(self, why: str) -> None:
        """Stop with ``why``, moving the finished output to a visible folder beside the destination."""
        kept = f"{self.dest}.kept-{time.strftime('%Y%m%d-%H%M%S')}-{os.getpid()}"
        try:
            os.chmod(self.tmp, 0o777 & ~umask())
            swap.rename_noreplace(self.tmp, kept)
        except OSError:
            raise OutputError(self.key, f"{why}; nothing was replaced, and this run's output is lost") from None
        self.kept = kept
        try:
            near = min(kept, os.path.relpath(kept), key=len)
        except (OSError, ValueError):
            near = kept
        near = near if len(near) <= 120 else os.path.basename(kept) + " beside it"
        raise OutputError(self.key, f"{why}; this run's output is in {shown(near, 140)}, nothing was replaced")

    def discard(self) -> None:
        """Remove the staging folder (and ancestors made for it if nothing landed). Safe to call twice."""
        if self._lock_fd is not None:
            if self._moved is None:
                shutil.rmtree(self.container, ignore_errors=True)  # only this run's own output is inside
            else:
                swap.remove_container(self.container, *self._moved)  # may hold the replaced folder: by content
            os.close(self._lock_fd)  # after the removal: until then the folder is provably a live run's
            self._lock_fd = None
        if self.committed or self.kept:
            return
        for d in self.made:  # innermost first; only if still empty
            try:
                os.rmdir(d)
            except OSError:
                break


def _cwd_ident() -> tuple[int, int] | None:
    try:
        st = os.stat(".")
    except OSError:
        return None
    return st.st_dev, st.st_ino


def prepare(path: str, owner: str, *, key: str = "--out", force: bool = False) -> Staging:
    """Check the destination and create the staging folder beside it (proving the place is writable)."""
    verdict = check_destination(path, owner, key=key, force=force)
    dest = verdict.path
    parent = os.path.dirname(dest)
    made, p = [], parent
    while not os.path.exists(p):
        made.append(p)
        p = os.path.dirname(p)
    container, fd = None, None
    try:
        os.makedirs(parent, exist_ok=True)
        with swap.locked(parent):  # made and locked at once, as far as another run's clean-up can tell
            container = tempfile.mkdtemp(prefix=swap.container_prefix(dest), dir=parent)
            fd = os.open(os.path.join(container, swap.PIDFILE), os.O_RDWR | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC,
                         0o600)
            fcntl.flock(fd, fcntl.LOCK_EX)
        os.write(fd, f"{os.getpid()}\n".encode())
        os.mkdir(os.path.join(container, swap.NEW))
    except (OSError, TimeoutError) as e:
        if fd is not None:
            os.close(fd)
        if container is not None:
            shutil.rmtree(container, ignore_errors=True)
        for d in made:
            try:
                os.rmdir(d)
            except OSError:
                break
        why = _reason(e) if isinstance(e, OSError) and not isinstance(e, TimeoutError) else str(e)
        raise OutputError(key, f"cannot write in {shown(parent)}: {why}") from None
    return Staging(dest, owner, verdict, container, key, force, path, made, _lock_fd=fd)
