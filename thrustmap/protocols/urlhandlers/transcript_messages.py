"""A transcript read as messages, for message-level replay (``replay_matching``): each
protocol (MAVLink 2/1 on pymavlink, MSP v1/v2) splits a byte stream into frames and decodes a
frame into a ``Message`` (its name, the fields compared, whether it is a barrier, a motor run or a
stop, and the keys it asks or answers); ``detect_protocol`` recognises the protocol from the
recorded writes. Pure: bytes in, messages out.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Hashable, Sequence
from dataclasses import dataclass
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from thrustmap.protocols.msp.framing import MspCommand, MspDecoder, MspDirection, MspFrame
from thrustmap.protocols.transcript import TranscriptEvent


@dataclass(frozen=True)
class Message:
    """One decoded frame: its name, the fields compared, the keys it answers or asks."""

    name: str
    fields: tuple[tuple[str, Any], ...]
    text: str  # how it is named in a report: "PARAM_REQUEST_READ MOT_SPIN_ARM"
    barrier: bool = False
    run: bool = False  # a motor command that makes a motor turn (not a stop)
    asks: frozenset[Hashable] = frozenset()  # keys of the replies a request expects
    answers: frozenset[Hashable] = frozenset()  # keys a reply carries
    throttle_field: str | None = None  # compared within ``throttle_tolerance``
    throttle_tolerance: float = 0.0

    def exact_key(self) -> Hashable:
        return (self.name, tuple((k, _norm(v)) for k, v in self.fields))

    def same_as(self, other: Message) -> bool:
        if self.name != other.name or len(self.fields) != len(other.fields):
            return False
        if self.run != other.run:
            return False
        for (ka, va), (kb, vb) in zip(self.fields, other.fields, strict=True):
            if ka != kb:
                return False
            if ka == self.throttle_field and self.run:
                if not _close(va, vb, self.throttle_tolerance):
                    return False
            elif _norm(va) != _norm(vb):
                return False
        return True


def _norm(value: Any) -> Any:
    if isinstance(value, float):
        return "nan" if math.isnan(value) else round(value, 6)
    if isinstance(value, list):
        return tuple(_norm(v) for v in value)
    return value


def _close(a: Any, b: Any, tolerance: float) -> bool:
    if isinstance(a, tuple) and isinstance(b, tuple):
        return len(a) == len(b) and all(_close(x, y, tolerance) for x, y in zip(a, b, strict=True))
    try:
        fa, fb = float(a), float(b)
    except (TypeError, ValueError):
        return bool(a == b)
    if math.isnan(fa) or math.isnan(fb):
        return math.isnan(fa) and math.isnan(fb)
    return abs(fa - fb) <= tolerance + 1e-9


class Protocol:
    name = "bytes"

    def split(self, buf: bytes) -> tuple[list[bytes], int]:
        """Whole frames (or runs of bytes that are no frame) and how many bytes they cover."""
        raise NotImplementedError

    def decode(self, frame: bytes) -> Message | None:
        raise NotImplementedError


# -- MAVLink ----------------------------------------------------------------------------------
_MAV_QUERY_COMMANDS = {511, 512, 519, 520, 521, 522}  # SET_MESSAGE_INTERVAL, REQUEST_*
_MAV_BARRIER_MESSAGES = {"PARAM_SET", "SET_MODE", "COMMAND_LONG", "COMMAND_INT", "PARAM_EXT_SET"}
_MAV_COMMAND_NAMES = {209: "DO_MOTOR_TEST", 310: "ACTUATOR_TEST", 400: "ARM_DISARM"}


class MavlinkProtocol(Protocol):
    name = "MAVLink"

    def __init__(self) -> None:
        self._mav = mavlink2.MAVLink(None)
        self._mav.robust_parsing = True

    def split(self, buf: bytes) -> tuple[list[bytes], int]:
        chunks: list[bytes] = []
        pos, n = 0, len(buf)
        while pos < n:
            magic = buf[pos]
            if magic == 0xFD:
                if n - pos < 10:
                    break
                size = 12 + buf[pos + 1] + (13 if buf[pos + 2] & 1 else 0)
            elif magic == 0xFE:
                if n - pos < 6:
                    break
                size = 8 + buf[pos + 1]
            else:
                nxt = [i for i in (buf.find(b"\xfd", pos), buf.find(b"\xfe", pos)) if i >= 0]
                end = min(nxt) if nxt else n
                chunks.append(buf[pos:end])
                pos = end
                continue
            if n - pos < size:
                break
            chunks.append(buf[pos : pos + size])
            pos += size
        return chunks, pos

    def decode(self, frame: bytes) -> Message | None:
        if not frame or frame[0] not in (0xFD, 0xFE):
            return None
        try:
            msg = self._mav.decode(bytearray(frame))
        except Exception:  # noqa: BLE001 - a bad or unknown frame is served as opaque bytes
            return None
        if msg is None or msg.get_type() in ("BAD_DATA",) or msg.get_type().startswith("UNK"):
            return None
        return self._message(msg)

    def _message(self, msg: Any) -> Message:
        name = msg.get_type()
        data = msg.to_dict()
        data.pop("mavpackettype", None)
        asks: set[Hashable] = set()
        answers: set[Hashable] = {("msg", msg.get_msgId())}
        text = name
        barrier = name in _MAV_BARRIER_MESSAGES
        run = False
        throttle_field: str | None = None
        tolerance = 0.0
        if name in ("COMMAND_LONG", "COMMAND_INT"):
            data.pop("confirmation", None)
            command = int(data["command"])
            asks.add(("ack", command))
            if command == 512:
                asks.add(("msg", int(data["param1"])))
            if command == 520:
                asks.add(("msg", 148))
            barrier = command not in _MAV_QUERY_COMMANDS
            params = ", ".join(_num(data.get(f"param{i}")) for i in range(1, 8))
            label = _MAV_COMMAND_NAMES.get(command)
            text = f"{name} {command}" + (f" {label}" if label else "") + f" ({params})"
            if command == 209:  # DO_MOTOR_TEST: param3 is the throttle (0 stops)
                run = float(data["param3"]) != 0.0 and float(data["param4"]) != 0.0
                throttle_field = "param3"
                tolerance = 50.0 if int(data["param2"]) == 1 else 5.0
            elif command == 310:  # ACTUATOR_TEST: param1 the value, NaN stops
                run = not math.isnan(float(data["param1"]))
                throttle_field = "param1"
                tolerance = 0.05
            elif command == 400:
                run = float(data["param1"]) == 1.0
        elif name in ("PARAM_REQUEST_READ", "PARAM_SET"):
            pid = _text(data.get("param_id"))
            asks.add(("param", pid))
            text = f"{name} {pid}"
        elif name in ("PARAM_VALUE", "PARAM_ERROR"):
            pid = _text(data.get("param_id"))
            answers.add(("param", pid))
            text = f"{name} {pid}"
        elif name == "COMMAND_ACK":
            answers.add(("ack", int(data["command"])))
            text = f"COMMAND_ACK {data['command']} result {data['result']}"
        fields = tuple(sorted((k, v) for k, v in data.items()))
        return Message(
            name=name,
            fields=fields,
            text=text,
            barrier=barrier,
            run=run,
            asks=frozenset(asks),
            answers=frozenset(answers),
            throttle_field=throttle_field,
            throttle_tolerance=tolerance,
        )


def _text(value: Any) -> str:
    if isinstance(value, bytes):
        value = value.decode("ascii", "replace")
    return str(value).rstrip("\x00")


def _num(value: Any) -> str:
    try:
        number = float(value)
    except (TypeError, ValueError):
        return str(value)
    return "nan" if math.isnan(number) else f"{number:g}"


# -- MSP --------------------------------------------------------------------------------------
_MSP_STOP_VALUE = 1000  # Betaflight's mincommand: a SET_MOTOR value at or below it stops
_MSP_NAMES = {int(c): c.name for c in MspCommand}


class MspProtocol(Protocol):
    name = "MSP"

    def split(self, buf: bytes) -> tuple[list[bytes], int]:
        chunks: list[bytes] = []
        pos, n = 0, len(buf)
        while pos < n:
            if buf[pos] != 0x24:  # '$'
                end = buf.find(b"$", pos)
                end = n if end < 0 else end
                chunks.append(buf[pos:end])
                pos = end
                continue
            if n - pos < 3:
                break
            proto = buf[pos + 1]
            if proto == 0x4D:  # 'M'
                if n - pos < 5:
                    break
                size, header = buf[pos + 3], 5
                if size == 255:
                    if n - pos < 7:
                        break
                    size, header = buf[pos + 5] | (buf[pos + 6] << 8), 7
            elif proto == 0x58:  # 'X'
                if n - pos < 8:
                    break
                size, header = buf[pos + 6] | (buf[pos + 7] << 8), 8
            else:
                chunks.append(buf[pos : pos + 1])
                pos += 1
                continue
            total = header + size + 1
            if n - pos < total:
                break
            chunks.append(buf[pos : pos + total])
            pos += total
        return chunks, pos

    def decode(self, frame: bytes) -> Message | None:
        frames = MspDecoder().feed(frame)
        if len(frames) != 1:
            return None
        return self._message(frames[0])

    def _message(self, frame: MspFrame) -> Message:
        cmd = frame.cmd
        name = _MSP_NAMES.get(cmd, f"MSP {cmd}")
        key = ("cmd", cmd)
        if frame.direction is not MspDirection.REQUEST:
            return Message(
                name=name, fields=(("payload", frame.payload),), text=name, answers=frozenset({key})
            )
        barrier = cmd in (68, 99) or cmd >= 200
        run = False
        throttle_field: str | None = None
        fields: tuple[tuple[str, Any], ...] = (("payload", frame.payload),)
        text = name + (f" {frame.payload.hex()}" if frame.payload else "")
        if cmd == MspCommand.SET_MOTOR and len(frame.payload) % 2 == 0:
            values = struct.unpack(f"<{len(frame.payload) // 2}H", frame.payload)
            fields = (("motors", values),)
            run = any(v > _MSP_STOP_VALUE for v in values)
            throttle_field = "motors"
            text = f"{name} {' '.join(str(v) for v in values)}"
        return Message(
            name=name,
            fields=fields,
            text=text,
            barrier=barrier,
            run=run,
            asks=frozenset({key}),
            throttle_field=throttle_field,
            throttle_tolerance=50.0,
        )


def detect_protocol(events: Sequence[TranscriptEvent]) -> Protocol | None:
    """The protocol the recorded writes speak (MAVLink or MSP), or None (match bytes)."""
    written = b"".join(e.data for e in events if e.direction == "w")[:4096]
    if not written:
        return None
    candidates: list[Protocol] = []
    if written[:2] in (b"$M", b"$X"):
        candidates.append(MspProtocol())
    if written[0] in (0xFD, 0xFE):
        candidates.append(MavlinkProtocol())
    for proto in candidates:  # the first frame must decode, or it is some other protocol
        frames, _ = proto.split(written)
        if frames and proto.decode(frames[0]) is not None:
            return proto
    return None
