"""[profile]: the vertical resolution a survey's profiles are wanted at.

This module owns the `[profile]` section's model; `config.resolution` reads it with
the rest of the settings into what it asks of a cast. `cc_daemon.config` only adds
the section to `Settings` and checks that `resolve` names parameters of the map.
It never opens a device.
"""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, Field

from cc_daemon.config.rules import _SECTION

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
