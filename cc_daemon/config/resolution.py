"""What the configuration asks of a cast: its resolution, and the line that says it.

This module owns the one reading of the whole configuration that gives a cast's
`core.cast.resolution.Resolution` (the `[profile]` bins and least readings a bin,
the sonde's period, each parameter's `response_s`, the parameters to resolve), the
winch's speeds it is judged against, and the line the daemon's start and `doctor`
say about it. It never opens a device.
"""

from __future__ import annotations

from cc_daemon.config.schema import Settings
from cc_daemon.core.cast.resolution import Resolution
from cc_daemon.core.winch.status import APPROACH_FRACTION


def cast_resolution(settings: Settings) -> Resolution | None:
    """The resolution the casts are planned for; None without a sonde (nothing to resolve)."""
    if settings.sonde.backend == "none":
        return None
    response = {p.name: p.response_s for p in settings.sonde.parameters}
    return Resolution(
        bin_m=settings.profile.bin_m,
        min_count=settings.profile.min_count,
        period_s=settings.sonde.period_s,
        response_s=response,
        # The default's temperature where the map has one (a given name must be in it).
        resolve=tuple(name for name in settings.profile.resolve if name in response),
    )


def winch_speeds(settings: Settings) -> tuple[float, float]:
    """The configured winch's line speed and its approach speed (the slowest it runs)."""
    winch = settings.winch
    speed = winch.gpio.line_speed_m_s if winch.backend == "gpio" else winch.sim.speed_m_s
    return speed, speed * APPROACH_FRACTION


def describe_resolution(settings: Settings) -> tuple[str, bool] | None:
    """What the configuration's casts resolve, in one line, and whether the winch falls
    short of it; None without a sonde."""
    resolution = cast_resolution(settings)
    if resolution is None:
        return None
    speed, floor = winch_speeds(settings)
    return resolution.describe(settings.cast.mode, speed, floor)
