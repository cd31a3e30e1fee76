"""record:// sim:// replay:// through the same client code; strict mismatch errors; URL rules."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import serial

import thrustmap.protocols  # noqa: F401 - registers the URL handlers
from thrustmap.core.clock import SimClock
from thrustmap.core.errors import ConfigError, ThrustmapError
from thrustmap.protocols.mavlink import codec as mav
from thrustmap.protocols.mavlink.link import MavlinkSerialLink, open_mavlink
from thrustmap.protocols.peer import register_peer, unregister_peer
from thrustmap.protocols.transcript import read_transcript
from thrustmap.protocols.transport import open_transport
from thrustmap.protocols.urlhandlers.protocol_record import record_url, split_record_url
from thrustmap.protocols.urlhandlers.protocol_replay import (
    ReplayIncompleteError,
    ReplayMismatchError,
    ReplaySerial,
)
from thrustmap.protocols.urlhandlers.protocol_sim import SimPeerSilentError, SimSerial
from thrustmap.rig.sim import mavlink_peers  # noqa: F401 - registers sim://px4


class CounterPeer:
    """Answers each 'PING\\n' 50 ms later with 'PONG <n>\\n'."""

    def __init__(self, options: dict[str, str]) -> None:
        self.prefix = options.get("prefix", "PONG")
        self._pending: list[tuple[float, bytes]] = []
        self._rx = b""
        self.count = 0

    def write(self, data: bytes, now_s: float) -> None:
        self._rx += data
        while b"\n" in self._rx:
            line, self._rx = self._rx.split(b"\n", 1)
            if line == b"PING":
                self.count += 1
                self._pending.append((now_s + 0.05, f"{self.prefix} {self.count}\n".encode()))

    def read(self, now_s: float) -> bytes:
        ready = [d for t, d in self._pending if t <= now_s]
        self._pending = [(t, d) for t, d in self._pending if t > now_s]
        return b"".join(ready)


@pytest.fixture
def counter_peer() -> Iterator[None]:
    register_peer("counter", lambda options: CounterPeer(dict(options)), replace=True)
    yield
    unregister_peer("counter")


def ping_client(port: Any, n: int) -> list[str]:
    """The 'driver' under test: n request/response pairs, line protocol."""
    answers = []
    for _ in range(n):
        port.write(b"PING\n")
        answers.append(port.read_until(b"\n").decode().strip())
    return answers


def test_record_then_replay_a_sim_session_strictly(tmp_path: Path, counter_peer: None) -> None:
    path = tmp_path / "sim.jsonl"
    clock = SimClock(50.0)
    url = record_url("sim://counter?prefix=ACK", str(path))
    port = open_transport(url, timeout=0.2, clock=clock)
    assert ping_client(port, 3) == ["ACK 1", "ACK 2", "ACK 3"]
    port.close()

    t = read_transcript(path)
    assert t.header.inner == "sim://counter?prefix=ACK"
    assert t.written() == b"PING\n" * 3
    assert t.read() == b"ACK 1\nACK 2\nACK 3\n"
    first_read = next(e for e in t.events if e.direction == "r")
    assert first_read.time_s == pytest.approx(0.05, abs=0.0015)  # peer latency, on the sim clock

    replay_clock = SimClock()
    replay = open_transport(f"replay://{path}", timeout=0.2, clock=replay_clock)
    assert ping_client(replay, 3) == ["ACK 1", "ACK 2", "ACK 3"]
    report = replay.assert_consumed()
    assert report.read_bytes_served == len(b"ACK 1\nACK 2\nACK 3\n")
    assert report.write_bytes_matched == 15 and report.mismatches == 0
    assert replay_clock.now_s() >= first_read.time_s  # the clock followed the recording
    replay.close()


def test_record_then_replay_loop(tmp_path: Path) -> None:
    path = tmp_path / "loop.jsonl"
    port = open_transport(f"record://loop://?file={path}", timeout=0, clock=SimClock())
    port.write(b"\x01\x02\x03")
    assert port.read(8) == b"\x01\x02\x03"
    port.note("marker")
    port.write(b"\xfe")
    assert port.read(1) == b"\xfe"
    port.close()
    t = read_transcript(path)
    assert [(e.direction, e.data, e.note) for e in t.events] == [
        ("w", b"\x01\x02\x03", None),
        ("r", b"\x01\x02\x03", None),
        (None, b"", "marker"),
        ("w", b"\xfe", None),
        ("r", b"\xfe", None),
    ]
    replay = open_transport(f"replay://{path}", timeout=0)
    assert replay.read(8) == b""  # nothing was read before the first write
    replay.write(b"\x01\x02")  # chunking may differ from the recording
    assert replay.read(8) == b""
    replay.write(b"\x03")
    assert replay.in_waiting == 3
    assert replay.read(2) == b"\x01\x02"
    replay.write(b"\xfe")  # unread bytes stay buffered across a write
    assert replay.read(8) == b"\x03\xfe"
    assert replay.report().fully_consumed


def test_replay_strict_mismatch_names_offset_bytes_and_line(
    tmp_path: Path, counter_peer: None
) -> None:
    path = tmp_path / "m.jsonl"
    port = open_transport(record_url("sim://counter", str(path)), timeout=0.1, clock=SimClock())
    ping_client(port, 2)
    port.close()
    replay = open_transport(f"replay://{path}", timeout=0.1)
    replay.write(b"PING\n")
    assert replay.read(7) == b"PONG 1\n"
    with pytest.raises(ReplayMismatchError) as info:
        replay.write(b"PINX\n")
    err = info.value
    assert isinstance(err, ThrustmapError)
    assert (err.offset, err.expected, err.actual) == (8, ord("G"), ord("X"))
    second_write = [e for e in read_transcript(path).events if e.direction == "w"][1]
    assert err.file == str(path) and err.line == second_write.line
    assert "byte 8" in str(err) and "0x58" in str(err) and "0x47" in str(err)


def test_replay_non_strict_counts_and_reports_extra_writes(
    tmp_path: Path, counter_peer: None
) -> None:
    path = tmp_path / "n.jsonl"
    port = open_transport(record_url("sim://counter", str(path)), timeout=0.1, clock=SimClock())
    ping_client(port, 1)
    port.close()
    replay = open_transport(f"replay://{path}?strict=0", timeout=0.1)
    replay.write(b"PONG\n")  # one differing byte, tolerated
    assert replay.read(7) == b"PONG 1\n"
    replay.write(b"more")  # past the end of the recording
    assert replay.report().mismatches == 2  # one per write that differed
    strict = open_transport(f"replay://{path}", timeout=0.1)
    strict.write(b"PING\n")
    strict.read(7)
    with pytest.raises(ReplayMismatchError, match="end of recording"):
        strict.write(b"x")


def test_replay_reports_unconsumed_transcript(tmp_path: Path, counter_peer: None) -> None:
    path = tmp_path / "u.jsonl"
    port = open_transport(record_url("sim://counter", str(path)), timeout=0.1, clock=SimClock())
    ping_client(port, 2)
    port.close()
    replay = ReplaySerial(read_transcript(path), timeout=0.1)
    ping_client(replay, 1)
    report = replay.report()
    assert not report.fully_consumed
    assert report.write_bytes_remaining == 5 and report.read_bytes_remaining == 7
    with pytest.raises(ReplayIncompleteError):
        replay.assert_consumed()


def test_replay_short_read_advances_the_given_clock_by_the_timeout(tmp_path: Path) -> None:
    path = tmp_path / "c.jsonl"
    port = open_transport(f"record://loop://?file={path}", timeout=0, clock=SimClock())
    port.write(b"a")
    port.close()
    clock = SimClock()
    replay = open_transport(f"replay://{path}", timeout=0.25, clock=clock)
    assert replay.read(1) == b""
    assert clock.now_s() == pytest.approx(0.25)


def test_mavlink_session_recorded_from_sim_replays_through_the_same_link(tmp_path: Path) -> None:
    """A MAVLink 'driver' against sim://px4, recorded, then replayed strictly: same values."""
    from thrustmap.rig.devices.urls import load_sim_peers

    load_sim_peers()  # the simulator registers sim://px4 (protocols/ does not know it)

    def driver(link: MavlinkSerialLink) -> tuple[Any, ...]:
        hb = mav.decode(link.wait_heartbeat(timeout=2.0))
        link.mav.send(mav.actuator_test(2, 0.25, timeout_s=1.0).to_message())
        ack = mav.decode(link.recv_match(type="COMMAND_ACK", blocking=True, timeout=1.0))
        esc = None
        for _ in range(100):  # the first ESC_STATUS showing the motor turning (bounded)
            esc = mav.decode(link.recv_match(type="ESC_STATUS", blocking=True, timeout=1.0))
            if esc is not None and esc.rpm[1] > 0:
                break
        link.mav.send(mav.actuator_test_stop(2).to_message())
        stop = mav.decode(link.recv_match(type="COMMAND_ACK", blocking=True, timeout=1.0))
        return hb, ack, esc, stop

    path = tmp_path / "px4.jsonl"
    clock = SimClock()
    link = open_mavlink(record_url("sim://px4?motors=4", str(path)), clock=clock)
    recorded = driver(link)
    link.close()
    hb, ack, esc, stop = recorded
    assert isinstance(hb, mav.Heartbeat) and hb.autopilot == mav.Autopilot.PX4
    assert isinstance(ack, mav.CommandAck) and ack.result == mav.MavResult.ACCEPTED
    assert isinstance(esc, mav.EscStatus) and esc.rpm[1] > 1000.0
    assert isinstance(stop, mav.CommandAck) and stop.accepted

    replay_clock = SimClock()
    replay_link = open_mavlink(f"replay://{path}", clock=replay_clock)
    assert driver(replay_link) == recorded
    replay_link.port.assert_consumed()
    assert read_transcript(path).written()[:1] == b"\xfd"  # MAVLink 2 on the wire


def test_sim_url_options_unknown_peer_and_blocking_read(counter_peer: None) -> None:
    port = open_transport("sim://counter?prefix=HI%20THERE", timeout=0.1, clock=SimClock())
    assert ping_client(port, 1) == ["HI THERE 1"]
    with pytest.raises(ConfigError, match="known peers: .*counter"):
        open_transport("sim://no-such-peer")
    clock = SimClock()
    blocking = SimSerial(CounterPeer({}), clock, timeout=None, max_block_s=2.0)
    with pytest.raises(SimPeerSilentError):
        blocking.read(1)
    assert clock.now_s() == pytest.approx(2.0)


def test_sim_serial_read_waits_on_the_clock_only_as_long_as_needed() -> None:
    clock = SimClock()
    port = SimSerial(CounterPeer({}), clock, timeout=1.0)
    port.write(b"PING\n")
    assert port.read(7) == b"PONG 1\n"
    assert clock.now_s() == pytest.approx(0.05, abs=0.0011)
    assert port.read(1) == b""
    assert clock.now_s() == pytest.approx(1.05, abs=0.0011)


@pytest.mark.parametrize(
    ("url", "inner", "own"),
    [
        (
            "record:///dev/ttyACM0?file=run.jsonl&baudrate=115200",
            "/dev/ttyACM0",
            {"file": "run.jsonl", "baudrate": "115200"},
        ),
        ("record://COM3?file=a%26b.jsonl", "COM3", {"file": "a&b.jsonl"}),
        ("record://sim://px4?motors=4&file=px4.jsonl", "sim://px4?motors=4", {"file": "px4.jsonl"}),
        ("record://loop://?file=x+y.jsonl", "loop://", {"file": "x+y.jsonl"}),
        (
            "record://socket://192.168.4.1:23?file=w.jsonl",
            "socket://192.168.4.1:23",
            {"file": "w.jsonl"},
        ),
    ],
)
def test_record_url_split(url: str, inner: str, own: dict[str, str]) -> None:
    assert split_record_url(url) == (inner, own)


def test_record_url_errors_and_builder() -> None:
    with pytest.raises(serial.SerialException, match="file="):
        split_record_url("record://loop://")
    assert split_record_url(record_url("sim://px4?motors=4", "dir/a&b.jsonl")) == (
        "sim://px4?motors=4",
        {"file": "dir/a&b.jsonl"},
    )
