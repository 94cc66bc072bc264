"""The command line's error contract, in one place.

- A refusal is exactly one line on standard error, ``error: <key or flag>: <why>``, at most
  ``messages.MAX_LINE`` characters, user text shortened and control characters escaped; exit status 2.
- Warnings (Python's and log records, JAX's included) raised while a command checks its input are held back:
  dropped when the command refuses, shown once the work starts (``Held``).
- A closed pipe on standard output (``jaxdip list | head -1``) ends the command quietly (status 141, as a
  process killed by SIGPIPE); a terminal that cannot encode a character gets it escaped; a full disk or any
  other failed write, and running out of memory, end in one line (``guarded``).
"""

from __future__ import annotations

import errno
import logging
import os
import sys
import warnings
from typing import Callable

from jaxdip.messages import MAX_LINE, clean, shorten

KEY_LIMIT = 80  # a key or flag longer than this is user text (an unknown key), cut like any other
BROKEN_PIPE = 141  # 128 + SIGPIPE: what a shell reports for a writer whose reader went away


def error(key: str, why: str = "") -> int:
    """Print the one error line and return the exit status 2; warnings held so far are dropped."""
    Held.drop_all()
    key = shorten(clean(str(key), 10 * KEY_LIMIT), KEY_LIMIT)
    line = f"error: {key}: {why}" if why else f"error: {key}"
    _say(clean(line, MAX_LINE))
    return 2


def note(text: str) -> None:
    """A one-line remark (``interrupted: ...``) under the same rules as an error line."""
    _say(clean(text, 2 * MAX_LINE))


def warn(text: str) -> None:
    """A warning of jaxdip's own: held with the others while the command checks its input."""
    if Held.current is not None:
        Held.current.lines.append(clean(f"warning: {text}", MAX_LINE))
    else:
        _say(clean(f"warning: {text}", MAX_LINE))


def _say(line: str) -> None:
    try:
        print(line, file=sys.stderr, flush=True)
    except (BrokenPipeError, ValueError):  # nobody reads standard error any more: nothing left to tell
        pass


class _Holder(logging.Handler):
    def __init__(self, lines: list[str]):
        super().__init__(logging.WARNING)
        self.lines = lines

    def emit(self, record):
        try:
            self.lines.append(clean(f"warning: {record.getMessage()}", MAX_LINE))
        except Exception:  # noqa: BLE001  (a record that cannot be formatted is not worth a crash)
            pass


class Held:
    """Holds warnings back from the start of a command until ``release`` (the work starts: they are shown) or
    an error line (they are dropped, so a refusal stays one line)."""

    current: "Held | None" = None

    def __init__(self):
        self.lines: list[str] = []
        self._handler = _Holder(self.lines)
        self._showwarning = None

    def __enter__(self) -> "Held":
        self._showwarning = warnings.showwarning
        warnings.showwarning = self._hold_warning
        logging.getLogger().addHandler(self._handler)
        Held.current = self
        return self

    def __exit__(self, *exc) -> bool:
        self.release()
        return False

    def _hold_warning(self, message, category, filename, lineno, file=None, line=None):
        self.lines.append(clean(f"warning: {category.__name__}: {message}", MAX_LINE))

    def _restore(self) -> None:
        if Held.current is self:
            Held.current = None
            warnings.showwarning = self._showwarning
            logging.getLogger().removeHandler(self._handler)

    def release(self) -> None:
        """The work starts: show what was held, and let later warnings through as usual."""
        if Held.current is not self:
            return
        self._restore()
        for line in self.lines:
            _say(line)
        self.lines.clear()

    @classmethod
    def drop_all(cls) -> None:
        if cls.current is not None:
            cur = cls.current
            cur._restore()
            cur.lines.clear()


def release_held() -> None:
    if Held.current is not None:
        Held.current.release()


def _reconfigure_streams() -> None:
    """Characters a terminal's encoding lacks (LANG=C, PYTHONIOENCODING=ascii) are escaped, not an error."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.reconfigure(errors="backslashreplace")
        except (AttributeError, ValueError, OSError):
            pass


def _stdout_gone() -> None:
    """Point standard output at /dev/null, so the interpreter's last flush at exit finds nothing to complain of."""
    try:
        fd = os.open(os.devnull, os.O_WRONLY)
        os.dup2(fd, sys.stdout.fileno())
        os.close(fd)
    except (OSError, ValueError, AttributeError):
        pass


WRITE_ERRNOS = {errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EFBIG, errno.EIO, errno.EACCES, errno.EPERM}


def _oserror_line(e: OSError, key: str) -> int:
    where = e.filename if e.filename is not None else "standard output"
    why = e.strerror or str(e)
    if e.errno in WRITE_ERRNOS:
        return error(key, f"cannot write {where}: {why}")
    return error(key, f"{where}: {why}")


OUT_OF_MEMORY = "the run ran out of memory; lower --seeds, shorten the run or save less"


def out_of_memory(e: BaseException) -> bool:
    text = str(e)
    # XLA's allocation failures, and a shared library that could not be mapped under a memory limit
    return isinstance(e, MemoryError) or any(s in text for s in ("RESOURCE_EXHAUSTED", "Out of memory",
                                                                 "Cannot allocate memory"))


def guarded(command: Callable[[], int], key: str = "--out") -> int:
    """Run a command under the contract: its status, or the status of the one line that replaced a crash."""
    _reconfigure_streams()
    try:
        with Held():
            code = command()
            if sys.stdout is not None:  # None when the command was started with standard output closed
                sys.stdout.flush()
        return code
    except BrokenPipeError:
        Held.drop_all()
        _stdout_gone()
        return BROKEN_PIPE
    except KeyboardInterrupt:
        Held.drop_all()
        note("interrupted: nothing was written")
        return 130
    except MemoryError:
        return error("--seeds", OUT_OF_MEMORY)
    except OSError as e:
        if e.filename is None:  # standard output itself (a full disk behind a redirection)
            _stdout_gone()
        return _oserror_line(e, key if e.filename is not None else "stdout")
    except Exception as e:
        if out_of_memory(e):
            return error("--seeds", OUT_OF_MEMORY)
        raise
