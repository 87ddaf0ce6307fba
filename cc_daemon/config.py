"""The daemon's configuration: its schema, where values come from, and what a bad one says.

This module owns every configuration key (names, types, defaults, allowed ranges and
the combinations that cannot work together), the order of the sources (command-line
flag > environment > TOML file > default) and the wording of configuration errors:
one line per problem naming the dotted key, the value given, what is allowed and
where the value came from.

It must never open a device, start a task, configure logging or exit the process:
it reads at most one TOML file and the environment mapping it is given, and either
returns a frozen `Settings` or raises `ConfigError`. Deciding the exit status
(2 for a bad configuration) is the command line's job.

`Settings()` and `Settings.model_validate(...)` read nothing but their arguments;
only `load_settings` looks at files and the environment.
"""

from __future__ import annotations

import difflib
import json
import os
import re
import tomllib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Annotated, Any, Literal, NamedTuple

from pydantic import (
    AfterValidator,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    PrivateAttr,
    ValidationError,
    model_validator,
)
from pydantic_core import ErrorDetails, PydanticCustomError
from pydantic_settings import (
    BaseSettings,
    PydanticBaseSettingsSource,
    SettingsConfigDict,
    TomlConfigSettingsSource,
)

from cc_daemon.errors import ConfigError
from cc_daemon.sonde.settings import SondeSettings

__all__ = [
    "DEFAULT_SEARCH_PATHS",
    "ENV_NESTED_DELIMITER",
    "ENV_PREFIX",
    "FLAG_NAMES",
    "STANDARD_BAUDRATES",
    "CastSettings",
    "LogSettings",
    "SerialSettings",
    "Settings",
    "SonarSettings",
    "StatusSettings",
    "StoreSettings",
    "WinchGpioSettings",
    "WinchSettings",
    "WinchSimSettings",
    "load_settings",
]

ENV_PREFIX = "CC_DAEMON_"
ENV_NESTED_DELIMITER = "__"
# Searched in order when no --config is given; the first that exists is used.
DEFAULT_SEARCH_PATHS: tuple[Path, ...] = (
    Path("cc-daemon.toml"),
    Path("/etc/cc-daemon/cc-daemon.toml"),
)
# The command line's flags, so an error can name the flag a value came from.
FLAG_NAMES: Mapping[tuple[str, ...], str] = {
    ("serial", "port"): "--port",
    ("serial", "baudrate"): "--baudrate",
    ("winch", "backend"): "--winch",
    ("winch", "gpio", "pin_factory"): "--winch",
    ("store", "path"): "--db",
    ("log", "format"): "--log-format",
    ("log", "level"): "--log-level",
}
STANDARD_BAUDRATES: tuple[int, ...] = (
    1200,
    2400,
    4800,
    9600,
    19200,
    38400,
    57600,
    115200,
    230400,
    460800,
    921600,
)
_STOPBITS: tuple[float, ...] = (1, 1.5, 2)
_PREFIX = "cc-daemon: bad configuration: "


# --- the schema -------------------------------------------------------------------------


def _not_allowed(message: str) -> PydanticCustomError:
    return PydanticCustomError("not_allowed", message)


def _impossible(rule: str, *keys: str) -> PydanticCustomError:
    """An error about several keys together; `keys` are relative to the failing model.

    The keys travel in the error's context so `load_settings` can show each one's
    value and source; `rule` uses {0}, {1}... for them.
    """
    return PydanticCustomError(
        "impossible_combination",
        "impossible combination: " + rule.format(*keys),
        {"keys": keys, "rule": rule},
    )


def _check_baudrate(value: int) -> int:
    if value not in STANDARD_BAUDRATES:
        rates = ", ".join(map(str, STANDARD_BAUDRATES))
        raise _not_allowed(f"must be one of the standard rates: {rates}")
    return value


def _check_stopbits(value: float) -> float:
    if value not in _STOPBITS:
        raise _not_allowed("must be 1, 1.5 or 2")
    return value


def _upper(value: Any) -> Any:
    return value.upper() if isinstance(value, str) else value


def _lower(value: Any) -> Any:
    return value.lower() if isinstance(value, str) else value


def _empty_is_none(value: Any) -> Any:
    # TOML has no null, so "none" is spelled by leaving the key out; from the
    # environment (a systemd drop-in) an empty value is the natural way to say it.
    return None if value == "" else value


_SECTION = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
_Positive = Annotated[float, Field(gt=0)]
_NonNegative = Annotated[float, Field(ge=0)]

# What each key means, and its unit, is documented once, in config/cc-daemon.toml and
# docs/configuration.md; tests keep both in step with these models.


class SerialSettings(BaseModel):
    """[serial]: the UART to the autopilot and how to reopen it when it fails."""

    model_config = _SECTION

    port: Annotated[str, Field(min_length=1)] = "/dev/serial0"
    baudrate: Annotated[int, AfterValidator(_check_baudrate)] = 9600
    bytesize: Annotated[int, Field(ge=5, le=8)] = 8
    parity: Annotated[Literal["N", "E", "O", "M", "S"], BeforeValidator(_upper)] = "N"
    stopbits: Annotated[float, AfterValidator(_check_stopbits)] = 1
    accept_g_alias: bool = False
    reconnect_initial_s: _Positive = 0.2
    reconnect_max_s: _Positive = 5.0

    @model_validator(mode="after")
    def _check(self) -> SerialSettings:
        if self.reconnect_max_s < self.reconnect_initial_s:
            raise _impossible(
                "{0} must be at least {1} (the reopen delay grows from the first to the second)",
                "reconnect_max_s",
                "reconnect_initial_s",
            )
        return self


class WinchSimSettings(BaseModel):
    """[winch.sim]: the simulated winch's physics and its fault injection (for tests)."""

    model_config = _SECTION

    speed_m_s: _Positive = 0.25
    stall_at_m: Annotated[_Positive | None, BeforeValidator(_empty_is_none)] = None
    fail_home: bool = False
    # Outside --simulate a simulated winch would answer a real autopilot for a probe
    # that never moves: it runs only when this says so in so many words.
    allow_outside_simulation: bool = False


_Bcm = Annotated[int, Field(ge=0, le=27)]
_Duty = Annotated[float, Field(gt=0, le=1)]
_Pull = Literal["none", "up", "down"]
_Level = Literal["high", "low"]


class WinchGpioSettings(BaseModel):
    """[winch.gpio]: the real winch on the Pi's GPIO (BCM numbers); defaults from the
    group's previous controller where it had one (docs/gpio-winch.md says which)."""

    model_config = _SECTION

    pin_factory: Literal["native", "mock"] = "native"
    payout_pin: _Bcm = 5
    haulin_pin: _Bcm = 0
    enable_pin: _Bcm = 13
    pwm_frequency_hz: Annotated[float, Field(gt=0, le=100_000)] = 1000.0
    payout_duty: _Duty = 0.9
    haulin_duty: _Duty = 0.9
    ramp_s: _NonNegative = 0.2
    approach_m: _NonNegative = 0.1
    switch_pin: _Bcm = 17
    switch_pull: _Pull = "none"
    switch_active: _Level = "high"
    switch_debounce_s: Annotated[float, Field(ge=0, le=1)] = 0.002
    counter: Literal["pulse", "quadrature"] = "pulse"
    pulse_pin: _Bcm = 27
    encoder_b_pin: _Bcm = 22
    pulse_pull: _Pull = "none"
    pulse_debounce_s: Annotated[float, Field(ge=0, le=1)] = 0.002
    pulses_per_rev: Annotated[int, Field(ge=1)] = 2
    drum_diameter_m: _Positive = 0.09
    line_speed_m_s: _Positive = 0.25
    stall_timeout_s: _Positive = 2.0
    home_margin_s: _NonNegative = 10.0
    count_tolerance_m: _Positive = 0.5
    home_at_start: bool = True
    loop_watchdog_s: Annotated[float, Field(ge=0.05, le=60)] = 1.0
    adc: bool = False
    adc_spi_device: Annotated[int, Field(ge=0, le=1)] = 0
    voltage_channel: Annotated[int, Field(ge=0, le=7)] = 0
    current_channel: Annotated[int, Field(ge=0, le=7)] = 1
    adc_vref_v: _Positive = 3.3
    current_zero_v: _NonNegative = 2.5
    current_v_per_a: _Positive = 0.185
    divider_r1_ohm: _Positive = 29400.0
    divider_r2_ohm: _Positive = 7400.0
    max_current_a: _Positive = 4.0
    overcurrent_s: _Positive = 0.5

    def pins(self) -> dict[str, int]:
        """Every GPIO this configuration claims, by key (SPI0 too when the ADC is on)."""
        used = {
            "payout_pin": self.payout_pin,
            "haulin_pin": self.haulin_pin,
            "enable_pin": self.enable_pin,
            "switch_pin": self.switch_pin,
            "pulse_pin": self.pulse_pin,
        }
        if self.counter == "quadrature":
            used["encoder_b_pin"] = self.encoder_b_pin
        return used

    @model_validator(mode="after")
    def _check(self) -> WinchGpioSettings:
        # A pull resistor fixes which level is "open": a switch can only pull the other way.
        if (self.switch_pull, self.switch_active) in (("up", "high"), ("down", "low")):
            raise _impossible(
                '{0} = "'
                + self.switch_pull
                + '" needs {1} = "'
                + ("low" if self.switch_pull == "up" else "high")
                + '" (the pull holds the open switch at the other level)',
                "switch_pull",
                "switch_active",
            )
        seen: dict[int, str] = {}
        for key, pin in self.pins().items():
            if pin in seen:
                raise _impossible(
                    "{0} and {1} must be different pins (one GPIO cannot do both)", seen[pin], key
                )
            seen[pin] = key
        if self.adc:
            # SPI0: MOSI 10, MISO 9, SCLK 11, CE0 8 / CE1 7.
            spi = {10: "MOSI", 9: "MISO", 11: "SCLK", 8 - self.adc_spi_device: "CE"}
            for pin, key in seen.items():
                if pin in spi:
                    raise _impossible(
                        "{0} must not be an SPI0 pin (" + spi[pin] + ") when {1} is true",
                        key,
                        "adc",
                    )
            if self.voltage_channel == self.current_channel:
                raise _impossible(
                    "{0} and {1} must be different ADC channels",
                    "voltage_channel",
                    "current_channel",
                )
            if self.current_zero_v >= self.adc_vref_v:
                raise _impossible(
                    "{0} must be below {1} (the ADC could not read the zero)",
                    "current_zero_v",
                    "adc_vref_v",
                )
        return self


class WinchSettings(BaseModel):
    """[winch]: which backend drives the probe and how much line it has."""

    model_config = _SECTION

    backend: Literal["sim", "gpio"] = "sim"
    max_line_m: _Positive = 20.0
    sim: WinchSimSettings = WinchSimSettings()
    gpio: WinchGpioSettings = WinchGpioSettings()

    @model_validator(mode="after")
    def _check(self) -> WinchSettings:
        if self.sim.stall_at_m is not None and self.sim.stall_at_m >= self.max_line_m:
            raise _impossible(
                "{0} must be less than {1} (the line ends before the stall)",
                "sim.stall_at_m",
                "max_line_m",
            )
        return self


class CastSettings(BaseModel):
    """[cast]: how deep, how long and in which profile a cast of the probe runs."""

    model_config = _SECTION

    target_depth_m: _Positive = 5.0
    min_sonar_confidence: Annotated[int, Field(ge=0, le=100)] = 70
    bottom_clearance_m: _NonNegative = 0.5
    min_depth_m: _NonNegative = 0.3
    mode: Literal["continuous", "stepped"] = "continuous"
    bottom_dwell_s: _NonNegative = 10.0
    step_m: _Positive = 1.0
    dwell_s: _NonNegative = 5.0
    soak_s: _NonNegative = 0.0
    soak_depth_m: _NonNegative = 0.5
    report_period_s: _Positive = 1.0
    max_duration_s: _Positive = 600.0
    rearm_s: _NonNegative = 120.0
    rearm_distance_m: _NonNegative = 10.0
    depth_source: Literal["winch", "sonde"] = "winch"

    @model_validator(mode="after")
    def _check(self) -> CastSettings:
        if self.min_depth_m > self.target_depth_m:
            raise _impossible(
                "{0} must not be deeper than {1} (every cast would be skipped)",
                "min_depth_m",
                "target_depth_m",
            )
        if self.soak_s > 0 and self.soak_depth_m >= self.target_depth_m:
            raise _impossible(
                "{0} must be shallower than {1} when {2} > 0 (the soak comes before the descent)",
                "soak_depth_m",
                "target_depth_m",
                "soak_s",
            )
        return self


class StoreSettings(BaseModel):
    """[store]: where the survey journal is written."""

    model_config = _SECTION

    # None lets the journal choose its default location.
    path: Annotated[Path | None, BeforeValidator(_empty_is_none)] = None


class LogSettings(BaseModel):
    """[log]: how and how much the daemon logs."""

    model_config = _SECTION

    format: Literal["console", "json", "auto"] = "auto"
    level: Annotated[
        Literal["debug", "info", "warning", "error", "critical"], BeforeValidator(_lower)
    ] = "info"


class StatusSettings(BaseModel):
    """[status]: the read-only status socket `cc-daemon status` and `doctor` ask."""

    model_config = _SECTION

    enabled: bool = True
    # None: $RUNTIME_DIRECTORY/status.sock under systemd, else no socket.
    path: Annotated[Path | None, BeforeValidator(_empty_is_none)] = None
    max_clients: Annotated[int, Field(ge=1, le=1024)] = 32
    client_timeout_s: _Positive = 2.0


class SonarSettings(BaseModel):
    """[sonar]: a Ping1D echosounder wired to the companion computer (off without a port)."""

    model_config = _SECTION

    # None (or empty): no sonar on this computer; the autopilot's frames are the only source.
    port: Annotated[str | None, BeforeValidator(_empty_is_none)] = None
    baudrate: Annotated[int, AfterValidator(_check_baudrate)] = 115200
    max_age_s: _Positive = 1.0
    restart_after_s: _Positive = 3.0
    reconnect_initial_s: _Positive = 0.2
    reconnect_max_s: _Positive = 5.0

    @model_validator(mode="after")
    def _check(self) -> SonarSettings:
        if self.reconnect_max_s < self.reconnect_initial_s:
            raise _impossible(
                "{0} must be at least {1} (the reopen delay grows from the first to the second)",
                "reconnect_max_s",
                "reconnect_initial_s",
            )
        return self


class Settings(BaseSettings):
    """The whole configuration, frozen. Build it with `load_settings` to read sources."""

    model_config = SettingsConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    serial: SerialSettings = SerialSettings()
    winch: WinchSettings = WinchSettings()
    cast: CastSettings = CastSettings()
    store: StoreSettings = StoreSettings()
    log: LogSettings = LogSettings()
    status: StatusSettings = StatusSettings()
    sonde: SondeSettings = SondeSettings()
    sonar: SonarSettings = SonarSettings()

    _source_file: Path | None = PrivateAttr(default=None)

    @property
    def source_file(self) -> Path | None:
        """The TOML file the settings were read from, if any (for the startup log).

        pydantic compares private attributes too: compare `model_dump()`s to ask
        whether two Settings read from different files hold the same values.
        """
        return self._source_file

    @classmethod
    def settings_customise_sources(
        cls,
        settings_cls: type[BaseSettings],
        init_settings: PydanticBaseSettingsSource,
        env_settings: PydanticBaseSettingsSource,
        dotenv_settings: PydanticBaseSettingsSource,
        file_secret_settings: PydanticBaseSettingsSource,
    ) -> tuple[PydanticBaseSettingsSource, ...]:
        # Only the constructor's arguments: `Settings()` in a test must not pick up a
        # developer's CC_DAEMON_* variables or ./cc-daemon.toml. load_settings reads
        # the sources itself, one layer at a time, because an error must name the
        # source of the bad value; and it reads the environment without
        # EnvSettingsSource, which skips unknown CC_DAEMON_ variables silently.
        return (init_settings,)

    @model_validator(mode="after")
    def _check(self) -> Settings:
        if self.cast.target_depth_m > self.winch.max_line_m:
            raise _impossible(
                "{0} must not be deeper than {1} (the probe cannot go below the line's end)",
                "cast.target_depth_m",
                "winch.max_line_m",
            )
        if self.cast.depth_source == "sonde" and self.sonde.backend == "none":
            raise _impossible(
                "{0} needs a sonde: set {1} (the R-M depth would come from nowhere)",
                "cast.depth_source",
                "sonde.backend",
            )
        if self.sonar.port is not None and self.sonar.port == self.serial.port:
            raise _impossible(
                "{0} must not be {1} (the sonar and the autopilot need a port each)",
                "sonar.port",
                "serial.port",
            )
        return self


# --- sources ----------------------------------------------------------------------------


class _Origin(NamedTuple):
    kind: Literal["file", "env", "flag"]
    name: str  # file path, variable name or flag


_Key = tuple[str, ...]
_Leaf = tuple[_Key, Any, _Origin]


def load_settings(
    config_path: Path | None = None,
    overrides: Mapping[str, Any] | None = None,
    *,
    env: Mapping[str, str] | None = None,
    search_paths: Sequence[Path] = DEFAULT_SEARCH_PATHS,
) -> Settings:
    """Read the configuration: flag (`overrides`) > environment > TOML file > default.

    `config_path` is the --config file, which must exist; without it the first of
    `search_paths` that exists is read, and none is fine. `overrides` holds the
    command-line flags as a nested dict; None values mean "flag not given". `env`
    defaults to `os.environ`. Raises ConfigError, one line per problem.
    """
    problems: list[str] = []
    file_leaves: list[_Leaf] = []
    source_file = _find_file(config_path, search_paths, problems)
    if source_file is not None:
        file_leaves = _read_toml(source_file, problems)
    env_leaves = _read_env(os.environ if env is None else env, problems)
    if problems:
        raise ConfigError("\n".join(_PREFIX + p for p in problems))

    flag_leaves = _flatten(overrides or {}, (), None)
    merged, origins = _merge([file_leaves, env_leaves, flag_leaves])
    try:
        settings = Settings.model_validate(merged)
    except ValidationError as exc:
        lines = [_describe(error, merged, origins) for error in exc.errors()]
        raise ConfigError("\n".join(_PREFIX + line for line in lines)) from None
    settings._source_file = source_file
    return settings


def _find_file(
    config_path: Path | None, search_paths: Sequence[Path], problems: list[str]
) -> Path | None:
    if config_path is not None:
        config_path = Path(config_path)  # tolerate the str argparse hands over
        if not config_path.is_file():
            what = "is not a file" if config_path.exists() else "no such file"
            problems.append(f"--config {config_path}: {what}")
            return None
        return config_path.absolute()
    for candidate in search_paths:
        if candidate.is_file():
            return candidate.absolute()
    return None


_TOML_POSITION = re.compile(r"\s*\(at line (\d+), column (\d+)\)$")


def _read_toml(path: Path, problems: list[str]) -> list[_Leaf]:
    try:
        data = TomlConfigSettingsSource(Settings, toml_file=path)()
    except tomllib.TOMLDecodeError as exc:
        message = str(exc)
        found = _TOML_POSITION.search(message)
        where = f"line {found[1]}, column {found[2]}: " if found else ""
        message = message[: found.start()] if found else message
        problems.append(f"{path}: {where}not valid TOML: {message}")
        return []
    except UnicodeDecodeError as exc:
        line = bytes(exc.object[: exc.start]).count(b"\n") + 1
        problems.append(f"{path}: line {line}: not valid TOML: not UTF-8 text")
        return []
    except OSError as exc:
        problems.append(f"{path}: cannot read: {exc.strerror or exc}")
        return []
    return _flatten(data, (), _Origin("file", str(path)))


def _read_env(env: Mapping[str, str], problems: list[str]) -> list[_Leaf]:
    leaves: list[_Leaf] = []
    seen: dict[_Key, str] = {}
    for name in sorted(env):
        # Matched without regard to case, like pydantic-settings' default.
        if not name.upper().startswith(ENV_PREFIX):
            continue
        key = tuple(name[len(ENV_PREFIX) :].lower().split(ENV_NESTED_DELIMITER))
        if not all(key):
            form = f"{ENV_PREFIX}<SECTION>{ENV_NESTED_DELIMITER}<KEY>"
            problems.append(
                f"{name}: not a setting name; use {form}, e.g. {ENV_PREFIX}SERIAL__PORT"
            )
            continue
        # CC_DAEMON_SERIAL and CC_DAEMON_SERIAL__PORT cannot both be meant.
        clash = next(
            (other for k, other in seen.items() if k[: len(key)] == key or key[: len(k)] == k),
            None,
        )
        if clash is not None:
            problems.append(f"{name}: conflicts with {clash}; set only one of them")
            continue
        seen[key] = name
        leaves.append((key, env[name], _Origin("env", name)))
    return leaves


def _flatten(data: Mapping[str, Any], prefix: _Key, origin: _Origin | None) -> list[_Leaf]:
    """Leaves of a nested mapping; `origin` None means the command line (per-flag names)."""
    leaves: list[_Leaf] = []
    for name, value in data.items():
        key = (*prefix, str(name))
        if isinstance(value, Mapping):
            leaves.extend(_flatten(value, key, origin))
        elif value is not None or origin is not None:
            here = origin or _Origin("flag", FLAG_NAMES.get(key, "the command line"))
            leaves.append((key, value, here))
    return leaves


def _merge(layers: Sequence[Sequence[_Leaf]]) -> tuple[dict[str, Any], dict[_Key, _Origin]]:
    """Apply layers lowest precedence first; remember who set each leaf."""
    merged: dict[str, Any] = {}
    origins: dict[_Key, _Origin] = {}
    for layer in layers:
        for key, value, origin in layer:
            node = merged
            for part in key[:-1]:
                child = node.get(part)
                if not isinstance(child, dict):
                    child = node[part] = {}
                node = child
            node[key[-1]] = value
            # Whatever a lower layer set at or below this key is gone now.
            for stale in [k for k in origins if k[: len(key)] == key or key[: len(k)] == k]:
                del origins[stale]
            origins[key] = origin
    return merged, origins


# --- error messages ---------------------------------------------------------------------

_MISSING = object()


def _describe(
    error: ErrorDetails, merged: Mapping[str, Any], origins: Mapping[_Key, _Origin]
) -> str:
    loc = tuple(str(part) for part in error["loc"])
    kind = error["type"]
    if kind == "impossible_combination":
        ctx = error.get("ctx") or {}
        keys = [(*loc, *str(k).split(".")) for k in ctx.get("keys", ())]
        shown = [_key_value_source(k, merged, origins) for k in keys]
        listed = ", ".join(shown[:-1]) + " and " + shown[-1] if len(shown) > 1 else "".join(shown)
        rule = str(ctx.get("rule", "")).format(*(".".join(k) for k in keys))
        return f"{listed}: impossible combination: {rule}"
    if kind == "extra_forbidden":
        return f"{_dotted(loc)} ({_source(loc, origins)}): {_unknown_key(loc)}"
    return f"{_key_value_source(loc, merged, origins)}: {_requirement(error, loc)}"


def _dotted(key: _Key) -> str:
    return ".".join(key) if key else "(top level)"


def _key_value_source(key: _Key, merged: Mapping[str, Any], origins: Mapping[_Key, _Origin]) -> str:
    value = _lookup(merged, key)
    if value is _MISSING:
        return f"{_dotted(key)} = {_render(_default(key))} (default)"
    origin = origins.get(key)
    if origin is not None and origin.kind == "env" and isinstance(value, str) and value.strip():
        # Exactly as typed: every environment value is text, quoting it would mislead.
        shown = value
    else:
        shown = _render(value)
    return f"{_dotted(key)} = {shown} ({_source(key, origins)})"


def _source(key: _Key, origins: Mapping[_Key, _Origin]) -> str:
    for length in range(len(key), 0, -1):
        origin = origins.get(key[:length])
        if origin is not None:
            return f"from {origin.name}"
    # A section such as [winch.bogus] has no value of its own: name one of its keys' source.
    for k, origin in origins.items():
        if k[: len(key)] == key:
            return f"from {origin.name}"
    return "default"


def _lookup(data: Any, key: _Key) -> Any:
    for part in key:
        if isinstance(data, list | tuple) and part.isdigit() and int(part) < len(data):
            data = data[int(part)]  # an array of tables: [[sonde.parameters]]
            continue
        if not isinstance(data, Mapping) or part not in data:
            return _MISSING
        data = data[part]
    return data


def _default(key: _Key) -> Any:
    node: Any = Settings()
    for part in key:
        node = getattr(node, part, None)
    return node


def _render(value: Any) -> str:
    """A value as it would be written in the TOML file."""
    if value is None:
        return "none"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str | Path):
        return json.dumps(str(value))
    if isinstance(value, int | float):
        return repr(value)
    if isinstance(value, Mapping):
        return "{" + ", ".join(f"{k} = {_render(v)}" for k, v in value.items()) + "}"
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_render(v) for v in value) + "]"
    return repr(value)


def _model_at(key: _Key) -> type[BaseModel] | None:
    model: type[BaseModel] = Settings
    for part in key:
        field = model.model_fields.get(part)
        annotation = field.annotation if field else None
        if not (isinstance(annotation, type) and issubclass(annotation, BaseModel)):
            return None
        model = annotation
    return model


def _unknown_key(key: _Key) -> str:
    parent = key[:-1]
    model = _model_at(parent)
    names = list(model.model_fields) if model else []
    if parent:
        text = f"unknown key; allowed keys in [{'.'.join(parent)}]: {', '.join(names)}"
    else:
        text = f"unknown section; allowed sections: {', '.join(names)}"
    close = difflib.get_close_matches(key[-1], names, n=1)
    return text + (f" (did you mean {close[0]}?)" if close else "")


_REQUIREMENTS = {
    "int_type": "must be a whole number",
    "int_parsing": "must be a whole number",
    "int_from_float": "must be a whole number",
    "float_type": "must be a number",
    "float_parsing": "must be a number",
    "finite_number": "must be a finite number",
    "bool_type": "must be true or false",
    "bool_parsing": "must be true or false",
    "string_type": "must be a string",
    "string_too_short": "must not be empty",
    "path_type": "must be a file path (a string)",
    "model_type": "must be a table of keys",
    "model_attributes_type": "must be a table of keys",
    "dict_type": "must be a table of keys",
}


def _number(value: Any) -> Any:
    # A bound of 0 on a float field arrives as 0.0; say it as written.
    return int(value) if isinstance(value, float) and value.is_integer() else value


def _requirement(error: ErrorDetails, key: _Key) -> str:
    kind = error["type"]
    ctx = error.get("ctx") or {}
    if kind in ("model_type", "model_attributes_type", "dict_type"):
        return f"must be a table of keys ([{'.'.join(key)}])"
    if kind in _REQUIREMENTS:
        return _REQUIREMENTS[kind]
    if kind == "greater_than":
        return f"must be greater than {_number(ctx['gt'])}"
    if kind == "greater_than_equal":
        return f"must be at least {_number(ctx['ge'])}"
    if kind == "less_than":
        return f"must be less than {_number(ctx['lt'])}"
    if kind == "less_than_equal":
        return f"must be at most {_number(ctx['le'])}"
    if kind == "literal_error":
        # Double quotes, as the value would be written in TOML.
        return "must be one of " + str(ctx["expected"]).replace("'", '"')
    if kind == "value_error" and "error" in ctx:
        return str(ctx["error"])
    # pydantic's own wording, made to match ours, for anything not listed above.
    return re.sub(r"^Input should be", "must be", error["msg"])
