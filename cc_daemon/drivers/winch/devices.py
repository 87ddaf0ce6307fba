"""The gpiozero devices of the GPIO winch, opened from `[winch.gpio]` on a given pin factory.

It owns the mapping from configuration to gpiozero: which class each part is,
its pull, active level and debounce, and closing them all again. The pin
factory is always passed in; nothing here sets gpiozero's global factory.
It never decides when to move the motor (`gpio.GpioWinch` does).
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass
from typing import Any

from gpiozero import (
    MCP3008,
    DigitalInputDevice,
    DigitalOutputDevice,
    PWMOutputDevice,
    RotaryEncoder,
)

from cc_daemon.config import WinchGpioSettings
from cc_daemon.drivers.winch.motor import HBridge


@dataclass
class GpioDevices:
    bridge: HBridge
    switch: DigitalInputDevice
    pulses: DigitalInputDevice | None  # single channel
    encoder: RotaryEncoder | None  # quadrature
    current: MCP3008 | None
    voltage: MCP3008 | None

    def close(self) -> None:
        """Close everything, the motor first; one failing never skips the others."""
        try:
            self.bridge.close()
        finally:
            for device in (self.switch, self.pulses, self.encoder, self.current, self.voltage):
                if device is not None:
                    with contextlib.suppress(Exception):
                        device.close()


def _input_args(pull: str, active: str) -> dict[str, Any]:
    # gpiozero: pull_up True/False fixes the active level; None needs it stated.
    if pull == "up":
        return {"pull_up": True}
    if pull == "down":
        return {"pull_up": False}
    return {"pull_up": None, "active_state": active == "high"}


def open_devices(cfg: WinchGpioSettings, factory: Any) -> GpioDevices:
    """Open every device; on any failure close what was opened and re-raise."""
    opened: list[Any] = []

    def keep(device: Any) -> Any:
        opened.append(device)
        return device

    try:
        # The enable pin first, so the H-bridge never sees a direction without a
        # known-off power line.
        enable = keep(
            PWMOutputDevice(
                cfg.enable_pin,
                frequency=cfg.pwm_frequency_hz,
                initial_value=0.0,
                pin_factory=factory,
            )
        )
        pay_out = keep(DigitalOutputDevice(cfg.payout_pin, pin_factory=factory))
        haul_in = keep(DigitalOutputDevice(cfg.haulin_pin, pin_factory=factory))
        bridge = HBridge(pay_out, haul_in, enable)
        opened[:] = [bridge]
        switch = keep(
            DigitalInputDevice(
                cfg.switch_pin,
                bounce_time=cfg.switch_debounce_s or None,
                pin_factory=factory,
                **_input_args(cfg.switch_pull, cfg.switch_active),
            )
        )
        pulses = encoder = None
        if cfg.counter == "pulse":
            pulses = keep(
                DigitalInputDevice(
                    cfg.pulse_pin,
                    bounce_time=cfg.pulse_debounce_s or None,
                    pin_factory=factory,
                    **_input_args(cfg.pulse_pull, "high"),
                )
            )
        else:
            encoder = keep(
                RotaryEncoder(
                    cfg.pulse_pin,
                    cfg.encoder_b_pin,
                    bounce_time=cfg.pulse_debounce_s or None,
                    max_steps=0,
                    pin_factory=factory,
                )
            )
        current = voltage = None
        if cfg.adc:
            spi = {"device": cfg.adc_spi_device, "max_voltage": cfg.adc_vref_v}
            current = keep(MCP3008(cfg.current_channel, pin_factory=factory, **spi))
            voltage = keep(MCP3008(cfg.voltage_channel, pin_factory=factory, **spi))
    except BaseException:
        for device in reversed(opened):
            with contextlib.suppress(Exception):
                device.close()
        raise
    return GpioDevices(bridge, switch, pulses, encoder, current, voltage)
