"""What a value read back from a journal file must be before it is shown as one.

The daemon writes every row itself, but the file the read side is given may
come from anywhere: text where a time belongs, a time of 1e308 (no calendar
has it), JSON nested fifty thousand deep (Python's parser gives up with
`RecursionError`) or holding millions of items. Each function here takes one
stored value and returns it as the type the records promise, or raises
`ValueError` naming what is wrong, so the reader skips (and counts) the row or
marks the value unreadable: a value that cannot be true is never shown as good.

Pure: values in, values out; no connection, no file. (`dated` is the same rule
for a time, spelt in SQL, for the aggregates a query computes itself.)
"""

from __future__ import annotations

import json
import math
from typing import Any

# 0001-01-01 to 9999-12-31: what `datetime` (and so every ISO 8601 time written) can show.
WALL_MIN_S = -62_135_596_800.0
WALL_MAX_S = 253_402_300_799.0
JSON_MAX_DEPTH = 32  # the journal's own JSON is 3 deep at most (a sonde map's parameters)
JSON_MAX_ITEMS = 10_000  # and holds a few dozen values


def number(value: Any, what: str) -> float:
    """A finite number (SQLite may hand back text or bytes from a column typed REAL)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"{what} is not a number: {type(value).__name__}")
    result = float(value)
    if not math.isfinite(result):
        raise ValueError(f"{what} is {result}")
    return result


def wall_time(value: Any, what: str = "a time") -> float:
    """Unix seconds that a calendar can show."""
    result = number(value, what)
    if not WALL_MIN_S <= result <= WALL_MAX_S:
        raise ValueError(f"{what} {result:g} s is no date")
    return result


def dated(column: str) -> str:
    """SQL: `column` where it holds a time a calendar can show, else NULL (so that `min`
    and `max` pass over the rest)."""
    return (
        f"CASE WHEN typeof({column}) IN ('integer', 'real')"
        f" AND {column} BETWEEN {WALL_MIN_S:.0f} AND {WALL_MAX_S:.0f} THEN {column} END"
    )


def optional_wall_time(value: Any, what: str = "a time") -> float | None:
    return None if value is None else wall_time(value, what)


def optional_number(value: Any, what: str) -> float | None:
    return None if value is None else number(value, what)


def integer(value: Any, what: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"{what} is not a whole number")
    return value


def text(value: Any, what: str) -> str:
    if not isinstance(value, str):
        raise ValueError(f"{what} is not text")
    return value


def _check_shape(value: Any) -> None:
    """Walk the parsed value without recursion: not too deep, not too many items."""
    todo: list[tuple[Any, int]] = [(value, 1)]
    items = 0
    while todo:
        node, depth = todo.pop()
        items += 1
        if items > JSON_MAX_ITEMS:
            raise ValueError(f"JSON of more than {JSON_MAX_ITEMS} items")
        if isinstance(node, dict | list):
            if depth > JSON_MAX_DEPTH:
                raise ValueError(f"JSON nested deeper than {JSON_MAX_DEPTH}")
            children = node.values() if isinstance(node, dict) else node
            todo.extend((child, depth + 1) for child in children)


def json_value(raw: Any) -> Any:
    """Stored JSON text (or the bytes a damaged file holds in its place) as a value."""
    if isinstance(raw, bytes):
        raw = raw.decode("utf-8")  # UnicodeDecodeError is a ValueError
    if not isinstance(raw, str):
        raise ValueError(f"JSON is not text: {type(raw).__name__}")
    try:
        value = json.loads(raw)
    except RecursionError:
        raise ValueError("JSON nested too deep to read") from None
    _check_shape(value)
    return value
