"""A dead drum encoder: told from a jam by the motor current, the depth estimated honestly.

The pure rules on fake time (`core.winch.silence`, `core.winch.safety`), then the
GPIO winch on gpiozero's MockFactory with the simulated drum, whose pulse pin
goes silent for ever on the first haul in from below 1 m (`DrumFaults.
encoder_dead_in_from_m`): the drum turns on, the count does not. Last, one
`--simulate --winch gpio-mock --winch-fault encoder-dead` survey end to end.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest

from cc_daemon.config import Settings
from cc_daemon.core.errors import WinchFault
from cc_daemon.core.winch.safety import Limits, MotionGuard
from cc_daemon.core.winch.silence import (
    RUN_MARGIN,
    TURNING_MIN_A,
    Cause,
    DepthEstimate,
    judge_silence,
)
from cc_daemon.drivers.winch.motor import Direction
from cc_daemon.sim import drum as drum_module
from cc_daemon.sim.drum import DrumFaults, SimulatedDrum, mock_drum_for
from tests.gpiokit import GpioRig, gpio_rig
from tests.test_sim_runner import _casts, _row, _simulate, gpio_mock_pace

MPP = 3.141592653589793 * 0.09 / 2  # metres of line per pulse with the kit's drum
# How far the dead reckoning may be from the drum's true line: the line within a
# pulse of the count at the last edge, and a tick (50 ms at 1 m/s) of stopping.
RECKONING_TOLERANCE_M = MPP + 0.1
LIMITS = Limits(stall_timeout_s=2.0, max_current_a=4.0, overcurrent_s=0.5)


# ---------------------------------------------------------------- the pure rules


def test_the_range_and_the_best_estimate_hauling_in_and_paying_out() -> None:
    counted = DepthEstimate.counted(2.12)
    up = counted.after_run(-1, 2.0, turned=True)
    assert up.best_m == pytest.approx(0.12) and up.reckoned
    assert up.low_m == 0.0 and up.high_m == pytest.approx(2.12)  # 2.12 - 3.0: not above 0
    maybe = counted.after_run(-1, 1.0, turned=False)  # may have been jammed
    assert maybe.best_m == pytest.approx(2.12) and not maybe.reckoned
    assert maybe.low_m == pytest.approx(2.12 - RUN_MARGIN) and maybe.high_m == pytest.approx(2.12)
    down = counted.after_run(+1, 1.0, turned=True)
    assert down.best_m == pytest.approx(3.12)
    assert (down.low_m, down.high_m) == pytest.approx((2.12, 2.12 + RUN_MARGIN))
    # A second blind run starts from the first's estimate, not from the stale count.
    again = up.after_run(+1, 0.5, turned=True)
    assert again.best_m == pytest.approx(0.62) and again.counted_m == 2.12
    assert again.low_m == 0.0 and again.high_m == pytest.approx(2.12 + 0.5 * RUN_MARGIN)
    assert "between 0.00 and 2.12 m, best estimate 0.12 m (by dead reckoning" in up.describe()
    assert DepthEstimate.counted(-0.2).best_m == 0.0  # wound past zero: not above the surface


@pytest.mark.parametrize(
    ("currents", "cause", "best"),
    [
        ([0.9, 1.0, 0.95], Cause.ENCODER_DEAD, 2.12 - 1.8),  # turned free: dead reckoning
        (None, Cause.UNKNOWN, 2.12),  # no sensor: the count, the range
        ([4.6, 4.8], Cause.JAM, 2.12),  # pulled against a jam: the count stands
        ([0.1, 0.2], Cause.NO_POWER, 2.12),  # too little to turn anything
    ],
)
def test_the_current_tells_a_dead_encoder_from_a_jam(
    currents: list[float] | None, cause: Cause, best: float
) -> None:
    silence = judge_silence(
        quiet_s=2.04,
        stall_timeout_s=2.0,
        max_current_a=4.0,
        currents=currents,
        base=DepthEstimate.counted(2.12),
        direction=-1,
        run_m=1.8,
    )
    assert silence.cause is cause
    assert silence.estimate.best_m == pytest.approx(best)
    assert silence.encoder_dead is (cause is Cause.ENCODER_DEAD)
    if cause is Cause.ENCODER_DEAD:
        assert silence.text.startswith(
            "encoder dead: no drum pulse for 2.0 s (stall_timeout_s 2) while the motor drew "
            "0.95 A (turning, not jammed)"
        )
    else:
        assert silence.text.startswith("stall: no drum pulse for 2.0 s")
    if cause is Cause.UNKNOWN:
        assert "a jammed drum or a dead encoder; no current sensor to tell" in silence.text
    if cause is not Cause.JAM:
        low = max(0.0, 2.12 - 1.8 * RUN_MARGIN)
        assert f"between {low:.2f} and 2.12 m" in silence.text
    assert TURNING_MIN_A > 0.5  # above the zero check's tolerance: an offset never turns


def test_the_guard_reckons_the_duty_it_ran_at_since_the_last_pulse() -> None:
    guard = MotionGuard(
        LIMITS, started_at=0.0, home_deadline=None, direction=-1, full_speed_m_s=1.0
    )
    t = 0.0
    for _ in range(20):  # 1 s at duty 0.5, a pulse at its end
        t += 0.05
        assert guard.check(t, 1.0, 3.0, duty=0.5) is None
    guard.pulse(t)
    fault = None
    while fault is None:  # then duty 0.9 and no pulse: dead reckoning from the pulse on
        t += 0.05
        fault = guard.check(t, 1.0, 3.0, duty=0.9)
    assert guard.silence is not None and guard.silence.encoder_dead
    quiet = t - 1.0
    assert guard.silence.estimate.best_m == pytest.approx(3.0 - 0.9 * quiet)
    # The verdict is in the estimate: stopping now moves it no further.
    assert guard.stopped(t) == guard.silence.estimate


def test_a_stop_after_a_blind_run_moves_a_standing_estimate_and_a_pulse_ends_it() -> None:
    prior = DepthEstimate.counted(2.0).after_run(-1, 1.0, turned=True)  # about 1.0 m
    guard = MotionGuard(
        LIMITS, started_at=0.0, home_deadline=None, direction=-1, full_speed_m_s=1.0, prior=prior
    )
    assert guard.check(0.25, 1.0, 2.0, duty=0.8) is None
    moved = guard.stopped(0.5)  # an operator's jog released: 0.5 s at 0.8
    assert moved is not None and moved.best_m == pytest.approx(1.0 - 0.4)
    assert guard.stopped(0.6) == moved  # stopped once
    counted = MotionGuard(
        LIMITS, started_at=0.0, home_deadline=None, direction=-1, full_speed_m_s=1.0, prior=prior
    )
    counted.pulse(0.1)  # a counted pulse: the count says where it is again
    assert counted.stopped(0.5) is None


# ---------------------------------------------------------------- on mock pins


def _faults() -> DrumFaults:
    return DrumFaults(encoder_dead_in_from_m=1.0)


def _only_fault(rig: GpioRig) -> dict[str, Any]:
    faults = [detail for kind, detail in rig.events if kind == "winch_fault"]
    assert len(faults) == 1, faults
    return faults[0]


async def test_a_dead_encoder_hauling_in_is_found_by_the_current_and_the_depth_reckoned() -> None:
    async with gpio_rig(adc=True, faults=_faults()) as rig:
        rig.winch.move_to(2.0)  # paying out: the encoder is alive
        await rig.settle()
        counted = rig.winch.line_m
        assert rig.winch.status().fault is None and not rig.drum.encoder_dead
        rig.winch.move_to(0.0)  # the first haul in from below 1 m: the pulse pin dies
        await rig.settle()
        status = rig.winch.status()
        assert rig.drum.encoder_dead and rig.drum.motor() == (0, 0.0)
        assert status.fault is not None
        verdict = r"encoder dead: no drum pulse for [\d.]+ s \(stall_timeout_s 0.6\)"
        assert re.match(verdict, status.fault)
        assert "(turning, not jammed)" in status.fault and "no longer trusted" in status.fault
        # The probe went up while the count stood still: the depth is the reckoning's.
        true_line = rig.drum.line_m
        assert true_line < counted - 0.4
        assert abs(status.depth_m - true_line) <= RECKONING_TOLERANCE_M
        assert rig.winch.line_m == counted  # the count frozen where the last pulse left it
        assert not status.at_home and not status.moving
        fault = _only_fault(rig)
        assert fault["fault"] == status.fault and fault["cause"] == "encoder dead"
        assert fault["line_m"] == round(status.depth_m, 3)
        assert fault["counted_line_m"] == round(counted, 3)
        assert fault["depth_low_m"] <= true_line <= fault["depth_high_m"]
        assert fault["depth_by"] == "dead reckoning" and fault["switch_closed"] is False
        with pytest.raises(WinchFault, match="encoder dead"):
            rig.winch.move_to(0.0)  # no cast moves it on a count that is not trusted


async def test_an_operators_haul_after_the_verdict_follows_the_probe_and_the_switch_stops_it() -> (
    None
):
    async with gpio_rig(adc=True, faults=_faults()) as rig:
        rig.winch.move_to(1.5)
        await rig.settle()
        rig.winch.move_to(0.0)  # dies at once: stopped about 0.55 m up, ~0.95 m down
        await rig.settle()
        first = rig.winch.status()
        assert first.fault is not None and first.fault.startswith("encoder dead")
        assert abs(first.depth_m - rig.drum.line_m) <= RECKONING_TOLERANCE_M
        # The operator hauls in by hand: each run is reckoned from the last estimate.
        for _ in range(4):
            if rig.winch.switch_closed:
                break
            rig.winch.jog(Direction.HAUL_IN)
            await rig.settle()
            if not rig.winch.switch_closed:
                assert abs(rig.winch.status().depth_m - rig.drum.line_m) <= 2 * (
                    RECKONING_TOLERANCE_M
                )
        # The switch stopped the haul at the block; the frozen count cannot agree.
        assert rig.winch.switch_closed and rig.drum.motor() == (0, 0.0)
        status = rig.winch.status()
        assert status.fault is not None and "witnesses disagree" in status.fault
        assert not status.at_home
        assert status.depth_m <= 2 * RECKONING_TOLERANCE_M  # the reckoning says near home
        # The switch closed, the count not trusted: refused, saying what is left to do.
        with pytest.raises(WinchFault, match="cc-daemon release"):
            rig.winch.jog(Direction.HAUL_IN)
        assert rig.drum.motor() == (0, 0.0)


async def test_without_a_current_sensor_a_silent_drum_may_be_either_and_says_so() -> None:
    async with gpio_rig(faults=_faults()) as rig:
        rig.winch.move_to(2.0)
        await rig.settle()
        counted = rig.winch.line_m
        rig.winch.move_to(0.0)
        await rig.settle()
        status = rig.winch.status()
        assert status.fault is not None and status.fault.startswith("stall: no drum pulse")
        assert "a jammed drum or a dead encoder; no current sensor to tell" in status.fault
        assert rig.drum.motor() == (0, 0.0)
        # The range holds the truth; the best estimate is the count (it may have jammed).
        low, high = (
            float(x) for x in re.findall(r"between ([\d.]+) and ([\d.]+) m", status.fault)[0]
        )
        assert low <= rig.drum.line_m <= high and high == pytest.approx(counted, abs=0.005)
        assert status.depth_m == pytest.approx(counted)
        fault = _only_fault(rig)
        assert fault["cause"] == "unknown" and fault["depth_by"] == "the count"
        assert (fault["depth_low_m"], fault["depth_high_m"]) == pytest.approx((low, high), abs=0.01)


async def test_a_dead_encoder_paying_out_is_reckoned_deeper() -> None:
    async with gpio_rig(adc=True) as rig:
        rig.winch.move_to(1.0)
        await rig.settle()
        rig.drum.encoder_dead = True  # the wire cut at 1 m: the drum pays out on unseen
        rig.winch.move_to(3.0)
        await rig.settle()
        status = rig.winch.status()
        assert status.fault is not None and status.fault.startswith("encoder dead")
        assert rig.drum.motor() == (0, 0.0)
        assert rig.drum.line_m > rig.winch.line_m + 0.4  # deeper than counted
        assert abs(status.depth_m - rig.drum.line_m) <= RECKONING_TOLERANCE_M
        fault = _only_fault(rig)
        assert fault["depth_low_m"] == round(rig.winch.line_m, 3)
        assert fault["depth_low_m"] <= rig.drum.line_m <= fault["depth_high_m"]


@pytest.mark.parametrize("running_a", [1.05, 1.2], ids=["read", "past-the-sensors-range"])
async def test_a_genuine_jam_on_the_way_up_is_still_a_jam(running_a: float) -> None:
    async with gpio_rig(adc=True, faults=DrumFaults(jam_in_at_m=1.7)) as rig:
        # Jammed, the mock motor draws 4 x its running current: 4.2 A is over
        # max_current_a and read as it is; 4.8 A is past the 4.29 A the ACS712-5A reads
        # on 3.3 V, at the ADC's top rail: the most it can say, still a jam.
        rig.drum.running_current_a = running_a
        rig.winch.move_to(2.0)
        await rig.settle()
        rig.winch.move_to(0.0)
        await rig.settle()
        status = rig.winch.status()
        # The overcurrent rule (or the no-pulse rule, seeing the jam's current): a stall.
        assert status.fault is not None and status.fault.startswith("stall: ")
        assert "above max_current_a" in status.fault and "encoder" not in status.fault
        assert rig.drum.motor() == (0, 0.0)
        # Jammed: the count is right, and is the depth; nothing distrusts it.
        assert abs(status.depth_m - rig.drum.line_m) <= MPP
        assert rig.winch.distrust is None
        assert _only_fault(rig)["line_m"] == round(status.depth_m, 3)


def test_winch_sim_drum_fault_encoder_dead_reaches_the_mock_drum() -> None:
    settings = Settings.model_validate(
        {
            "winch": {
                "backend": "gpio",
                "gpio": {"pin_factory": "mock"},
                "sim": {"drum_fault": "encoder-dead"},
            }
        }
    )
    drum = mock_drum_for(settings)
    try:
        assert drum.faults == DrumFaults(encoder_dead_in_from_m=drum_module.ENCODER_DEAD_FROM_M)
    finally:
        drum.close()
        drum.factory.reset()


# ---------------------------------------------------------------- the survey


async def test_encoder_dead_on_the_mock_drum_halts_the_survey_with_the_reckoned_depth(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    drums: list[SimulatedDrum] = []
    real = drum_module.mock_drum_for

    def keep(settings: Settings) -> SimulatedDrum:  # the real drum, kept to read its line
        drums.append(real(settings))
        return drums[-1]

    monkeypatch.setattr(drum_module, "mock_drum_for", keep)
    # 3 m down, 2 s of blind haul at 1 m/s: the probe stays about 1 m down.
    gpio_mock, quick = gpio_mock_pace(
        {"bottom_dwell_s": 0.5, "max_duration_s": 7.0, "target_depth_m": 3.0}, 2.0
    )
    code, text, _ = await _simulate(
        tmp_path, stations=2, pace=quick, settings=gpio_mock, winch_fault="encoder-dead"
    )
    assert code == 4, text
    assert "--winch-fault encoder-dead" in text.splitlines()[0]
    assert "encoder dead: no drum pulse" in text and "(turning, not jammed)" in text
    assert "SURVEY HALTED: probe stranded at S1, fault reported to the autopilot" in text
    assert "stranded: R-L x" in _row(text, "S1")
    assert "← R-F" not in text
    [drum] = drums
    reported = [float(d) for d in re.findall(r"← R-L t=\d+ depth ([\d.]+) m", text)]
    assert reported, text
    assert drum.line_m < 2.5  # the probe came up, the count (about 3 m) did not
    assert all(abs(depth - drum.line_m) <= RECKONING_TOLERANCE_M for depth in reported)
    [(outcome, _planned, _reached)] = _casts(tmp_path)
    assert outcome == "unfinished"
