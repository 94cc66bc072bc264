"""A folder's exact state, to show that a command left every path it does not own as it was."""

from __future__ import annotations

import hashlib
import os
import stat


def snapshot(root) -> dict:
    """Every path under ``root`` with its kind and content hash (and link target); symbolic links not followed."""
    out = {}
    for dirpath, dirnames, filenames in os.walk(root):
        for name in dirnames + filenames:
            p = os.path.join(dirpath, name)
            rel = os.path.relpath(p, root)
            if os.path.islink(p):
                out[rel] = ("link", os.readlink(p))
            elif os.path.isdir(p):
                out[rel] = ("dir", oct(os.stat(p).st_mode))
            elif not stat.S_ISREG(os.lstat(p).st_mode):
                out[rel] = ("special", oct(os.lstat(p).st_mode))  # a FIFO or socket: reading it would block
            else:
                with open(p, "rb") as fh:
                    out[rel] = ("file", hashlib.sha256(fh.read()).hexdigest(), oct(os.stat(p).st_mode))
    return out
