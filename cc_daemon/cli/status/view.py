"""The status document for a person: a block of aligned lines, once or live.

It renders whatever document it is given; sections it does not know (added by
later features) are shown as `name  value`. It never talks to the socket itself
except through the `fetch` callable `watch` is handed.
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Callable
from typing import Any, TextIO

from rich.console import Console
from rich.live import Live
from rich.panel import Panel
from rich.text import Text

Document = dict[str, Any]
KNOWN = ("daemon", "link", "fix", "cast", "winch", "journal", "counters", "clock")


def _duration(seconds: float) -> str:
    seconds = int(seconds)
    if seconds < 60:
        return f"{seconds} s"
    minutes, _ = divmod(seconds, 60)
    hours, minutes = divmod(minutes, 60)
    days, hours = divmod(hours, 24)
    if days:
        return f"{days} d {hours} h"
    return f"{hours} h {minutes:02d} min" if hours else f"{minutes} min"


def _bytes(n: int | None) -> str:
    if n is None:
        return "unknown"
    for unit in ("B", "KB", "MB", "GB"):
        if n < 1000:
            return f"{n:.0f} {unit}"
        n = n // 1000 if unit == "B" else n / 1000  # type: ignore[assignment]
    return f"{n:.1f} TB"


def _section(doc: Document, name: str) -> dict[str, Any]:
    value = doc.get(name)
    return value if isinstance(value, dict) else {}


def status_lines(doc: Document) -> list[tuple[str, str]]:
    """(label, text) rows; every known section, then any others as JSON."""
    rows: list[tuple[str, str]] = []
    d = _section(doc, "daemon")
    rows.append(
        (
            "daemon",
            f"cc-daemon {d.get('version', '?')} on {d.get('host', '?')}, pid {d.get('pid', '?')},"
            f" up {_duration(float(d.get('uptime_s', 0)))}"
            + (
                ", STOPPING (bringing the probe home first)" if d.get("state") == "stopping" else ""
            ),
        )
    )
    link = _section(doc, "link")
    state = "UP" if link.get("up") else "DOWN"
    rows.append(
        (
            "link",
            f"{state} on {link.get('port', '?')} at {link.get('baudrate', '?')} bit/s,"
            f" {link.get('port_losses', 0)} port losses"
            + (
                f", {link['open_attempts']} attempts to open it"
                if link.get("open_attempts")
                else ""
            ),
        )
    )
    fix = doc.get("fix")
    if isinstance(fix, dict):
        lat = fix.get("lat_e7", 0) / 1e7
        lon = fix.get("lon_e7", 0) / 1e7
        sonar = fix.get("sonar_distance_mm", 0) / 1000
        rows.append(
            (
                "last fix",
                f"{fix.get('frame', '?')} {fix.get('age_s', '?')} s ago: {lat:.7f}, {lon:.7f},"
                f" sonar {sonar:.2f} m ({fix.get('sonar_confidence_pct', '?')} %)",
            )
        )
    else:
        rows.append(("last fix", "none yet"))
    cast = _section(doc, "cast")
    planned = cast.get("planned_depth_m")
    text = str(cast.get("phase", "?"))
    if cast.get("cast_id") is not None:
        text += f", cast {cast['cast_id']}"
    text += f", probe at {cast.get('depth_m', 0):.2f} m"
    if planned is not None:
        text += f" of {planned:.2f} m planned"
    rows.append(("cast", text))
    reported = cast.get("fault_reported")
    if isinstance(reported, dict):
        low, high = reported.get("depth_low_m"), reported.get("depth_high_m")
        where = f"probe at {reported.get('depth_m', 0):.2f} m"
        if isinstance(low, int | float) and isinstance(high, int | float):
            where = (
                f"probe between {low:.2f} and {high:.2f} m (an estimate: best "
                f"{reported.get('depth_m', 0):.2f} m)"
            )
        rows.append(
            (
                "STRANDED",
                f"{where} ({reported.get('fault')}); "
                f"R-L sent to the autopilot x{reported.get('r_l_sent', 0)}, no R-F",
            )
        )
    w = _section(doc, "winch")
    motion = "moving" if w.get("moving") else "stopped"
    home = ", home" if w.get("at_home") else ""
    fault = w.get("fault")
    sensor = w.get("sensor_fault")
    rows.append(
        (
            "winch",
            f"{w.get('backend', '?')}: {motion}{home}"
            + (f", FAULT: {fault}" if fault else "")
            + (f", SENSOR FAULT (overcurrent by pulses only): {sensor}" if sensor else ""),
        )
    )
    j = doc.get("journal")
    if isinstance(j, dict):
        health = "writable" if j.get("writable") else "NOT WRITABLE"
        text = (
            f"{j.get('path', '?')}: {health}, {j.get('pending_rows', 0)} rows pending,"
            f" {_bytes(j.get('disk_free_bytes'))} free"
        )
        if j.get("spilled_rows"):
            files = ", ".join(str(f) for f in j.get("spill_files") or [])
            text += f", {j['spilled_rows']} of them in spill files ({files})"
        if j.get("dropped_rows"):
            text += f", {j['dropped_rows']} rows DROPPED"
        if j.get("last_error"):
            text += f" (last error: {j['last_error']})"
        rows.append(("journal", text))
    c = _section(doc, "counters")
    rows.append(
        (
            "counters",
            f"frames {c.get('frames_in', 0)} in / {c.get('frames_out', 0)} out,"
            f" {c.get('corrupt_frames', 0)} corrupt; casts {c.get('casts_completed', 0)} completed,"
            f" {c.get('casts_aborted', 0)} aborted, {c.get('casts_skipped', 0)} skipped",
        )
    )
    clock = _section(doc, "clock")
    synced = clock.get("synchronised")
    text = {True: "synchronised", False: "NOT synchronised", None: "unknown"}[synced]
    if clock.get("max_error_s") is not None:
        text += f" (max error {clock['max_error_s']:.3f} s)"
    rows.append(("clock", f"{text}, by {clock.get('source', '?')}"))
    for name, value in doc.items():
        if name not in KNOWN:
            rows.append((name, json.dumps(value, default=str)))
    return rows


def render_text(doc: Document) -> str:
    rows = status_lines(doc)
    width = max(len(label) for label, _ in rows)
    return "\n".join(f"{label:<{width}}  {text}" for label, text in rows)


def watch(
    fetch: Callable[[], Document],
    *,
    interval_s: float = 1.0,
    updates: int | None = None,
    stream: TextIO | None = None,
) -> int:
    """Show the status, refreshed every `interval_s`, until Ctrl-C (or `updates` times).

    A terminal gets a live panel; a pipe gets one block per refresh. A daemon that
    stops answering is shown as such, and watched until it answers again.
    """
    out = stream or sys.stdout
    console = Console(file=out)
    shown = 0

    def frame() -> str:
        try:
            return render_text(fetch())
        except Exception as exc:
            return f"daemon not answering: {exc}"

    try:
        if console.is_terminal:
            with Live(console=console, auto_refresh=False) as live:
                while updates is None or shown < updates:
                    text = Text(frame())
                    live.update(Panel(text, title="cc-daemon status"), refresh=True)
                    shown += 1
                    if updates is None or shown < updates:
                        time.sleep(interval_s)
        else:
            while updates is None or shown < updates:
                out.write(time.strftime("%H:%M:%S") + "\n" + frame() + "\n\n")
                out.flush()
                shown += 1
                if updates is None or shown < updates:
                    time.sleep(interval_s)
    except KeyboardInterrupt:
        pass
    return 0
