"""The marker ``.jaxdip.json``: what jaxdip writes into each output folder, and the strict reader of it.

A marker is data found on disk (an unpacked archive, a shared drive, a cloned repository may hold any), so the
reader accepts exactly what ``marker_text`` writes and nothing else: a regular file of at most ``MAX_BYTES``,
owned by this user, UTF-8 JSON with no duplicate keys, the four keys below and no others, an experiment id as
owner, and a mapping from plain file names to SHA-256 hex digests. Anything else is "not a jaxdip folder".
The names it lists are only ever compared with names found by listing the folder itself; they never become
paths.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import stat

MARKER = ".jaxdip.json"
FORMAT = 2  # format 1 listed names without content hashes: such a folder cannot be verified, so it is refused
MAX_BYTES = 64 * 1024
MAX_FILES = 256  # with names of up to 128 characters the marker stays under MAX_BYTES
MAX_FILE_BYTES = 1 << 30  # a file larger than this is not one jaxdip wrote (and hashing it would take long)

# file names jaxdip gives its outputs: plain, visible, portable (no separators, no "..", no control characters)
_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9._+-]{0,127}")
_OWNER = re.compile(r"[a-z0-9][a-z0-9-]{0,63}")
_DIGEST = re.compile(r"[0-9a-f]{64}")


class NotOurs(Exception):
    """Why something on disk is not what jaxdip wrote (a short phrase, shown to the user)."""


def valid_name(name: object) -> bool:
    """True for a file name jaxdip could have given one of its outputs."""
    return isinstance(name, str) and _NAME.fullmatch(name) is not None and ".." not in name


def valid_owner(owner: object) -> bool:
    return isinstance(owner, str) and _OWNER.fullmatch(owner) is not None


def _open_regular(dir_fd: int | None, name: str, limit: int, what: str) -> tuple[int, os.stat_result]:
    """Open ``name`` (relative to ``dir_fd``) for reading only if it is a regular file of this user, at most
    ``limit`` bytes: never follows a symbolic link, never blocks on a FIFO or a device."""
    try:
        st = os.lstat(name, dir_fd=dir_fd)
    except FileNotFoundError:
        raise NotOurs(f"{what} is missing") from None
    except OSError as e:
        raise NotOurs(f"{what} cannot be read ({e.strerror or e})") from None
    if not stat.S_ISREG(st.st_mode):
        raise NotOurs(f"{what} is not a regular file")
    if st.st_uid != os.geteuid():
        raise NotOurs(f"{what} belongs to another user")
    if st.st_size > limit:
        raise NotOurs(f"{what} is too large")
    try:
        fd = os.open(name, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC, dir_fd=dir_fd)
    except OSError as e:
        raise NotOurs(f"{what} cannot be read ({e.strerror or e})") from None
    st2 = os.fstat(fd)
    if (st2.st_dev, st2.st_ino) != (st.st_dev, st.st_ino) or not stat.S_ISREG(st2.st_mode):
        os.close(fd)
        raise NotOurs(f"{what} changed while it was read")
    return fd, st2


def file_digest(name: str, dir_fd: int | None = None) -> str:
    """SHA-256 of a regular file of this user (``NotOurs`` for anything else)."""
    fd, _ = _open_regular(dir_fd, name, MAX_FILE_BYTES, name)
    h = hashlib.sha256()
    with os.fdopen(fd, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def marker_text(owner: str, files: dict[str, str]) -> str:
    """The marker jaxdip writes: ``files`` maps each output's name to its SHA-256."""
    if not valid_owner(owner):
        raise ValueError(f"not an experiment id: {owner!r}")
    bad = [n for n in files if not valid_name(n)]
    if bad or len(files) > MAX_FILES:
        raise ValueError(f"output names jaxdip cannot record: {bad[:3]}")
    text = json.dumps({"tool": "jaxdip", "format": FORMAT, "owner": owner, "files": dict(sorted(files.items()))},
                      indent=1)
    if len(text.encode()) > MAX_BYTES:
        raise ValueError("too many outputs to record in a marker")
    return text


def _no_duplicates(pairs):
    keys = [k for k, _ in pairs]
    if len(set(keys)) != len(keys):
        raise NotOurs("the marker repeats a key")
    return dict(pairs)


def _no_constant(name):
    raise NotOurs("the marker holds a non-JSON number")


def parse_marker(data: bytes) -> tuple[str, dict[str, str]]:
    """``(owner, {name: sha256})`` of marker bytes exactly as ``marker_text`` writes them, else ``NotOurs``."""
    try:
        text = data.decode("utf-8")
        m = json.loads(text, object_pairs_hook=_no_duplicates, parse_constant=_no_constant)
    except (UnicodeDecodeError, ValueError, RecursionError):
        raise NotOurs("the marker is not JSON") from None
    if not isinstance(m, dict) or m.get("tool") != "jaxdip":
        raise NotOurs("the marker was not written by jaxdip")
    if set(m) != {"tool", "format", "owner", "files"}:
        if isinstance(m.get("files"), list):
            raise NotOurs("the marker was written by an older jaxdip without content hashes")
        raise NotOurs("the marker has unexpected keys")
    if type(m["format"]) is not int or m["format"] != FORMAT:
        raise NotOurs("the marker has an unknown format")
    if not valid_owner(m["owner"]):
        raise NotOurs("the marker names no experiment")
    files = m["files"]
    if not isinstance(files, dict) or len(files) > MAX_FILES:
        raise NotOurs("the marker's file list is malformed")
    for name, digest in files.items():
        if not valid_name(name) or not isinstance(digest, str) or _DIGEST.fullmatch(digest) is None:
            raise NotOurs("the marker lists a name or hash jaxdip never writes")
    return m["owner"], files


def read_marker(dir_fd: int) -> tuple[str, dict[str, str]]:
    """The marker of the folder open as ``dir_fd`` (``NotOurs`` if absent or not exactly jaxdip's)."""
    fd, _ = _open_regular(dir_fd, MARKER, MAX_BYTES, "the marker")
    with os.fdopen(fd, "rb") as fh:
        data = fh.read(MAX_BYTES + 1)
    if len(data) > MAX_BYTES:
        raise NotOurs("the marker is too large")
    return parse_marker(data)
