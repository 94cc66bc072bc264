"""The command line's error contract, in one place.

- A refusal is exactly one line on standard error, ``error: <key or flag>: <why>``, at most
  ``messages.MAX_LINE`` characters, user text shortened and control characters escaped; exit status 2.
- Warnings (Python's and log records, JAX's included) are held back for the whole command: dropped when it
  ends in an error line, shown when it ends otherwise (``Held``). A refusal can come late (a Riccati design
  that fails on an extreme weight, after NumPy warned of an overflow) and must still be one line.
- A closed pipe on standard output (``jaxdip list | head -1``) ends the command quietly (status 141, as a
  process killed by SIGPIPE); a terminal that cannot encode a character gets it escaped; a full disk or any
  other failed write, and running out of memory, end in one line (``guarded``).
- A component's ``ArgumentError`` while a run builds its scenario (a config value that passed the config's checks
  but not the component's) is a refusal like a config error: one line, status 2 (``component_refusal``); every
  refusal a run can end in is mapped to its line in one place (``run_refusal``), for ``run`` and its sweeps.
- SIGINT and SIGTERM stop a run (``Signals``) with exit status 130.
- A finished command's process ends with its status, at once (``end_process``).
"""

from __future__ import annotations

import dataclasses
import errno
import logging
import os
import signal
import sys
import warnings
from typing import Any, Callable

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
        _keep(Held.current.lines, clean(f"warning: {text}", MAX_LINE))
    else:
        _say(clean(f"warning: {text}", MAX_LINE))


def _say(line: str) -> None:
    try:
        print(line, file=sys.stderr, flush=True)
    except (BrokenPipeError, ValueError):  # nobody reads standard error any more: nothing left to tell
        pass


MAX_HELD = 50  # a library that warns on every step should not fill the memory of a long run


def _keep(lines: list[str], line: str) -> None:
    if len(lines) < MAX_HELD:
        lines.append(line)
    elif len(lines) == MAX_HELD:
        lines.append("warning: (more warnings left out)")


class _Holder(logging.Handler):
    def __init__(self, lines: list[str]):
        super().__init__(logging.WARNING)
        self.lines = lines

    def emit(self, record):
        try:
            _keep(self.lines, clean(f"warning: {record.getMessage()}", MAX_LINE))
        except Exception:  # noqa: BLE001  (a record that cannot be formatted is not worth a crash)
            pass


class Held:
    """Holds warnings back from the start of a command until ``release`` (the command ended without an error:
    they are shown) or an error line (they are dropped, so a refusal stays one line)."""

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
        _keep(self.lines, clean(f"warning: {category.__name__}: {message}", MAX_LINE))

    def _restore(self) -> None:
        if Held.current is self:
            Held.current = None
            warnings.showwarning = self._showwarning
            logging.getLogger().removeHandler(self._handler)

    def release(self) -> None:
        """Show what was held, and let later warnings through as usual."""
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


def _oserror_line(e: OSError, key: str, where: str | None = None) -> int:
    where = where or (str(e.filename) if e.filename is not None else None)
    why = e.strerror or str(e) or type(e).__name__
    if e.errno in WRITE_ERRNOS:
        return error(key, f"cannot write {where}: {why}" if where else f"a write failed: {why}")
    return error(key, f"{where}: {why}" if where else why)


OUT_OF_MEMORY = "the run ran out of memory; lower --seeds, shorten the run or save less"


def out_of_memory(e: BaseException) -> bool:
    text = str(e)
    # XLA's allocation failures, and a shared library that could not be mapped under a memory limit
    return isinstance(e, MemoryError) or any(s in text for s in ("RESOURCE_EXHAUSTED", "Out of memory",
                                                                 "Cannot allocate memory"))


class _StdoutFailed(Exception):
    def __init__(self, error: OSError):
        super().__init__(str(error))
        self.error = error


def emit(text: str, end: str = "\n") -> None:
    """Print to standard output and flush, so that a failed write (a redirection to a full disk) is known to be
    standard output's, not an output file's."""
    if sys.stdout is None:  # started with standard output closed
        return
    try:
        print(text, end=end)
        sys.stdout.flush()
    except BrokenPipeError:
        raise
    except OSError as e:
        raise _StdoutFailed(e) from None


def guarded(command: Callable[[], int], key: str = "--out") -> int:
    """Run a command under the contract: its status, or the status of the one line that replaced a crash."""
    _reconfigure_streams()
    try:
        with Held():
            code = command()
            emit("", end="")
        return code
    except _StdoutFailed as e:
        _stdout_gone()
        return _oserror_line(e.error, "stdout", "standard output")
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
        return _oserror_line(e, key)
    except Exception as e:
        if out_of_memory(e):
            return error("--seeds", OUT_OF_MEMORY)
        raise


def riccati_keys(cfg) -> str:
    """The config keys that shape a Riccati design, to point the user at what to change."""
    names = [f.name for f in dataclasses.fields(cfg)] if dataclasses.is_dataclass(cfg) else []
    keys = [n for n in names if n in ("Q", "R", "Q_lqr", "R_lqr", "Qk", "Rk", "W", "V")
            or n.startswith(("Q_", "R_", "lqr_"))]
    return ", ".join(keys) if keys else "the weights"


def component_refusal(cfg, e: Exception, exp_id: str, where: str = "") -> int:
    """An ``ArgumentError`` raised while a run builds its scenario: a config value that passed the config's own
    checks but not a component's (``ExtraControl: k1 must be >= 0 and finite, got -1``). One line, keyed by the
    config key of the argument's name when the config has one (the component's own words follow), else by the
    experiment."""
    text = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
    names = {f.name for f in dataclasses.fields(cfg)} if dataclasses.is_dataclass(cfg) else set()
    # "<owner>: <argument> must ...": the argument, without an index or attribute ("pend.alpha" -> "pend")
    arg = text.split(": ", 1)[1].split(" ", 1)[0].split(".")[0].split("[")[0] if ": " in text else ""
    key = f"{where}{arg}" if arg in names else exp_id
    return error(key, text)


EXTREME_DECADES = 12  # a value this many decades from 1 is named as the likely cause of a numerical failure


def numerical(cfg, e: Exception, where: str = "") -> int:
    """A design or simulation whose linear algebra or arithmetic failed on the config's values: one line naming
    the most extreme value when there is one (weights of 1e308); a failed factorisation with ordinary values
    names the design's weights. Anything else is a bug, and keeps its traceback."""
    import numpy as np

    from jaxdip.config import most_extreme
    from jaxdip.messages import shown

    key, value, decades = most_extreme(cfg)
    first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
    if decades >= EXTREME_DECADES:
        return error(f"{where}{key}", f"{shown(value, 24)} is out of range: the computation failed ({first})")
    if isinstance(e, np.linalg.LinAlgError):
        return error(f"{where}{riccati_keys(cfg)}", f"the computation failed on these values ({first})")
    raise e


def run_refusal(e: Exception, cfg, exp_id: str) -> int | None:
    """The one line for an exception a run of ``exp_id`` with ``cfg`` raised, as its exit status: a refusal of the
    config, destination, checkpoint or results, a component's, a failed design or an out-of-memory. None for
    anything else (a bug: the caller re-raises it, keeping its traceback)."""
    import numpy as np

    from jaxdip.checkpoint import CheckpointError
    from jaxdip.config import ConfigError
    from jaxdip.control.riccati import RiccatiError
    from jaxdip.engine.checks import ArgumentError
    from jaxdip.outdir import OutputError
    from jaxdip.runner.results import ResultError
    from jaxdip.search.failures import SearchStopped

    if isinstance(e, (ConfigError, OutputError, ResultError, SearchStopped)):
        return error(e.key, e.why)
    if isinstance(e, CheckpointError):
        return error("--resume", str(e))
    if isinstance(e, RiccatiError):
        return error(riccati_keys(cfg), str(e))
    if isinstance(e, ArgumentError):
        return component_refusal(cfg, e, exp_id)
    if isinstance(e, (np.linalg.LinAlgError, ArithmeticError, ValueError)):
        return numerical(cfg, e)
    if out_of_memory(e):
        return error("--seeds", OUT_OF_MEMORY)
    return None


_SEEN: list = []  # the signals any handler below has taken in this process


def interrupt_seen() -> bool:
    """Whether this process has taken Ctrl-C (or, inside ``Signals``, SIGTERM) since ``main`` began, even where the
    KeyboardInterrupt it raised was swallowed: Python prints and drops an exception raised inside a
    garbage-collector callback, and JAX runs one at every collection, so a Ctrl-C can land there and vanish."""
    return bool(_SEEN)


def remember_sigint() -> Any:
    """From here on Ctrl-C raises KeyboardInterrupt as Python's own handler does, and is remembered
    (``interrupt_seen``, cleared here), for the waits that poll it. Returns the handler it replaced."""
    def handler(signum, frame):
        _SEEN.append(signum)
        raise KeyboardInterrupt

    _SEEN.clear()
    return signal.signal(signal.SIGINT, handler)


class Signals:
    """SIGINT and SIGTERM stop a run: the first raises KeyboardInterrupt and is remembered, so a run whose
    library code swallowed it still refuses to write its folder (``run_experiment``'s ``stop_requested``)."""

    def __init__(self):
        self.hit = None
        self._old = {}

    def _handler(self, signum, frame):
        self.hit = signum
        _SEEN.append(signum)
        raise KeyboardInterrupt

    def __enter__(self):
        for sig in (signal.SIGINT, signal.SIGTERM):
            self._old[sig] = signal.signal(sig, self._handler)
        return self

    def __exit__(self, *exc):
        for sig, h in self._old.items():
            signal.signal(sig, h)
        return False

    def requested(self) -> bool:
        return self.hit is not None


def end_process(code: int) -> None:
    """Exit with ``code`` once a command is done, without the interpreter's teardown where nothing needs it.

    When a command returns, its files are written and closed; what the teardown would still do is JAX clearing
    its backends and compiled programs, 0.3-0.5 s of a warm ``jaxdip run`` and about 1.3 s that a reproduction
    waited for its last worker. It is kept where something does need it: a multi-process run (JAX shuts the
    distributed system down in it), and a process being traced or profiled (coverage, cProfile write their data
    at exit)."""
    jax = sys.modules.get("jax")
    if (jax is not None and jax.distributed.is_initialized()) or sys.gettrace() or sys.getprofile():
        sys.exit(code)
    flush_output()
    os._exit(code)


def flush_output() -> None:
    """Write out what standard output and error hold, before ``os._exit`` or ``os.fork`` (which would drop it,
    or write it twice); a closed pipe (``| head``) or stream is no error: nothing more can be said there."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
