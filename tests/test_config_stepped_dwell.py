"""A stepped cast whose dwell at a level is as long as `cast.max_duration_s` can never
finish: every cast would be aborted at its first level. The dwell is `cast.dwell_s`,
or three response times of the slowest parameter of `profile.resolve` when that is
longer (a `response_s` may be up to 600 s: an 1800 s dwell). Refused, exit 2, naming
the keys, before anything is opened."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.test_config import load, problems, write
from tests.test_preflight import PREFIX, run_daemon

SLOW_OXYGEN = """
[cast]
mode = "stepped"
[sonde]
backend = "sim"
[[sonde.parameters]]
name = "depth"
register = 40011
unit = "m"
long_name = "sonde pressure depth"
[[sonde.parameters]]
name = "temperature"
register = 40029
unit = "degC"
long_name = "water temperature"
response_s = 2.0
[[sonde.parameters]]
name = "oxygen"
register = 40035
unit = "mg/L"
long_name = "dissolved oxygen"
response_s = 250.0
[profile]
resolve = ["temperature", "oxygen"]
"""


def test_a_response_time_that_outlasts_the_cast_is_refused(tmp_path: Path) -> None:
    config = write(tmp_path, SLOW_OXYGEN)
    assert problems(config) == [
        f'cast.mode = "stepped" (from {config}), '
        f'profile.resolve = ["temperature", "oxygen"] (from {config}) and '
        "cast.max_duration_s = 600.0 (default): impossible combination: a cast.mode cast "
        "dwells at each level 3 x the response_s of oxygen (250 s) in profile.resolve, "
        "750 s, which must be under cast.max_duration_s (every cast would be aborted at "
        "its first level)"
    ]
    # Time enough for it, or continuous casts (a slower descent, no dwell): allowed.
    assert load(config, {"cast": {"max_duration_s": 3600.0}}).cast.mode == "stepped"
    assert load(config, {"cast": {"mode": "continuous"}}).profile.resolve[1] == "oxygen"
    # Without a sonde nothing is resolved: no dwell is asked for.
    assert load(config, {"sonde": {"backend": "none"}}).cast.dwell_s == 5.0


def test_a_dwell_as_long_as_the_cast_may_last_is_refused(tmp_path: Path) -> None:
    config = write(tmp_path, '[cast]\nmode = "stepped"\ndwell_s = 600\n')
    assert problems(config) == [
        f"cast.dwell_s = 600 (from {config}) and cast.max_duration_s = 600.0 (default): "
        "impossible combination: a stepped cast dwells cast.dwell_s at each level, which "
        "must be under cast.max_duration_s (every cast would be aborted at its first level)"
    ]
    assert load(config, {"cast": {"dwell_s": 599.0}}).cast.dwell_s == 599.0


@pytest.mark.slow
def test_the_daemon_exits_2_naming_the_keys_before_opening_anything(tmp_path: Path) -> None:
    config = write(tmp_path, SLOW_OXYGEN)
    done = run_daemon(
        tmp_path,
        "--config", str(config),
        "--db", str(tmp_path / "journal.db"),
        "--port", str(tmp_path / "ttyNotThere"),
    )  # fmt: skip
    assert done.returncode == 2, done.stderr
    assert done.stderr.startswith(f'{PREFIX}cast.mode = "stepped"'), done.stderr
    assert "profile.resolve" in done.stderr and "cast.max_duration_s" in done.stderr
    assert not (tmp_path / "journal.db").exists()
