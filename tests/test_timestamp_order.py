"""The autopilot's timestamp byte order: fixed settings, and "auto" on fake time."""

from __future__ import annotations

import pytest

from cc_daemon.core.cast.timestamps import TimestampOrder, swap_bytes


def wire(value: int, order: str) -> int:
    """What the parser reads (big-endian) when the autopilot writes `value` in `order`."""
    return value if order == "big" else swap_bytes(value)


def feed(detector: TimestampOrder, values: list[int], order: str, period: float = 1.1) -> list:
    decisions = []
    for i, value in enumerate(values):
        decision = detector.observe_telemetry(wire(value, order), i * period)
        if decision is not None:
            decisions.append(decision)
    return decisions


def firmware_clock(start: int, count: int, period: float = 1.1) -> list[int]:
    """The firmware's whole-second clock sampled every `period` s (steps of 1, now and then 2)."""
    return [(int(start + i * period)) % 65536 for i in range(count)]


@pytest.mark.parametrize("order", ["big", "little"])
def test_auto_decides_each_order_once_with_its_evidence(order: str) -> None:
    detector = TimestampOrder("auto")
    assert detector.order == "big" and not detector.decided  # the manual until decided
    decisions = feed(detector, firmware_clock(1, 20), order)
    assert len(decisions) == 1
    [decision] = decisions
    assert decision.order == order and decision.against == 0 and len(decision.evidence) == 3
    assert detector.decided and detector.order == order
    assert detector.decode(wire(301, order)) == 301


def test_the_issue_fixtures_read_little_endian() -> None:
    # P-T t=1 s arrives as 01 00, t=301 s as 2D 01.
    detector = TimestampOrder("little")
    assert detector.decode(0x0100) == 1 and detector.decode(0x2D01) == 301


def test_big_endian_is_used_until_auto_has_decided() -> None:
    detector = TimestampOrder("auto")
    feed(detector, [1, 2, 3], "little")
    assert not detector.decided
    assert detector.decode(0x0100) == 0x0100  # the manual's reading, for now


def test_a_stuck_clock_never_decides() -> None:
    detector = TimestampOrder("auto")
    assert feed(detector, [0] * 50, "little") == []
    assert detector.order == "big" and not detector.decided


@pytest.mark.parametrize("order", ["big", "little"])
def test_a_wrap_at_65535_is_taken_in_stride(order: str) -> None:
    detector = TimestampOrder("auto")
    decisions = feed(detector, [65533, 65534, 65535, 0, 1, 2, 3, 4], order, period=1.0)
    assert [d.order for d in decisions] == [order]
    assert detector.decode(wire(0, order)) == 0


@pytest.mark.parametrize("order", ["big", "little"])
def test_frames_too_close_or_too_far_apart_say_nothing(order: str) -> None:
    detector = TimestampOrder("auto")
    assert feed(detector, list(range(1, 30)), order, period=0.1) == []
    assert feed(TimestampOrder("auto"), list(range(1, 300, 10)), order, period=10.0) == []


def test_a_fixed_setting_never_changes() -> None:
    for setting in ("big", "little"):
        detector = TimestampOrder(setting)  # type: ignore[arg-type]
        assert detector.decided and detector.order == setting
        assert feed(detector, firmware_clock(1, 10), "little" if setting == "big" else "big") == []
        assert detector.order == setting


def test_contradicting_evidence_needs_a_clear_lead() -> None:
    detector = TimestampOrder("auto")
    # Two pairs read big (1, 2, 3), then a jump and four little-endian steps.
    readings = [1, 2, 3, swap_bytes(300), swap_bytes(301), swap_bytes(302), swap_bytes(303)]
    readings += [swap_bytes(v) for v in (304, 305, 306)]
    decisions = [detector.observe_telemetry(raw, i * 1.0) for i, raw in enumerate(readings)]
    decided = [d for d in decisions if d is not None]
    assert [d.order for d in decided] == ["little"]
    assert decided[0].against == 2 and decided[0].votes == 5
