"""The register map's arithmetic: which blocks to read, and how registers become values.

Pure: it plans the fewest block reads (function 3, at most 125 registers each)
covering a register map and decodes one block's registers into values with
each parameter's type and word order; `encode` is the inverse, for the
simulated sonde and the tests. It never does I/O and never imports pymodbus.

A NaN or infinite float decodes to None with the reason "nan": a missing
value is never turned into a number.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

__all__ = ["Block", "ParameterLike", "decode", "encode", "plan_blocks"]

MAX_REGISTERS_PER_READ = 125

_FORMATS = {"float32": ">f", "int32": ">i", "uint32": ">I", "int16": ">h", "uint16": ">H"}


class ParameterLike(Protocol):
    """What the arithmetic needs of a parameter (satisfied by `SondeParameter`)."""

    @property
    def name(self) -> str: ...
    @property
    def address(self) -> int: ...
    @property
    def count(self) -> int: ...
    @property
    def type(self) -> str: ...
    @property
    def word_order(self) -> str: ...


@dataclass(frozen=True, slots=True)
class Block:
    """One read request: `count` registers from protocol address `address`."""

    address: int
    count: int
    parameters: tuple[ParameterLike, ...]

    @property
    def has_gaps(self) -> bool:
        return sum(p.count for p in self.parameters) < self.count


def plan_blocks(
    parameters: Sequence[ParameterLike],
    max_registers: int = MAX_REGISTERS_PER_READ,
    *,
    gaps: bool = True,
) -> list[Block]:
    """The fewest contiguous reads covering every parameter, in address order.

    Registers between two parameters are read and ignored: one request more
    costs far more at 9600 baud (a turnaround plus 8 + 5 bytes) than a few
    registers of padding. With `gaps=False` a block covers only the
    parameters' own registers, for a sonde that refuses unmapped ones
    (exception 2, illegal data address).
    """
    blocks: list[Block] = []
    start = end = 0
    members: list[ParameterLike] = []
    for p in sorted(parameters, key=lambda p: p.address):
        joins = gaps or p.address <= end
        if members and joins and p.address + p.count - start <= max_registers:
            members.append(p)
            end = max(end, p.address + p.count)
            continue
        if members:
            blocks.append(Block(start, end - start, tuple(members)))
        start, end, members = p.address, p.address + p.count, [p]
    if members:
        blocks.append(Block(start, end - start, tuple(members)))
    return blocks


def _raw(p: ParameterLike, words: Sequence[int]) -> bytes:
    if p.count == 2 and p.word_order == "little":
        words = (words[1], words[0])
    return b"".join(w.to_bytes(2, "big") for w in words)


def decode(block: Block, registers: Sequence[int]) -> dict[str, float | None]:
    """Each parameter's value from one block's registers; None for NaN or infinity."""
    if len(registers) != block.count:
        raise ValueError(f"block of {block.count} registers got {len(registers)}")
    values: dict[str, float | None] = {}
    for p in block.parameters:
        offset = p.address - block.address
        words = registers[offset : offset + p.count]
        (value,) = struct.unpack(_FORMATS[p.type], _raw(p, words))
        number = float(value)
        values[p.name] = number if math.isfinite(number) else None
    return values


def encode(p: ParameterLike, value: float) -> list[int]:
    """The registers a sonde sends for `value` (the inverse of `decode`)."""
    fmt = _FORMATS[p.type]
    packed = struct.pack(fmt, value if p.type == "float32" else round(value))
    words = [int.from_bytes(packed[i : i + 2], "big") for i in range(0, len(packed), 2)]
    if p.count == 2 and p.word_order == "little":
        words.reverse()
    return words
