"""The simulated Ping1D over a real pty, read with brping's own parser and device class."""

from __future__ import annotations

import asyncio
import itertools
import re
import statistics
import sys
import time
from collections.abc import AsyncIterator, Iterator
from pathlib import Path
from typing import Any

import pytest
import serial_asyncio
from brping import Ping1D, PingParser, definitions

from cc_daemon.drivers.sonar import ping
from cc_daemon.drivers.sonar.ping import PING1D_TABLE
from cc_daemon.sim.mission import make_mission
from cc_daemon.sim.ping1d import (
    SPEED_OF_SOUND_MM_S,
    Echo,
    FieldSounder,
    Ping1DDevice,
    Ping1DServer,
)
from cc_daemon.sim.pty import PtyPair
from tests.test_sonar_ping import (
    MANUAL_DEVICE_ID,
    MANUAL_DISTANCE_SIMPLE,
    MANUAL_PROTOCOL_VERSION,
    MANUAL_SPEED_OF_SOUND,
    MANUAL_STREAM_START,
    MANUAL_STREAM_STOP,
)


class ScriptedSounder:
    """Echoes 4000, 4001, ... mm with confidence 90, recorded as they are heard."""

    def __init__(self) -> None:
        self._n = itertools.count()
        self.heard: list[Echo] = []

    def __call__(self) -> Echo:
        echo = Echo(4000 + next(self._n), 90)
        self.heard.append(echo)
        return echo


class Host:
    """The autopilot's end of the sonar cable: pyserial on the pty, brping's parser."""

    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.reader = reader
        self.writer = writer
        self.parser = PingParser(payload_dict=PING1D_TABLE)
        self.messages: list[tuple[float, Any]] = []

    async def send(self, data: bytes) -> None:
        self.writer.write(data)
        await self.writer.drain()

    async def collect(self, seconds: float, *, until: int | None = None) -> list[Any]:
        """Messages arriving within `seconds` (or as soon as `until` of them came)."""
        found: list[Any] = []
        deadline = time.monotonic() + seconds
        while until is None or len(found) < until:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                break
            try:
                data = await asyncio.wait_for(self.reader.read(256), remaining)
            except TimeoutError:
                break
            now = time.monotonic()
            for byte in data:
                if self.parser.parse_byte(byte) == PingParser.NEW_MESSAGE:
                    self.messages.append((now, self.parser.rx_msg))
                    found.append(self.parser.rx_msg)
        return found


@pytest.fixture
def pair(tmp_path: Path) -> Iterator[PtyPair]:
    with PtyPair(tmp_path / "ttySONAR") as p:
        yield p


@pytest.fixture
async def rig(pair: PtyPair) -> AsyncIterator[tuple[Ping1DServer, Host, ScriptedSounder]]:
    sounder = ScriptedSounder()
    server = await Ping1DServer.over_fd(pair.master_fd, Ping1DDevice(sounder))
    reader, writer = await serial_asyncio.open_serial_connection(
        url=str(pair.path), baudrate=115200
    )
    yield server, Host(reader, writer), sounder
    writer.close()
    await server.close()


async def test_answers_the_manuals_requests_in_order(
    rig: tuple[Ping1DServer, Host, ScriptedSounder],
) -> None:
    server, host, sounder = rig
    await host.send(
        MANUAL_PROTOCOL_VERSION + MANUAL_DEVICE_ID + MANUAL_SPEED_OF_SOUND + MANUAL_DISTANCE_SIMPLE
    )
    replies = await host.collect(3.0, until=4)
    assert [m.message_id for m in replies] == [5, 1201, 1203, 1211]
    version, device, sound, distance = replies
    assert (version.version_major, version.version_minor, version.version_patch) == (1, 0, 0)
    assert device.device_id == 1
    assert sound.speed_of_sound == SPEED_OF_SOUND_MM_S
    assert (distance.distance, distance.confidence) == (4000, 90)
    assert sounder.heard == [Echo(4000, 90)]
    assert all(m.src_device_id == 1 and m.dst_device_id == 0 for m in replies)
    assert server.device.requests == [5, 1201, 1203, 1211]


async def test_streams_every_250_ms_between_start_and_stop(
    rig: tuple[Ping1DServer, Host, ScriptedSounder],
) -> None:
    server, host, sounder = rig
    assert await host.collect(0.6) == []  # nothing unasked
    await host.send(MANUAL_STREAM_START)
    streamed = await host.collect(2.1)
    times = [t for t, m in host.messages if m.message_id == ping.DISTANCE_SIMPLE]
    # Nominally 8 in 2.1 s; the machine is shared, so allow for a late wake-up.
    assert 6 <= len(streamed) <= 9
    gaps = [b - a for a, b in itertools.pairwise(times)]
    assert 0.2 <= statistics.median(gaps) <= 0.3
    assert [m.distance for m in streamed] == [e.distance_mm for e in sounder.heard]
    await host.send(MANUAL_STREAM_STOP)
    await host.collect(0.3)  # a reading may have crossed the stop on the wire
    assert await host.collect(0.8) == []
    assert not server.device.streaming
    assert server.device.requests == [1400, 1401]


async def test_corrupt_bytes_on_the_line_are_skipped(
    rig: tuple[Ping1DServer, Host, ScriptedSounder],
) -> None:
    server, host, _ = rig
    spoiled = bytearray(MANUAL_DEVICE_ID)
    spoiled[8] ^= 0x04  # the requested id: the checksum no longer adds up
    await host.send(b"\x00\xffBR\x13" + bytes(spoiled) + b"BB" + MANUAL_SPEED_OF_SOUND)
    replies = await host.collect(1.5, until=1)
    assert [m.message_id for m in replies] == [ping.SPEED_OF_SOUND]
    assert server.device.bad_frames >= 1
    assert server.device.requests == [ping.SPEED_OF_SOUND]


async def test_unknown_requests_are_nacked(
    rig: tuple[Ping1DServer, Host, ScriptedSounder],
) -> None:
    _, host, _ = rig
    # (pcb_temperature used to be NACKed here; a Ping1D answers it, and so does
    # the simulated one now: an id no Ping1D reports is the unknown request.)
    await host.send(ping.request(definitions.PING1D_CONTINUOUS_START))
    [nack] = await host.collect(1.5, until=1)
    assert nack.message_id == ping.NACK and nack.nacked_id == definitions.PING1D_CONTINUOUS_START


def _brping_device(path: str, table: dict[int, Any] | None) -> tuple[Any, Any]:
    device = Ping1D(payload_dict=table) if table is not None else Ping1D()
    device.connect_serial(path, 115200)
    try:
        return device.get_distance_simple(), device.get_protocol_version()
    finally:
        device.iodev.close()


async def test_brpings_ping1d_class_reads_it_with_the_ping1d_table(
    pair: PtyPair, capsys: pytest.CaptureFixture[str]
) -> None:
    sounder = ScriptedSounder()
    server = await Ping1DServer.over_fd(pair.master_fd, Ping1DDevice(sounder))
    try:
        distance, version = await asyncio.to_thread(
            _brping_device, str(pair.path), definitions.payload_dict_ping1d
        )
        assert distance == {"distance": 4000, "confidence": 90}
        assert version["version_major"] == 1
        # brping's Ping1D() with its default table takes 1211 for the S500's altitude.
        with pytest.raises(AttributeError, match="_distance"):
            await asyncio.to_thread(_brping_device, str(pair.path), None)
    finally:
        await server.close()
    capsys.readouterr()  # brping prints what it opens


def test_field_sounder_drops_confidence_in_shallow_or_steep_water_and_drops_out() -> None:
    mission = make_mission(3, seed=1)
    shoal = next(s for s in mission.stations if s.too_shallow)
    deep = next(s for s in mission.stations if not s.too_shallow)

    def confidences(point: Any, moving: bool) -> list[int]:
        sounder = FieldSounder(mission, lambda: (point, moving), seed=3)
        return [sounder().confidence_pct for _ in range(200)]

    still_deep = confidences(deep.point, False)
    still_shoal = confidences(shoal.point, False)
    assert min(still_deep) >= 85
    assert statistics.mean(still_shoal) < statistics.mean(still_deep) - 5
    assert min(still_shoal) >= 70  # still trusted: the shoal must be seen to be refused
    # The shoal's flank is steep: less confidence there than on its flat top.
    sounder = FieldSounder(mission, lambda: (shoal.point, False), seed=3)
    flank = max(
        (shoal.point.towards(deep.point, r) for r in range(10, 80, 5)),
        key=sounder.slope,
    )
    assert sounder.slope(flank) > 0.05
    assert statistics.mean(confidences(flank, False)) < statistics.mean(still_deep) - 5
    # Under way: noisier returns and the odd dropout (distance 0, confidence 0).
    under_way = FieldSounder(mission, lambda: (deep.point, True), seed=3)
    echoes = [under_way() for _ in range(500)]
    assert 1 <= under_way.dropouts <= 40
    assert sum(e == Echo(0, 0) for e in echoes) == under_way.dropouts
    held = [FieldSounder(mission, lambda: (deep.point, False), seed=s)() for s in range(50)]
    assert all(abs(e.distance_mm / 1000 - deep.water_depth_m) <= 0.07 for e in held)


# Every get and set brping's own example (`python -m brping.ping1d`) makes.
_GETS = (
    "get_device_id", "get_distance", "get_distance_simple", "get_firmware_version",
    "get_gain_setting", "get_general_info", "get_mode_auto", "get_oss_profile_configuration",
    "get_pcb_temperature", "get_ping_enable", "get_ping_interval", "get_processor_temperature",
    "get_profile", "get_range", "get_speed_of_sound", "get_transmit_duration", "get_voltage_5",
)  # fmt: skip
_SETS = (
    ("set_device_id", (43,)), ("set_mode_auto", (False,)), ("set_range", (1000, 2000)),
    ("set_speed_of_sound", (1444000,)), ("set_ping_interval", (36,)),
    ("set_gain_setting", (3,)), ("set_ping_enable", (True,)),
)  # fmt: skip


def _brping_session(path: str) -> dict[str, Any]:
    device = Ping1D(payload_dict=definitions.payload_dict_ping1d)
    device.connect_serial(path, 115200)
    try:
        out: dict[str, Any] = {"initialize": device.initialize()}
        out |= {name: getattr(device, name)() for name in _GETS}
        out |= {name: getattr(device, name)(*args) for name, args in _SETS}  # verify=True
        out["after"] = (device.get_range(), device.get_speed_of_sound(), device.get_device_id())
        return out
    finally:
        device.iodev.close()


async def test_brping_initialize_every_get_and_every_set_against_it(
    pair: PtyPair, capsys: pytest.CaptureFixture[str]
) -> None:
    server = await Ping1DServer.over_fd(pair.master_fd, Ping1DDevice(ScriptedSounder()))
    try:
        out = await asyncio.to_thread(_brping_session, str(pair.path))
    finally:
        await server.close()
    capsys.readouterr()
    assert out["initialize"] is True  # protocol_version, then general_info (1210)
    assert [name for name in _GETS if out[name] is None] == []
    assert out["get_distance"]["distance"] >= 4000  # device_information, distance (1212) ...
    # Each set is kept and read back. brping packs set_speed_of_sound (1002) with
    # its default table, the S500's field `sos_mm_per_sec`: the Ping1D's
    # `speed_of_sound` goes out as 0, so the read-back differs, as it would
    # from a real Ping1D. The device keeps what it was sent.
    assert [name for name, _ in _SETS if out[name] is not True] == ["set_speed_of_sound"]
    rng, sos, device_id = out["after"]
    assert rng == {"scan_start": 1000, "scan_length": 2000}
    assert sos == {"speed_of_sound": 0} and device_id == {"device_id": 43}


async def test_brpings_own_example_against_it(pair: PtyPair) -> None:
    """`python -m brping.ping1d --device PTY` (docs/sonar.md, bench step 2), as shipped.

    brping's example builds `Ping1D()` with its default table, in which 1203 and
    1213 are the S500's (`sos_mm_per_sec`, a 4-byte `centi_degC`): it misreads a
    Ping1D's processor temperature and stops at get_speed_of_sound with an
    AttributeError, whatever answers. Every check before that passes.
    """
    server = await Ping1DServer.over_fd(pair.master_fd, Ping1DDevice(ScriptedSounder()))
    try:
        proc = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "brping.ping1d", "--device", str(pair.path),
            stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.STDOUT,
        )  # fmt: skip
        out, _ = await asyncio.wait_for(proc.communicate(), 60)
    finally:
        await server.close()
    text = out.decode()
    assert "Initialized: True" in text
    results = re.findall(r"testing (\w+)\n(?:.*\n)*?  > > pass: (\w+) < <", text)
    failed = [name for name, ok in results if ok != "True"]
    assert failed == ["get_processor_temperature"], text  # brping's S500 layout for 1213
    assert len(results) == 14 and "_speed_of_sound" in text


def test_set_values_are_kept_and_acknowledged() -> None:
    device = Ping1DDevice(lambda: Echo(4200, 97))
    stream = ping.PingStream()
    acked = stream.feed(device.receive(0.0, ping.encode(1002, dst=1, speed_of_sound=1444000)))
    assert [e.event for e in acked] == [ping.OtherMessage(1, (("acked_id", 1002),))]
    (reply,) = stream.feed(device.receive(0.0, ping.request(ping.SPEED_OF_SOUND)))
    assert reply.event == ping.SpeedOfSound(1444000)
    stream.feed(device.receive(0.0, ping.encode(1001, dst=1, scan_start=500, scan_length=9000)))
    (general,) = stream.feed(device.receive(0.0, ping.request(1212)))
    fields = dict(general.event.fields)  # type: ignore[union-attr]
    assert (fields["scan_start"], fields["scan_length"], fields["distance"]) == (500, 9000, 4200)
    # The bootloader command gets no answer: a real Ping leaves the protocol.
    assert device.receive(0.0, ping.encode(1100, dst=1)) == b""
