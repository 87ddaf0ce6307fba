"""One check's verdict: OK, WARN or FAIL, what it saw, and the fix; or SKIP, a check
that cannot be made here (systemd is not asked about a system image), and why."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

Level = Literal["OK", "WARN", "FAIL", "SKIP"]


@dataclass(frozen=True, slots=True)
class Check:
    name: str
    level: Level
    detail: str
    fix: str = ""
