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
from cc_daemon.core.winch.drum import CurrentSensor, Drum, VoltageDivider
from cc_daemon.core.winch.encoder import max_pulse_rate
from cc_daemon.core.winch.sensors import RAIL_MARGIN, TURNING_MIN_A

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


class WinchSimSettings(BaseModel):
    """[winch.sim]: the simulated winch's physics and its fault injection (for tests)."""

    model_config = _SECTION

    speed_m_s: _Positive = 0.25
    stall_at_m: Annotated[_Positive | None, BeforeValidator(_empty_is_none)] = None
    fail_home: bool = False
    # The mock drum's sensor fault (--winch gpio-mock --winch-fault NAME): a switch
    # stuck closed, a snag at 1 m, the current sensor's ADC at full scale, a pulse
    # storm from 1 m down, the pulse pin dead from the first haul in below 1 m.
    drum_fault: Literal[
        "none", "switch-stuck", "snag", "adc-garbage", "pulse-storm", "encoder-dead"
    ] = "none"
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
    # Home needs the switch closed this long as well as the count near zero.
    switch_settle_s: Annotated[float, Field(ge=0.01, le=2)] = 0.2
    counter: Literal["pulse", "quadrature"] = "pulse"
    pulse_pin: _Bcm = 27
    encoder_b_pin: _Bcm = 22
    pulse_pull: _Pull = "none"
    pulse_debounce_s: Annotated[float, Field(ge=0, le=1)] = 0.002
    pulses_per_rev: Annotated[int, Field(ge=1)] = 2
    drum_diameter_m: _Positive = 0.09
    line_speed_m_s: _Positive = 0.25
    # Safety times have physical upper bounds (docs/gpio-winch.md "Bounds").
    stall_timeout_s: Annotated[float, Field(gt=0, le=10)] = 2.0
    home_margin_s: Annotated[float, Field(ge=0, le=120)] = 10.0
    # A count 5 m off at home is no count (and its coasting allowance would let a
    # pulse storm of ~35 pulses pass as a drum).
    count_tolerance_m: Annotated[float, Field(gt=0, le=5)] = 0.5
    home_at_start: bool = True
    # At least four of the winch's 50 ms feeding ticks: any less trips on every move.
    loop_watchdog_s: Annotated[float, Field(ge=0.2, le=5)] = 1.0
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
    overcurrent_s: Annotated[float, Field(gt=0, le=5)] = 0.5
    # The supply's possible range: a reading outside it is the supply or the ADC (a
    # sensor fault). A 12 V lead-acid system: flat at 10.5 V at rest and sagging
    # under the motor, so 9 V; 16 V is above any charger's equalisation (15.5 V).
    # At most 60 V: a safety-extra-low-voltage boat, past every H-bridge here.
    supply_min_v: Annotated[float, Field(ge=0, le=60)] = 9.0
    supply_max_v: Annotated[float, Field(gt=0, le=60)] = 16.0

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
    def _check(self) -> Self:
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
            if self.current_zero_v <= self.adc_vref_v * RAIL_MARGIN:
                raise _impossible(
                    "{0} must be above the ADC's bottom rail, {1} x "
                    + f"{RAIL_MARGIN:g} (0 A would read at the rail: every zero check a fault)",
                    "current_zero_v",
                    "adc_vref_v",
                )
        if self.supply_min_v >= self.supply_max_v:
            raise _impossible(
                "{0} must be below {1} (the supply's range would be empty)",
                "supply_min_v",
                "supply_max_v",
            )
        self._check_debounce()
        if self.adc:
            self._check_supply_range()
            self._check_current_range()
        return self

    def _check_debounce(self) -> None:
        """A debounce as long as half the pulse period at full speed loses pulses."""
        metres_per_pulse = Drum(self.pulses_per_rev, self.drum_diameter_m).metres_per_pulse
        lowest = min(self.payout_duty, self.haulin_duty)
        period_s = 1 / max_pulse_rate(self.line_speed_m_s, lowest, metres_per_pulse)
        if self.pulse_debounce_s >= period_s / 2:
            raise _impossible(
                "{0} must be under half the pulse period at full speed, "
                + f"{period_s / 2:.4g} s from {{1}}, {{2}} and {{3}} (longer loses pulses)",
                "pulse_debounce_s",
                "line_speed_m_s",
                "drum_diameter_m",
                "pulses_per_rev",
            )

    def _check_current_range(self) -> None:
        """An overcurrent the sensor cannot read could never be seen: max_current_a must
        be below the most the sensor reads before the ADC's top rail."""
        sensor = CurrentSensor(self.adc_vref_v, self.current_zero_v, self.current_v_per_a)
        top_a = sensor.amps(1 - RAIL_MARGIN)
        if self.max_current_a <= TURNING_MIN_A:
            raise _impossible(
                "{0} must be above "
                + f"{TURNING_MIN_A:g} A, the least a turning motor draws (a silent drum "
                + "could never be told from a jam)",
                "max_current_a",
            )
        if self.max_current_a >= top_a:
            raise _impossible(
                "{0} must be below the most the current sensor reads, ({1} - {2}) / {3} = "
                + f"{top_a:.2f} A at the ADC's top (a higher current reads there, "
                + "never above {0})",
                "max_current_a",
                "adc_vref_v",
                "current_zero_v",
                "current_v_per_a",
            )

    def _check_supply_range(self) -> None:
        """The supply's range must be one the divider can tell from outside it."""
        divider = VoltageDivider(self.adc_vref_v, self.divider_r1_ohm, self.divider_r2_ohm)
        full_scale = divider.volts(1.0)
        if self.supply_max_v >= full_scale:
            raise _impossible(
                "{0} must be below the most the divider can read, {1} x ({2} + {3}) / {3} = "
                + f"{full_scale:.2f} V (a supply above it reads full scale, never above {{0}})",
                "supply_max_v",
                "adc_vref_v",
                "divider_r1_ohm",
                "divider_r2_ohm",
            )
        if self.supply_min_v <= full_scale * RAIL_MARGIN:
            raise _impossible(
                "{0} must be above the ADC's bottom rail through the divider, "
                + f"{full_scale * RAIL_MARGIN:.3f} V (a dead channel reading 0 V would pass)",
                "supply_min_v",
            )
        step = 2 * full_scale / 1024  # two steps of the 10-bit MCP3008
        if self.supply_max_v - self.supply_min_v < step:
            raise _impossible(
                "{0} to {1} is narrower than two steps of the ADC through the divider "
                + f"({step:.3f} V): no reading could be trusted inside it",
                "supply_min_v",
                "supply_max_v",
            )


class WinchSettings(BaseModel):
    """[winch]: which backend drives the probe and how much line it has."""

    model_config = _SECTION

    backend: Literal["sim", "gpio"] = "sim"
    max_line_m: _Positive = 20.0
    sim: WinchSimSettings = WinchSimSettings()
    gpio: WinchGpioSettings = WinchGpioSettings()

    @model_validator(mode="after")
    def _check(self) -> Self:
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
