"""How a configuration error names a key: `key = value (from source)`.

It owns the wording of one key's value and where it came from, for
`loading` (errors while loading) and `Settings.describe` (checks made later).
It knows no schema: the defaults are handed in as a settings object.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from cc_daemon.config.rules import _Key, _Origin

MISSING = object()


def dotted(key: _Key) -> str:
    return ".".join(key) if key else "(top level)"


def key_value_source(
    key: _Key, merged: Mapping[str, Any], origins: Mapping[_Key, _Origin], defaults: Any
) -> str:
    value = lookup(merged, key)
    if value is MISSING:
        return f"{dotted(key)} = {render(default_at(defaults, key))} (default)"
    origin = origins.get(key)
    if origin is not None and origin.kind == "env" and isinstance(value, str) and value.strip():
        # Exactly as typed: every environment value is text, quoting it would mislead.
        shown = value
    else:
        shown = render(value)
    return f"{dotted(key)} = {shown} ({source(key, origins)})"


def source(key: _Key, origins: Mapping[_Key, _Origin]) -> str:
    for length in range(len(key), 0, -1):
        origin = origins.get(key[:length])
        if origin is not None:
            return f"from {origin.name}"
    # A section such as [winch.bogus] has no value of its own: name one of its keys' source.
    for k, origin in origins.items():
        if k[: len(key)] == key:
            return f"from {origin.name}"
    return "default"


def lookup(data: Any, key: _Key) -> Any:
    for part in key:
        if isinstance(data, list | tuple) and part.isdigit() and int(part) < len(data):
            data = data[int(part)]  # an array of tables: [[sonde.parameters]]
            continue
        if not isinstance(data, Mapping) or part not in data:
            return MISSING
        data = data[part]
    return data


def default_at(defaults: Any, key: _Key) -> Any:
    node: Any = defaults
    for part in key:
        node = getattr(node, part, None)
    return node


def render(value: Any) -> str:
    """A value as it would be written in the TOML file."""
    if value is None:
        return "none"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str | Path):
        return json.dumps(str(value))
    if isinstance(value, int | float):
        return repr(value)
    if isinstance(value, Mapping):
        return "{" + ", ".join(f"{k} = {render(v)}" for k, v in value.items()) + "}"
    if isinstance(value, list | tuple):
        return "[" + ", ".join(render(v) for v in value) + "]"
    return repr(value)
