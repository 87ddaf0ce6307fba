"""Bad input: one line, exit 2. Strict types from the file; the environment parsed as text.

A value of the wrong TOML type is refused naming its key (no coercion of
`true` to 1, of "1.0" to 1.0, of a table to a string); the environment only
has text, so it is parsed by the key's type; a file nested a thousand deep is
one line, not a RecursionError.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from cc_daemon.cli.app import main
from cc_daemon.config import load_settings
from cc_daemon.core.errors import ConfigError

PREFIX = "cc-daemon: bad configuration: "


def problems(tmp_path: Path, toml: str, env: dict[str, str] | None = None) -> list[str]:
    path = tmp_path / "c.toml"
    path.write_text(toml)
    with pytest.raises(ConfigError) as caught:
        load_settings(path, env=env or {}, search_paths=())
    return [
        line.removeprefix(PREFIX).replace(str(path), "F") for line in str(caught.value).split("\n")
    ]


@pytest.mark.parametrize(
    ("toml", "starts"),
    [
        ("[winch.gpio]\npulses_per_rev = true\n", "winch.gpio.pulses_per_rev = true (from F)"),
        ('[winch.gpio]\nloop_watchdog_s = "1.0"\n', 'winch.gpio.loop_watchdog_s = "1.0" (from F)'),
        ("[serial]\ntimestamp_order = {}\n", "serial.timestamp_order"),
        ('[serial]\nbaudrate = "57600"\n', 'serial.baudrate = "57600" (from F)'),
        ("[sonde]\nslave_id = 80.0\n", "sonde.slave_id = 80.0 (from F)"),
        ('[[sonde.parameters]]\nname = "depth"\nregister = "40011"\nunit = "m"\n'
         'long_name = "d"\n', "sonde.parameters.0.register"),
    ],
)  # fmt: skip
def test_a_value_of_the_wrong_type_is_refused_naming_its_key(
    tmp_path: Path, toml: str, starts: str
) -> None:
    (line,) = problems(tmp_path, toml)
    assert line.startswith(starts), line


def test_the_environment_is_parsed_as_the_keys_type(tmp_path: Path) -> None:
    path = tmp_path / "c.toml"
    path.write_text("")
    env = {
        "CC_DAEMON_SERIAL__BAUDRATE": "57600",
        "CC_DAEMON_WINCH__GPIO__LOOP_WATCHDOG_S": "1.5",
        "CC_DAEMON_WINCH__SIM__FAIL_HOME": "true",
        "CC_DAEMON_SERIAL__TIMESTAMP_ORDER": "little",
        "CC_DAEMON_STORE__PATH": str(tmp_path / "j.db"),
    }
    s = load_settings(path, env=env, search_paths=())
    assert s.serial.baudrate == 57600 and s.winch.gpio.loop_watchdog_s == 1.5
    assert s.winch.sim.fail_home is True and s.serial.timestamp_order == "little"
    assert s.store.path == tmp_path / "j.db"
    (line,) = problems(tmp_path, "", env={"CC_DAEMON_WINCH__GPIO__PULSES_PER_REV": "2.5"})
    assert line.startswith("winch.gpio.pulses_per_rev = 2.5 (from CC_DAEMON_WINCH__GPIO__")
    (line,) = problems(tmp_path, "", env={"CC_DAEMON_WINCH__SIM__FAIL_HOME": "maybe"})
    assert line.startswith("winch.sim.fail_home = maybe (from CC_DAEMON_WINCH__SIM__FAIL_HOME)")


@pytest.mark.parametrize(
    "toml",
    [
        "a = " + "[" * 1000 + "]" * 1000 + "\n",  # tomllib recurses: RecursionError
        "a = " + "{b = " * 1000 + "1" + "}" * 1000 + "\n",
        "a" + "".join(f".k{i}" for i in range(1000)) + " = 1\n",  # parsed, then walked
        "[serial]\nport = " + "[" * 40 + "]" * 40 + "\n",
    ],
    ids=["arrays", "inline_tables", "dotted_keys", "forty_deep"],
)
def test_a_file_nested_a_thousand_deep_is_one_line(tmp_path: Path, toml: str) -> None:
    (line,) = problems(tmp_path, toml)
    assert line.startswith("F: not")
    assert "nested" in line


def test_the_daemon_exits_2_on_a_deeply_nested_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    config = tmp_path / "c.toml"
    config.write_text("a = " + "[" * 1000 + "]" * 1000 + "\n")
    assert main(["--config", str(config)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "nested too deeply" in err and "Traceback" not in err
    assert main(["status", "--config", str(config)]) == 2
    assert "nested too deeply" in capsys.readouterr().err
