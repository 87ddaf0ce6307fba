"""The building blocks of the configuration's rules: validators, bounded types, and
the error kinds that `loading` turns into one plain line per problem.

Shared by every section's model (`schema`, and the sections that live beside the
code they configure, such as `cc_daemon.config.sonde`). Pure: no I/O.
"""

import os
from typing import Annotated, Any, Literal, NamedTuple

from pydantic import ConfigDict, Field
from pydantic_core import PydanticCustomError

STANDARD_BAUDRATES: tuple[int, ...] = (
    1200,
    2400,
    4800,
    9600,
    19200,
    38400,
    57600,
    115200,
    230400,
    460800,
    921600,
)
_STOPBITS: tuple[float, ...] = (1, 1.5, 2)


def _not_allowed(message: str) -> PydanticCustomError:
    return PydanticCustomError("not_allowed", message)


def _impossible(rule: str, *keys: str) -> PydanticCustomError:
    """An error about several keys together; `keys` are relative to the failing model.

    The keys travel in the error's context so `load_settings` can show each one's
    value and source; `rule` uses {0}, {1}... for them.
    """
    return PydanticCustomError(
        "impossible_combination",
        "impossible combination: " + rule.format(*keys),
        {"keys": keys, "rule": rule},
    )


def _check_baudrate(value: int) -> int:
    if value not in STANDARD_BAUDRATES:
        rates = ", ".join(map(str, STANDARD_BAUDRATES))
        raise _not_allowed(f"must be one of the standard rates: {rates}")
    return value


def _check_stopbits(value: float) -> float:
    if value not in _STOPBITS:
        raise _not_allowed("must be 1, 1.5 or 2")
    return value


def _upper(value: Any) -> Any:
    return value.upper() if isinstance(value, str) else value


def _lower(value: Any) -> Any:
    return value.lower() if isinstance(value, str) else value


def _empty_is_none(value: Any) -> Any:
    # TOML has no null, so "none" is spelled by leaving the key out; from the
    # environment (a systemd drop-in) an empty value is the natural way to say it.
    return None if value == "" else value


_SECTION = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False, strict=True)
_Positive = Annotated[float, Field(gt=0)]
_NonNegative = Annotated[float, Field(ge=0)]
# Every period and duration has a floor and a ceiling a real boat could want; the
# reasons are in config/cc-daemon.toml. A value that validates must also work: a
# microsecond report period would saturate the line and a core.
_HOUR_S = 3600.0
_Dwell = Annotated[float, Field(ge=0, le=_HOUR_S)]


def _no_nul(value: Any) -> Any:
    if isinstance(value, str | os.PathLike) and "\0" in os.fspath(value):
        raise _not_allowed("must not contain a NUL character")
    return value


# Where a value came from, for the error lines (`loading`) and `Settings.describe`.
class _Origin(NamedTuple):
    kind: Literal["file", "env", "flag"]
    name: str  # file path, variable name or flag


_Key = tuple[str, ...]
_Leaf = tuple[_Key, Any, _Origin]
