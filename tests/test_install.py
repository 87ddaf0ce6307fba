"""`make install` / `make uninstall` staged into a scratch DESTDIR, for real.

The script runs as it would on a Pi (systemd-sysusers, a venv with pip, the
files), only rooted in a temporary directory: nothing on this machine changes.
"""

from __future__ import annotations

import json
import os
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from tests.daemonkit import REPO

pytestmark = [
    pytest.mark.slow,
    # A real pip install into a fresh venv, three times over: about a minute on an idle
    # machine, several on a loaded one (a backstop against a hang, not a speed rule).
    pytest.mark.timeout(1200),
    pytest.mark.skipif(
        shutil.which("systemd-sysusers") is None,
        reason="systemd-sysusers not installed (apt-get install systemd): install not checked",
    ),
]


def make(target: str, destdir: Path | None, **env: str) -> subprocess.CompletedProcess[str]:
    """`make target DESTDIR=destdir`; None stands for the real thing (an empty DESTDIR)."""
    stage = "" if destdir is None else str(destdir)
    return subprocess.run(
        ["make", "--no-print-directory", "-C", str(REPO), target, f"DESTDIR={stage}"],
        capture_output=True,
        text=True,
        check=False,
        env={**os.environ, "PYTHON": sys.executable, **env},
        timeout=600,
    )


def mode(path: Path) -> str:
    return oct(stat.S_IMODE(path.stat().st_mode))


def test_install_twice_then_uninstall(tmp_path: Path) -> None:
    dest = tmp_path / "root"
    first = make("install", dest)
    assert first.returncode == 0, first.stdout + first.stderr
    assert "systemctl daemon-reload skipped" in first.stdout
    assert "systemctl enable --now cc-daemon" in first.stdout

    unit = dest / "etc/systemd/system/cc-daemon.service"
    config = dest / "etc/cc-daemon/cc-daemon.toml"
    venv = dest / "opt/cc-daemon/.venv"
    assert unit.read_text() == (REPO / "systemd/cc-daemon.service").read_text()
    assert config.read_text() == (REPO / "config/cc-daemon.toml").read_text()
    assert (mode(unit), mode(config)) == ("0o644", "0o640")
    assert (dest / "opt/cc-daemon/share/udev/99-cc-autopilot.rules").is_file()
    assert (dest / "opt/cc-daemon/share/docs/deployment.md").is_file()
    web_unit = dest / "etc/systemd/system/cc-daemon-web.service"  # the field page
    assert web_unit.read_text() == (REPO / "systemd/cc-daemon-web.service").read_text()
    assert (dest / "opt/cc-daemon/share/docs/web.md").is_file()
    # The user and the groups the unit names, written by systemd-sysusers.
    passwd = (dest / "etc/passwd").read_text()
    groups = {line.split(":")[0] for line in (dest / "etc/group").read_text().splitlines()}
    assert "cc-daemon:" in passwd and "/usr/sbin/nologin" in passwd
    assert {"cc-daemon", "dialout", "gpio", "spi"} <= groups
    # The venv really holds the package (its scripts name /opt: they run once moved, below).
    version = subprocess.run(
        [str(venv / "bin/python"), "-m", "cc_daemon", "--version"],
        capture_output=True,
        text=True,
        check=True,
    )
    assert version.stdout.startswith("cc-daemon ")
    # On everyone's PATH, pointing into the venv as the Pi will see it.
    link = dest / "usr/local/bin/cc-daemon"
    assert os.readlink(link) == "/opt/cc-daemon/.venv/bin/cc-daemon"
    # The staged tree names its final place, never the staging directory.
    assert str(dest) not in (venv / "bin/cc-daemon").read_text()
    assert str(dest) not in (venv / "pyvenv.cfg").read_text()
    moved_tree_runs(dest)

    # An operator's configuration survives a second install (an upgrade).
    config.write_text('[serial]\nport = "/dev/cc-autopilot"\n')
    second = make("install", dest)
    assert second.returncode == 0, second.stdout + second.stderr
    assert "keeping the existing" in second.stdout
    assert config.read_text() == '[serial]\nport = "/dev/cc-autopilot"\n'

    # Uninstall: everything but the data and the configuration.
    data = dest / "var/lib/cc-daemon/cc-daemon.db"
    data.parent.mkdir(parents=True)
    data.write_bytes(b"survey")
    gone = make("uninstall", dest)
    assert gone.returncode == 0, gone.stdout + gone.stderr
    assert not unit.exists() and not web_unit.exists() and not (dest / "opt/cc-daemon").exists()
    assert not link.is_symlink()
    assert not (dest / "etc/sysusers.d/cc-daemon.conf").exists()
    assert data.read_bytes() == b"survey"
    assert config.read_text() == '[serial]\nport = "/dev/cc-autopilot"\n'


def test_real_install_needs_root_and_says_so(tmp_path: Path) -> None:
    if os.geteuid() == 0:
        pytest.skip("running as root: a real install would change this machine")
    result = make("install", None)
    assert result.returncode != 0
    assert "run as root" in result.stderr


MOVE_TO_ROOT = r"""
set -eu
dest="$1"
# The staged tree where the Pi will have it: /opt/cc-daemon and /etc/cc-daemon ...
mount -t tmpfs none /opt
mkdir /opt/cc-daemon
mount --bind "$dest/opt/cc-daemon" /opt/cc-daemon
mkdir -p "$dest.ov/upper" "$dest.ov/work"
mount -t overlay overlay -o "lowerdir=/etc,upperdir=$dest.ov/upper,workdir=$dest.ov/work" /etc
cp -a "$dest/etc/cc-daemon" /etc/cc-daemon
# ... and the staging directory gone: a path into it would fail.
mount -t tmpfs none "$dest"
cd /
/opt/cc-daemon/.venv/bin/cc-daemon --version
/opt/cc-daemon/.venv/bin/cc-daemon doctor --json || test $? -eq 1
"""


def moved_tree_runs(dest: Path) -> None:
    """Stage, move to / (in a private mount namespace), run --version and doctor there."""
    if shutil.which("unshare") is None or os.geteuid() != 0:
        pytest.skip("the moved tree is checked as root with unshare(1): not available here")
    probe = subprocess.run(["unshare", "-m", "true"], capture_output=True, check=False)
    if probe.returncode != 0:
        pytest.skip(f"no private mount namespace here: {probe.stderr.decode().strip()}")
    env = {k: v for k, v in os.environ.items() if not k.startswith(("PYTHON", "VIRTUAL_ENV"))}
    result = subprocess.run(
        ["unshare", "-m", "sh", "-c", MOVE_TO_ROOT, "sh", str(dest)],
        capture_output=True,
        text=True,
        check=False,
        env=env,
        timeout=60,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    version, doctor = result.stdout.split("\n", 1)
    assert version.startswith("cc-daemon ")
    checks = {c["name"]: c for c in json.loads(doctor)}
    # The shipped configuration (the GPIO winch) with what it needs installed.
    assert checks["config"]["level"] == "OK", checks["config"]
    assert checks["lgpio"]["level"] == "OK", checks["lgpio"]
    assert checks["plots and NetCDF"]["level"] == "OK", checks["plots and NetCDF"]
    assert "Traceback" not in result.stderr
