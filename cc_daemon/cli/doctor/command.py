"""`cc-daemon doctor`: run the checks, print each with its fix, exit 1 on any FAIL."""

from __future__ import annotations

import argparse
import json
from dataclasses import asdict
from pathlib import Path

from cc_daemon.cli.doctor.checks import run_checks
from cc_daemon.cli.doctor.system import System
from cc_daemon.cli.doctor.verdict import Check

EXIT_FAIL = 1


def add_commands(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "doctor",
        help="check this machine is ready to run the service",
        description="Check the configuration, the serial port, GPIO/SPI, the journal's disk, "
        "the clock, the service and its status socket. Exit status 1 on any FAIL.",
    )
    p.add_argument(
        "--config",
        dest="doctor_config",
        type=Path,
        help="the configuration to check (default: /etc/cc-daemon/cc-daemon.toml)",
    )
    p.add_argument("--root", type=Path, default=Path("/"), help="check a system image at DIR")
    p.add_argument("--json", action="store_true", help="the checks as one JSON list")
    p.set_defaults(handler=run_doctor)


def format_checks(checks: list[Check]) -> str:
    width = max(len(c.name) for c in checks)
    lines = []
    for c in checks:
        lines.append(f"{c.level:<4}  {c.name:<{width}}  {c.detail}")
        if c.fix and c.level != "OK":
            lines.append(f"{'':<4}  {'':<{width}}  fix: {c.fix}")
    return "\n".join(lines)


def run_doctor(args: argparse.Namespace) -> int:
    checks = run_checks(System(root=args.root), args.doctor_config)
    if args.json:
        print(json.dumps([asdict(c) for c in checks]))
    else:
        print(format_checks(checks))
        count = {level: sum(c.level == level for c in checks) for level in ("FAIL", "WARN", "OK")}
        skipped = len(checks) - sum(count.values())
        print(
            f"\n{count['FAIL']} FAIL, {count['WARN']} WARN, {count['OK']} OK"
            + (f", {skipped} not checked here" if skipped else "")
        )
    return EXIT_FAIL if any(c.level == "FAIL" for c in checks) else 0
