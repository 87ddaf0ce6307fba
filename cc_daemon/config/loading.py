"""Where configuration values come from, and what a bad one says.

This module owns the order of the sources (command-line flag > environment >
TOML file > default) and the wording of configuration errors: one line per
problem naming the dotted key, the value given, what is allowed and where the
value came from. It reads at most one TOML file and the environment mapping it
is given, and either returns a frozen `Settings` or raises `ConfigError`.
"""

from __future__ import annotations

import contextlib
import difflib
import os
import re
import tomllib
import types
import typing
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ValidationError
from pydantic_core import ErrorDetails

from cc_daemon.config import naming
from cc_daemon.config.rules import _Key, _Leaf, _Origin
from cc_daemon.config.schema import Settings
from cc_daemon.core.errors import ConfigError

ENV_PREFIX = "CC_DAEMON_"
ENV_NESTED_DELIMITER = "__"
# Searched in order when no --config is given; the first that exists is used.
DEFAULT_SEARCH_PATHS: tuple[Path, ...] = (
    Path("cc-daemon.toml"),
    Path("/etc/cc-daemon/cc-daemon.toml"),
)
# The command line's flags, so an error can name the flag a value came from.
FLAG_NAMES: Mapping[tuple[str, ...], str] = {
    ("serial", "port"): "--port",
    ("serial", "baudrate"): "--baudrate",
    ("winch", "backend"): "--winch",
    ("winch", "gpio", "pin_factory"): "--winch",
    ("store", "path"): "--db",
    ("log", "format"): "--log-format",
    ("log", "level"): "--log-level",
}
_PREFIX = "cc-daemon: bad configuration: "


def load_settings(
    config_path: Path | None = None,
    overrides: Mapping[str, Any] | None = None,
    *,
    env: Mapping[str, str] | None = None,
    search_paths: Sequence[Path] = DEFAULT_SEARCH_PATHS,
) -> Settings:
    """Read the configuration: flag (`overrides`) > environment > TOML file > default.

    `config_path` is the --config file, which must exist; without it the first of
    `search_paths` that exists is read, and none is fine. `overrides` holds the
    command-line flags as a nested dict; None values mean "flag not given". `env`
    defaults to `os.environ`. Raises ConfigError, one line per problem.
    """
    problems: list[str] = []
    file_leaves: list[_Leaf] = []
    source_file = _find_file(config_path, search_paths, problems)
    if source_file is not None:
        file_leaves = _read_toml(source_file, problems)
    env_leaves = _read_env(os.environ if env is None else env, problems)
    if problems:
        raise ConfigError("\n".join(_PREFIX + p for p in problems))

    flag_leaves = _flatten(overrides or {}, (), None)
    merged, origins = _merge([file_leaves, env_leaves, flag_leaves])
    try:
        settings = Settings.model_validate(merged)
    except ValidationError as exc:
        lines = [_describe(error, merged, origins) for error in exc.errors()]
        raise ConfigError("\n".join(_PREFIX + line for line in lines)) from None
    settings._source_file = source_file
    settings._merged, settings._origins = merged, origins
    return settings


def _find_file(
    config_path: Path | None, search_paths: Sequence[Path], problems: list[str]
) -> Path | None:
    if config_path is not None:
        config_path = Path(config_path)  # tolerate the str argparse hands over
        if not config_path.is_file():
            what = "is not a file" if config_path.exists() else "no such file"
            problems.append(f"--config {config_path}: {what}")
            return None
        return config_path.absolute()
    for candidate in search_paths:
        if candidate.is_file():
            return candidate.absolute()
    return None


_TOML_POSITION = re.compile(r"\s*\(at line (\d+), column (\d+)\)$")


def _read_toml(path: Path, problems: list[str]) -> list[_Leaf]:
    try:
        with path.open("rb") as file:
            data = tomllib.load(file)
    except tomllib.TOMLDecodeError as exc:
        message = str(exc)
        found = _TOML_POSITION.search(message)
        where = f"line {found[1]}, column {found[2]}: " if found else ""
        message = message[: found.start()] if found else message
        problems.append(f"{path}: {where}not valid TOML: {message}")
        return []
    except UnicodeDecodeError as exc:
        line = bytes(exc.object[: exc.start]).count(b"\n") + 1
        problems.append(f"{path}: line {line}: not valid TOML: not UTF-8 text")
        return []
    except OSError as exc:
        problems.append(f"{path}: cannot read: {exc.strerror or exc}")
        return []
    except RecursionError:
        # tomllib parses nested arrays and inline tables recursively: a file
        # nested a thousand deep is not a configuration, and not a traceback.
        problems.append(f"{path}: not valid TOML: nested too deeply to read")
        return []
    if _too_deep(data):
        problems.append(
            f"{path}: not a configuration: tables or arrays nested deeper than {_MAX_DEPTH} levels"
        )
        return []
    return _flatten(data, (), _Origin("file", str(path)))


# No setting is nested deeper than a few tables; this bound keeps every walk
# over the file's values (ours and pydantic's) far from Python's recursion limit.
_MAX_DEPTH = 16


def _too_deep(data: object) -> bool:
    """Whether `data` nests tables or arrays deeper than `_MAX_DEPTH` (no recursion)."""
    stack: list[tuple[object, int]] = [(data, 0)]
    while stack:
        value, depth = stack.pop()
        if depth > _MAX_DEPTH:
            return True
        if isinstance(value, Mapping):
            stack.extend((v, depth + 1) for v in value.values())
        elif isinstance(value, list | tuple):
            stack.extend((v, depth + 1) for v in value)
    return False


def _read_env(env: Mapping[str, str], problems: list[str]) -> list[_Leaf]:
    leaves: list[_Leaf] = []
    seen: dict[_Key, str] = {}
    for name in sorted(env):
        # Matched without regard to case, like pydantic-settings' default.
        if not name.upper().startswith(ENV_PREFIX):
            continue
        key = tuple(name[len(ENV_PREFIX) :].lower().split(ENV_NESTED_DELIMITER))
        if not all(key):
            form = f"{ENV_PREFIX}<SECTION>{ENV_NESTED_DELIMITER}<KEY>"
            problems.append(
                f"{name}: not a setting name; use {form}, e.g. {ENV_PREFIX}SERIAL__PORT"
            )
            continue
        # CC_DAEMON_SERIAL and CC_DAEMON_SERIAL__PORT cannot both be meant.
        clash = next(
            (other for k, other in seen.items() if k[: len(key)] == key or key[: len(k)] == k),
            None,
        )
        if clash is not None:
            problems.append(f"{name}: conflicts with {clash}; set only one of them")
            continue
        seen[key] = name
        leaves.append((key, _from_text(key, env[name]), _Origin("env", name)))
    return leaves


# --- text from the environment, parsed by the key's type ------------------------------
# The models are strict (`true` is not a number, "1.0" is not a float): the
# environment only has text, so each value is parsed here, explicitly, as the
# key's type says. Text that does not parse is passed on as text, for the
# model to refuse with the usual one line naming the key.

_TRUE = ("true", "yes", "on", "1")
_FALSE = ("false", "no", "off", "0")


def _kinds(annotation: object) -> set[type]:
    """The plain types a field accepts (Annotated, unions and Literals unwrapped)."""
    origin = typing.get_origin(annotation)
    if origin is typing.Annotated:
        return _kinds(typing.get_args(annotation)[0])
    if origin is typing.Literal:
        return {type(v) for v in typing.get_args(annotation)}
    if origin in (typing.Union, types.UnionType):
        return set().union(*(_kinds(a) for a in typing.get_args(annotation)))
    return {annotation} if isinstance(annotation, type) else set()


def _field_kinds(key: _Key) -> set[type]:
    model: object = Settings
    kinds: set[type] = set()
    for part in key:
        fields = getattr(model, "model_fields", None)
        if not isinstance(fields, dict) or part not in fields:
            return set()
        annotation = fields[part].annotation
        kinds = _kinds(annotation)
        model = next((k for k in kinds if issubclass(k, BaseModel)), None)
    return kinds


def _from_text(key: _Key, text: str) -> object:
    kinds = _field_kinds(key)
    word = text.strip().lower()
    if bool in kinds:
        if word in _TRUE:
            return True
        if word in _FALSE:
            return False
        return text
    if int in kinds or float in kinds:  # "6" stays 6 (a float key takes it), as written
        with contextlib.suppress(ValueError):
            return int(text)
    if float in kinds:
        with contextlib.suppress(ValueError):
            return float(text)
    return text


def _flatten(data: Mapping[str, Any], prefix: _Key, origin: _Origin | None) -> list[_Leaf]:
    """Leaves of a nested mapping; `origin` None means the command line (per-flag names)."""
    leaves: list[_Leaf] = []
    for name, value in data.items():
        key = (*prefix, str(name))
        if isinstance(value, Mapping) and value:
            leaves.extend(_flatten(value, key, origin))
        elif isinstance(value, Mapping) and origin is not None:
            # An empty table is a value too: `timestamp_order = {}` must be
            # refused as a table, not vanish into the default.
            leaves.append((key, {}, origin))
        elif value is not None or origin is not None:
            here = origin or _Origin("flag", FLAG_NAMES.get(key, "the command line"))
            leaves.append((key, value, here))
    return leaves


def _merge(layers: Sequence[Sequence[_Leaf]]) -> tuple[dict[str, Any], dict[_Key, _Origin]]:
    """Apply layers lowest precedence first; remember who set each leaf."""
    merged: dict[str, Any] = {}
    origins: dict[_Key, _Origin] = {}
    for layer in layers:
        for key, value, origin in layer:
            node = merged
            for part in key[:-1]:
                child = node.get(part)
                if not isinstance(child, dict):
                    child = node[part] = {}
                node = child
            replaced = node.get(key[-1])
            node[key[-1]] = value
            # Whatever a lower layer set at or below this key is gone now: a leaf
            # where a table now is, or the leaves of a table this replaces (looked
            # for only then: every leaf against every origin was quadratic).
            for depth in range(1, len(key)):
                origins.pop(key[:depth], None)
            if isinstance(replaced, dict) and replaced:
                for stale in [k for k in origins if k[: len(key)] == key]:
                    del origins[stale]
            origins[key] = origin
    return merged, origins


# --- error messages ---------------------------------------------------------------------


def _describe(
    error: ErrorDetails, merged: Mapping[str, Any], origins: Mapping[_Key, _Origin]
) -> str:
    loc = tuple(str(part) for part in error["loc"])
    kind = error["type"]
    if kind == "impossible_combination":
        ctx = error.get("ctx") or {}
        keys = [(*loc, *str(k).split(".")) for k in ctx.get("keys", ())]
        shown = [_key_value_source(k, merged, origins) for k in keys]
        listed = ", ".join(shown[:-1]) + " and " + shown[-1] if len(shown) > 1 else "".join(shown)
        rule = str(ctx.get("rule", "")).format(*(".".join(k) for k in keys))
        return f"{listed}: impossible combination: {rule}"
    if kind == "extra_forbidden":
        return f"{_dotted(loc)} ({_source(loc, origins)}): {_unknown_key(loc)}"
    return f"{_key_value_source(loc, merged, origins)}: {_requirement(error, loc)}"


_dotted = naming.dotted
_source = naming.source
_lookup = naming.lookup
_render = naming.render
_MISSING = naming.MISSING


def _default(key: _Key) -> Any:
    return naming.default_at(Settings(), key)


def _key_value_source(key: _Key, merged: Mapping[str, Any], origins: Mapping[_Key, _Origin]) -> str:
    return naming.key_value_source(key, merged, origins, Settings())


def _model_at(key: _Key) -> type[BaseModel] | None:
    model: type[BaseModel] = Settings
    for part in key:
        field = model.model_fields.get(part)
        annotation = field.annotation if field else None
        if not (isinstance(annotation, type) and issubclass(annotation, BaseModel)):
            return None
        model = annotation
    return model


def _unknown_key(key: _Key) -> str:
    parent = key[:-1]
    model = _model_at(parent)
    names = list(model.model_fields) if model else []
    if parent:
        text = f"unknown key; allowed keys in [{'.'.join(parent)}]: {', '.join(names)}"
    else:
        text = f"unknown section; allowed sections: {', '.join(names)}"
    close = difflib.get_close_matches(key[-1], names, n=1)
    return text + (f" (did you mean {close[0]}?)" if close else "")


_REQUIREMENTS = {
    "int_type": "must be a whole number",
    "int_parsing": "must be a whole number",
    "int_from_float": "must be a whole number",
    "float_type": "must be a number",
    "float_parsing": "must be a number",
    "finite_number": "must be a finite number",
    "bool_type": "must be true or false",
    "bool_parsing": "must be true or false",
    "string_type": "must be a string",
    "string_too_short": "must not be empty",
    "path_type": "must be a file path (a string)",
    "model_type": "must be a table of keys",
    "model_attributes_type": "must be a table of keys",
    "dict_type": "must be a table of keys",
}


def _number(value: Any) -> Any:
    # A bound of 0 on a float field arrives as 0.0; say it as written.
    return int(value) if isinstance(value, float) and value.is_integer() else value


def _requirement(error: ErrorDetails, key: _Key) -> str:
    kind = error["type"]
    ctx = error.get("ctx") or {}
    if kind in ("model_type", "model_attributes_type", "dict_type"):
        return f"must be a table of keys ([{'.'.join(key)}])"
    if kind in _REQUIREMENTS:
        return _REQUIREMENTS[kind]
    if kind == "greater_than":
        return f"must be greater than {_number(ctx['gt'])}"
    if kind == "greater_than_equal":
        return f"must be at least {_number(ctx['ge'])}"
    if kind == "less_than":
        return f"must be less than {_number(ctx['lt'])}"
    if kind == "less_than_equal":
        return f"must be at most {_number(ctx['le'])}"
    if kind == "literal_error":
        # Double quotes, as the value would be written in TOML.
        return "must be one of " + str(ctx["expected"]).replace("'", '"')
    if kind == "value_error" and "error" in ctx:
        return str(ctx["error"])
    # pydantic's own wording, made to match ours, for anything not listed above.
    return re.sub(r"^Input should be", "must be", error["msg"])
