"""The register map's arithmetic: block planning and word order with known bit patterns."""

from __future__ import annotations

import math
import struct

import pytest
from hypothesis import given
from hypothesis import strategies as st

from cc_daemon.config.sonde import DEFAULT_PARAMETERS, SondeParameter
from cc_daemon.drivers.sonde.registers import Block, decode, encode, plan_blocks


def param(name: str, register: int, **kw: str) -> SondeParameter:
    return SondeParameter(name=name, register=register, unit="1", long_name=name, **kw)


def test_default_map_is_one_block_of_30_registers_from_address_10() -> None:
    blocks = plan_blocks(DEFAULT_PARAMETERS)
    assert [(b.address, b.count) for b in blocks] == [(10, 30)]
    assert [p.name for p in blocks[0].parameters] == [p.name for p in DEFAULT_PARAMETERS]


def test_a_map_wider_than_125_registers_takes_two_blocks() -> None:
    far = (param("a", 40001), param("b", 40100), param("c", 40300), param("d", 40303, type="int16"))
    assert [(b.address, b.count) for b in plan_blocks(far)] == [(0, 101), (299, 4)]


@pytest.mark.parametrize(
    ("registers", "expected"),
    [
        ([0x3F80, 0x0000], 1.0),
        ([0xC000, 0x0000], -2.0),
        ([0x41C8, 0x0000], 25.0),
        ([0x40E0, 0x0000], 7.0),
        ([0x3DCC, 0xCCCD], struct.unpack(">f", bytes.fromhex("3DCCCCCD"))[0]),
    ],
)
def test_high_word_first_known_patterns(registers: list[int], expected: float) -> None:
    p = param("x", 40011)
    assert decode(Block(10, 2, (p,)), registers) == {"x": expected}
    assert encode(p, expected) == registers


def test_low_word_first_is_the_other_order() -> None:
    p = param("x", 40011, word_order="little")
    assert decode(Block(10, 2, (p,)), [0x0000, 0x3F80]) == {"x": 1.0}
    assert encode(p, 1.0) == [0x0000, 0x3F80]
    # The same registers read high word first are a tiny denormal, not 1.0.
    assert decode(Block(10, 2, (param("y", 40011),)), [0x0000, 0x3F80])["y"] != 1.0


def test_nan_and_infinity_are_missing_not_zero() -> None:
    p = param("x", 40011)
    assert decode(Block(10, 2, (p,)), [0x7FC0, 0x0000]) == {"x": None}
    assert decode(Block(10, 2, (p,)), [0x7F80, 0x0000]) == {"x": None}


def test_integers_and_padding() -> None:
    a, b = param("a", 40011, type="int16"), param("b", 40014, type="uint32")
    (block,) = plan_blocks((a, b))
    assert (block.address, block.count) == (10, 5)
    assert decode(block, [0xFFFF, 0xAAAA, 0xBBBB, 0x0001, 0x0002]) == {"a": -1.0, "b": 65538.0}


def test_wrong_length_is_refused() -> None:
    with pytest.raises(ValueError, match="30 registers got 2"):
        decode(plan_blocks(DEFAULT_PARAMETERS)[0], [0, 0])


@given(
    st.floats(width=32, allow_nan=False, allow_infinity=False), st.sampled_from(["big", "little"])
)
def test_round_trip(value: float, order: str) -> None:
    p = param("x", 40011, word_order=order)
    got = decode(Block(10, 2, (p,)), encode(p, value))["x"]
    assert got == value or (math.isclose(got or 0.0, value) and value == 0.0)
