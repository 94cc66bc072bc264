"""Text that reaches a terminal: user-supplied values shortened and made harmless before they are echoed.

A value from the command line or a config file can be 100,000 characters long or hold escape sequences that a
terminal would obey (colours, cursor moves, a title change); an undecodable byte in a path arrives as a lone
surrogate that a strict encoder refuses. Everything jaxdip echoes back goes through ``shown`` (one value) or
``clean`` (a whole message).
"""

from __future__ import annotations

MAX_LINE = 300  # one error line, "error: " included


def escape(text: str) -> str:
    """``text`` with every character a terminal would not print as itself (control characters, format
    characters such as bidirectional overrides, lone surrogates) written as a Python escape (``\\x1b``)."""
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else c.encode("unicode_escape", "backslashreplace").decode("ascii")
                   for c in text)


def shorten(text: str, limit: int) -> str:
    """``text`` cut in the middle to at most ``limit`` characters (the start and the end say most)."""
    if len(text) <= limit:
        return text
    keep = max(limit - 5, 2)
    head = (keep * 2) // 3
    return f"{text[:head]} ... {text[len(text) - (keep - head):]}"


def shown(value, limit: int = 60) -> str:
    """A user-supplied value for a message: its repr, escaped, at most ``limit`` characters."""
    text = value if isinstance(value, str) else None
    if text is not None and len(text) > 4 * limit:
        text = text[: 2 * limit] + text[-2 * limit:]  # repr of 100 kB just to cut it would be wasted work
    return shorten(escape(repr(value if text is None else text)), limit)


def clean(message: str, limit: int = MAX_LINE) -> str:
    """A message as one terminal line: whitespace runs (newlines included) folded, the rest escaped, cut to
    ``limit`` characters."""
    if len(message) > 8 * limit:
        message = message[: 4 * limit] + " ... " + message[-2 * limit:]
    return shorten(escape(" ".join(message.split())), limit)
