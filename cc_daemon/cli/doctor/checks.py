"""The doctor's checks: each says OK, WARN or FAIL, what it saw, and the fix.

Every check reads the machine through `System` (so a fake root can plant each
failure) and never changes anything: no device is opened, no file written.
"""

from __future__ import annotations

import os
import re
import stat
from collections.abc import Iterator
from pathlib import Path

from cc_daemon.cli.doctor.software import check_software
from cc_daemon.cli.doctor.system import Identity, System, describe_owner, may, resolve
from cc_daemon.cli.doctor.verdict import Check, Level
from cc_daemon.cli.status.client import StatusUnavailable, read_status
from cc_daemon.config import Settings, load_settings
from cc_daemon.config.resolution import describe_resolution
from cc_daemon.config.statuspaths import SERVICE_SOCKET
from cc_daemon.core.errors import ConfigError

CONFIG_PATH = "/etc/cc-daemon/cc-daemon.toml"
STATE_DIR = "/var/lib/cc-daemon"
# A day of survey journal measured at 6.8 MB (README, "a day of data"); rounded up.
JOURNAL_BYTES_PER_DAY = 7_000_000
READ, WRITE = 4, 2
UART_NAMES = re.compile(r"^(serial\d|ttyS\d+|ttyAMA\d+)$")


def load_config(system: System, config: Path | None) -> tuple[Check, Settings | None]:
    path = config if config is not None else system.path(CONFIG_PATH)
    if config is None and not path.exists():
        # No file: the defaults, and the environment's CC_DAEMON_ variables over them
        # (a web.listen set there is as much the field page's as one in a file).
        try:
            settings = load_settings(None, search_paths=())
        except ConfigError as exc:
            return Check(
                "config", "FAIL", str(exc), "correct the CC_DAEMON_ variable it names"
            ), None
        detail = f"no {CONFIG_PATH}: the defaults are in use (serial.port = {settings.serial.port})"
        fix = "sudo make install writes the default file; edit serial.port and winch there"
        return Check("config", "WARN", detail, fix), settings
    if path.exists() and not os.access(path, os.R_OK):
        fix = "run doctor with sudo, or join the group: sudo usermod -aG cc-daemon $USER"
        return Check("config", "FAIL", f"{path} is not readable by you", fix), None
    try:
        settings = load_settings(path)
    except ConfigError as exc:
        fix = f"correct {path} as the message says, then run doctor again"
        return Check("config", "FAIL", str(exc), fix), None
    return Check("config", "OK", f"{path} is valid"), settings


def check_user(system: System) -> tuple[Check, Identity | None]:
    who = system.service_identity()
    if who is None:
        fix = "sudo make install (it creates the user with systemd-sysusers)"
        return Check("service user", "FAIL", "no user cc-daemon", fix), None
    return Check("service user", "OK", f"{who.user} (uid {who.uid})"), who


def _holders(system: System, device: Path) -> tuple[list[tuple[int, str]], int]:
    """Processes with `device` open, and how many processes could not be inspected."""
    holders: list[tuple[int, str]] = []
    hidden = 0
    proc = system.path("/proc")
    try:
        pids = [int(p.name) for p in proc.iterdir() if p.name.isdigit()]
    except OSError:
        return [], 0
    for pid in pids:
        if pid == os.getpid() and system.root == Path("/"):
            continue
        try:
            fds = list((proc / str(pid) / "fd").iterdir())
        except PermissionError:
            hidden += 1
            continue
        except OSError:
            continue
        for fd in fds:
            try:
                target = Path(os.path.realpath(proc / str(pid) / "fd" / os.readlink(fd)))
            except OSError:
                continue
            if target == device:
                cmdline = system.read(f"/proc/{pid}/cmdline") or ""
                holders.append((pid, cmdline.replace("\0", " ").strip() or "?"))
                break
    return holders, hidden


def check_serial(system: System, settings: Settings, who: Identity | None) -> Iterator[Check]:
    port = settings.serial.port
    device, name = resolve(system, Path(port))
    try:
        st = device.stat()
    except OSError:
        fix = (
            "USB adapter: plug it in (ls /dev/serial/by-id/); the Pi's UART: "
            "sudo raspi-config nonint do_serial_hw 0 and reboot; or correct serial.port"
        )
        yield Check("serial port", "FAIL", f"{port} does not exist", fix)
        return
    if not stat.S_ISCHR(st.st_mode):
        yield Check("serial port", "FAIL", f"{port} is not a serial device", "correct serial.port")
        return
    if who is not None and not may(who, st, READ | WRITE):
        fix = (
            "the device must be group dialout, mode 0660 (see the udev rule example "
            "in /opt/cc-daemon/share/udev/); the unit gives the service the dialout group"
        )
        yield Check(
            "serial port",
            "FAIL",
            f"{port} ({device}, {describe_owner(st)}) is not readable and writable by {who.user}",
            fix,
        )
    else:
        yield Check("serial port", "OK", f"{port} is {device}, a tty the service may use")
    yield from _console(system, port, name)
    holders, hidden = _holders(system, device)
    others = [(pid, cmd) for pid, cmd in holders if "cc-daemon" not in cmd]
    if others:
        listed = ", ".join(f"{cmd} (pid {pid})" for pid, cmd in others)
        fix = "stop it (a login console: see above; minicom/screen: quit it)"
        yield Check("port free", "FAIL", f"{port} is held by {listed}", fix)
    elif holders:
        yield Check("port free", "OK", f"{port} is held by the running cc-daemon only")
    elif hidden:
        fix = "run doctor as root to see every process"
        yield Check("port free", "WARN", f"{hidden} processes could not be inspected", fix)
    else:
        yield Check("port free", "OK", f"no other process has {port} open")
    yield from _uart_kind(system, port, name)


def _console(system: System, port: str, name: str) -> Iterator[Check]:
    """The classic: the kernel or a getty uses the UART as a login console."""
    names = {Path(port).name, name, "serial0"} if UART_NAMES.match(name) else {name}
    cmdline = system.read("/proc/cmdline") or ""
    consoles = {c.split(",")[0] for c in re.findall(r"console=(\S+)", cmdline)}
    wants = system.path("/etc/systemd/system/getty.target.wants")
    gettys = {n for n in names if (wants / f"serial-getty@{n}.service").exists()}
    if consoles & names:
        fix = (
            "sudo raspi-config nonint do_serial_cons 1 (or delete console=serial0,115200 "
            "from /boot/firmware/cmdline.txt), then reboot"
        )
        yield Check("login console", "FAIL", f"the kernel console is on {port}", fix)
    elif gettys:
        unit = f"serial-getty@{sorted(gettys)[0]}.service"
        yield Check(
            "login console",
            "FAIL",
            f"a login prompt runs on {port}",
            f"sudo systemctl disable --now {unit}",
        )
    else:
        yield Check("login console", "OK", f"no login console on {port}")


def _uart_kind(system: System, port: str, name: str) -> Iterator[Check]:
    model = (system.read("/proc/device-tree/model") or "").strip("\0\n ")
    if "Raspberry Pi" not in model or not UART_NAMES.match(name):
        return  # a USB adapter, or not a Pi: its own clock, nothing to say
    if name.startswith("ttyS"):
        fix = (
            "use the PL011: add dtoverlay=disable-bt to /boot/firmware/config.txt, "
            "sudo systemctl disable hciuart, reboot (/dev/serial0 is then ttyAMA0)"
        )
        detail = f"{port} is the mini-UART ({name}): its baud rate follows the core clock"
        yield Check("UART", "WARN", detail, fix)
    elif name == "ttyAMA10":
        fix = "the GPIO 14/15 UART is /dev/ttyAMA0: dtparam=uart0=on in config.txt"
        yield Check("UART", "WARN", f"{port} is the Pi 5's debug-connector UART", fix)
    else:
        yield Check("UART", "OK", f"{port} is a PL011 UART ({name}) on a {model}")


def check_gpio(system: System, settings: Settings, who: Identity | None) -> Iterator[Check]:
    gpio = settings.winch.gpio
    if settings.winch.backend != "gpio" or gpio.pin_factory != "native":
        return
    needed = [("GPIO", "gpiochip*", "a Raspberry Pi kernel provides /dev/gpiochip0; group gpio")]
    if gpio.adc:  # the MCP3008 on SPI0
        needed.append(
            ("SPI", "spidev*", "enable SPI: sudo raspi-config nonint do_spi 0, then reboot")
        )
    for label, pattern, fix in needed:
        devices = sorted(system.path("/dev").glob(pattern))
        if not devices:
            yield Check(label, "FAIL", f"no /dev/{pattern}", fix)
            continue
        refused = [d for d in devices if who is not None and not may(who, d.stat(), READ | WRITE)]
        if refused:
            owner = describe_owner(refused[0].stat())
            detail = f"/dev/{refused[0].name} ({owner}) is not usable by the service user"
            yield Check(label, "FAIL", detail, f"the device must be group {label.lower()}, 0660")
        else:
            yield Check(label, "OK", ", ".join(f"/dev/{d.name}" for d in devices))


def check_journal(system: System, settings: Settings, who: Identity | None) -> Iterator[Check]:
    configured = settings.store.path
    path = Path(STATE_DIR) / (configured or "cc-daemon.db")  # relative: the unit's WorkingDirectory
    directory = system.path(path.parent)
    if not path.parent.is_relative_to(STATE_DIR):
        fix = f"keep store.path under {STATE_DIR}: the unit lets the service write nothing else"
        yield Check("journal", "FAIL", f"{path} is outside {STATE_DIR}", fix)
        return
    try:
        st = directory.stat()
    except OSError:
        fix = "systemd creates it at the service's first start (StateDirectory=)"
        yield Check("journal", "WARN", f"{path.parent} does not exist yet", fix)
        return
    if who is not None and not may(who, st, WRITE | 1):
        fix = f"sudo chown -R {who.user}: {path.parent} (systemd does it for StateDirectory=)"
        detail = f"{path.parent} ({describe_owner(st)}) is not writable by {who.user}"
        yield Check("journal", "FAIL", detail, fix)
        return
    vfs = system.statvfs(str(directory))
    free = vfs.f_bavail * vfs.f_frsize
    days = free / JOURNAL_BYTES_PER_DAY
    detail = f"{path}: {free / 1e6:.0f} MB free, about {days:.0f} days of survey"
    fix = "free space (cc-daemon export, then archive old journals) or a larger card"
    if days < 1:
        yield Check("journal", "FAIL", detail + " (a day needs 7 MB)", fix)
    elif days < 7:
        yield Check("journal", "WARN", detail, fix)
    else:
        yield Check("journal", "OK", detail)


def check_clock(system: System) -> Check:
    sync = system.clock()
    if sync.synchronised:
        error = f", max error {sync.max_error_s:.3f} s" if sync.max_error_s is not None else ""
        return Check("clock", "OK", f"synchronised ({sync.source}{error})")
    fix = (
        "give the Pi network time (timedatectl set-ntp true) or a GPS/RTC time source; "
        "until then journal rows carry clock_synced = 0"
    )
    what = "not synchronised" if sync.synchronised is False else "synchronisation unknown"
    detail = f"{what} ({sync.source})" + (f": {sync.detail}" if sync.detail else "")
    return Check("clock", "WARN", detail, fix)


def check_service(system: System, settings: Settings) -> Iterator[Check]:
    state = system.state()
    if state is None and system.image:
        what = f"not asked: --root {system.root} is a system image, not this running system"
        yield Check("service", "SKIP", what)
    elif state is None:
        yield Check("service", "WARN", "systemd could not be asked", "systemctl status cc-daemon")
    elif state == "active":
        yield Check("service", "OK", "cc-daemon is active")
    elif state == "failed":
        fix = "journalctl -u cc-daemon -e shows why; then sudo systemctl restart cc-daemon"
        yield Check("service", "FAIL", "cc-daemon has failed", fix)
    else:
        yield Check(
            "service", "WARN", f"cc-daemon is {state}", "sudo systemctl enable --now cc-daemon"
        )
    path = system.path(settings.status.path or SERVICE_SOCKET)
    try:
        doc = read_status(path, timeout_s=3.0)
    except StatusUnavailable as exc:
        level: Level = "FAIL" if state == "active" else "WARN"
        yield Check("status socket", level, str(exc), "cc-daemon status --socket PATH to try")
        return
    link, cast = (v if isinstance(v := doc.get(k), dict) else {} for k in ("link", "cast"))
    up = "UP" if link.get("up") else "DOWN"
    detail = f"answering: link {up} on {link.get('port', '?')}, cast {cast.get('phase', '?')}"
    if link.get("up"):
        yield Check("status socket", "OK", detail)
    else:
        fix = "the daemon cannot open the port: see the serial port checks above"
        yield Check("status socket", "WARN", detail, fix)


def check_profile(settings: Settings) -> Check:
    """What resolution and lag the configuration's casts give (docs/profiles.md)."""
    described = describe_resolution(settings)
    if described is None:
        return Check("profile", "OK", "no sonde (sonde.backend = none): casts are not limited")
    line, short = described
    if short:
        fix = "widen profile.bin_m, lower profile.min_count or resolve fewer parameters"
        return Check("profile", "WARN", line, fix)
    return Check("profile", "OK", line)


def run_checks(system: System, config: Path | None = None) -> list[Check]:
    first, settings = load_config(system, config)
    results = [first]
    if settings is None:
        return results  # everything else depends on a valid configuration
    user, who = check_user(system)
    results.append(user)
    results += check_serial(system, settings, who)
    results += check_gpio(system, settings, who)
    results += check_software(settings, system.installed)
    results.append(check_profile(settings))
    results += check_journal(system, settings, who)
    results.append(check_clock(system))
    results += check_service(system, settings)
    return results
