"""MSP (MultiWii Serial Protocol) framing as Betaflight and INAV speak it: a pure codec.

Wire formats (all little-endian)::

    v1          '$' 'M' dir | u8 size | u8 cmd | payload | u8 xor(size, cmd, payload)
    v1 jumbo    '$' 'M' dir | 255 | u8 cmd | u16 size | payload | u8 xor(255, cmd, size, payload)
    v2          '$' 'X' dir | u8 flag | u16 cmd | u16 size | payload | u8 crc8_dvb_s2(flag..payload)
    v2 over v1  a v1 frame with cmd 255 whose payload is the v2 flag..crc (6 + size bytes)

``dir`` is ``<`` (host to FC), ``>`` (reply) or ``!`` (error reply: the request's cmd, empty
payload). Jumbo frames are FC→host only; the FC silently drops any request whose payload is
over :data:`MSP_MAX_REQUEST_PAYLOAD` (192) bytes and any frame with a bad checksum — a client
needs a timeout and resynchronises on the next ``$``.

Decoding (:class:`MspDecoder`) is incremental: feed bytes in any chunking. Errors are NOT
raised; they are returned in stream order as :class:`MspProtocolError` instances from
:meth:`MspDecoder.feed_events` (``MspChecksumError``, ``MspLengthError``), which is friendlier to
a stream: one corrupt frame never hides the good frame after it. :meth:`MspDecoder.feed` returns
only the frames and keeps the errors in ``decoder.errors`` (bounded) and ``decoder.error_count``.
Bytes outside frames (garbage, CLI text) are skipped and counted in ``decoder.skipped_bytes``.
After any error the decoder resumes scanning one byte after the bad frame's ``$``. No input can
make the decoder raise.

Message payloads (typed records in SI units) live in :mod:`thrustmap.protocols.msp.messages`.
"""

from __future__ import annotations

import enum
import logging
from collections import deque
from dataclasses import dataclass

from thrustmap.core.errors import ThrustmapError

log = logging.getLogger(__name__)

#: The FC drops (without reply) any request whose payload is larger than this.
MSP_MAX_REQUEST_PAYLOAD = 192
#: v1 cmd value that announces a v2 frame tunnelled in a v1 payload.
MSP_V2_FRAME_ID = 255
#: v1 size byte that announces a jumbo frame (real size in the following u16).
MSP_JUMBO_SIZE = 255
#: Largest payload the default decoder accepts (firmware buffers are far smaller). A bogus
#: length above this is reported as a length error at once instead of stalling the stream.
DEFAULT_MAX_PAYLOAD = 4096

_DOLLAR = 0x24
_M = 0x4D
_X = 0x58


class MspVersion(enum.Enum):
    V1 = "v1"
    V2 = "v2"
    V2_OVER_V1 = "v2-over-v1"


class MspDirection(enum.Enum):
    REQUEST = "<"
    REPLY = ">"
    ERROR = "!"


_DIR_BY_BYTE = {ord(d.value): d for d in MspDirection}


class MspProtocolError(ThrustmapError):
    """A malformed MSP frame seen on the wire (returned as an event, never raised by decoding)."""

    def __init__(self, message: str, *, cmd: int | None = None, version: MspVersion | None = None):
        super().__init__(message)
        self.cmd = cmd
        self.version = version


class MspChecksumError(MspProtocolError):
    """The v1 XOR or the v2 crc8 does not match; the FC would not answer such a frame."""


class MspLengthError(MspProtocolError):
    """A declared size over the limit, or a v2-over-v1 frame whose inner size does not fit."""


class MspPayloadError(MspProtocolError):
    """A frame's payload is too short or malformed for its command (raised by record decoders)."""


class MspCommand(enum.IntEnum):
    """The command ids thrustmap uses (Betaflight/INAV msp_protocol.h)."""

    API_VERSION = 1
    FC_VARIANT = 2
    FC_VERSION = 3
    BOARD_INFO = 4
    BATTERY_CONFIG = 32
    REBOOT = 68  # never send during a test
    ADVANCED_CONFIG = 90
    SET_ARMING_DISABLED = 99
    STATUS = 101
    MOTOR = 104
    ANALOG = 110
    BATTERY_STATE = 130
    MOTOR_CONFIG = 131
    MOTOR_TELEMETRY = 139
    STATUS_EX = 150
    SET_MOTOR = 214
    INAV_ANALOG = 0x2002  # MSP2_INAV_ANALOG (v2 only)


@dataclass(frozen=True)
class MspFrame:
    """One MSP frame. ``flag`` is the v2 flag byte (0 for v1)."""

    version: MspVersion
    direction: MspDirection
    cmd: int
    payload: bytes = b""
    flag: int = 0

    @property
    def is_error(self) -> bool:
        return self.direction is MspDirection.ERROR

    def encode(self) -> bytes:
        return encode_frame(self)


# --------------------------------------------------------------------------- checksums


def _make_crc8_table(poly: int) -> bytes:
    table = bytearray(256)
    for i in range(256):
        crc = i
        for _ in range(8):
            crc = ((crc << 1) ^ poly) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table[i] = crc
    return bytes(table)


_CRC8_DVB_S2 = _make_crc8_table(0xD5)


def crc8_dvb_s2(data: bytes | bytearray | memoryview, crc: int = 0) -> int:
    """crc8 DVB-S2: polynomial 0xD5, init 0, MSB first, no reflection, no final xor."""
    table = _CRC8_DVB_S2
    for byte in data:
        crc = table[crc ^ byte]
    return crc


def xor_checksum(data: bytes | bytearray | memoryview, start: int = 0) -> int:
    """MSP v1 checksum: XOR of every byte."""
    for byte in data:
        start ^= byte
    return start


# --------------------------------------------------------------------------- encoding


def _v2_body(flag: int, cmd: int, payload: bytes) -> bytes:
    """flag | u16 cmd | u16 size | payload | crc8 — the part after ``$X<``."""
    if not 0 <= cmd <= 0xFFFF:
        raise ValueError(f"MSP v2 cmd must be 0..65535, got {cmd}")
    if len(payload) > 0xFFFF:
        raise ValueError(f"MSP v2 payload too long: {len(payload)} bytes")
    if not 0 <= flag <= 0xFF:
        raise ValueError(f"MSP v2 flag must be 0..255, got {flag}")
    head = bytes((flag, cmd & 0xFF, cmd >> 8, len(payload) & 0xFF, len(payload) >> 8))
    body = head + payload
    return body + bytes((crc8_dvb_s2(body),))


def _v1_frame(direction: MspDirection, cmd: int, payload: bytes) -> bytes:
    size = len(payload)
    if size >= MSP_JUMBO_SIZE:
        if size > 0xFFFF:
            raise ValueError(f"MSP v1 jumbo payload too long: {size} bytes")
        head = bytes((MSP_JUMBO_SIZE, cmd, size & 0xFF, size >> 8))
    else:
        head = bytes((size, cmd))
    return (
        b"$M"
        + direction.value.encode()
        + head
        + payload
        + bytes((xor_checksum(payload, xor_checksum(head)),))
    )


def encode_frame(frame: MspFrame) -> bytes:
    """Encode a frame. v1 cmds are 0..254 (255 is the v2-over-v1 marker); payloads of 255 bytes
    or more use a jumbo header (which only an FC sends)."""
    payload = bytes(frame.payload)
    if frame.version is MspVersion.V1:
        if not 0 <= frame.cmd < MSP_V2_FRAME_ID:
            raise ValueError(f"MSP v1 cmd must be 0..254, got {frame.cmd}; use v2")
        return _v1_frame(frame.direction, frame.cmd, payload)
    body = _v2_body(frame.flag, frame.cmd, payload)
    if frame.version is MspVersion.V2:
        return b"$X" + frame.direction.value.encode() + body
    return _v1_frame(frame.direction, MSP_V2_FRAME_ID, body)


def encode_request(cmd: int, payload: bytes = b"", version: MspVersion = MspVersion.V1) -> bytes:
    return encode_frame(MspFrame(version, MspDirection.REQUEST, cmd, payload))


def encode_reply(cmd: int, payload: bytes = b"", version: MspVersion = MspVersion.V1) -> bytes:
    return encode_frame(MspFrame(version, MspDirection.REPLY, cmd, payload))


def encode_error(cmd: int, version: MspVersion = MspVersion.V1) -> bytes:
    """The FC's answer to an unknown or refused command: ``!`` with the cmd, empty payload."""
    return encode_frame(MspFrame(version, MspDirection.ERROR, cmd, b""))


# --------------------------------------------------------------------------- decoding

MspEvent = MspFrame | MspProtocolError


class MspDecoder:
    """Incremental MSP decoder (v1, jumbo, v2, v2-over-v1; any direction).

    ``max_payload`` caps the declared payload size; an FC-side decoder uses
    :data:`MSP_MAX_REQUEST_PAYLOAD`. See the module docstring for the error policy.
    """

    def __init__(self, max_payload: int = DEFAULT_MAX_PAYLOAD, max_kept_errors: int = 64):
        self.max_payload = max_payload
        self._buf = bytearray()
        self.errors: deque[MspProtocolError] = deque(maxlen=max_kept_errors)
        self.error_count = 0
        self.skipped_bytes = 0
        self.frame_count = 0

    @property
    def pending_bytes(self) -> int:
        """Bytes held back waiting for the rest of a frame."""
        return len(self._buf)

    def reset(self) -> None:
        self._buf.clear()

    def feed(self, data: bytes | bytearray | memoryview) -> list[MspFrame]:
        """Decode what ``data`` completes; errors go to ``errors``/``error_count`` and the log."""
        frames: list[MspFrame] = []
        for event in self.feed_events(data):
            if isinstance(event, MspFrame):
                frames.append(event)
            else:
                self.errors.append(event)
                log.debug("MSP stream: %s", event)
        return frames

    def feed_events(self, data: bytes | bytearray | memoryview) -> list[MspEvent]:
        """Decode what ``data`` completes: frames and protocol errors, in stream order."""
        buf = self._buf
        buf += data
        events: list[MspEvent] = []
        pos = 0
        n = len(buf)
        while True:
            start = buf.find(_DOLLAR, pos)
            if start < 0:
                self.skipped_bytes += n - pos
                pos = n
                break
            self.skipped_bytes += start - pos
            pos = start
            if n - start < 3:
                break
            proto = buf[start + 1]
            direction = _DIR_BY_BYTE.get(buf[start + 2])
            if direction is None or proto not in (_M, _X):
                self.skipped_bytes += 1
                pos = start + 1
                continue
            if proto == _M:
                result = self._parse_v1(buf, start, n, direction)
            else:
                result = self._parse_v2(buf, start, n, direction)
            if result is None:  # incomplete: wait for more bytes
                break
            event, end = result
            events.append(event)
            if isinstance(event, MspFrame):
                self.frame_count += 1
                pos = end
            else:
                self.error_count += 1
                pos = start + 1  # resynchronise on the next '$' after the bad frame's start
        del buf[:pos]
        return events

    def _parse_v1(
        self, buf: bytearray, start: int, n: int, direction: MspDirection
    ) -> tuple[MspEvent, int] | None:
        if n - start < 5:
            return None
        size = buf[start + 3]
        cmd = buf[start + 4]
        body = start + 5
        if size == MSP_JUMBO_SIZE:
            if n - start < 7:
                return None
            size = buf[start + 5] | (buf[start + 6] << 8)
            body = start + 7
        if size > self.max_payload:
            return (
                MspLengthError(
                    f"MSP v1 cmd {cmd}: declared payload {size} bytes > limit {self.max_payload}",
                    cmd=cmd,
                    version=MspVersion.V1,
                ),
                body,
            )
        end = body + size + 1
        if n < end:
            return None
        expected = xor_checksum(memoryview(buf)[start + 3 : end - 1])
        if expected != buf[end - 1]:
            return (
                MspChecksumError(
                    f"MSP v1 cmd {cmd}: checksum 0x{buf[end - 1]:02x}, computed 0x{expected:02x}",
                    cmd=cmd,
                    version=MspVersion.V1,
                ),
                end,
            )
        payload = bytes(buf[body : end - 1])
        if cmd != MSP_V2_FRAME_ID:
            return MspFrame(MspVersion.V1, direction, cmd, payload), end
        return self._unwrap_v2(payload, direction), end

    def _unwrap_v2(self, body: bytes, direction: MspDirection) -> MspEvent:
        if len(body) < 6:
            return MspLengthError(
                f"MSP v2-over-v1: {len(body)} payload bytes cannot hold a v2 header and crc",
                version=MspVersion.V2_OVER_V1,
            )
        cmd = body[1] | (body[2] << 8)
        size = body[3] | (body[4] << 8)
        if size != len(body) - 6:
            return MspLengthError(
                f"MSP v2-over-v1 cmd {cmd}: inner size {size} does not match {len(body) - 6}",
                cmd=cmd,
                version=MspVersion.V2_OVER_V1,
            )
        crc = crc8_dvb_s2(body[:-1])
        if crc != body[-1]:
            return MspChecksumError(
                f"MSP v2-over-v1 cmd {cmd}: crc 0x{body[-1]:02x}, computed 0x{crc:02x}",
                cmd=cmd,
                version=MspVersion.V2_OVER_V1,
            )
        return MspFrame(MspVersion.V2_OVER_V1, direction, cmd, body[5:-1], body[0])

    def _parse_v2(
        self, buf: bytearray, start: int, n: int, direction: MspDirection
    ) -> tuple[MspEvent, int] | None:
        if n - start < 8:
            return None
        flag = buf[start + 3]
        cmd = buf[start + 4] | (buf[start + 5] << 8)
        size = buf[start + 6] | (buf[start + 7] << 8)
        if size > self.max_payload:
            return (
                MspLengthError(
                    f"MSP v2 cmd {cmd}: declared payload {size} bytes > limit {self.max_payload}",
                    cmd=cmd,
                    version=MspVersion.V2,
                ),
                start + 8,
            )
        end = start + 8 + size + 1
        if n < end:
            return None
        crc = crc8_dvb_s2(memoryview(buf)[start + 3 : end - 1])
        if crc != buf[end - 1]:
            return (
                MspChecksumError(
                    f"MSP v2 cmd {cmd}: crc 0x{buf[end - 1]:02x}, computed 0x{crc:02x}",
                    cmd=cmd,
                    version=MspVersion.V2,
                ),
                end,
            )
        return MspFrame(MspVersion.V2, direction, cmd, bytes(buf[start + 8 : end - 1]), flag), end
