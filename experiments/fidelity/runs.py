"""The runs behind the fidelity readings: one ``jaxdip run`` command line per row, run as a child process.

``command`` builds the exact line a readings row shows; ``run`` executes it (as this interpreter's jaxdip) into
``workdir``/<a slug of the line> and returns its metrics.json; a folder that already holds a finished run of the
same line is read, not run again (so ``--runs DIR`` resumes a long readings study).
"""

from __future__ import annotations

import json
import os
import shlex
import subprocess
import sys

# the repository root: the child runs start there, and the pages go under its docs/
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def command(exp: str, sets: list[str], seeds: int | None, quick: bool) -> list[str]:
    cmd = ["jaxdip", "run", exp]
    if quick:
        cmd.append("--quick")
    if seeds is not None:
        cmd += ["--seeds", str(seeds)]
    for s in sets:
        cmd += ["--set", s]
    return cmd


def run(cmd: list[str], workdir: str) -> dict:
    """metrics.json of the ``jaxdip ...`` line ``cmd``, run into ``workdir`` unless already there."""
    slug = "_".join(cmd[2:]).replace("--set_", "").replace("=", "-").replace("--", "")
    slug = "".join(c if c.isalnum() or c in "-_.," else "_" for c in slug)[:200]
    out = os.path.join(workdir, slug)
    if not os.path.isfile(os.path.join(out, "metrics.json")):
        print("$", shlex.join(cmd), flush=True)
        # errors stay on stderr; the progress bars do not
        subprocess.run([sys.executable, "-m", "jaxdip.cli", *cmd[1:], "--out", out], check=True, cwd=ROOT,
                       stdout=subprocess.DEVNULL, env=dict(os.environ, JAXDIP_NO_PROGRESS="1"))
    with open(os.path.join(out, "metrics.json")) as fh:
        return json.load(fh)
