"""[sonde] configuration: defaults, the register map from TOML, and errors naming the key."""

from __future__ import annotations

from pathlib import Path

import pytest

from cc_daemon.cli.app import main
from cc_daemon.config import load_settings
from cc_daemon.config.sonde import DEFAULT_PARAMETERS, SondeSettings
from cc_daemon.core.errors import ConfigError

PREFIX = "cc-daemon: bad configuration: "


def problems(tmp_path: Path, toml: str = "", env: dict[str, str] | None = None) -> list[str]:
    path = tmp_path / "c.toml"
    path.write_text(toml)
    with pytest.raises(ConfigError) as caught:
        load_settings(path, env=env or {}, search_paths=())
    return [
        line.removeprefix(PREFIX).replace(str(path), "F") for line in str(caught.value).split("\n")
    ]


def test_defaults_are_the_groups_sonde() -> None:
    s = SondeSettings()
    assert (s.backend, s.port, s.baudrate, s.parity, s.stopbits, s.slave_id) == (
        "none", "/dev/ttyUSB0", 9600, "N", 1, 80,
    )  # fmt: skip
    assert [(p.name, p.modicon) for p in s.parameters] == [
        ("depth", 40011),
        ("temperature", 40029),
        ("ph", 40031),
        ("do_saturation", 40033),
        ("do_concentration", 40035),
        ("blue", 40037),
        ("chlorophyll", 40039),
    ]
    assert all(p.type == "float32" and p.word_order == "big" for p in s.parameters)
    assert (s.period_s, s.idle_period_s) == (1.0, 10.0)


def test_a_map_from_toml(tmp_path: Path) -> None:
    path = tmp_path / "c.toml"
    path.write_text(
        '[sonde]\nbackend = "modbus"\n'
        '[[sonde.parameters]]\nname = "depth"\nregister = 40001\nunit = "m"\nlong_name = "d"\n'
        '[[sonde.parameters]]\nname = "cond"\nregister = 40003\ntype = "uint16"\n'
        'unit = "uS/cm"\nlong_name = "conductivity"\nword_order = "little"\n'
    )
    s = load_settings(path, env={}, search_paths=()).sonde
    assert [(p.name, p.address, p.count, p.word_order) for p in s.parameters] == [
        ("depth", 0, 2, "big"),
        ("cond", 2, 1, "little"),
    ]


def test_bad_values_name_their_key(tmp_path: Path) -> None:
    assert problems(tmp_path, env={"CC_DAEMON_SONDE__BACKEND": "rs485"}) == [
        'sonde.backend = rs485 (from CC_DAEMON_SONDE__BACKEND): must be one of "none", '
        '"modbus" or "sim"'
    ]
    (line,) = problems(tmp_path, "[sonde]\nslave_id = 300\n")
    assert line == "sonde.slave_id = 300 (from F): must be at most 247"
    (line,) = problems(
        tmp_path,
        '[[sonde.parameters]]\nname = "depth"\nregister = 30011\nunit = "m"\nlong_name = "d"\n',
    )
    assert line.startswith("sonde.parameters.0.register = 30011 (from F): must be at least 40001")


def test_impossible_combinations(tmp_path: Path) -> None:
    (line,) = problems(tmp_path, '[cast]\ndepth_source = "sonde"\n')
    assert "cast.depth_source" in line and "sonde.backend" in line
    # One request must fit in a period (a retry that cannot fit is skipped, not refused).
    (line,) = problems(tmp_path, "[sonde]\ntimeout_s = 1.0\nretries = 0\n")
    assert "sonde.timeout_s = 1.0" in line and "impossible combination" in line
    # Malacate's libmodbus wait (0.5 s) with one retry at 1 s is accepted.
    malacate = tmp_path / "m.toml"
    malacate.write_text("[sonde]\ntimeout_s = 0.5\nretries = 1\nperiod_s = 1.0\n")
    assert load_settings(malacate, env={}, search_paths=()).sonde.retries == 1
    (line,) = problems(
        tmp_path,
        '[[sonde.parameters]]\nname = "depth"\nregister = 40011\naddress = 10\n'
        'unit = "m"\nlong_name = "d"\n',
    )
    assert "give exactly one of sonde.parameters.0.register" in line
    assert "sonde.parameters.0.address = 10" in line
    overlapping = "".join(
        f'[[sonde.parameters]]\nname = "{n}"\nregister = {r}\nunit = "1"\nlong_name = "x"\n'
        for n, r in (("depth", 40011), ("b", 40012))
    )
    (line,) = problems(tmp_path, overlapping)
    assert "'b' overlaps 'depth' at register 40012" in line
    (line,) = problems(tmp_path, '[sonde]\ndepth_parameter = "pressure"\n')
    assert "sonde.depth_parameter" in line


def test_the_daemon_exits_2_before_opening_anything(tmp_path: Path) -> None:
    config = tmp_path / "c.toml"
    config.write_text("[sonde]\nperiod_s = 0\n")
    assert main(["--config", str(config)]) == 2


def test_default_parameters_are_the_settings_default() -> None:
    assert SondeSettings().parameters == DEFAULT_PARAMETERS


def test_the_shipped_october_2025_map_loads(tmp_path: Path) -> None:
    """The commented alternative in config/cc-daemon.toml, uncommented, is valid."""
    import tomllib

    text = (Path(__file__).parents[1] / "config" / "cc-daemon.toml").read_text()
    start = text.index("# --- the group's October 2025 map")
    end = text.index("# --- end of the October 2025 map ---")
    lines = text[start:end].splitlines()
    body = "\n".join(ln.removeprefix("# ") for ln in lines if ln.startswith("# [") or "=" in ln)
    parameters = tomllib.loads(body)["sonde"]["parameters"]
    s = SondeSettings.model_validate(
        {"parameters": parameters, "timeout_s": 0.5, "retries": 1, "period_s": 1.0}
    )
    assert [p.address for p in s.parameters] == [30101, *range(31001, 31602, 100)]
    assert [p.name for p in s.parameters][-1] == "conductivity"
    assert {p.type for p in s.parameters} == {"float32"}
    assert {p.word_order for p in s.parameters} == {"big"}
