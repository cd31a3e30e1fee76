"""MSP motor records and throttle encodings: SET_MOTOR/MOTOR values, motor config and ESC
telemetry, ADVANCED_CONFIG's motor protocol, and the mapping from MSP's "external" motor values
(1000..2000) to what the ESC receives for each protocol.

Records follow the conventions of :mod:`thrustmap.protocols.msp.messages`: ``CMD``, ``encode() -> bytes``, ``decode(payload)``, SI units.

Betaflight's motor protocol enum (ADVANCED_CONFIG) is :class:`MotorProtocol`; INAV numbers its
protocols differently, so INAV drivers should not trust ``AdvancedConfig.protocol``.
"""

from __future__ import annotations

import enum
import struct
from dataclasses import dataclass
from typing import ClassVar

from thrustmap.core.errors import ConfigError
from thrustmap.core.units import SCALES, ThrottleScale
from thrustmap.protocols.msp.framing import MspCommand, MspPayloadError


class MotorProtocol(enum.IntEnum):
    """Betaflight ``motor_pwm_protocol``."""

    PWM = 0
    ONESHOT125 = 1
    ONESHOT42 = 2
    MULTISHOT = 3
    BRUSHED = 4
    DSHOT150 = 5
    DSHOT300 = 6
    DSHOT600 = 7
    PROSHOT1000 = 8
    DISABLED = 9
    DRONECAN = 10

    @property
    def is_digital(self) -> bool:
        return self in (
            MotorProtocol.DSHOT150,
            MotorProtocol.DSHOT300,
            MotorProtocol.DSHOT600,
            MotorProtocol.PROSHOT1000,
        )


#: SET_MOTOR / MOTOR "external" units: 1000 = stop, 2000 = full, whatever the protocol.
MSP_MOTOR_SCALE = ThrottleScale("msp", 1000.0, 2000.0, "ext")
MSP_MOTOR_STOP = 1000
DSHOT_MIN = 48
DSHOT_MAX = 2047

_PULSE_SCALE = {
    MotorProtocol.PWM: "pwm",
    MotorProtocol.ONESHOT125: "oneshot125",
    MotorProtocol.ONESHOT42: "oneshot42",
    MotorProtocol.MULTISHOT: "multishot",
    MotorProtocol.BRUSHED: "percent",
}


def throttle_scale_for(protocol: MotorProtocol) -> ThrottleScale:
    """The native scale of the ESC signal: PWM 1000..2000 µs, ONESHOT125 125..250 µs,
    ONESHOT42 42..84 µs, MULTISHOT 5..25 µs, BRUSHED duty %, DShot/ProShot 48..2047."""
    if protocol.is_digital:
        return SCALES["dshot"]
    try:
        return SCALES[_PULSE_SCALE[protocol]]
    except KeyError:
        raise ConfigError(f"motor protocol {protocol.name} has no throttle scale") from None


def external_to_native(value: float, protocol: MotorProtocol) -> float:
    """What the ESC receives for a SET_MOTOR value (clamped to 1000..2000 as the FC does).

    DShot: 1000 -> 0 (the stop command), 1001..2000 -> 48..2047 linearly. Pulse protocols:
    the value passes through unchanged and the timer scales it (ONESHOT125: value/8 µs, ...).
    """
    ext = min(max(float(value), 1000.0), 2000.0)
    if protocol.is_digital:
        if ext < 1001.0:
            return 0.0
        return DSHOT_MIN + (ext - 1001.0) * (DSHOT_MAX - DSHOT_MIN) / 999.0
    return float(throttle_scale_for(protocol).from_pct(MSP_MOTOR_SCALE.to_pct(ext)))


def native_to_external(native: float, protocol: MotorProtocol) -> float:
    """Inverse of :func:`external_to_native` (DShot 0 -> 1000, 48..2047 -> 1001..2000)."""
    if protocol.is_digital:
        if native < DSHOT_MIN:
            return 1000.0
        return 1001.0 + (native - DSHOT_MIN) * 999.0 / (DSHOT_MAX - DSHOT_MIN)
    return float(MSP_MOTOR_SCALE.from_pct(throttle_scale_for(protocol).to_pct(native)))


def external_to_fraction(value: float, protocol: MotorProtocol) -> float:
    """Duty fraction 0..1 a SET_MOTOR value asks for (DShot 1001..2000 -> 0..1; PWM-like
    (v-1000)/1000); 1000 and below is 0."""
    ext = min(max(float(value), 1000.0), 2000.0)
    if protocol.is_digital:
        return 0.0 if ext < 1001.0 else (ext - 1001.0) / 999.0
    return (ext - 1000.0) / 1000.0


def _need(payload: bytes, size: int, what: str) -> None:
    if len(payload) < size:
        raise MspPayloadError(f"{what}: need {size} payload bytes, got {len(payload)}")


def _q(value: float, resolution: float) -> int:
    return int(round(value / resolution))


# --------------------------------------------------------------------------- motors


def _u16_values(payload: bytes, what: str) -> tuple[int, ...]:
    if len(payload) % 2:
        raise MspPayloadError(f"{what}: odd payload length {len(payload)}")
    return struct.unpack(f"<{len(payload) // 2}H", payload)


@dataclass(frozen=True)
class Motor:
    """Reply: the motor values in external units (8 of them; 0 when the protocol is off)."""

    CMD: ClassVar[int] = MspCommand.MOTOR
    values: tuple[int, ...]

    def encode(self) -> bytes:
        return struct.pack(f"<{len(self.values)}H", *self.values)

    @classmethod
    def decode(cls, payload: bytes) -> Motor:
        return cls(_u16_values(payload, "MOTOR"))


@dataclass(frozen=True)
class SetMotor:
    """Request: external values 1000..2000 per motor. Send 8: newer Betaflight answers ``!`` to
    fewer, and INAV needs the full 16 bytes. Use :meth:`for_motors` to pad with stops."""

    CMD: ClassVar[int] = MspCommand.SET_MOTOR
    values: tuple[int, ...]

    @classmethod
    def for_motors(cls, values: dict[int, int] | list[int], total: int = 8) -> SetMotor:
        out = [MSP_MOTOR_STOP] * total
        items = values.items() if isinstance(values, dict) else enumerate(values)
        for index, value in items:
            if not 0 <= index < total:
                raise ConfigError(f"motor index {index} out of range 0..{total - 1}")
            out[index] = int(value)
        return cls(tuple(out))

    @classmethod
    def stop_all(cls, total: int = 8) -> SetMotor:
        return cls((MSP_MOTOR_STOP,) * total)

    def encode(self) -> bytes:
        return struct.pack(f"<{len(self.values)}H", *self.values)

    @classmethod
    def decode(cls, payload: bytes) -> SetMotor:
        return cls(_u16_values(payload, "SET_MOTOR"))


@dataclass(frozen=True)
class MotorConfig:
    """Throttle limits are in external units (1000..2000)."""

    CMD: ClassVar[int] = MspCommand.MOTOR_CONFIG
    min_throttle_ext: int
    max_throttle_ext: int
    min_command_ext: int
    motor_count: int = 4
    motor_poles: int = 14
    use_dshot_telemetry: bool = False
    use_esc_sensor: bool = False
    tail: bytes = b""

    _S: ClassVar[struct.Struct] = struct.Struct("<HHHBBBB")

    def encode(self) -> bytes:
        return (
            self._S.pack(
                self.min_throttle_ext,
                self.max_throttle_ext,
                self.min_command_ext,
                self.motor_count,
                self.motor_poles,
                int(self.use_dshot_telemetry),
                int(self.use_esc_sensor),
            )
            + self.tail
        )

    @classmethod
    def decode(cls, payload: bytes) -> MotorConfig:
        _need(payload, 6, "MOTOR_CONFIG")
        if len(payload) < cls._S.size:  # very old firmware: only the three limits
            lo, hi, cmd = struct.unpack_from("<HHH", payload)
            return cls(lo, hi, cmd, tail=payload[6:])
        v = cls._S.unpack_from(payload)
        return cls(v[0], v[1], v[2], v[3], v[4], bool(v[5]), bool(v[6]), payload[cls._S.size :])


@dataclass(frozen=True)
class EscTelemetry:
    rpm: float  # mechanical rpm
    invalid_pct: float  # bidirectional DShot frames with a bad crc, percent
    temperature_c: float
    voltage_v: float
    current_a: float
    consumed_mah: int


_ESC_TELEM = struct.Struct("<IHBHHH")  # 13 bytes


@dataclass(frozen=True)
class MotorTelemetry:
    CMD: ClassVar[int] = MspCommand.MOTOR_TELEMETRY
    motors: tuple[EscTelemetry, ...]

    def encode(self) -> bytes:
        out = bytearray((len(self.motors),))
        for m in self.motors:
            out += _ESC_TELEM.pack(
                _q(m.rpm, 1.0),
                _q(m.invalid_pct, 0.01),
                _q(m.temperature_c, 1.0),
                _q(m.voltage_v, 0.01),
                _q(m.current_a, 0.01),
                m.consumed_mah,
            )
        return bytes(out)

    @classmethod
    def decode(cls, payload: bytes) -> MotorTelemetry:
        _need(payload, 1, "MOTOR_TELEMETRY")
        count = payload[0]
        _need(payload, 1 + count * _ESC_TELEM.size, "MOTOR_TELEMETRY")
        motors = []
        for i in range(count):
            rpm, invalid, temp, volt, amp, mah = _ESC_TELEM.unpack_from(payload, 1 + 13 * i)
            motors.append(
                EscTelemetry(float(rpm), invalid / 100, float(temp), volt / 100, amp / 100, mah)
            )
        return cls(tuple(motors))


@dataclass(frozen=True)
class AdvancedConfig:
    CMD: ClassVar[int] = MspCommand.ADVANCED_CONFIG
    motor_protocol: int  # raw; see ``protocol`` (Betaflight enum)
    motor_pwm_rate_hz: int = 480
    digital_idle_pct: float = 5.5
    pid_process_denom: int = 1
    use_unsynced_pwm: bool = False
    gyro_sync_denom: int = 1
    tail: bytes = b""

    @property
    def protocol(self) -> MotorProtocol | None:
        try:
            return MotorProtocol(self.motor_protocol)
        except ValueError:
            return None

    def encode(self) -> bytes:
        head = struct.pack(
            "<BBBBHH",
            self.gyro_sync_denom,
            self.pid_process_denom,
            int(self.use_unsynced_pwm),
            self.motor_protocol,
            self.motor_pwm_rate_hz,
            _q(self.digital_idle_pct, 0.01),
        )
        return head + self.tail

    @classmethod
    def decode(cls, payload: bytes) -> AdvancedConfig:
        _need(payload, 8, "ADVANCED_CONFIG")
        gsd, pid, unsynced, proto, rate, idle = struct.unpack_from("<BBBBHH", payload)
        return cls(proto, rate, idle / 100, pid, bool(unsynced), gsd, payload[8:])
