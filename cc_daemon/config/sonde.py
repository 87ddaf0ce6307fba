"""[sonde]: the multiparameter sonde's link, sampling, register map and depth checks.

This module owns the sonde's configuration models and the default register map
(the group's current winch controller's device: Modbus RTU, 9600 8N1, slave 80,
32-bit IEEE floats high word first from holding register 40011 on). `cc_daemon.config`
only adds the section to `Settings`; errors are worded there.

It must never open a port or import pymodbus: validating a configuration
touches no device.
"""

from typing import Annotated, Literal, Self

from pydantic import AfterValidator, BaseModel, BeforeValidator, ConfigDict, Field, model_validator
from pydantic_core import PydanticCustomError

__all__ = [
    "DEFAULT_PARAMETERS",
    "MODICON_HOLDING_BASE",
    "SondeParameter",
    "SondeSettings",
    "register_count",
]

# Modicon numbering: holding register 40001 is protocol address 0.
MODICON_HOLDING_BASE = 40001
MODICON_HOLDING_LAST = 49999
MAX_ADDRESS = 0xFFFF  # a Modbus protocol address is 16 bits
# Function 3 returns at most 125 registers in one response (the Modbus spec's limit).
MAX_REGISTERS_PER_READ = 125
_BAUDRATES = (1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200)
DataType = Literal["float32", "int32", "uint32", "int16", "uint16"]

_SECTION = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False, strict=True)
_Positive = Annotated[float, Field(gt=0)]


def register_count(data_type: str) -> int:
    """How many 16-bit registers one value of `data_type` takes."""
    return 1 if data_type.endswith("16") else 2


def _impossible(rule: str, *keys: str) -> PydanticCustomError:
    # The same error shape as cc_daemon.config's, so the message names each key.
    return PydanticCustomError(
        "impossible_combination",
        "impossible combination: " + rule.format(*keys),
        {"keys": keys, "rule": rule},
    )


def _where(address: int) -> str:
    if address <= MODICON_HOLDING_LAST - MODICON_HOLDING_BASE:
        return f"register {address + MODICON_HOLDING_BASE} (protocol address {address})"
    return f"protocol address {address}"


def _check_baudrate(value: int) -> int:
    if value not in _BAUDRATES:
        raise PydanticCustomError(
            "not_allowed", "must be one of " + ", ".join(map(str, _BAUDRATES))
        )
    return value


def _upper(value: object) -> object:
    return value.upper() if isinstance(value, str) else value


class SondeParameter(BaseModel):
    """One value the sonde reports: where it is, how to decode it, what it means."""

    model_config = ConfigDict(
        extra="forbid", frozen=True, allow_inf_nan=False, populate_by_name=True, strict=True
    )

    # Column and variable name in the exports: lower case, digits and underscores.
    name: Annotated[str, Field(pattern=r"^[a-z][a-z0-9_]*$", max_length=40)]
    # Where the value is, one of two ways: a Modicon holding-register number
    # (`register = 40011` is protocol address 10), or the raw protocol address
    # as libmodbus and the wire take it (`address = 30101`, 0 to 65535).
    # ("register" in the file; the attribute name would shadow pydantic's own.)
    modicon: Annotated[
        int | None, Field(alias="register", ge=MODICON_HOLDING_BASE, le=MODICON_HOLDING_LAST)
    ] = None
    protocol_address: Annotated[int | None, Field(alias="address", ge=0, le=MAX_ADDRESS)] = None
    type: DataType = "float32"
    # For 32-bit values: "big" = high word first (ABCD), "little" = low word first (CDAB).
    word_order: Literal["big", "little"] = "big"
    unit: Annotated[str, Field(min_length=1)]
    long_name: Annotated[str, Field(min_length=1)]
    # The CF standard name, where one exists for this quantity in this unit.
    standard_name: Annotated[str | None, BeforeValidator(lambda v: None if v == "" else v)] = None
    # The sensor's first-order response time (s): 0 for one faster than a reading.
    # The cast plan honours it ([profile] resolve) and the profiles correct it.
    response_s: Annotated[float, Field(ge=0.0, le=600.0)] = 0.0

    @model_validator(mode="after")
    def _one_place(self) -> Self:
        if (self.modicon is None) == (self.protocol_address is None):
            raise _impossible(
                "give exactly one of {0} (Modicon number, 40001 to 49999) or {1} "
                "(protocol address, 0 to 65535)",
                "register",
                "address",
            )
        if self.address + self.count - 1 > MAX_ADDRESS:
            raise _impossible("{0}: the value's last register is past 65535", "address")
        return self

    @property
    def address(self) -> int:
        """The protocol address (0-based) of the value's first register."""
        if self.protocol_address is not None:
            return self.protocol_address
        assert self.modicon is not None
        return self.modicon - MODICON_HOLDING_BASE

    @property
    def count(self) -> int:
        return register_count(self.type)


DEFAULT_PARAMETERS: tuple[SondeParameter, ...] = (
    SondeParameter(
        name="depth", modicon=40011, unit="m", long_name="sonde pressure depth",
        standard_name="depth",
    ),
    SondeParameter(
        name="temperature", modicon=40029, unit="degC", long_name="water temperature",
        standard_name="sea_water_temperature", response_s=2.0,
    ),
    SondeParameter(
        name="ph", modicon=40031, unit="1", long_name="pH",
        standard_name="sea_water_ph_reported_on_total_scale", response_s=4.0,
    ),
    SondeParameter(
        name="do_saturation", modicon=40033, unit="%",
        long_name="dissolved oxygen saturation",
        standard_name="fractional_saturation_of_oxygen_in_sea_water", response_s=8.0,
    ),
    SondeParameter(
        name="do_concentration", modicon=40035, unit="mg/L", long_name="dissolved oxygen",
        standard_name="mass_concentration_of_oxygen_in_sea_water", response_s=8.0,
    ),
    SondeParameter(
        name="blue", modicon=40037, unit="RFU",
        long_name="phycocyanin (blue-green algae) fluorescence",
    ),
    SondeParameter(
        name="chlorophyll", modicon=40039, unit="RFU", long_name="chlorophyll fluorescence",
    ),
)  # fmt: skip


class SondeSettings(BaseModel):
    """[sonde]: which backend reads the sonde, how often, and what its registers hold."""

    model_config = _SECTION

    backend: Literal["none", "modbus", "sim"] = "none"
    port: Annotated[str, Field(min_length=1)] = "/dev/ttyUSB0"
    baudrate: Annotated[int, AfterValidator(_check_baudrate)] = 9600
    parity: Annotated[Literal["N", "E", "O"], BeforeValidator(_upper)] = "N"
    stopbits: Literal[1, 2] = 1
    slave_id: Annotated[int, Field(ge=1, le=247)] = 80
    # Bounds on every period and duration, as in cc_daemon.config (reasons: config/cc-daemon.toml).
    period_s: Annotated[float, Field(ge=0.1, le=60.0)] = 1.0
    idle_period_s: Annotated[float, Field(ge=0.1, le=3600.0)] = 10.0
    timeout_s: Annotated[float, Field(ge=0.05, le=10.0)] = 0.3
    retries: Annotated[int, Field(ge=0, le=5)] = 1
    reconnect_initial_s: Annotated[float, Field(ge=0.05, le=60.0)] = 0.5
    reconnect_max_s: Annotated[float, Field(ge=0.05, le=600.0)] = 10.0
    stale_s: Annotated[float, Field(ge=0.1, le=60.0)] = 3.0
    depth_parameter: Annotated[str, Field(min_length=1)] = "depth"
    depth_disagreement_m: _Positive = 1.0
    bottom_contact_s: Annotated[float, Field(ge=0.1, le=600.0)] = 5.0
    bottom_contact_tolerance_m: _Positive = 0.05
    # A TOML array of tables arrives as a list; each table is checked strictly.
    parameters: Annotated[tuple[SondeParameter, ...], Field(strict=False)] = DEFAULT_PARAMETERS

    @model_validator(mode="after")
    def _check(self) -> Self:
        if self.reconnect_max_s < self.reconnect_initial_s:
            raise _impossible(
                "{0} must be at least {1} (the reopen delay grows from the first to the second)",
                "reconnect_max_s",
                "reconnect_initial_s",
            )
        if self.idle_period_s < self.period_s:
            raise _impossible(
                "{0} must be at least {1} (the surface is sampled less often than a cast)",
                "idle_period_s",
                "period_s",
            )
        # One request must fit in a period; a retry that cannot fit is skipped
        # by the reader (docs/sonde.md), not refused here.
        if self.timeout_s >= self.period_s:
            raise _impossible(
                "{0} must be shorter than {1} (not one request would fit in a period)",
                "timeout_s",
                "period_s",
            )
        names = [p.name for p in self.parameters]
        if not names:
            raise _impossible("{0} must hold at least the depth", "parameters")
        if len(set(names)) != len(names):
            raise _impossible("{0} must have a different name for each value", "parameters")
        if self.depth_parameter not in names:
            raise _impossible("{0} must name one of {1}", "depth_parameter", "parameters")
        taken: dict[int, str] = {}
        for p in self.parameters:
            for address in range(p.address, p.address + p.count):
                if address in taken:
                    raise _impossible(
                        f"{{0}}: {p.name!r} overlaps {taken[address]!r} at " + _where(address),
                        "parameters",
                    )
                taken[address] = p.name
        return self

    @property
    def depth(self) -> SondeParameter:
        return next(p for p in self.parameters if p.name == self.depth_parameter)
