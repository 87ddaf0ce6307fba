"""SIGHUP's logic: what changed, what applies live, what needs a restart, what is refused."""

from __future__ import annotations

import io
import json
import re
from pathlib import Path
from typing import Any

import pytest

from cc_daemon.config import Settings, load_settings
from cc_daemon.core.errors import ConfigError
from cc_daemon.daemon.reload import Reloader, ReloadRefused, is_live, plan_reload
from cc_daemon.ground.logsetup import configure_logging


def settings(**sections: Any) -> Settings:
    return Settings.model_validate(sections)


def test_nothing_changed_is_an_empty_plan() -> None:
    plan = plan_reload(settings(), settings())
    assert (plan.applied, plan.needs_restart) == ((), ())
    assert plan.settings.model_dump() == Settings().model_dump()


def test_live_keys_apply_and_the_rest_is_kept_and_named() -> None:
    old = settings(serial={"port": "/dev/ttyA"})
    new = settings(
        serial={"port": "/dev/ttyB", "baudrate": 19200},
        winch={"backend": "gpio"},
        store={"path": "/srv/other.db", "telemetry_rate_hz": 1.0},
        cast={"target_depth_m": 8.0, "report_period_s": 0.5},
        log={"level": "debug", "format": "json"},
    )
    plan = plan_reload(old, new)
    assert plan.applied == (
        "cast.target_depth_m",
        "cast.report_period_s",
        "store.telemetry_rate_hz",
        "log.format",
        "log.level",
    )
    assert plan.needs_restart == (
        "serial.port",
        "serial.baudrate",
        "winch.backend",
        "store.path",
    )
    got = plan.settings
    assert (got.serial.port, got.serial.baudrate, got.winch.backend, got.store.path) == (
        "/dev/ttyA",
        9600,
        "sim",
        None,
    )
    assert (got.cast.target_depth_m, got.cast.report_period_s, got.store.telemetry_rate_hz) == (
        8.0,
        0.5,
        1.0,
    )
    assert (got.log.level, got.log.format) == ("debug", "json")
    assert plan.logging_changed


@pytest.mark.parametrize(
    ("key", "live"),
    [
        ("log.level", True),
        ("cast.mode", True),
        ("store.telemetry_rate_hz", True),
        ("store.path", False),
        ("serial.port", False),
        ("winch.sim.speed_m_s", False),
        ("castaway.x", False),
    ],
)
def test_which_keys_are_live(key: str, live: bool) -> None:
    assert is_live(key) is live


def test_a_live_value_impossible_with_a_kept_one_is_refused() -> None:
    old = settings()  # 20 m of line
    new = settings(winch={"max_line_m": 30.0}, cast={"target_depth_m": 25.0})
    with pytest.raises(ReloadRefused, match=re.escape("winch.max_line_m = 20.0")):
        plan_reload(old, new)


# ------------------------------------------------------------------- the Reloader


class FakeDaemon:
    """Records what the reloader did to it, as the real Daemon would hold it."""

    def __init__(self, current: Settings, *, shutting_down: bool = False) -> None:
        self.settings = current
        self.shutting_down = shutting_down
        self.reloads: list[tuple[str, ...]] = []
        self.events: list[tuple[str, dict[str, Any]]] = []

    def reload(self, settings: Settings, applied: tuple[str, ...]) -> None:
        self.settings = settings
        self.reloads.append(applied)

    def record_event(self, kind: str, **detail: Any) -> None:
        self.events.append((kind, detail))


def logged(out: io.StringIO) -> list[dict[str, Any]]:
    return [json.loads(line) for line in out.getvalue().splitlines()]


def test_a_reload_from_a_file_applies_and_warns(tmp_path: Path) -> None:
    config = tmp_path / "cc-daemon.toml"
    config.write_text('[serial]\nport = "/dev/ttyA"\n')
    out = io.StringIO()
    configure_logging("json", "info", out)
    load = lambda: load_settings(config, env={}, search_paths=())  # noqa: E731
    daemon = FakeDaemon(load())
    configured: list[str] = []
    reloader = Reloader(daemon, load, lambda s: configured.append(s.log.level))
    config.write_text('[serial]\nport = "/dev/ttyB"\n[cast]\ntarget_depth_m = 7.5\n')
    reloader()
    assert daemon.settings.cast.target_depth_m == 7.5
    assert daemon.settings.serial.port == "/dev/ttyA"
    assert daemon.reloads == [("cast.target_depth_m",)]
    assert configured == []  # logging unchanged: not reconfigured
    warnings = [e for e in logged(out) if e["level"] == "warning"]
    assert [(e["key"], e["in_use"], e["in_file"]) for e in warnings] == [
        ("serial.port", "/dev/ttyA", "/dev/ttyB")
    ]


def test_an_invalid_file_keeps_everything_and_says_what_config_says(tmp_path: Path) -> None:
    config = tmp_path / "cc-daemon.toml"
    config.write_text("[cast]\ntarget_depth_m = 4.0\n")
    out = io.StringIO()
    configure_logging("json", "info", out)
    load = lambda: load_settings(config, env={}, search_paths=())  # noqa: E731
    daemon = FakeDaemon(load())
    before = daemon.settings
    config.write_text("[cast]\nreport_period_s = 1e-6\ntarget_depth_m = 6.0\n")
    with pytest.raises(ConfigError) as at_start:
        load()
    Reloader(daemon, load, lambda s: None)()
    assert daemon.settings is before and daemon.reloads == []
    errors = [e for e in logged(out) if e["level"] == "error"]
    assert [e["problems"] for e in errors] == [str(at_start.value).splitlines()]
    assert daemon.events == [("config_reload_refused", {"problems": errors[0]["problems"]})]


def test_a_reload_during_shutdown_is_ignored(tmp_path: Path) -> None:
    calls: list[str] = []

    def load() -> Settings:
        calls.append("load")
        return settings(cast={"target_depth_m": 2.0})

    daemon = FakeDaemon(settings(), shutting_down=True)
    Reloader(daemon, load, lambda s: None)()
    assert (calls, daemon.reloads) == ([], [])


def test_a_failure_inside_a_reload_never_escapes() -> None:
    def load() -> Settings:
        raise RuntimeError("a bug")

    daemon = FakeDaemon(settings())
    Reloader(daemon, load, lambda s: None)()  # must not raise
    assert daemon.reloads == []


def test_a_log_change_reconfigures_logging() -> None:
    daemon = FakeDaemon(settings())
    configured: list[str] = []
    Reloader(
        daemon,
        lambda: settings(log={"level": "debug"}),
        lambda s: configured.append(s.log.level),
    )()
    assert configured == ["debug"]
    assert daemon.settings.log.level == "debug"
