"""One request on the control socket: its bounds and what is kept of it.

A request is one line of at most `MAX_REQUEST` bytes: `release <reason>` or
`home [<reason>]`. What a client wrote is kept only as printable text: the
reason goes to the log, the journal and the casts' table, and is read on a
terminal or in a spreadsheet later, so control and format characters (ESC, CR,
NUL, the bidirectional overrides such as U+202E, zero-width ones) are written
as their escapes (`\\x1b`, `\\u202e`), and the reason is cut to `MAX_REASON`
characters.

It is pure: no I/O; the control server reads the line and answers.
"""

from __future__ import annotations

import unicodedata
from typing import NamedTuple

MAX_REQUEST = 512  # bytes: "release " and a reason, one line
MAX_REASON = 200  # characters kept, escapes included
_UNPRINTABLE = {"Cc", "Cf", "Cs", "Co", "Cn", "Zl", "Zp"}
USAGE = "expected one line: release <reason>, or home"


class Request(NamedTuple):
    verb: str  # "release" or "home"
    reason: str  # printable, at most MAX_REASON characters ("" for a bare home)


def printable(text: str, limit: int = MAX_REASON) -> str:
    """`text` with each character that is not printable written as its escape,
    runs of spaces made one, and cut to `limit` characters (ending "…" if cut)."""
    escaped = "".join(_escape(char) for char in text)
    kept = " ".join(word for word in escaped.split(" ") if word)
    return kept if len(kept) <= limit else kept[: limit - 1] + "…"


def _escape(char: str) -> str:
    if unicodedata.category(char) not in _UNPRINTABLE:
        return char
    code = ord(char)
    if code < 0x100:
        return f"\\x{code:02x}"
    return f"\\u{code:04x}" if code < 0x10000 else f"\\U{code:08x}"


def parse(line: bytes) -> Request | str:
    """The request on one line (its newline removed), or why it is refused."""
    if len(line) > MAX_REQUEST:
        return f"request too long ({len(line)} bytes): one line of at most {MAX_REQUEST}"
    text = line.decode("utf-8", "replace").strip(" \t\r\n")
    verb, _, rest = text.partition(" ")
    reason = printable(rest)
    if verb == "home":
        return Request("home", reason)
    if verb == "release" and reason:
        return Request("release", reason)
    return USAGE
