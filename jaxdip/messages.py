"""Text that reaches a terminal: user-supplied values shortened and made harmless before they are echoed.

A value from the command line or a config file can be 100,000 characters long or hold escape sequences that a
terminal would obey (colours, cursor moves, a title change); an undecodable byte in a path arrives as a lone
surrogate that a strict encoder refuses. Everything jaxdip echoes back goes through ``shown`` (one value) or
``clean`` (a whole message).

A name jaxdip does not know (an experiment id, a config key, a choice, a flag) is answered with the closest one
it knows, ``(did you mean 'dip-lqr'?)``, else the list (``suggestion``, ``unknown``): one wording everywhere.
"""

from __future__ import annotations

import difflib
from typing import Iterable

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


def closest(word: str, choices: Iterable[str]) -> str | None:
    """The one of ``choices`` that ``word`` most likely misspells, or None when none is close."""
    close = difflib.get_close_matches(word, list(choices), n=1)
    return close[0] if close else None


def suggestion(word: str, choices: Iterable[str], known: str | None = "known") -> str:
    """The hint after a name jaxdip does not know (an experiment id, a config key, a flag, a choice):
    `` (did you mean 'x'?)`` for the closest of ``choices``, else `` (known: a, b, c)`` (nothing with
    ``known=None``: for a message that lists the choices already). Every such refusal words its hint here, so a
    user reads it the same way wherever the command line takes a name."""
    choices = [str(c) for c in choices]
    if isinstance(word, str) and (near := closest(word, choices)) is not None:
        return f" (did you mean {shown(near)}?)"
    return listing(choices, known) if known else ""


def listing(choices: Iterable[str], known: str = "known") -> str:
    """`` (known: a, b, c)``: the names there are, for a refusal that has no closest one to suggest."""
    choices = [str(c) for c in choices]
    return f" ({known}: {', '.join(choices)})" if choices else ""


def unknown(what: str, names: Iterable[str], choices: Iterable[str]) -> str:
    """``unknown <what> 'x' (did you mean 'y'?), 'z' (known: a, b)``: several unknown names (a comma list a
    flag took), each with its closest choice, and the whole list once when one of them has none."""
    names, choices = list(names), [str(c) for c in choices]
    hints = [f"{shown(w)}{suggestion(w, choices, known=None)}" for w in names]
    rest = "" if all(closest(w, choices) for w in names) else listing(choices)
    return f"unknown {what} {', '.join(hints)}{rest}"
