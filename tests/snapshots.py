"""A folder's exact state, to show that a command left every path it does not own as it was."""

from __future__ import annotations

import hashlib
import os
import stat


def snapshot(root) -> dict:
    """Every path under ``root`` with its kind, mode and content hash (and link target); symbolic links not
    followed, special files (FIFOs, sockets, devices) never opened."""
    out = {}
    for dirpath, dirnames, filenames in os.walk(root):
        for name in dirnames + filenames:
            p = os.path.join(dirpath, name)
            rel = os.path.relpath(p, root)
            st = os.lstat(p)
            if stat.S_ISLNK(st.st_mode):
                out[rel] = ("link", os.readlink(p))
            elif stat.S_ISDIR(st.st_mode):
                out[rel] = ("dir", oct(st.st_mode), st.st_ino)
            elif stat.S_ISREG(st.st_mode):
                with open(p, "rb") as fh:
                    out[rel] = ("file", hashlib.sha256(fh.read()).hexdigest(), oct(st.st_mode), st.st_uid)
            else:
                out[rel] = ("special", oct(st.st_mode))
    return out
