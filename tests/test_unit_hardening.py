"""The systemd unit: least privilege measured by systemd-analyze, and its stop budget.

`systemd-analyze security --offline=yes` and `systemd-analyze verify` read the
unit file alone, so they run without systemd as PID 1 (a container, CI). Where
the tool is missing the checks are skipped with the reason; `make test` installs
Debian's `systemd` package first where it can (root with apt).
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from tests.daemonkit import REPO

UNIT = REPO / "systemd" / "cc-daemon.service"
WEB_UNIT = REPO / "systemd" / "cc-daemon-web.service"  # the field page (docs/web.md)
UNITS = pytest.mark.parametrize("unit", [UNIT, WEB_UNIT], ids=lambda u: u.stem)
MAX_EXPOSURE = 2.0
ANALYZE = shutil.which("systemd-analyze")
needs_analyze = pytest.mark.skipif(
    ANALYZE is None,
    reason="systemd-analyze not installed (apt-get install systemd): unit hardening not checked",
)


def unit_settings(text: str) -> dict[str, list[str]]:
    """Every `Key=value` of the unit, in order (a key may repeat)."""
    out: dict[str, list[str]] = {}
    for raw in text.splitlines():
        line = raw.strip()
        if line and not line.startswith(("#", ";", "[")) and "=" in line:
            key, value = line.split("=", 1)
            out.setdefault(key.strip(), []).append(value.strip())
    return out


def exposure(unit: Path) -> float:
    assert ANALYZE is not None
    result = subprocess.run(
        [ANALYZE, "security", "--offline=yes", "--no-pager", str(unit)],
        capture_output=True,
        text=True,
        check=False,
    )
    found = re.search(r"Overall exposure level for \S+: (\d+\.\d+)", result.stdout)
    assert found, result.stdout + result.stderr
    return float(found[1])


@needs_analyze
@UNITS
def test_exposure_is_at_most_two(unit: Path) -> None:
    assert exposure(unit) <= MAX_EXPOSURE


@needs_analyze
def test_the_measure_would_catch_a_weakened_unit(tmp_path: Path) -> None:
    # Without the sandboxing lines the same measure must fail the check.
    weak = tmp_path / "cc-daemon.service"
    kept = [
        line
        for line in UNIT.read_text().splitlines()
        if not line.startswith(("Protect", "Restrict", "SystemCall", "Capability", "Private"))
    ]
    weak.write_text("\n".join(kept) + "\n")
    assert exposure(weak) > MAX_EXPOSURE


@needs_analyze
@UNITS
def test_verify_is_clean(unit: Path, tmp_path: Path) -> None:
    # verify also insists that ExecStart= exists; the installed venv is not on this
    # machine, so point it at this checkout's own entry point and check the rest.
    entry = Path(sys.executable).with_name("cc-daemon")
    assert entry.exists(), entry
    text = unit.read_text().replace("/opt/cc-daemon/.venv/bin/cc-daemon", str(entry))
    assert str(entry) in text
    copy = tmp_path / unit.name
    copy.write_text(text)
    result = subprocess.run(
        [ANALYZE, "verify", str(copy)], capture_output=True, text=True, check=False
    )
    assert (result.returncode, result.stdout + result.stderr) == (0, "")


def test_everything_the_issue_asks_for_is_set() -> None:
    s = unit_settings(UNIT.read_text())
    expected = {
        "User": "cc-daemon",
        "PrivateNetwork": "yes",
        "RestrictAddressFamilies": "AF_UNIX",
        "CapabilityBoundingSet": "",
        "AmbientCapabilities": "",
        "SystemCallArchitectures": "native",
        "DevicePolicy": "closed",
        "ProtectProc": "invisible",
        "ProcSubset": "pid",
        "UMask": "0027",
        "KillMode": "mixed",
        "Restart": "on-failure",
        "RestartPreventExitStatus": "2",
        "ExecReload": "/bin/kill -HUP $MAINPID",
        "StateDirectory": "cc-daemon",
        "RuntimeDirectory": "cc-daemon",
        "ConfigurationDirectory": "cc-daemon",
    }
    assert {k: s.get(k, ["<missing>"])[-1] for k in expected} == expected
    assert set(s["SupplementaryGroups"][-1].split()) == {"dialout", "gpio", "spi"}
    assert s["SystemCallFilter"] == [
        "@system-service",
        "~@privileged @resources",
        "adjtimex clock_adjtime",  # read the clock's sync state; setting needs CAP_SYS_TIME
    ]
    # ProtectClock= would deny reading the kernel's clock state, which every journal
    # row records; the clock stays unsettable: no capability at all is granted.
    assert "ProtectClock" not in s
    assert s["CapabilityBoundingSet"][-1] == ""
    allowed = {v.split()[0] for v in s["DeviceAllow"]}
    devices = ("ttyS", "ttyAMA", "ttyUSB", "ttyACM", "gpiochip", "spi")
    assert allowed == {f"char-{n}" for n in devices}
    for key in ("Kernel" + k for k in ("Tunables", "Modules", "Logs")):
        assert s[f"Protect{key}"] == ["yes"]
    # Wants= without After= would not order the start after the clock is synchronised.
    assert "time-sync.target" in s["Wants"] and "time-sync.target" in s["After"]
    assert s["StartLimitBurst"] and s["StartLimitIntervalSec"]


def test_stop_budget_brings_the_probe_home_from_the_end_of_the_line() -> None:
    """TimeoutStopSec= covers a haul from winch.max_line_m at the shipped haul speed."""
    config = tomllib.loads((REPO / "config" / "cc-daemon.toml").read_text())
    winch = config["winch"]
    backend = winch.get(winch.get("backend", "sim"), {})
    speed = backend.get("speed_m_s", winch["sim"]["speed_m_s"])
    haul_s = winch["max_line_m"] / speed
    budget = float(unit_settings(UNIT.read_text())["TimeoutStopSec"][-1])
    assert budget >= haul_s + 30  # + stopping a descent, journal and close


def test_the_web_unit_reads_and_never_writes_the_daemons_files() -> None:
    s = unit_settings(WEB_UNIT.read_text())
    assert s["ExecStart"] == [
        "/opt/cc-daemon/.venv/bin/cc-daemon web --config /etc/cc-daemon/cc-daemon.toml"
    ]
    assert s["DynamicUser"] == ["yes"] and s["SupplementaryGroups"] == ["cc-daemon"]
    assert s["ProtectSystem"] == ["strict"]  # no ReadWritePaths: it writes nothing
    assert not {"ReadWritePaths", "StateDirectory", "RuntimeDirectory"} & set(s)
    assert s["RestrictAddressFamilies"] == ["AF_UNIX AF_INET AF_INET6"]
    assert s["RestartPreventExitStatus"] == ["2"]


def test_the_web_units_descriptor_limit_holds_its_connections_and_a_reserve() -> None:
    from cc_daemon.cli.web.policy import Limits

    limit = unit_settings(WEB_UNIT.read_text())["LimitNOFILE"]
    assert len(limit) == 1 and limit[0].isdigit()  # one figure: soft and hard the same
    limits = Limits()
    assert limits.connections + limits.reserve_fds <= int(limit[0]) <= 4096
