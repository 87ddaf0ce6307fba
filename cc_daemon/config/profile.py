"""[profile]: the vertical resolution a survey's profiles are wanted at.

This module owns the `[profile]` section's model; `config.resolution` reads it with
the rest of the settings into what it asks of a cast. `cc_daemon.config` only adds
the section to `Settings` and checks that `resolve` names parameters of the map, and
(`stepped_dwell_problem`) that the dwell it asks of a stepped cast leaves the cast
time to finish. It never opens a device.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Annotated, Protocol

from pydantic import BaseModel, Field
from pydantic_core import PydanticCustomError

from cc_daemon.config.rules import _SECTION, _impossible
from cc_daemon.config.sonde import SondeSettings
from cc_daemon.core.cast.resolution import SETTLING_RESPONSES

_Name = Annotated[str, Field(pattern=r"^[a-z][a-z0-9_]*$", max_length=40)]


class ProfileSettings(BaseModel):
    """[profile]: the wanted vertical resolution of the sonde's profiles."""

    model_config = _SECTION

    # Bin thickness (m): 1 cm to 5 m.
    bin_m: Annotated[float, Field(ge=0.01, le=5.0)] = 0.25
    # A bin with fewer readings is flagged; the descent leaves time for this many.
    min_count: Annotated[int, Field(ge=1, le=100)] = 2
    # The parameters whose response times the cast must honour (names of the map).
    resolve: Annotated[tuple[_Name, ...], Field(strict=False)] = ("temperature",)


class _Cast(Protocol):
    @property
    def mode(self) -> str: ...

    @property
    def dwell_s(self) -> float: ...

    @property
    def max_duration_s(self) -> float: ...


def stepped_dwell_problem(
    cast: _Cast, sonde: SondeSettings, resolve: Sequence[str]
) -> PydanticCustomError | None:
    """Why a stepped cast could never finish, or None. It holds each level for
    `cast.dwell_s`, or three response times of the slowest parameter to resolve when
    that is longer (`core.cast.resolution`; nothing is resolved without a sonde): a
    hold as long as `cast.max_duration_s` is aborted at the first level of every cast."""
    if cast.mode != "stepped":
        return None
    timed = [(p.response_s, p.name) for p in sonde.parameters if p.name in resolve]
    slowest, name = max(timed, default=(0.0, "")) if sonde.backend != "none" else (0.0, "")
    settling = SETTLING_RESPONSES * slowest
    if max(cast.dwell_s, settling) < cast.max_duration_s:
        return None
    never = " (every cast would be aborted at its first level)"
    if settling > cast.dwell_s:
        return _impossible(
            "a {0} cast dwells at each level 3 x the response_s of "
            + f"{name} ({slowest:g} s) in {{1}}, {settling:g} s, which must be under {{2}}"
            + never,
            "cast.mode",
            "profile.resolve",
            "cast.max_duration_s",
        )
    return _impossible(
        "a stepped cast dwells {0} at each level, which must be under {1}" + never,
        "cast.dwell_s",
        "cast.max_duration_s",
    )
