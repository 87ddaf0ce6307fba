"""Configuration: sources and their precedence, the error messages, the documented defaults."""

from __future__ import annotations

import re
import tomllib
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import pydantic
import pytest

from cc_daemon.config import (
    DEFAULT_SEARCH_PATHS,
    Settings,
    load_settings,
)
from cc_daemon.core.errors import ConfigError

ROOT = Path(__file__).resolve().parent.parent
EXAMPLE_TOML = ROOT / "config" / "cc-daemon.toml"
# The configuration reference (docs/configuration.md): its key table and examples.
CONFIG_REFERENCE = ROOT / "docs" / "configuration.md"
# Sections and keys documented on their own page, in the same table form.
SECTION_REFERENCES = (
    ROOT / "docs" / "sonde.md",
    ROOT / "docs" / "sonar.md",
    ROOT / "docs" / "firmware.md",
)
PREFIX = "cc-daemon: bad configuration: "
RATES = "1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200, 230400, 460800, 921600"
LEVELS = '"debug", "info", "warning", "error" or "critical"'
SERIAL_KEYS = (
    "port, baudrate, bytesize, parity, stopbits, accept_g_alias, "
    "reconnect_initial_s, reconnect_max_s, timestamp_order, jog_hold_s"
)


def fields(
    model: type[pydantic.BaseModel] = Settings, prefix: str = ""
) -> Iterator[tuple[str, Any]]:
    """Every leaf key of the configuration, dotted, with its default."""
    for name, info in model.model_fields.items():
        annotation = info.annotation
        if isinstance(annotation, type) and issubclass(annotation, pydantic.BaseModel):
            yield from fields(annotation, f"{prefix}{name}.")
        else:
            yield f"{prefix}{name}", info.default


ALL_KEYS = [key for key, _ in fields()]


def load(
    config: Path | None = None,
    overrides: Mapping[str, Any] | None = None,
    env: Mapping[str, str] | None = None,
) -> Settings:
    """load_settings isolated from the machine: no search paths, an empty environment."""
    return load_settings(config, overrides, env=env or {}, search_paths=())


def problems(
    config: Path | None = None,
    overrides: Mapping[str, Any] | None = None,
    env: Mapping[str, str] | None = None,
) -> list[str]:
    """The lines of the ConfigError load would raise, without the common prefix."""
    with pytest.raises(ConfigError) as caught:
        load(config, overrides, env)
    lines = str(caught.value).splitlines()
    assert all(line.startswith(PREFIX) for line in lines), lines
    return [line.removeprefix(PREFIX) for line in lines]


def write(tmp_path: Path, text: str, name: str = "cc-daemon.toml") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def get(settings: Settings, dotted: str) -> Any:
    value: Any = settings
    for part in dotted.split("."):
        value = getattr(value, part)
    return value


# --- sources and precedence -------------------------------------------------------------


def test_no_sources_gives_the_defaults() -> None:
    settings = load()
    assert settings == Settings()
    assert settings.source_file is None
    assert settings.serial.port == "/dev/serial0"
    assert settings.serial.baudrate == 9600
    assert (settings.serial.bytesize, settings.serial.parity, settings.serial.stopbits) == (
        8,
        "N",
        1,
    )
    assert settings.cast.rearm_s == 120.0
    assert settings.store.path is None


def test_settings_constructor_reads_neither_environment_nor_files(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    write(tmp_path, '[serial]\nport = "/dev/from-file"\n')
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("CC_DAEMON_SERIAL__BAUDRATE", "19200")
    assert Settings().serial.port == "/dev/serial0"
    assert Settings().serial.baudrate == 9600
    built = Settings.model_validate({"serial": {"port": "/dev/x"}})
    assert built.serial.port == "/dev/x"
    assert built.serial.baudrate == 9600


def test_environment_defaults_to_os_environ(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("CC_DAEMON_SERIAL__PORT", "/dev/ttyAMA0")
    assert load_settings(search_paths=()).serial.port == "/dev/ttyAMA0"


# (key, file value as TOML, environment value, flag value, the three as loaded)
PRECEDENCE_CASES = [
    ("serial.port", '"/dev/f"', "/dev/e", "/dev/c", ("/dev/f", "/dev/e", "/dev/c")),
    ("serial.baudrate", "19200", "38400", 57600, (19200, 38400, 57600)),
    ("winch.backend", '"gpio"', "sim", "gpio", ("gpio", "sim", "gpio")),
    ("store.path", '"f.db"', "e.db", "c.db", (Path("f.db"), Path("e.db"), Path("c.db"))),
    ("log.format", '"json"', "console", "json", ("json", "console", "json")),
    ("log.level", '"debug"', "WARNING", "error", ("debug", "warning", "error")),
]


@pytest.mark.parametrize(
    ("key", "in_file", "in_env", "as_flag", "expected"),
    PRECEDENCE_CASES,
    ids=[case[0] for case in PRECEDENCE_CASES],
)
def test_flag_beats_environment_beats_file_beats_default(
    tmp_path: Path,
    key: str,
    in_file: str,
    in_env: str,
    as_flag: Any,
    expected: tuple[Any, Any, Any],
) -> None:
    section, name = key.split(".")
    config = write(tmp_path, f"[{section}]\n{name} = {in_file}\n")
    env = {f"CC_DAEMON_{section.upper()}__{name.upper()}": in_env}
    flags = {section: {name: as_flag}}
    default = dict(fields())[key]

    assert get(load(), key) == default
    assert get(load(config), key) == expected[0]
    assert get(load(config, env=env), key) == expected[1]
    assert get(load(config, flags, env), key) == expected[2]
    assert get(load(None, flags), key) == expected[2]
    # A flag that was not given (None) leaves the lower sources in charge.
    assert get(load(config, {section: {name: None}}, env), key) == expected[1]


def test_layers_merge_key_by_key(tmp_path: Path) -> None:
    config = write(
        tmp_path, "[cast]\ntarget_depth_m = 8.0\nstep_m = 2.0\n[winch.sim]\nspeed_m_s = 1\n"
    )
    env = {"CC_DAEMON_CAST__STEP_M": "0.5", "CC_DAEMON_WINCH__SIM__FAIL_HOME": "true"}
    settings = load(config, {"winch": {"max_line_m": 30.0}}, env)
    assert settings.cast.target_depth_m == 8.0  # file
    assert settings.cast.step_m == 0.5  # environment over file
    assert settings.cast.dwell_s == 5.0  # default
    assert settings.winch.sim.speed_m_s == 1.0  # file, in a subsection
    assert settings.winch.sim.fail_home is True  # environment, in a subsection
    assert settings.winch.max_line_m == 30.0  # flag


def test_environment_names_ignore_case_and_empty_means_none(tmp_path: Path) -> None:
    config = write(tmp_path, '[winch.sim]\nstall_at_m = 3.0\n[store]\npath = "x.db"\n')
    env = {
        "cc_daemon_serial__port": "/dev/lower",
        "CC_DAEMON_WINCH__SIM__STALL_AT_M": "",
        "CC_DAEMON_STORE__PATH": "",
        "OTHER_SERIAL__PORT": "/dev/not-ours",
    }
    settings = load(config, env=env)
    assert settings.serial.port == "/dev/lower"
    assert settings.winch.sim.stall_at_m is None
    assert settings.store.path is None


def test_values_are_normalised() -> None:
    settings = load(
        env={
            "CC_DAEMON_LOG__LEVEL": "DeBuG",
            "CC_DAEMON_SERIAL__PARITY": "e",
            "CC_DAEMON_SERIAL__STOPBITS": "1.5",
        }
    )
    assert settings.log.level == "debug"
    assert settings.serial.parity == "E"
    assert settings.serial.stopbits == 1.5


def test_search_paths_first_existing_file_wins(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    etc = write(tmp_path, '[serial]\nport = "/dev/etc"\n', "etc.toml")
    here = write(tmp_path, '[serial]\nport = "/dev/here"\n')
    monkeypatch.chdir(tmp_path)
    search = (Path("cc-daemon.toml"), etc)

    settings = load_settings(env={}, search_paths=search)
    assert settings.serial.port == "/dev/here"
    assert settings.source_file == here

    here.unlink()
    settings = load_settings(env={}, search_paths=search)
    assert settings.serial.port == "/dev/etc"
    assert settings.source_file == etc

    etc.unlink()
    assert load_settings(env={}, search_paths=search).source_file is None


def test_default_search_paths_are_the_documented_ones() -> None:
    expected = (Path("cc-daemon.toml"), Path("/etc/cc-daemon/cc-daemon.toml"))
    assert expected == DEFAULT_SEARCH_PATHS


def test_explicit_config_replaces_the_search(tmp_path: Path) -> None:
    found = write(tmp_path, '[serial]\nport = "/dev/found"\n', "found.toml")
    chosen = write(tmp_path, "[serial]\nbaudrate = 115200\n", "chosen.toml")
    settings = load_settings(chosen, env={}, search_paths=(found,))
    assert settings.source_file == chosen
    assert settings.serial.port == "/dev/serial0"
    assert settings.serial.baudrate == 115200


def test_settings_are_frozen() -> None:
    settings = load()
    with pytest.raises(pydantic.ValidationError):
        settings.serial.port = "/dev/other"  # type: ignore[misc]


# --- errors -----------------------------------------------------------------------------


def test_missing_explicit_config_file_is_an_error(tmp_path: Path) -> None:
    missing = tmp_path / "nope.toml"
    assert problems(missing) == [f"--config {missing}: no such file"]
    assert problems(tmp_path) == [f"--config {tmp_path}: is not a file"]


def test_toml_syntax_error_names_file_and_line(tmp_path: Path) -> None:
    config = write(tmp_path, '[serial]\nport = "/dev/x"\nbaudrate = \n')
    [line] = problems(config)
    assert line.startswith(f"{config}: line 3, column 12: not valid TOML: ")


def test_file_that_is_not_text(tmp_path: Path) -> None:
    config = tmp_path / "cc-daemon.toml"
    config.write_bytes(b'[serial]\nport = "/dev/\xff"\n')
    assert problems(config) == [f"{config}: line 2: not valid TOML: not UTF-8 text"]


def test_unknown_key_in_file(tmp_path: Path) -> None:
    config = write(tmp_path, '[serial]\nprot = "/dev/x"\n')
    assert problems(config) == [
        f"serial.prot (from {config}): unknown key; allowed keys in [serial]: {SERIAL_KEYS}"
        " (did you mean port?)"
    ]


def test_unknown_section_and_subsection_in_file(tmp_path: Path) -> None:
    config = write(tmp_path, "[winch.stepper]\npin = 17\n[logging]\nlevel = 'debug'\n")
    assert problems(config) == [
        f"winch.stepper (from {config}): unknown key; "
        "allowed keys in [winch]: backend, max_line_m, sim, gpio",
        f"logging (from {config}): unknown section; "
        "allowed sections: serial, winch, cast, store, log, status, sonde, sonar, web, survey, "
        "profile (did you mean log?)",
    ]


def test_unknown_environment_variables_are_errors() -> None:
    assert problems(env={"CC_DAEMON_SERIAL__BOGUS": "1", "CC_DAEMON_PORT": "/dev/x"}) == [
        f"serial.bogus (from CC_DAEMON_SERIAL__BOGUS): unknown key; allowed keys in [serial]: "
        f"{SERIAL_KEYS}",
        "port (from CC_DAEMON_PORT): unknown section; "
        "allowed sections: serial, winch, cast, store, log, status, sonde, sonar, web, survey, "
        "profile",
    ]


def test_malformed_and_conflicting_environment_names() -> None:
    assert problems(
        env={"CC_DAEMON_": "1", "CC_DAEMON_SERIAL": "x", "CC_DAEMON_SERIAL__PORT": "/dev/y"}
    ) == [
        "CC_DAEMON_: not a setting name; use CC_DAEMON_<SECTION>__<KEY>, "
        "e.g. CC_DAEMON_SERIAL__PORT",
        "CC_DAEMON_SERIAL__PORT: conflicts with CC_DAEMON_SERIAL; set only one of them",
    ]


def test_section_that_is_not_a_table(tmp_path: Path) -> None:
    config = write(tmp_path, 'serial = "/dev/ttyS0"\n')
    assert problems(config) == [
        f'serial = "/dev/ttyS0" (from {config}): must be a table of keys ([serial])'
    ]


@pytest.mark.parametrize(
    ("env", "expected"),
    [
        (
            {"CC_DAEMON_SERIAL__BAUDRATE": "fast"},
            "serial.baudrate = fast (from CC_DAEMON_SERIAL__BAUDRATE): must be a whole number",
        ),
        (
            {"CC_DAEMON_CAST__TARGET_DEPTH_M": "deep"},
            "cast.target_depth_m = deep (from CC_DAEMON_CAST__TARGET_DEPTH_M): must be a number",
        ),
        (
            {"CC_DAEMON_SERIAL__ACCEPT_G_ALIAS": "maybe"},
            "serial.accept_g_alias = maybe (from CC_DAEMON_SERIAL__ACCEPT_G_ALIAS): "
            "must be true or false",
        ),
        (
            {"CC_DAEMON_CAST__MIN_SONAR_CONFIDENCE": "70.5"},
            "cast.min_sonar_confidence = 70.5 (from CC_DAEMON_CAST__MIN_SONAR_CONFIDENCE): "
            "must be a whole number",
        ),
        (
            {"CC_DAEMON_CAST__MAX_DURATION_S": "inf"},
            "cast.max_duration_s = inf (from CC_DAEMON_CAST__MAX_DURATION_S): "
            "must be a finite number",
        ),
        (
            {"CC_DAEMON_SERIAL__PORT": ""},
            'serial.port = "" (from CC_DAEMON_SERIAL__PORT): must not be empty',
        ),
    ],
)
def test_wrong_type_from_environment(env: dict[str, str], expected: str) -> None:
    assert problems(env=env) == [expected]


def test_wrong_type_from_file(tmp_path: Path) -> None:
    config = write(tmp_path, '[cast]\nsoak_s = "long"\n[store]\npath = 5\n')
    assert problems(config) == [
        f'cast.soak_s = "long" (from {config}): must be a number',
        f"store.path = 5 (from {config}): must be a file path (a string)",
    ]


@pytest.mark.parametrize(
    ("toml", "shown", "requirement"),
    [
        ("[cast]\ntarget_depth_m = -1.0", "cast.target_depth_m = -1.0", "must be greater than 0"),
        (
            "[cast]\nmin_sonar_confidence = 101",
            "cast.min_sonar_confidence = 101",
            "must be at most 100",
        ),
        ("[cast]\nsoak_s = -5", "cast.soak_s = -5", "must be at least 0"),
        ("[serial]\nbytesize = 9", "serial.bytesize = 9", "must be at most 8"),
        (
            "[serial]\nbaudrate = 9601",
            "serial.baudrate = 9601",
            f"must be one of the standard rates: {RATES}",
        ),
        ("[serial]\nstopbits = 3", "serial.stopbits = 3", "must be 1, 1.5 or 2"),
        (
            '[serial]\nparity = "X"',
            'serial.parity = "X"',
            'must be one of "N", "E", "O", "M" or "S"',
        ),
        ('[winch]\nbackend = "dc"', 'winch.backend = "dc"', 'must be one of "sim" or "gpio"'),
        ("[winch.sim]\nstall_at_m = 0", "winch.sim.stall_at_m = 0", "must be greater than 0"),
        (
            '[log]\nformat = "xml"',
            'log.format = "xml"',
            'must be one of "console", "json" or "auto"',
        ),
        ('[log]\nlevel = "loud"', 'log.level = "loud"', f"must be one of {LEVELS}"),
    ],
)
def test_out_of_range_from_file(tmp_path: Path, toml: str, shown: str, requirement: str) -> None:
    config = write(tmp_path, toml + "\n")
    assert problems(config) == [f"{shown} (from {config}): {requirement}"]


def test_the_example_message_for_a_bad_etc_file(tmp_path: Path) -> None:
    etc = write(tmp_path, "[cast]\ntarget_depth_m = -1.0\n")
    with pytest.raises(ConfigError) as caught:
        load_settings(env={}, search_paths=(etc,))
    assert str(caught.value) == (
        f"cc-daemon: bad configuration: cast.target_depth_m = -1.0 (from {etc}): "
        "must be greater than 0"
    )


def test_out_of_range_from_flag_names_the_flag() -> None:
    assert problems(overrides={"serial": {"baudrate": 100}, "log": {"format": "xml"}}) == [
        f"serial.baudrate = 100 (from --baudrate): must be one of the standard rates: {RATES}",
        'log.format = "xml" (from --log-format): must be one of "console", "json" or "auto"',
    ]


def test_impossible_combinations(tmp_path: Path) -> None:
    config = write(
        tmp_path, "[cast]\nsoak_s = 30.0\nsoak_depth_m = 6.0\n[winch.sim]\nstall_at_m = 25\n"
    )
    assert problems(config, env={"CC_DAEMON_SERIAL__RECONNECT_MAX_S": "0.1"}) == [
        "serial.reconnect_max_s = 0.1 (from CC_DAEMON_SERIAL__RECONNECT_MAX_S) and "
        "serial.reconnect_initial_s = 0.2 (default): impossible combination: "
        "serial.reconnect_max_s must be at least serial.reconnect_initial_s "
        "(the reopen delay grows from the first to the second)",
        f"winch.sim.stall_at_m = 25 (from {config}) and winch.max_line_m = 20.0 (default): "
        "impossible combination: winch.sim.stall_at_m must be less than winch.max_line_m "
        "(the line ends before the stall)",
        f"cast.soak_depth_m = 6.0 (from {config}), cast.target_depth_m = 5.0 (default) and "
        f"cast.soak_s = 30.0 (from {config}): impossible combination: cast.soak_depth_m must be "
        "shallower than cast.target_depth_m when cast.soak_s > 0 "
        "(the soak comes before the descent)",
    ]
    # Without a soak, the soak depth does not matter.
    assert load(config, {"winch": {"max_line_m": 30}}, {"CC_DAEMON_CAST__SOAK_S": "0"})


def test_min_depth_deeper_than_target() -> None:
    assert problems(env={"CC_DAEMON_CAST__MIN_DEPTH_M": "6"}) == [
        "cast.min_depth_m = 6 (from CC_DAEMON_CAST__MIN_DEPTH_M) and cast.target_depth_m = 5.0 "
        "(default): impossible combination: cast.min_depth_m must not be deeper than "
        "cast.target_depth_m (every cast would be skipped)"
    ]


def test_target_deeper_than_the_line_across_sections(tmp_path: Path) -> None:
    config = write(tmp_path, "[winch]\nmax_line_m = 10.0\n")
    assert problems(config, {"cast": {"target_depth_m": 12.5}}) == [
        "cast.target_depth_m = 12.5 (from the command line) and "
        f"winch.max_line_m = 10.0 (from {config}): impossible combination: "
        "cast.target_depth_m must not be deeper than winch.max_line_m "
        "(the probe cannot go below the line's end)"
    ]
    assert load(config, {"cast": {"target_depth_m": 10.0}}).cast.target_depth_m == 10.0


def test_impossible_combination_when_built_directly() -> None:
    with pytest.raises(pydantic.ValidationError, match="impossible combination"):
        Settings.model_validate({"cast": {"target_depth_m": 30.0}})


def test_several_problems_from_several_sources_give_one_line_each(tmp_path: Path) -> None:
    config = write(tmp_path, "[cast]\nstep_m = 0\nmode = 'zigzag'\n")
    lines = problems(config, {"serial": {"port": ""}}, {"CC_DAEMON_LOG__LEVEL": "chatty"})
    assert lines == [
        'serial.port = "" (from --port): must not be empty',
        f'cast.mode = "zigzag" (from {config}): must be one of "continuous" or "stepped"',
        f"cast.step_m = 0 (from {config}): must be greater than 0",
        f"log.level = chatty (from CC_DAEMON_LOG__LEVEL): must be one of {LEVELS}",
    ]


# --- the documented example file and reference -----------------------------------------


def documented_keys(text: str) -> set[str]:
    """Dotted keys set or shown commented out (`# key = ...`) under their [table]."""
    keys: set[str] = set()
    table = ""
    for line in text.splitlines():
        header = re.fullmatch(r"\[([\w.]+)\]", line.strip())
        if header:
            table = header[1]
            continue
        assignment = re.match(r"#?\s*(\w+)\s*=", line.strip())
        if assignment and table:
            keys.add(f"{table}.{assignment[1]}")
    return keys


def test_example_file_loads_to_the_defaults() -> None:
    settings = load(EXAMPLE_TOML)
    # Every default, except that the shipped file selects the real winch: the
    # built-in "sim" is refused outside --simulate (cc_daemon.daemon.simgate).
    expected = Settings.model_validate({"winch": {"backend": "gpio"}}).model_dump()
    assert settings.model_dump() == expected
    assert settings.source_file == EXAMPLE_TOML


def test_example_file_documents_every_key() -> None:
    text = EXAMPLE_TOML.read_text(encoding="utf-8")
    assert set(ALL_KEYS) <= documented_keys(text)
    # Keys that have no default value are shown commented out, with an example.
    assert {"winch.sim.stall_at_m", "store.path"} <= documented_keys(text) - {
        f"{table}.{key}"
        for table, section in tomllib.loads(text).items()
        for key in _leaf_names(section)
    }


def _leaf_names(section: dict[str, Any], prefix: str = "") -> Iterator[str]:
    for key, value in section.items():
        if isinstance(value, dict):
            yield from _leaf_names(value, f"{prefix}{key}.")
        else:
            yield f"{prefix}{key}"


def reference_rows() -> dict[str, str]:
    """key -> default column of the reference's key table."""
    rows: dict[str, str] = {}
    lines = [
        line
        for page in (CONFIG_REFERENCE, *SECTION_REFERENCES)
        for line in page.read_text(encoding="utf-8").splitlines()
    ]
    for line in lines:
        row = re.match(r"\| `([\w.]+)` \| ([^|]*) \|", line)
        if row and "." in row[1]:
            rows[row[1]] = row[2].strip()
    return rows


def as_toml(value: Any) -> str:
    if value is None:
        return "none"
    if isinstance(value, bool):
        return "`true`" if value else "`false`"
    if isinstance(value, str):
        return f'`"{value}"`'
    if isinstance(value, tuple) and all(isinstance(v, str) for v in value):
        return "`[" + ", ".join(f'"{v}"' for v in value) + "]`"
    if isinstance(value, tuple):  # an array of tables, shown on its page
        return "the default map (below)"
    return f"`{value}`"


def test_reference_lists_every_key_with_its_default() -> None:
    rows = reference_rows()
    assert sorted(rows) == sorted(ALL_KEYS)
    assert {key: rows[key] for key in ALL_KEYS} == {key: as_toml(d) for key, d in fields()}


def test_reference_examples_are_what_the_daemon_says() -> None:
    text = CONFIG_REFERENCE.read_text(encoding="utf-8")
    examples = [line for line in text.splitlines() if line.startswith(PREFIX)]
    assert len(examples) == 3
    assert problems(env={"CC_DAEMON_SERIAL__BOGUS": "1"}) == [examples[1].removeprefix(PREFIX)]
    assert problems(env={"CC_DAEMON_CAST__MIN_DEPTH_M": "6"}) == [examples[2].removeprefix(PREFIX)]
