"""Every configuration key: the sections' models, their defaults, allowed ranges and
the combinations that cannot work together, and the frozen `Settings` they make.

`Settings()` and `Settings.model_validate(...)` read nothing but their arguments;
only `loading.load_settings` looks at files and the environment.
"""

import re
from pathlib import Path
from typing import Annotated, Any, Literal, Self

from pydantic import (
    AfterValidator,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    PrivateAttr,
    model_validator,
)

from cc_daemon.config import naming
from cc_daemon.config.profile import ProfileSettings, stepped_dwell_problem
from cc_daemon.config.rules import (
    _HOUR_S,
    _SECTION,
    _check_baudrate,
    _check_stopbits,
    _Dwell,
    _empty_is_none,
    _impossible,
    _Key,
    _lower,
    _no_nul,
    _NonNegative,
    _Origin,
    _Positive,
    _upper,
)
from cc_daemon.config.sonde import SondeSettings
from cc_daemon.config.survey import SurveySettings
from cc_daemon.config.winch import WinchSettings

# What each key means, and its unit, is documented once, in config/cc-daemon.toml and
# docs/configuration.md; tests keep both in step with these models.


class SerialSettings(BaseModel):
    """[serial]: the UART to the autopilot and how to reopen it when it fails."""

    model_config = _SECTION

    port: Annotated[str, Field(min_length=1), AfterValidator(_no_nul)] = "/dev/serial0"
    baudrate: Annotated[int, AfterValidator(_check_baudrate)] = 9600
    bytesize: Annotated[int, Field(ge=5, le=8)] = 8
    parity: Annotated[Literal["N", "E", "O", "M", "S"], BeforeValidator(_upper)] = "N"
    stopbits: Annotated[float, AfterValidator(_check_stopbits)] = 1
    accept_g_alias: bool = False
    reconnect_initial_s: Annotated[float, Field(ge=0.05, le=60.0)] = 0.2
    reconnect_max_s: Annotated[float, Field(ge=0.05, le=600.0)] = 5.0
    timestamp_order: Literal["auto", "big", "little"] = "auto"
    jog_hold_s: Annotated[float, Field(ge=0.5, le=10.0)] = 2.5

    @model_validator(mode="after")
    def _check(self) -> Self:
        if self.reconnect_max_s < self.reconnect_initial_s:
            raise _impossible(
                "{0} must be at least {1} (the reopen delay grows from the first to the second)",
                "reconnect_max_s",
                "reconnect_initial_s",
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
    bottom_dwell_s: _Dwell = 10.0
    step_m: _Positive = 1.0
    dwell_s: _Dwell = 5.0
    soak_s: _Dwell = 0.0
    soak_depth_m: _NonNegative = 0.5
    report_period_s: Annotated[float, Field(ge=0.2, le=10.0)] = 1.0
    max_duration_s: Annotated[float, Field(ge=1.0, le=6 * _HOUR_S)] = 600.0
    rearm_s: Annotated[float, Field(ge=0, le=_HOUR_S)] = 120.0
    rearm_distance_m: _NonNegative = 10.0
    depth_source: Literal["winch", "sonde"] = "winch"
    rf_repeat_after_s: Annotated[float, Field(ge=0.5, le=60.0)] = 2.5
    rf_repeats: Annotated[int, Field(ge=0, le=100)] = 3
    # With no trusted sonar bottom: cast no deeper than this, at the approach speed.
    # At most 10 m: deeper is no longer a careful cast into unknown water (see
    # docs/configuration.md).
    blind_max_depth_m: Annotated[float, Field(gt=0, le=10.0)] = 1.0

    @model_validator(mode="after")
    def _check(self) -> Self:
        if self.min_depth_m > self.target_depth_m:
            raise _impossible(
                "{0} must not be deeper than {1} (every cast would be skipped)",
                "min_depth_m",
                "target_depth_m",
            )
        if self.min_depth_m > self.blind_max_depth_m:
            raise _impossible(
                "{0} must not be deeper than {1} (every blind cast would be skipped)",
                "min_depth_m",
                "blind_max_depth_m",
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

    # None lets the journal choose its default location. Where the file may be
    # (not a directory, a device, /proc...) is checked at start, not here: that
    # needs the filesystem (see cc_daemon/daemon/preflight.py).
    # A path arrives as text from every source: lax here, so text becomes a Path.
    path: Annotated[
        Path | None, Field(strict=False), BeforeValidator(_empty_is_none), AfterValidator(_no_nul)
    ] = None
    # Telemetry fixes written to the journal per second at most: the latest of
    # each interval is kept, the rest counted. Bounds the disk a babbling
    # autopilot can fill, and the memory the unwritten rows can take.
    telemetry_rate_hz: Annotated[float, Field(ge=0.1, le=10.0)] = 2.0
    # A second place for rows the journal cannot write yet (another card),
    # tried after the journal's own directory, before the state and runtime ones.
    spill_dir: Annotated[Path | None, BeforeValidator(_empty_is_none), AfterValidator(_no_nul)] = (
        None
    )
    # The mode of the journal, its -wal and -shm, and spill files when created
    # (octal text): owner writes, its group may read, nobody else.
    file_mode: Annotated[str, Field(pattern=r"^0?[0-7]{3}$")] = "0640"

    @property
    def file_mode_bits(self) -> int:
        return int(self.file_mode, 8)


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
    # None: by the rule of config/statuspaths.py ($RUNTIME_DIRECTORY under systemd;
    # by hand, beside the journal or in $XDG_RUNTIME_DIR).
    # A path arrives as text from every source: lax here, so text becomes a Path.
    path: Annotated[
        Path | None, Field(strict=False), BeforeValidator(_empty_is_none), AfterValidator(_no_nul)
    ] = None
    max_clients: Annotated[int, Field(ge=1, le=1024)] = 32
    client_timeout_s: Annotated[float, Field(ge=0.1, le=60.0)] = 2.0


def _check_listen(value: str) -> str:
    """`host:port` (an IPv6 host in brackets): what the page's server binds."""
    host, sep, port = value.strip().rpartition(":")
    if not sep or not host or not port.isdigit() or not 1 <= int(port) <= 65535:
        raise ValueError('must be "host:port", e.g. "127.0.0.1:8080" or "0.0.0.0:8080"')
    if host.startswith("[") != host.endswith("]"):
        raise ValueError('an IPv6 host goes in brackets: "[::1]:8080"')
    return value.strip()


# What `cc-daemon web --hash-password` prints: scrypt$N$r$p$salt$hash (base64).
_PASSWORD_HASH = re.compile(r"scrypt\$\d+\$\d+\$\d+\$[A-Za-z0-9+/=]{16,}\$[A-Za-z0-9+/=]{43,}")


def _check_password_hash(value: str | None) -> str | None:
    if value is not None and not _PASSWORD_HASH.fullmatch(value):
        raise ValueError(
            "must be what `cc-daemon web --hash-password` prints (scrypt$...), never the "
            "password itself"
        )
    return value


# A DNS name as a browser sends it in `Host` (RFC 1123 labels), without a port.
_HOST_NAME = re.compile(r"(?!-)[A-Za-z0-9-]{1,63}(?<!-)(\.(?!-)[A-Za-z0-9-]{1,63}(?<!-))*\.?")


def _name_list(value: object) -> object:
    """Text from the environment ("a.org, b.org") as the list a TOML file gives."""
    if isinstance(value, str):
        return [part for part in re.split(r"[,\s]+", value) if part]
    return value


def _check_host_names(value: list[str]) -> list[str]:
    for name in value:
        if not _HOST_NAME.fullmatch(name):
            raise ValueError(f'{name!r} is not a host name (e.g. "boat.example.org", no port)')
    return value


class WebSettings(BaseModel):
    """[web]: the field page, `cc-daemon web` (a separate, read-only process)."""

    model_config = _SECTION

    listen: Annotated[str, AfterValidator(_check_listen)] = "127.0.0.1:8080"
    # None: no password (fine on 127.0.0.1; `doctor` warns beyond it).
    password_hash: Annotated[
        str | None, BeforeValidator(_empty_is_none), AfterValidator(_check_password_hash)
    ] = None
    # Names the page answers to besides its addresses, localhost and this
    # computer's own name (a `Host` naming any other is refused: DNS rebinding).
    hosts: Annotated[list[str], BeforeValidator(_name_list), AfterValidator(_check_host_names)] = []


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
    # At most this many readings a second go into the journal (the stream's
    # nominal 4 Hz by default); the rest are counted and summarised in events.
    # Bounded so that no stream, however fast, grows the journal past ~1 MB/min.
    journal_rate_hz: Annotated[float, Field(ge=0.1, le=50.0)] = 4.0

    @model_validator(mode="after")
    def _check(self) -> Self:
        if self.reconnect_max_s < self.reconnect_initial_s:
            raise _impossible(
                "{0} must be at least {1} (the reopen delay grows from the first to the second)",
                "reconnect_max_s",
                "reconnect_initial_s",
            )
        return self


class Settings(BaseModel):
    """The whole configuration, frozen. Build it with `load_settings` to read sources.

    A plain model, not pydantic-settings' BaseSettings: `load_settings` reads the
    sources itself, one layer at a time, because an error must name the source of
    the bad value (and `Settings()` in a test must not pick up a developer's
    CC_DAEMON_* variables); pydantic-settings cost the daemon 200 modules, 17 MiB
    and a third of its start (docs/performance.md).
    """

    model_config = ConfigDict(
        extra="forbid", frozen=True, allow_inf_nan=False, validate_default=True, strict=True
    )

    serial: SerialSettings = SerialSettings()
    winch: WinchSettings = WinchSettings()
    cast: CastSettings = CastSettings()
    store: StoreSettings = StoreSettings()
    log: LogSettings = LogSettings()
    status: StatusSettings = StatusSettings()
    sonde: SondeSettings = SondeSettings()
    sonar: SonarSettings = SonarSettings()
    web: WebSettings = WebSettings()
    survey: SurveySettings = SurveySettings()
    profile: ProfileSettings = ProfileSettings()

    _source_file: Path | None = PrivateAttr(default=None)
    # What load_settings merged and where each value came from, so a check made
    # later (the start-up checks of paths) can name a key as these errors do.
    _merged: dict[str, Any] = PrivateAttr(default_factory=dict)
    _origins: dict[_Key, _Origin] = PrivateAttr(default_factory=dict)

    @property
    def source_file(self) -> Path | None:
        """The TOML file the settings were read from, if any (for the startup log).

        pydantic compares private attributes too: compare `model_dump()`s to ask
        whether two Settings read from different files hold the same values.
        """
        return self._source_file

    def describe(self, dotted_key: str) -> str:
        """`key = value (from source)`, as a configuration error names a key."""
        key = tuple(dotted_key.split("."))
        if naming.lookup(self._merged, key) is naming.MISSING:
            node: Any = self
            for part in key:
                node = getattr(node, part)
            where = "default" if node == naming.default_at(type(self)(), key) else "given"
            return f"{dotted_key} = {naming.render(node)} ({where})"
        return naming.key_value_source(key, self._merged, self._origins, type(self)())

    @model_validator(mode="after")
    def _check(self) -> Self:
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
        # The default's temperature applies where the map has one; a name given
        # must be in the map.
        names = {p.name for p in self.sonde.parameters}
        given = "resolve" in self.profile.model_fields_set
        if given and any(name not in names for name in self.profile.resolve):
            raise _impossible(
                "{0} must name parameters of {1} (each with its response_s)",
                "profile.resolve",
                "sonde.parameters",
            )
        problem = stepped_dwell_problem(self.cast, self.sonde, self.profile.resolve)
        if problem is not None:
            raise problem
        if self.sonar.port is not None and self.sonar.port == self.serial.port:
            raise _impossible(
                "{0} must not be {1} (the sonar and the autopilot need a port each)",
                "sonar.port",
                "serial.port",
            )
        return self
