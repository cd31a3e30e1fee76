"""Tyto Robotics / RCbenchmark Series 1585 serial protocol (binary): a pure codec.

The protocol is not documented by Tyto; this follows the public reverse-engineered description:

- 250000 baud. After opening the port the stand prints the line ``Ready\\r\\n``; send nothing
  before it.
- Request: ``$R<`` + u8 length + u8 code + payload + u8 XOR(length, code, payload).
  Reply:   ``$R>`` + the same layout. ``length`` counts the payload bytes.
- Poll: code 3 with payload ``<HHHH`` = (ESC µs, servo 1 µs, servo 2 µs, servo 3 µs); the
  throttle is re-sent on every poll (~33 Hz).
- Poll reply payload ``<ffffffffffchhhhhhfc`` (58 bytes), in this order:

  ====  ================  =====================================================
  #     field             meaning
  ====  ================  =====================================================
  0     esc_voltage       V (float)
  1     esc_current       A (float)
  2     esc_power         W (float)
  3     load_thrust       thrust load cell, raw counts (float)
  4     load_left         left torque load cell, raw counts (float)
  5     rot_e             electrical speed (float; see ``electrical_rpm_factor``)
  6     rot_o             optical speed (float; see ``optical_rpm_factor``)
  7-9   temp0..temp2      °C (float)
  10    basic_data_flag   char
  11-13 acc_x/y/z         raw (i16)
  14    vibration         raw (i16)
  15-16 raw_pressure_p/t  raw (i16)
  17    load_right        right torque load cell, raw counts (float)
  18    pro_data_flag     char
  ====  ================  =====================================================

Load cells are raw: :class:`TytoCalibration` (per unit, a small JSON file) turns them into SI:
``thrust_n = (load_thrust - tare) * n_per_count`` (choose the sign so a pulling propeller is
positive; the RCbenchmark app shows it negative) and
``torque_nm = arm_length_m * (F_left - F_right)`` with each ``F = (raw - tare) * n_per_count``
and ``arm_length_m`` the distance from the motor axis to each torque cell.

:class:`TytoDecoder` is incremental like the MSP decoder: ``feed_events`` returns frames,
:class:`TytoReady` banner events and :class:`TytoProtocolError` instances in stream order and
never raises; ``feed`` returns only frames.
"""

from __future__ import annotations

import struct
from collections import deque
from dataclasses import dataclass, fields, replace
from typing import Any

from thrustmap.core.errors import ConfigError, ThrustmapError

TYTO_BAUDRATE = 250_000
TYTO_READY_LINE = "Ready"
TYTO_POLL_CODE = 3
TYTO_REQUEST = "<"
TYTO_REPLY = ">"

_READING = struct.Struct("<ffffffffffchhhhhhfc")  # 58 bytes
_POLL = struct.Struct("<HHHH")


class TytoProtocolError(ThrustmapError):
    """A malformed Series 1585 frame (returned as an event by the decoder, never raised)."""


class TytoChecksumError(TytoProtocolError):
    pass


class TytoPayloadError(TytoProtocolError):
    """A payload of the wrong size for its code (raised by ``decode``)."""


class TytoCalibrationError(ConfigError):
    """A calibration file that is missing, not JSON, or lacks a valid field."""


@dataclass(frozen=True)
class TytoFrame:
    direction: str  # "<" request, ">" reply
    code: int
    payload: bytes = b""

    def encode(self) -> bytes:
        if len(self.payload) > 255:
            raise ValueError(f"Tyto payload too long: {len(self.payload)} bytes")
        body = bytes((len(self.payload), self.code)) + self.payload
        xor = 0
        for byte in body:
            xor ^= byte
        return b"$R" + self.direction.encode() + body + bytes((xor,))


@dataclass(frozen=True)
class TytoReady:
    """The stand printed ``Ready``: it now accepts requests."""


TytoEvent = TytoFrame | TytoReady | TytoProtocolError


class TytoDecoder:
    """Incremental decoder of one direction (``">"`` on the host, ``"<"`` on a stand)."""

    def __init__(self, direction: str = TYTO_REPLY, max_kept_errors: int = 64) -> None:
        if direction not in (TYTO_REQUEST, TYTO_REPLY):
            raise ValueError(f"direction must be '<' or '>', got {direction!r}")
        self._magic = b"$R" + direction.encode()
        self.direction = direction
        self._buf = bytearray()
        self._line = bytearray()
        self.ready_seen = False
        self.errors: deque[TytoProtocolError] = deque(maxlen=max_kept_errors)
        self.error_count = 0
        self.skipped_bytes = 0

    def feed(self, data: bytes | bytearray | memoryview) -> list[TytoFrame]:
        frames: list[TytoFrame] = []
        for event in self.feed_events(data):
            if isinstance(event, TytoFrame):
                frames.append(event)
            elif isinstance(event, TytoProtocolError):
                self.errors.append(event)
        return frames

    def feed_events(self, data: bytes | bytearray | memoryview) -> list[TytoEvent]:
        buf = self._buf
        buf += data
        events: list[TytoEvent] = []
        pos = 0
        n = len(buf)
        while True:
            start = buf.find(b"$", pos)
            text_end = n if start < 0 else start
            self._text(buf[pos:text_end], events)
            if start < 0:
                pos = n
                break
            pos = start
            if n - start < 3:
                break
            if buf[start : start + 3] != self._magic:
                self._text(buf[start : start + 1], events)
                pos = start + 1
                continue
            if n - start < 6:
                break
            size = buf[start + 3]
            end = start + 6 + size
            if n < end:
                break
            xor = 0
            for byte in memoryview(buf)[start + 3 : end - 1]:
                xor ^= byte
            code = buf[start + 4]
            if xor != buf[end - 1]:
                self.error_count += 1
                events.append(
                    TytoChecksumError(
                        f"Tyto code {code}: checksum 0x{buf[end - 1]:02x}, computed 0x{xor:02x}"
                    )
                )
                self._text(buf[start : start + 1], events)
                pos = start + 1
                continue
            events.append(TytoFrame(self.direction, code, bytes(buf[start + 5 : end - 1])))
            pos = end
        del buf[:pos]
        return events

    def _text(self, chunk: bytes | bytearray, events: list[TytoEvent]) -> None:
        """Bytes outside frames: collect lines, report the ``Ready`` banner."""
        for byte in chunk:
            if byte == 0x0A:
                if self._line.strip() == TYTO_READY_LINE.encode():
                    self.ready_seen = True
                    events.append(TytoReady())
                else:
                    self.skipped_bytes += len(self._line) + 1
                self._line.clear()
            elif len(self._line) < 256:
                self._line.append(byte)
            else:
                self.skipped_bytes += 1


@dataclass(frozen=True)
class TytoPoll:
    """Poll request (code 3): the ESC and servo pulse widths in µs, re-sent on every poll."""

    esc_us: int
    servo1_us: int = 0
    servo2_us: int = 0
    servo3_us: int = 0

    def encode(self) -> bytes:
        return _POLL.pack(self.esc_us, self.servo1_us, self.servo2_us, self.servo3_us)

    def frame(self) -> bytes:
        return TytoFrame(TYTO_REQUEST, TYTO_POLL_CODE, self.encode()).encode()

    @classmethod
    def decode(cls, payload: bytes) -> TytoPoll:
        if len(payload) != _POLL.size:
            raise TytoPayloadError(f"Tyto poll: expected 8 payload bytes, got {len(payload)}")
        return cls(*_POLL.unpack(payload))


@dataclass(frozen=True)
class TytoReading:
    """The poll reply, field by field as on the wire (load cells raw)."""

    esc_voltage: float
    esc_current: float
    esc_power: float
    load_thrust: float
    load_left: float
    rot_e: float
    rot_o: float
    temp0: float
    temp1: float
    temp2: float
    basic_data_flag: int
    acc_x: int
    acc_y: int
    acc_z: int
    vibration: int
    raw_pressure_p: int
    raw_pressure_t: int
    load_right: float
    pro_data_flag: int

    def encode(self) -> bytes:
        values: list[Any] = [getattr(self, f.name) for f in fields(self)]
        values[10] = bytes((values[10],))
        values[18] = bytes((values[18],))
        return _READING.pack(*values)

    def frame(self) -> bytes:
        return TytoFrame(TYTO_REPLY, TYTO_POLL_CODE, self.encode()).encode()

    @classmethod
    def decode(cls, payload: bytes) -> TytoReading:
        if len(payload) != _READING.size:
            raise TytoPayloadError(
                f"Tyto poll reply: expected {_READING.size} payload bytes, got {len(payload)}"
            )
        values: list[Any] = list(_READING.unpack(payload))
        values[10] = values[10][0]
        values[18] = values[18][0]
        return cls(*values)


@dataclass(frozen=True)
class TytoMeasurement:
    """One poll reply in SI units, pulling thrust positive."""

    thrust_n: float
    torque_nm: float
    voltage_v: float
    current_a: float
    power_w: float
    rpm_electrical: float
    rpm_optical: float
    temperatures_c: tuple[float, float, float]
    vibration_g: float | None = None


@dataclass(frozen=True)
class LoadCell:
    """``force_n = (raw - tare) * n_per_count``."""

    tare: float
    n_per_count: float

    def force_n(self, raw: float) -> float:
        return (raw - self.tare) * self.n_per_count

    def raw(self, force_n: float) -> float:
        return force_n / self.n_per_count + self.tare

    @classmethod
    def from_two_points(cls, raw_unloaded: float, raw_loaded: float, force_n: float) -> LoadCell:
        """Calibrate from a reading at rest and one with a known force (mass × g)."""
        if raw_loaded == raw_unloaded:
            raise TytoCalibrationError("load cell calibration: the two readings are equal")
        return cls(raw_unloaded, force_n / (raw_loaded - raw_unloaded))


@dataclass(frozen=True)
class TytoCalibration:
    """Per-unit calibration of a Series 1585 (load cells, rpm factors)."""

    thrust: LoadCell
    torque_left: LoadCell
    torque_right: LoadCell
    arm_length_m: float
    electrical_rpm_factor: float = 1.0  # rot_e -> mechanical rpm
    optical_rpm_factor: float = 1.0  # rot_o -> mechanical rpm (1 / reflective strips)
    vibration_g_per_count: float | None = None
    serial: str = ""

    def to_si(self, reading: TytoReading) -> TytoMeasurement:
        torque = self.arm_length_m * (
            self.torque_left.force_n(reading.load_left)
            - self.torque_right.force_n(reading.load_right)
        )
        vib = None
        if self.vibration_g_per_count is not None:
            vib = reading.vibration * self.vibration_g_per_count
        return TytoMeasurement(
            thrust_n=self.thrust.force_n(reading.load_thrust),
            torque_nm=torque,
            voltage_v=reading.esc_voltage,
            current_a=reading.esc_current,
            power_w=reading.esc_power,
            rpm_electrical=reading.rot_e * self.electrical_rpm_factor,
            rpm_optical=reading.rot_o * self.optical_rpm_factor,
            temperatures_c=(reading.temp0, reading.temp1, reading.temp2),
            vibration_g=vib,
        )

    def raw_counts(self, thrust_n: float, torque_nm: float) -> tuple[float, float, float]:
        """Inverse (for simulators): raw (thrust, left, right) for a force and a torque, the
        torque split evenly between the two cells."""
        half = torque_nm / (2.0 * self.arm_length_m)
        return (
            self.thrust.raw(thrust_n),
            self.torque_left.raw(half),
            self.torque_right.raw(-half),
        )

    def tared(self, at_rest: TytoReading) -> TytoCalibration:
        """The same calibration with all tares taken from a reading at rest."""
        return replace(
            self,
            thrust=replace(self.thrust, tare=at_rest.load_thrust),
            torque_left=replace(self.torque_left, tare=at_rest.load_left),
            torque_right=replace(self.torque_right, tare=at_rest.load_right),
        )
