"""`cc-daemon doctor` against a fake Raspberry Pi root, healthy and with each failure planted.

The root holds the files the checks read (passwd and group, the unit, the
configuration, /dev links, /proc entries); the serial device is a real pty, the
status socket a real server; the kernel's answers that cannot live in a
directory (free space, clock, systemd's opinion) are injected.
"""

from __future__ import annotations

import asyncio
import dataclasses
import json
import os
import subprocess
import sys
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass
from pathlib import Path

import pytest

from cc_daemon.cli.doctor.checks import run_checks
from cc_daemon.cli.doctor.command import format_checks
from cc_daemon.cli.doctor.system import System
from cc_daemon.cli.doctor.verdict import Check
from cc_daemon.daemon.status_server import StatusServer
from cc_daemon.ground.clocksync import ClockSync
from cc_daemon.sim.pty import PtyPair
from tests.daemonkit import REPO

SERVICE_UID = 4242  # neither root nor the test: access is decided by groups and modes


def statvfs(free_bytes: int) -> Callable[[str], os.statvfs_result]:
    blocks = free_bytes // 4096
    return lambda _path: os.statvfs_result(
        (4096, 4096, blocks * 2, blocks, blocks, 0, 0, 0, 0, 255)
    )


@dataclass
class Pi:
    root: Path
    pty: PtyPair
    device: Path
    system: System
    server: StatusServer

    def write(self, path: str, text: str) -> Path:
        target = self.root / path.lstrip("/")
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_text(text)
        return target

    def link(self, path: str, to: str | Path) -> None:
        target = self.root / path.lstrip("/")
        target.unlink(missing_ok=True)
        target.symlink_to(to)

    async def checks(self, config: Path | None = None) -> dict[str, Check]:
        found = await asyncio.to_thread(run_checks, self.system, config)
        return {c.name: c for c in found}


def healthy_pi(tmp_path: Path) -> Pi:
    root = tmp_path / "r"
    pty = PtyPair(tmp_path / "tty")
    device = Path(os.path.realpath(pty.path))
    os.chmod(device, 0o660)
    tty_gid, own_gid = device.stat().st_gid, os.getgid()
    system = System(
        root=root,
        statvfs=statvfs(30 * 10**9),
        clock=lambda: ClockSync(True, 0.012, "adjtimex"),
        service_state=lambda: "active",
        installed=lambda module: True,  # the Pi's venv, as the installer makes it
    )
    server = StatusServer(
        root / "run/cc-daemon/status.sock",
        lambda: {"link": {"up": True, "port": "/dev/serial0"}, "cast": {"phase": "idle"}},
    )
    box = Pi(root, pty, device, system, server)
    box.write("/etc/passwd", f"cc-daemon:x:{SERVICE_UID}:{own_gid}::/var/lib/cc-daemon:/x\n")
    box.write("/etc/group", f"cc-daemon:x:{own_gid}:\ndialout:x:{tty_gid}:\n")
    unit = (REPO / "systemd/cc-daemon.service").read_text()
    box.write("/etc/systemd/system/cc-daemon.service", unit)
    box.write("/etc/cc-daemon/cc-daemon.toml", (REPO / "config/cc-daemon.toml").read_text())
    box.write("/proc/cmdline", "console=tty1 root=PARTUUID=1234-02 rootwait\n")
    box.write("/proc/device-tree/model", "Raspberry Pi 4 Model B Rev 1.4\0")
    (root / "proc/1/fd").mkdir(parents=True)
    (root / "dev").mkdir()
    box.write("/dev/gpiochip0", "")  # the shipped configuration drives the GPIO winch
    (root / "dev/gpiochip0").chmod(0o660)
    box.link("/dev/serial0", "ttyAMA0")
    box.link("/dev/ttyAMA0", device)  # absolute and outside the root: the real pty
    state = root / "var/lib/cc-daemon"
    state.mkdir(parents=True)
    state.chmod(0o770)
    (root / "run/cc-daemon").mkdir(parents=True)
    return box


@pytest.fixture
async def pi(tmp_path: Path) -> AsyncIterator[Pi]:
    box = await asyncio.to_thread(healthy_pi, tmp_path)
    await box.server.start()
    try:
        yield box
    finally:
        await box.server.close()
        box.pty.close()


async def test_a_healthy_pi_is_all_ok(pi: Pi) -> None:
    checks = await pi.checks()
    assert {n: c.level for n, c in checks.items()} == {
        "config": "OK",
        "service user": "OK",
        "serial port": "OK",
        "login console": "OK",
        "port free": "OK",
        "UART": "OK",
        "GPIO": "OK",
        "lgpio": "OK",
        "plots and NetCDF": "OK",
        "profile": "OK",
        "journal": "OK",
        "clock": "OK",
        "service": "OK",
        "status socket": "OK",
    }, format_checks(list(checks.values()))
    assert "PL011" in checks["UART"].detail
    assert "answering: link UP on /dev/serial0" in checks["status socket"].detail


def plant_bad_config(pi: Pi) -> None:
    pi.write("/etc/cc-daemon/cc-daemon.toml", "[serial]\nbaudrate = 1234\n")


def plant_no_user(pi: Pi) -> None:
    pi.write("/etc/passwd", "root:x:0:0::/root:/bin/sh\n")


def plant_no_port(pi: Pi) -> None:
    (pi.root / "dev/ttyAMA0").unlink()


def plant_not_a_tty(pi: Pi) -> None:
    (pi.root / "dev/ttyAMA0").unlink()
    pi.write("/dev/ttyAMA0", "")


def plant_private_port(pi: Pi) -> None:
    pi.device.chmod(0o600)


def plant_kernel_console(pi: Pi) -> None:
    pi.write("/proc/cmdline", "console=serial0,115200 console=tty1 root=PARTUUID=1234-02\n")


def plant_getty(pi: Pi) -> None:
    pi.write("/etc/systemd/system/getty.target.wants/serial-getty@ttyAMA0.service", "")


def plant_holder(pi: Pi) -> None:
    pi.write("/proc/777/cmdline", "minicom\0-D\0/dev/serial0\0")
    (pi.root / "proc/777/fd").mkdir()
    (pi.root / "proc/777/fd/3").symlink_to(pi.device)


def plant_mini_uart(pi: Pi) -> None:
    pi.link("/dev/serial0", "ttyS0")
    pi.link("/dev/ttyS0", pi.device)


def plant_gpio_without_devices(pi: Pi) -> None:
    pi.write(
        "/etc/cc-daemon/cc-daemon.toml", '[winch]\nbackend = "gpio"\n[winch.gpio]\nadc = true\n'
    )
    (pi.root / "dev/gpiochip0").unlink()


def plant_readonly_journal(pi: Pi) -> None:
    (pi.root / "var/lib/cc-daemon").chmod(0o750)  # the group may not write


def plant_journal_outside(pi: Pi) -> None:
    # (with the GPIO winch: the default simulated winch would be a second FAIL of its own)
    config = '[winch]\nbackend = "gpio"\n[store]\npath = "/home/pi/survey.db"\n'
    pi.write("/etc/cc-daemon/cc-daemon.toml", config)


def plant_full_disk(pi: Pi) -> None:
    pi.system.statvfs = statvfs(3_000_000)


def plant_small_disk(pi: Pi) -> None:
    pi.system.statvfs = statvfs(20_000_000)


def plant_unsynced_clock(pi: Pi) -> None:
    pi.system.clock = lambda: ClockSync(False, 16.0, "adjtimex", "STA_UNSYNC")


def plant_failed_service(pi: Pi) -> None:
    pi.system.service_state = lambda: "failed"


async def plant_silent_socket(pi: Pi) -> None:
    await pi.server.close()


@pytest.mark.parametrize(
    ("plant", "name", "level", "words"),
    [
        (plant_bad_config, "config", "FAIL", "serial.baudrate = 1234"),
        (plant_no_user, "service user", "FAIL", "no user cc-daemon"),
        (plant_no_port, "serial port", "FAIL", "does not exist"),
        (plant_not_a_tty, "serial port", "FAIL", "not a serial device"),
        (plant_private_port, "serial port", "FAIL", "not readable and writable by cc-daemon"),
        (plant_kernel_console, "login console", "FAIL", "kernel console is on /dev/serial0"),
        (plant_getty, "login console", "FAIL", "a login prompt runs"),
        (plant_holder, "port free", "FAIL", "held by minicom -D /dev/serial0 (pid 777)"),
        (plant_mini_uart, "UART", "WARN", "mini-UART (ttyS0)"),
        (plant_gpio_without_devices, "GPIO", "FAIL", "no /dev/gpiochip*"),
        (plant_readonly_journal, "journal", "FAIL", "not writable by cc-daemon"),
        (plant_journal_outside, "journal", "FAIL", "outside /var/lib/cc-daemon"),
        (plant_full_disk, "journal", "FAIL", "a day needs 7 MB"),
        (plant_small_disk, "journal", "WARN", "about 3 days"),
        (plant_unsynced_clock, "clock", "WARN", "not synchronised"),
        (plant_failed_service, "service", "FAIL", "has failed"),
        (plant_silent_socket, "status socket", "FAIL", "no status socket at"),
    ],
)
async def test_each_planted_failure_is_found_with_a_fix(
    pi: Pi, plant: Callable[[Pi], object], name: str, level: str, words: str
) -> None:
    planted = plant(pi)
    if asyncio.iscoroutine(planted):
        await planted
    checks = await pi.checks()
    assert (checks[name].level, words in checks[name].detail) == (level, True), checks[name]
    assert checks[name].fix
    others = {n: c.level for n, c in checks.items() if n != name and c.level != "OK"}
    if plant is plant_gpio_without_devices:
        assert others == {"SPI": "FAIL"}
    else:
        assert others == {}, others


async def test_the_running_daemon_holding_the_port_is_fine(pi: Pi) -> None:
    pi.write(
        "/proc/555/cmdline", "/opt/cc-daemon/.venv/bin/python\0/opt/cc-daemon/.venv/bin/cc-daemon\0"
    )
    (pi.root / "proc/555/fd").mkdir()
    (pi.root / "proc/555/fd/5").symlink_to(pi.device)
    checks = await pi.checks()
    assert checks["port free"].detail.endswith("held by the running cc-daemon only")


async def test_the_command_exits_1_on_a_fail_and_prints_the_fix(pi: Pi) -> None:
    plant_kernel_console(pi)
    result = await asyncio.to_thread(
        subprocess.run,
        [sys.executable, "-m", "cc_daemon", "doctor", "--root", str(pi.root)],
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONPATH": str(REPO)},
        timeout=30,
    )
    assert result.returncode == 1, result.stdout + result.stderr
    assert "FAIL  login console" in result.stdout
    assert "fix: sudo raspi-config nonint do_serial_cons 1" in result.stdout
    # Under --root systemd is not asked, and doctor says so; the socket in the root still is.
    [service] = [line for line in result.stdout.splitlines() if line.startswith("SKIP")]
    assert service.split()[:2] == ["SKIP", "service"]
    assert f"not asked: --root {pi.root} is a system image" in service
    assert "systemd could not be asked" not in result.stdout
    assert "OK    status socket" in result.stdout
    assert result.stdout.rstrip().endswith(", 1 not checked here")
    as_json = await asyncio.to_thread(
        subprocess.run,
        [sys.executable, "-m", "cc_daemon", "doctor", "--root", str(pi.root), "--json"],
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONPATH": str(REPO)},
        timeout=30,
    )
    checks = {c["name"]: c for c in json.loads(as_json.stdout)}
    assert as_json.returncode == 1 and checks["login console"]["level"] == "FAIL"
    assert set(checks["config"]) == {"name", "level", "detail", "fix"}


async def test_an_unreadable_configuration_says_how_to_read_it(
    pi: Pi, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Root reads everything, so an operator outside the group is played by os.access.
    config = pi.root / "etc/cc-daemon/cc-daemon.toml"
    real_access = os.access
    monkeypatch.setattr(os, "access", lambda p, m: Path(p) != config and real_access(p, m))
    checks = await pi.checks()
    assert list(checks) == ["config"]
    assert checks["config"].level == "FAIL" and "not readable by you" in checks["config"].detail
    assert "usermod -aG cc-daemon" in checks["config"].fix


async def test_a_missing_library_the_configuration_uses_is_a_fail(pi: Pi) -> None:
    pi.system = dataclasses.replace(pi.system, installed=lambda module: module != "lgpio")
    checks = await pi.checks()
    assert checks["lgpio"].level == "FAIL" and "cc-daemon[pi]" in checks["lgpio"].fix
    assert checks["plots and NetCDF"].level == "OK"


async def test_missing_plot_libraries_are_a_warning_only(pi: Pi) -> None:
    pi.system = dataclasses.replace(
        pi.system, installed=lambda module: module not in ("matplotlib", "netCDF4")
    )
    checks = await pi.checks()
    assert checks["plots and NetCDF"].level == "WARN"
    assert "matplotlib and netCDF4 not installed" in checks["plots and NetCDF"].detail
    assert checks["lgpio"].level == "OK"


async def test_a_simulated_winch_answering_the_autopilot_is_a_warning(pi: Pi) -> None:
    config = pi.root / "etc/cc-daemon/cc-daemon.toml"
    text = config.read_text().replace('backend = "gpio"', 'backend = "sim"', 1)
    config.write_text(
        text.replace("allow_outside_simulation = false", "allow_outside_simulation = true")
    )
    checks = await pi.checks()
    assert checks["config"].level == "OK"
    assert checks["winch"].level == "WARN" and "no probe moves" in checks["winch"].detail
    assert "lgpio" not in checks


async def test_a_sonde_without_pymodbus_is_a_fail(pi: Pi) -> None:
    config = pi.root / "etc/cc-daemon/cc-daemon.toml"
    config.write_text(config.read_text().replace('backend = "none"', 'backend = "modbus"', 1))
    pi.system = dataclasses.replace(pi.system, installed=lambda module: module != "pymodbus")
    checks = await pi.checks()
    assert checks["pymodbus"].level == "FAIL" and "sonde.backend" in checks["pymodbus"].detail


async def test_the_profile_line_says_the_resolution_and_lag_the_configuration_gives(
    pi: Pi,
) -> None:
    config = pi.root / "etc/cc-daemon/cc-daemon.toml"
    shipped = config.read_text()
    checks = await pi.checks()
    assert checks["profile"].detail.startswith("no sonde")  # as shipped: casts not limited
    config.write_text(shipped.replace('backend = "none"', 'backend = "modbus"', 1))
    profile = (await pi.checks())["profile"]
    assert profile.level == "OK", profile
    assert profile.detail.startswith("continuous casts descend at 0.125 m/s (limit 0.125 m/s")
    assert "2.0 readings a bin" in profile.detail
    assert "temperature 0.25 m" in profile.detail and "do_concentration 1.00 m" in profile.detail
    # Resolving the oxygen asks for 0.031 m/s: slower than the winch can run.
    config.write_text(
        shipped.replace('backend = "none"', 'backend = "modbus"', 1).replace(
            'resolve = ["temperature"]', 'resolve = ["temperature", "do_concentration"]'
        )
    )
    profile = (await pi.checks())["profile"]
    assert profile.level == "WARN" and "cannot descend slower than 0.125 m/s" in profile.detail
    assert "profile.bin_m" in profile.fix
    config.write_text(
        shipped.replace('backend = "none"', 'backend = "modbus"', 1).replace(
            'mode = "continuous"', 'mode = "stepped"'
        )
    )
    profile = (await pi.checks())["profile"]
    assert profile.detail.startswith("stepped casts dwell >= 6 s a level (3 x temperature 2 s)")


@pytest.mark.parametrize(
    ("web", "level"),
    [
        ('listen = "0.0.0.0:8080"', "WARN"),
        ('listen = "[::]:8080"', "WARN"),
        ('listen = "0.0.0.0:8080"\npassword_hash = "{hash}"', "OK"),
        ('listen = "[::1]:8080"', None),
        ('listen = "localhost:8080"', None),
    ],
)
async def test_the_field_page_beyond_localhost_without_a_password_is_a_warning(
    pi: Pi, web: str, level: str | None
) -> None:
    from cc_daemon.cli.web.auth import hash_password

    config = pi.root / "etc/cc-daemon/cc-daemon.toml"
    shipped = 'listen = "127.0.0.1:8080"'  # the [web] section of config/cc-daemon.toml
    assert shipped in config.read_text()
    config.write_text(
        config.read_text().replace(shipped, web.replace("{hash}", hash_password("x")))
    )
    checks = await pi.checks()
    assert checks["config"].level == "OK", checks["config"].detail
    if level is None:
        assert "field page" not in checks
    else:
        assert checks["field page"].level == level
    if level == "WARN":
        assert "no password" in checks["field page"].detail
        assert "--hash-password" in checks["field page"].fix


async def test_with_no_file_the_environment_is_the_configuration(
    pi: Pi, monkeypatch: pytest.MonkeyPatch
) -> None:
    (pi.root / "etc/cc-daemon/cc-daemon.toml").unlink()
    monkeypatch.setenv("CC_DAEMON_WEB__LISTEN", "0.0.0.0:8080")
    checks = await pi.checks()
    assert checks["config"].level == "WARN" and "the defaults are in use" in checks["config"].detail
    assert checks["field page"].level == "WARN", format_checks(list(checks.values()))
    assert "web.listen = 0.0.0.0:8080 reaches beyond this Pi" in checks["field page"].detail
    monkeypatch.setenv("CC_DAEMON_WEB__LISTEN", "nowhere")
    checks = await pi.checks()
    assert list(checks) == ["config"] and checks["config"].level == "FAIL"
    assert "CC_DAEMON_WEB__LISTEN" in checks["config"].detail
