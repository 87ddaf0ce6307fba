"""The simulated autopilot's settings: which firmware it plays and what it checks.

Plain values, validated on construction; `sim.autopilot` reads them. No I/O.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

Firmware = Literal["ucm-2023", "manual"]
FIRMWARES: tuple[Firmware, ...] = ("ucm-2023", "manual")
UCM_2023_FRAME_PERIOD_S = 1.1  # a 1 s interval checked on a 10 Hz tick


@dataclass(frozen=True, slots=True)
class AutopilotConfig:
    frame_period_s: float = 1.0
    boat_speed_m_s: float = 1.5
    query_every: int = 3  # while the probe is out, every n-th frame is S
    resend_m_during_cast: bool = False
    report_gap_s: float = 3.0
    answer_timeout_s: float = 1.0
    finish_timeout_s: float = 900.0  # from arriving at a station
    max_line_m: float = 20.0
    depth_tolerance_m: float = 0.05
    check_plan: bool = True  # a shoal station must be refused, every other one cast
    # A flipped bit this long (or a frame period, if longer) before a check's
    # window opened still explains it: a mangled frame can hold the peer's
    # parser until the next frame's bytes complete it.
    noise_margin_s: float = 1.0
    # After a replug: the daemon's reopen backoff tops out at its
    # serial.reconnect_max_s (5 s by default), plus a second to answer.
    outage_grace_s: float = 6.0
    station_grace_s: float = 3.0  # late answers to our last M after leaving are not news
    # Hold on station this long (sending T) before the first M, so a sonar read
    # over a real link (`sim.sonar_chain`) has heard the station, not the approach.
    settle_s: float = 0.0
    firmware: Firmware = "manual"
    stick_jog: bool = False  # ucm-2023: the safety pilot jogs the probe at the deepest station
    # The scripted jog: so many frames of stick down, then a pause (T), stick up, a pause.
    jog_script: tuple[tuple[str, int], ...] = (("D", 1), ("T", 2), ("U", 3), ("T", 3))

    def __post_init__(self) -> None:
        if self.frame_period_s <= 0:
            raise ValueError(f"frame_period_s={self.frame_period_s} is invalid: allowed > 0")
        if self.boat_speed_m_s <= 0:
            raise ValueError(f"boat_speed_m_s={self.boat_speed_m_s} is invalid: allowed > 0")
        if self.query_every < 2:
            raise ValueError(f"query_every={self.query_every} is invalid: allowed >= 2")
        if self.noise_margin_s < 0:
            raise ValueError(f"noise_margin_s={self.noise_margin_s} is invalid: allowed >= 0")
        if self.outage_grace_s < 0:
            raise ValueError(f"outage_grace_s={self.outage_grace_s} is invalid: allowed >= 0")
        if self.firmware not in FIRMWARES:
            raise ValueError(f"firmware={self.firmware!r} is invalid: allowed {FIRMWARES}")

    @property
    def ucm_2023(self) -> bool:
        return self.firmware == "ucm-2023"
