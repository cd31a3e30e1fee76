"""A recorded firmware served back over real UDP, to the real CLI (tests/test_firmware_recordings.py).

``ReplayPeer(transcript, port)`` sends what the firmware sent in a ``record://`` transcript to
``127.0.0.1:port`` (where `thrustmap spin udpin:...` listens) and feeds every datagram the CLI
sends back into thrustmap's own message-level replay (``ReplaySerial``, ``match=messages``, on
the real clock): the CLI's requests, motor commands and stops get the answers the firmware gave
when it was recorded, at the recorded latency. The CLI runs as a process, so signals, the
locked link and its exit codes are the real ones. ``go_silent()`` stops both ways (a lost link).
``Intruder`` is a second local sender, as in the recording.
"""

from __future__ import annotations

import socket
import threading
import time
from pathlib import Path
from typing import Any

from thrustmap.core.clock import MonotonicClock
from thrustmap.protocols.mavlink import codec as mav
from thrustmap.protocols.mavlink import encode as enc
from thrustmap.protocols.transcript import Transcript
from thrustmap.protocols.urlhandlers.protocol_replay import ReplaySerial
from thrustmap.protocols.urlhandlers.transcript_messages import MavlinkProtocol

#: MAVLink commands that start a motor (ArduPilot DO_MOTOR_TEST, PX4 ACTUATOR_TEST)
MOTOR_COMMANDS = (209, 310)


def is_stop(cmd: mav.CommandLong) -> bool:
    """A DO_MOTOR_TEST with throttle 0 or an ACTUATOR_TEST with NaN: the stop."""
    if cmd.command == 209:
        return cmd.params[2] == 0
    return cmd.command == 310 and cmd.params[0] != cmd.params[0]


def udp_listening(port: int) -> bool:
    """Something on this machine has bound UDP ``port`` (Linux: /proc/net/udp)."""
    try:
        text = Path("/proc/net/udp").read_text()
    except OSError:
        time.sleep(3.0)
        return True  # cannot tell (not Linux): give the CLI time to start
    return any(
        line.split()[1].endswith(f":{port:04X}") for line in text.splitlines()[1:] if line.split()
    )


def wait_listening(port: int, timeout_s: float = 30) -> None:
    deadline = time.monotonic() + timeout_s
    while not udp_listening(port):
        if time.monotonic() > deadline:
            raise AssertionError(f"nothing listens on UDP {port} after {timeout_s:g} s")
        time.sleep(0.05)


#: frames due together go out in datagrams of at most this many bytes, as PX4 and ArduPilot
#: fill theirs (one datagram per frame floods the listener on a 20 kB/s PX4 stream)
DATAGRAM_BYTES = 1400


def _datagrams(frames: list[bytes]) -> list[bytes]:
    out: list[bytes] = []
    for frame in frames:
        if out and len(out[-1]) + len(frame) <= DATAGRAM_BYTES:
            out[-1] += frame
        else:
            out.append(frame)
    return out


COMMAND_ACK = 77  # answers: the message-level replay times them (the stream is held here)


def _msgid(frame: bytes) -> int:
    if frame[:1] == b"\xfd":
        return int.from_bytes(frame[7:10], "little")
    return frame[5]


def _frames_after_first_stop(transcript: Transcript) -> dict[bytes, float]:
    """The firmware's frames recorded after the host's first stop after its last run command,
    each with its delay after that stop (empty: no such stop)."""
    split = MavlinkProtocol().split
    codec = mav.MavlinkCodec()
    first_stop = None  # the first stop after the last run command
    for event in transcript.events:
        if event.direction != "w":
            continue
        for msg in codec.feed(event.data):
            if msg.get_type() != "COMMAND_LONG":
                continue
            cmd = mav.CommandLong.from_message(msg)
            if cmd.command not in MOTOR_COMMANDS:
                continue
            if not is_stop(cmd):
                first_stop = None
            elif first_stop is None:
                first_stop = event.time_s
    if first_stop is None:
        return {}
    reads = [e for e in transcript.events if e.direction == "r"]
    stream = b"".join(e.data for e in reads)  # frames may span read calls
    ends, end = [], 0
    for e in reads:
        end += len(e.data)
        ends.append((end, e.time_s))
    delays: dict[bytes, float] = {}
    pos, i = 0, 0
    for frame in split(stream)[0]:
        pos = stream.index(frame, pos)
        while ends[i][0] <= pos:
            i += 1
        if ends[i][1] > first_stop:
            delays.setdefault(frame, ends[i][1] - first_stop)
        pos += len(frame)
    return delays


class ReplayPeer:
    def __init__(self, transcript: Transcript, port: int) -> None:
        """Starts serving once ``port`` is bound (the recording began with the vehicle's first
        datagram reaching the listening CLI)."""
        self.port = port
        wait_listening(port)
        self.serial = ReplaySerial(
            transcript, strict=False, clock=MonotonicClock(), match="messages", timeout=0
        )
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.setblocking(False)
        self._after_stop = _frames_after_first_stop(transcript)
        self._held: list[bytes] = []
        self.received = bytearray()  # everything the CLI sent
        self.commands: list[tuple[float, mav.CommandLong]] = []
        self.silent = False
        self._codec = mav.MavlinkCodec()
        self._t0 = time.monotonic()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        split = MavlinkProtocol().split
        while not self._stop.wait(0.002):
            try:
                while True:
                    data = self.sock.recv(65535)
                    if self.silent:
                        continue
                    self._take(data)
            except BlockingIOError:
                pass
            if self.silent:
                continue
            waiting = self.serial.in_waiting
            frames = split(self.serial.read(waiting))[0] if waiting else []
            for datagram in _datagrams(self._causal(frames)):  # held ones come due too
                self.sock.sendto(datagram, ("127.0.0.1", self.port))

    def _causal(self, frames: list[bytes]) -> list[bytes]:
        """What the firmware sent after the first stop it was sent is never served before the
        CLI's own first stop, and then with its recorded delay after it (the replay's clock
        alone would let a late CLI see the motor idle before it stopped it). Answers
        (COMMAND_ACK) are left to the message-level replay."""
        out: list[bytes] = []
        for frame in frames:
            held = frame in self._after_stop and _msgid(frame) != COMMAND_ACK
            (self._held if held else out).append(frame)
        stop_s = self._first_stop_after_run()
        if stop_s is not None and self._held:
            since_s = time.monotonic() - self._t0 - stop_s
            due = [f for f in self._held if self._after_stop[f] <= since_s]
            self._held = [f for f in self._held if self._after_stop[f] > since_s]
            out += due
        return out

    def _first_stop_after_run(self) -> float | None:
        first = None
        for t, cmd in self.commands:
            if cmd.command not in MOTOR_COMMANDS:
                continue
            if not is_stop(cmd):
                first = None
            elif first is None:
                first = t
        return first

    def _take(self, data: bytes) -> None:
        self.serial.write(data)
        with self._lock:
            self.received += data
            for msg in self._codec.feed(data):
                if msg.get_type() == "COMMAND_LONG":
                    self.commands.append(
                        (time.monotonic() - self._t0, mav.CommandLong.from_message(msg))
                    )

    def motor_commands(self) -> list[mav.CommandLong]:
        with self._lock:
            return [c for _, c in self.commands if c.command in MOTOR_COMMANDS]

    def wait_for_run(self, timeout_s: float = 60) -> None:
        """Until the CLI sent a motor command that runs a motor."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if any(not is_stop(c) for c in self.motor_commands()):
                return
            time.sleep(0.02)
        raise AssertionError(f"the CLI never ran a motor: {self.motor_commands()}")

    def go_silent(self) -> None:
        self.silent = True

    def close(self) -> Any:
        self._stop.set()
        self._thread.join(timeout=5)
        self.sock.close()
        report = self.serial.report()
        self.serial.close()
        return report


class Intruder:
    """A second local socket sending HEARTBEATs to the CLI's port; counts what comes back."""

    def __init__(self, port: int) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.setblocking(False)
        self.address = "{}:{}".format(*self.sock.getsockname())
        self.port = port
        self.sent = self.received = 0
        self._hb = mav.MavlinkCodec(255, 190).encode(
            enc.heartbeat_message(mav.Autopilot.INVALID, armed=False, vehicle_type=6)
        )
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def start(self) -> None:
        self._thread.start()

    def _drain(self) -> None:
        try:
            while True:
                self.received += len(self.sock.recv(65535))
        except BlockingIOError:
            pass

    def _run(self) -> None:
        while not self._stop.wait(0.05):
            self._drain()
            self.sock.sendto(self._hb, ("127.0.0.1", self.port))
            self.sent += 1

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=5)
        time.sleep(0.2)
        self._drain()
        self.sock.close()
