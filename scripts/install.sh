#!/usr/bin/env bash
# Install or uninstall cc-daemon as a systemd service (`sudo make install`).
#
#   scripts/install.sh install     user and groups, venv, unit, default config, udev example
#   scripts/install.sh uninstall   everything except the data (/var/lib/cc-daemon), the
#                                  configuration (/etc/cc-daemon) and the system user
#
# Environment:
#   DESTDIR    stage everything under this directory and touch nothing of the machine:
#              no systemctl, no chown; users are written to $DESTDIR/etc/{passwd,group}
#   PREFIX     where the venv, docs and examples go (/opt/cc-daemon; the unit's
#              ExecStart= expects that path)
#   PYTHON     the interpreter the venv is made from (python3, >= 3.11)
#   EXTRAS     pip extras to install, comma-separated; by default what the installed
#              service and its commands use: "plot,netcdf,science" (plots, NetCDF and the science on
#              the Pi), and "pi" (lgpio) when the configuration drives the GPIO winch
#   PIP_ARGS   extra arguments for pip (e.g. --no-index --find-links DIR, offline)
#
# Installing twice is safe: an existing configuration is never overwritten, the venv
# is upgraded in place, and the unit is replaced (run `systemctl restart cc-daemon`).
set -euo pipefail

SRC="$(cd "$(dirname "$0")/.." && pwd)"
DESTDIR="${DESTDIR:-}"
# A relative DESTDIR would be relative to wherever each tool runs: pin it.
[[ -n "$DESTDIR" ]] && DESTDIR="$(realpath -m "$DESTDIR")"
PREFIX="${PREFIX:-/opt/cc-daemon}"
PYTHON="${PYTHON:-python3}"
PIP_ARGS="${PIP_ARGS:-}"
ROOT="${DESTDIR%/}"
ETC="$ROOT/etc"
UNIT_DIR="$ETC/systemd/system"
CONFIG="$ETC/cc-daemon/cc-daemon.toml"
VENV="$ROOT$PREFIX/.venv"
SHARE="$ROOT$PREFIX/share"
SYSUSERS="$ETC/sysusers.d/cc-daemon.conf"
LINK="$ROOT/usr/local/bin/cc-daemon"

say() { printf 'cc-daemon install: %s\n' "$*"; }
die() { printf 'cc-daemon install: error: %s\n' "$*" >&2; exit 1; }

need_root() {
    # Staging into DESTDIR needs no privileges; the real thing does.
    if [[ -z "$DESTDIR" && "$(id -u)" -ne 0 ]]; then
        die "run as root (sudo make $1), or set DESTDIR to stage into a directory"
    fi
}

extras() {
    if [[ -n "${EXTRAS+set}" ]]; then
        printf '%s' "$EXTRAS"
        return
    fi
    # The backend the configuration in force selects (the shipped one on a first install).
    local config="$CONFIG"
    [[ -f "$config" ]] || config="$SRC/config/cc-daemon.toml"
    local backend wanted="plot,netcdf,science"
    backend="$(sed -n '/^\[winch\]/,/^\[/{s/^backend *= *"\([a-z]*\)".*/\1/p}' "$config" | head -n1)"
    # The extras' names are pyproject.toml's: fail loudly if one is ever renamed.
    local extra
    for extra in pi plot netcdf; do
        grep -q "^$extra *= *\[" "$SRC/pyproject.toml" || die "pyproject.toml has no extra '$extra'"
    done
    [[ "$backend" == "gpio" ]] && wanted="pi,$wanted"
    printf '%s' "$wanted"
}

make_users() {
    install -d -m 0755 "$ETC/sysusers.d"
    install -m 0644 "$SRC/systemd/cc-daemon.sysusers" "$SYSUSERS"
    if [[ -n "$DESTDIR" ]]; then
        systemd-sysusers --root="$ROOT" "$SYSUSERS"
    else
        systemd-sysusers "$SYSUSERS"
    fi
}

make_venv() {
    "$PYTHON" -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else "cc-daemon needs Python >= 3.11")'
    if [[ ! -x "$VENV/bin/python" ]]; then
        say "creating the virtualenv $VENV"
        "$PYTHON" -m venv "$VENV"
    fi
    local spec="$SRC" wanted
    wanted="$(extras)"
    [[ -n "$wanted" ]] && spec="$SRC[$wanted]"
    say "installing $spec into $VENV"
    # shellcheck disable=SC2086  # PIP_ARGS is a list of words
    "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check $PIP_ARGS "$spec"
    # The same version number from a newer checkout must still replace the old code.
    # shellcheck disable=SC2086
    "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check --no-deps \
        --force-reinstall $PIP_ARGS "$SRC"
    relocate_venv
}

relocate_venv() {
    # Staged under DESTDIR, pip wrote the staging path into every script's shebang and
    # into pyvenv.cfg: the tree would not run once moved to /. Name the final path.
    [[ -n "$DESTDIR" ]] || return 0
    local staged="$VENV" final="$PREFIX/.venv" file
    while IFS= read -r -d '' file; do
        sed -i "s#$staged#$final#g" "$file"
    done < <(grep -rlIZ -F -- "$staged" "$VENV/bin" "$VENV/pyvenv.cfg" || true)
}

install_files() {
    install -d -m 0755 "$UNIT_DIR" "$SHARE" "$SHARE/docs" "$SHARE/udev" "$ROOT/usr/local/bin"
    # `cc-daemon status` and `doctor` on every user's PATH; another cc-daemon there is kept.
    if [[ ! -e "$LINK" || "$(readlink "$LINK")" == "$PREFIX/.venv/bin/cc-daemon" ]]; then
        ln -sfn "$PREFIX/.venv/bin/cc-daemon" "$LINK"
    else
        say "keeping $LINK (not ours); the program is $PREFIX/.venv/bin/cc-daemon"
    fi
    install -m 0644 "$SRC/systemd/cc-daemon.service" "$UNIT_DIR/cc-daemon.service"
    # The field page (docs/web.md): installed, not enabled.
    install -m 0644 "$SRC/systemd/cc-daemon-web.service" "$UNIT_DIR/cc-daemon-web.service"
    install -m 0644 "$SRC/systemd/99-cc-autopilot.rules" "$SHARE/udev/99-cc-autopilot.rules"
    install -m 0644 "$SRC/config/cc-daemon.toml" "$SHARE/cc-daemon.toml.default"
    install -m 0644 "$SRC"/docs/*.md "$SHARE/docs/"
    install -d -m 0755 "$ETC/cc-daemon"
    if [[ -e "$CONFIG" ]]; then
        say "keeping the existing $CONFIG (the shipped default is $SHARE/cc-daemon.toml.default)"
    else
        # Group-readable by the service (and the operators), not by everyone.
        install -m 0640 "$SRC/config/cc-daemon.toml" "$CONFIG"
        [[ -z "$DESTDIR" ]] && chgrp cc-daemon "$CONFIG"
        say "wrote the default configuration $CONFIG"
    fi
}

do_install() {
    need_root install
    make_users
    make_venv
    install_files
    if [[ -z "$DESTDIR" ]]; then
        systemctl daemon-reload
    else
        say "DESTDIR set: systemctl daemon-reload skipped"
    fi
    cat <<EOF

cc-daemon is installed. Next steps:
  1. Edit the serial port and the winch in /etc/cc-daemon/cc-daemon.toml
     (for a stable name, see $PREFIX/share/udev/99-cc-autopilot.rules).
  2. Let your login read the status:  sudo usermod -aG cc-daemon \$USER  (then log in again)
  3. Check the Pi:                     sudo cc-daemon doctor
  4. Start it, now and at boot:        sudo systemctl enable --now cc-daemon
  5. Watch it:                         journalctl -u cc-daemon -f
                                       cc-daemon status --watch
  6. The field page, if wanted:        sudo systemctl enable --now cc-daemon-web
                                       ([web] in the configuration; $PREFIX/share/docs/web.md)
Upgrade later: git pull && sudo make install && sudo systemctl restart cc-daemon
EOF
}

do_uninstall() {
    need_root uninstall
    if [[ -z "$DESTDIR" ]]; then
        systemctl disable --now cc-daemon-web.service 2>/dev/null || true
        systemctl disable --now cc-daemon.service 2>/dev/null || true
    fi
    rm -f "$UNIT_DIR/cc-daemon.service" "$UNIT_DIR/cc-daemon-web.service" "$SYSUSERS"
    if [[ "$(readlink "$LINK" 2>/dev/null)" == "$PREFIX/.venv/bin/cc-daemon" ]]; then
        rm -f "$LINK"
    fi
    rm -rf "$ROOT$PREFIX"
    if [[ -z "$DESTDIR" ]]; then
        systemctl daemon-reload
    fi
    cat <<EOF
cc-daemon is uninstalled. Kept on purpose:
  the survey journal   /var/lib/cc-daemon
  the configuration    /etc/cc-daemon
  the system user      cc-daemon (it owns the journal); remove it with: sudo userdel cc-daemon
EOF
}

case "${1:-}" in
    install) do_install ;;
    uninstall) do_uninstall ;;
    *) die "usage: $0 install|uninstall" ;;
esac
