"""Settings that validate must be able to work: bounds on periods, durations and paths."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.test_config import problems, write


@pytest.mark.parametrize(
    ("toml", "expected"),
    [
        (
            "[cast]\nreport_period_s = 1e-6",
            "cast.report_period_s = 1e-06 ({src}): must be at least 0.2",
        ),
        ("[cast]\nreport_period_s = 11", "cast.report_period_s = 11 ({src}): must be at most 10"),
        (
            "[cast]\nbottom_dwell_s = 3601",
            "cast.bottom_dwell_s = 3601 ({src}): must be at most 3600",
        ),
        ("[cast]\ndwell_s = 1e9", "cast.dwell_s = 1000000000.0 ({src}): must be at most 3600"),
        ("[cast]\nsoak_s = 7200", "cast.soak_s = 7200 ({src}): must be at most 3600"),
        (
            "[cast]\nmax_duration_s = 21601",
            "cast.max_duration_s = 21601 ({src}): must be at most 21600",
        ),
        ("[cast]\nmax_duration_s = 0.5", "cast.max_duration_s = 0.5 ({src}): must be at least 1"),
        ("[cast]\nrearm_s = 86400", "cast.rearm_s = 86400 ({src}): must be at most 3600"),
        (
            "[serial]\nreconnect_initial_s = 0.001",
            "serial.reconnect_initial_s = 0.001 ({src}): must be at least 0.05",
        ),
        (
            "[serial]\nreconnect_max_s = 3600",
            "serial.reconnect_max_s = 3600 ({src}): must be at most 600",
        ),
        (
            "[store]\ntelemetry_rate_hz = 1000",
            "store.telemetry_rate_hz = 1000 ({src}): must be at most 10",
        ),
        ("[sonde]\nperiod_s = 1e-4", "sonde.period_s = 0.0001 ({src}): must be at least 0.1"),
        ("[sonde]\nstale_s = 86400", "sonde.stale_s = 86400 ({src}): must be at most 60"),
        (
            "[sonde]\nbottom_contact_s = 1e9",
            "sonde.bottom_contact_s = 1000000000.0 ({src}): must be at most 600",
        ),
        (
            "[status]\nclient_timeout_s = 3600",
            "status.client_timeout_s = 3600 ({src}): must be at most 60",
        ),
        (
            "[store]\ntelemetry_rate_hz = 0",
            "store.telemetry_rate_hz = 0 ({src}): must be at least 0.1",
        ),
        (
            "[winch.gpio]\nstall_timeout_s = 1e9",
            "winch.gpio.stall_timeout_s = 1000000000.0 ({src}): must be at most 10",
        ),
        (
            "[winch.gpio]\novercurrent_s = 6",
            "winch.gpio.overcurrent_s = 6 ({src}): must be at most 5",
        ),
        (
            "[winch.gpio]\nhome_margin_s = 121",
            "winch.gpio.home_margin_s = 121 ({src}): must be at most 120",
        ),
        (
            "[winch.gpio]\nloop_watchdog_s = 6",
            "winch.gpio.loop_watchdog_s = 6 ({src}): must be at most 5",
        ),
        (
            "[winch.gpio]\nswitch_settle_s = 3",
            "winch.gpio.switch_settle_s = 3 ({src}): must be at most 2",
        ),
        (
            "[winch.gpio]\nswitch_settle_s = 0",
            "winch.gpio.switch_settle_s = 0 ({src}): must be at least 0.01",
        ),
    ],
)
def test_periods_and_durations_have_floors_and_ceilings(
    tmp_path: Path, toml: str, expected: str
) -> None:
    config = write(tmp_path, toml + "\n")
    assert problems(config) == [expected.format(src=f"from {config}")]


def test_the_bounds_themselves_are_allowed(tmp_path: Path) -> None:
    from tests.test_config import load

    config = write(
        tmp_path,
        "[cast]\nreport_period_s = 0.2\nbottom_dwell_s = 3600\nmax_duration_s = 21600\n"
        "[serial]\nreconnect_initial_s = 0.05\nreconnect_max_s = 600\n"
        "[store]\ntelemetry_rate_hz = 10\n",
    )
    settings = load(config)
    assert (settings.cast.report_period_s, settings.store.telemetry_rate_hz) == (0.2, 10.0)


def test_a_nul_character_in_a_path_is_refused_naming_the_key() -> None:
    found = problems(
        env={"CC_DAEMON_STORE__PATH": "survey\0.db", "CC_DAEMON_SERIAL__PORT": "/dev/tty\0S0"}
    )
    nul = "must not contain a NUL character"
    assert found == [
        f"serial.port = /dev/tty\0S0 (from CC_DAEMON_SERIAL__PORT): {nul}",
        f"store.path = survey\0.db (from CC_DAEMON_STORE__PATH): {nul}",
    ]


@pytest.mark.parametrize(
    ("toml", "expected"),
    [
        (
            "[cast]\nblind_max_depth_m = 0",
            "cast.blind_max_depth_m = 0 ({src}): must be greater than 0",
        ),
        (
            "[cast]\nblind_max_depth_m = 10.5",
            "cast.blind_max_depth_m = 10.5 ({src}): must be at most 10",
        ),
        (
            "[cast]\nmin_depth_m = 1.5",
            "cast.min_depth_m = 1.5 ({src}) and cast.blind_max_depth_m = 1.0 (default): "
            "impossible combination: cast.min_depth_m must not be deeper than "
            "cast.blind_max_depth_m (every blind cast would be skipped)",
        ),
    ],
)
def test_the_blind_cast_depth_is_bounded(tmp_path: Path, toml: str, expected: str) -> None:
    config = write(tmp_path, toml + "\n")
    assert problems(config) == [expected.format(src=f"from {config}")]


def test_the_blind_cast_bound_itself_is_allowed(tmp_path: Path) -> None:
    from tests.test_config import load

    config = write(
        tmp_path, "[cast]\nblind_max_depth_m = 10\nmin_depth_m = 10\ntarget_depth_m = 10\n"
    )
    assert load(config).cast.blind_max_depth_m == 10.0
