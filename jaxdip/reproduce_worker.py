"""A worker of ``jaxdip reproduce``: runs the ``jaxdip run`` commands its parent sends, one after another, in this
one process, so the experiments it runs share one JAX start-up and one in-memory cache of compiled programs.

Protocol (one JSON object per line): the parent writes ``{"id", "argv", "log"}`` on the worker's standard input;
the worker runs ``jaxdip <argv>`` with its standard output and error (the file descriptors, so XLA's messages too)
going to ``log``, then answers ``{"id", "rc"}`` on its original standard output. End of input ends the worker; so
does an interrupted run (exit code 130), after its answer.
"""

from __future__ import annotations

import json
import os
import sys
import traceback
from typing import TextIO


def keep_to_cpus(cpus: str | None = None) -> None:
    """Keep this process to ``cpus`` ("0,1"; default: the ``JAXDIP_WORKER_CPUS`` its parent gave it, see
    ``reproduce_pool.cpu_blocks``), before JAX starts its backend and sizes its thread pool from them."""
    cpus = os.environ.get("JAXDIP_WORKER_CPUS") if cpus is None else cpus
    if cpus and hasattr(os, "sched_setaffinity"):
        try:
            os.sched_setaffinity(0, {int(c) for c in cpus.split(",")})
        except (OSError, ValueError):
            pass  # the CPUs changed under us: run unpinned, as before


def main(tasks: TextIO | None = None) -> int:
    """Run the tasks read from ``tasks`` (default: standard input), answering on standard output."""
    keep_to_cpus()
    answers = os.fdopen(os.dup(1), "w", buffering=1)
    from jaxdip import cli

    for line in sys.stdin if tasks is None else tasks:
        task = json.loads(line)
        fd = os.open(task["log"], os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        sys.stdout.flush()
        sys.stderr.flush()
        os.dup2(fd, 1)
        os.dup2(fd, 2)
        os.close(fd)
        try:
            rc = cli.main(task["argv"])
        except SystemExit as e:
            rc = e.code if isinstance(e.code, int) else 1
        except Exception:
            traceback.print_exc()
            rc = 1
        sys.stdout.flush()
        sys.stderr.flush()
        answers.write(json.dumps({"id": task["id"], "rc": rc}) + "\n")
        if rc == 130:
            break
    return 0


if __name__ == "__main__":
    from jaxdip import gc_policy
    from jaxdip.cli_errors import end_process

    gc_policy.for_a_command()  # a started worker, as the command that starts it (a forked one inherits it)

    end_process(main())  # every run's files are written and its answer sent: no teardown to wait for
