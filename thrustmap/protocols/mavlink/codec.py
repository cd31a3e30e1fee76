"""MAVLink helpers on pymavlink: motor-test commands, telemetry decoded into SI dataclasses.

MAVLink 2 everywhere, chosen by module, not by environment: this module imports pymavlink's
generated v2.0 ``ardupilotmega`` dialect directly (it includes common.xml), so encoding and
parsing are MAVLink 2 whatever ``MAVLINK20`` says and whether or not ``mavutil`` was imported
first. (``thrustmap.protocols.mavlink.link`` builds its connections on the same v2.0 dialect.)
Framing, CRCs and field packing are pymavlink's; nothing here
re-implements them. Functions only, no I/O: ``MavlinkCodec`` turns messages into bytes and bytes
(in any chunking) into messages.

Encoders for telemetry (``*_message``) live in ``thrustmap.protocols.mavlink.encode``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from enum import IntEnum
from typing import Any, Union

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from thrustmap.core.errors import ConfigError
from thrustmap.protocols.mavlink.ext import register_extensions
from thrustmap.protocols.mavlink.params import (
    ParamEncoding,
    ParamType,
    decode_param,
    encode_param_float,
    float_field_bytes,
)

register_extensions()

MAV_CMD_DO_MOTOR_TEST = 209
MAV_CMD_ACTUATOR_TEST = 310
MAV_CMD_SET_MESSAGE_INTERVAL = 511
MAV_CMD_REQUEST_MESSAGE = 512
MSG_HEARTBEAT = 0
MSG_SYS_STATUS = 1
MSG_SERVO_OUTPUT_RAW = 36
MSG_BATTERY_STATUS = 147
MSG_AUTOPILOT_VERSION = 148
MSG_ESC_STATUS = 291
MSG_ESC_TELEMETRY_1_TO_4 = 11030
MSG_ESC_TELEMETRY_5_TO_8 = 11031
FIRMWARE_TYPES = {0: "dev", 64: "alpha", 128: "beta", 192: "rc", 255: "official"}
MAV_MODE_FLAG_SAFETY_ARMED = 128
MAV_TYPE_QUADROTOR = 2
MAV_TYPE_GCS = 6
MAV_AUTOPILOT_INVALID = 8
UINT16_MAX = 65535
INT16_MAX = 32767
ESC_TELEMETRY_FIRST_INDEX = {11030: 0, 11031: 4, 11032: 8, 11040: 12, 11041: 16, 11042: 20}
ARDUPILOT_MOTOR_TEST_MAX_TIMEOUT_S = 600.0  # ArduCopter's limit
ARDUPILOT_MOTOR_TEST_PWM_RANGE_US = (800, 2200)  # outside this a test stops
PX4_ACTUATOR_TEST_MAX_TIMEOUT_S = 3.0


class MavResult(IntEnum):
    ACCEPTED = 0
    TEMPORARILY_REJECTED = 1
    DENIED = 2
    UNSUPPORTED = 3
    FAILED = 4
    IN_PROGRESS = 5
    CANCELLED = 6
    COMMAND_LONG_ONLY = 7
    COMMAND_INT_ONLY = 8
    UNSUPPORTED_MAV_FRAME = 9


class Autopilot(IntEnum):
    GENERIC = 0
    ARDUPILOT = 3
    INVALID = 8
    PX4 = 12


class MotorTestThrottleType(IntEnum):
    PERCENT = 0
    PWM = 1
    PILOT = 2
    COMPASS_CAL = 3


class Severity(IntEnum):
    EMERGENCY = 0
    ALERT = 1
    CRITICAL = 2
    ERROR = 3
    WARNING = 4
    NOTICE = 5
    INFO = 6
    DEBUG = 7


def _enum_or_int(enum: type[IntEnum], value: int) -> Any:
    try:
        return enum(value)
    except ValueError:
        return int(value)


# ---------------------------------------------------------------------------------------------
# Commands
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class CommandLong:
    """A COMMAND_LONG, independent of pymavlink objects (so it can be compared and printed)."""

    command: int
    params: tuple[float, float, float, float, float, float, float]
    target_system: int = 1
    target_component: int = 1
    confirmation: int = 0

    def to_message(self) -> Any:
        return mavlink2.MAVLink_command_long_message(
            self.target_system, self.target_component, self.command, self.confirmation, *self.params
        )

    @classmethod
    def from_message(cls, msg: Any) -> CommandLong:
        params = (
            float(msg.param1),
            float(msg.param2),
            float(msg.param3),
            float(msg.param4),
            float(msg.param5),
            float(msg.param6),
            float(msg.param7),
        )
        return cls(
            command=int(msg.command),
            params=params,
            target_system=int(msg.target_system),
            target_component=int(msg.target_component),
            confirmation=int(msg.confirmation),
        )


def _params(*values: float) -> tuple[float, float, float, float, float, float, float]:
    padded = [float(v) for v in values] + [0.0] * (7 - len(values))
    return (padded[0], padded[1], padded[2], padded[3], padded[4], padded[5], padded[6])


def motor_test(
    motor_instance: int,
    value: float,
    *,
    timeout_s: float,
    throttle_type: MotorTestThrottleType = MotorTestThrottleType.PWM,
    motor_count: int = 0,
    target_system: int = 1,
    target_component: int = 1,
) -> CommandLong:
    """ArduPilot MAV_CMD_DO_MOTOR_TEST (209).

    ``motor_instance`` is ArduCopter's test-order number (1..N), not an output channel.
    ``value`` is µs for PWM (800..2200 runs; use ``motor_test_stop`` to stop) or 0..100 for
    PERCENT. ``timeout_s`` 0..600 (0 stops). ``motor_count`` 0/1 = one motor.
    """
    if motor_instance < 1:
        raise ConfigError(
            f"motor test instance must be >= 1 (ArduCopter counts from 1), got {motor_instance}"
        )
    if not 0.0 <= timeout_s <= ARDUPILOT_MOTOR_TEST_MAX_TIMEOUT_S or math.isnan(timeout_s):
        raise ConfigError(f"motor test timeout must be 0..600 s, got {timeout_s}")
    if throttle_type == MotorTestThrottleType.PERCENT and not 0.0 <= value <= 100.0:
        raise ConfigError(f"motor test throttle in percent must be 0..100, got {value}")
    if throttle_type == MotorTestThrottleType.PWM and not 0.0 <= value <= 2500.0:
        raise ConfigError(f"motor test PWM must be 0..2500 µs (800..2200 runs), got {value}")
    if motor_count < 0:
        raise ConfigError(f"motor count must be >= 0, got {motor_count}")
    return CommandLong(
        MAV_CMD_DO_MOTOR_TEST,
        _params(motor_instance, int(throttle_type), value, timeout_s, motor_count, 0, 0),
        target_system,
        target_component,
    )


def motor_test_stop(
    motor_instance: int = 1, *, target_system: int = 1, target_component: int = 1
) -> CommandLong:
    """Stop an ArduPilot motor test at once: PWM 0 (outside 800..2200) and timeout 0."""
    return motor_test(
        motor_instance,
        0.0,
        timeout_s=0.0,
        throttle_type=MotorTestThrottleType.PWM,
        target_system=target_system,
        target_component=target_component,
    )


def actuator_output_function(motor: int) -> int:
    """ACTUATOR_OUTPUT_FUNCTION_MOTORn for motor n = 1..16 (the enum value is n)."""
    if not 1 <= motor <= 16:
        raise ConfigError(f"PX4 actuator test addresses MOTOR1..16, got motor {motor}")
    return motor


def actuator_test(
    motor: int,
    value: float,
    *,
    timeout_s: float = PX4_ACTUATOR_TEST_MAX_TIMEOUT_S,
    target_system: int = 1,
    target_component: int = 1,
) -> CommandLong:
    """PX4 MAV_CMD_ACTUATOR_TEST (310) for MOTOR``motor``.

    ``value`` -1..1, or NaN to stop. ``timeout_s`` is clamped to (0, 3] as PX4 does (PX4 turns 0
    or anything above 3 into 3): a sweep must re-send well inside 3 s.
    """
    if not math.isnan(value) and not -1.0 <= value <= 1.0:
        raise ConfigError(f"actuator test value must be -1..1 or NaN (stop), got {value}")
    if math.isnan(timeout_s) or timeout_s < 0:
        raise ConfigError(f"actuator test timeout must be >= 0 s, got {timeout_s}")
    timeout = PX4_ACTUATOR_TEST_MAX_TIMEOUT_S if timeout_s == 0 else min(timeout_s, 3.0)
    return CommandLong(
        MAV_CMD_ACTUATOR_TEST,
        _params(value, timeout, 0, 0, actuator_output_function(motor), 0, 0),
        target_system,
        target_component,
    )


def actuator_test_stop(
    motor: int, *, target_system: int = 1, target_component: int = 1
) -> CommandLong:
    return actuator_test(
        motor, math.nan, target_system=target_system, target_component=target_component
    )


def set_message_interval(
    message_id: int, interval_s: float | None, *, target_system: int = 1, target_component: int = 1
) -> CommandLong:
    """MAV_CMD_SET_MESSAGE_INTERVAL: ``interval_s`` None disables, 0 restores the default."""
    interval_us = -1.0 if interval_s is None else round(interval_s * 1e6)
    return CommandLong(
        MAV_CMD_SET_MESSAGE_INTERVAL,
        _params(message_id, interval_us),
        target_system,
        target_component,
    )


def request_message(
    message_id: int, *, target_system: int = 1, target_component: int = 1
) -> CommandLong:
    """MAV_CMD_REQUEST_MESSAGE (512): ask the vehicle to send ``message_id`` once."""
    return CommandLong(
        MAV_CMD_REQUEST_MESSAGE, _params(message_id), target_system, target_component
    )


def decode_flight_sw_version(value: int) -> str:
    """AUTOPILOT_VERSION.flight_sw_version -> "1.14.3" (with "-beta"/"-rc"/"-dev" if not official)."""
    major, minor, patch = (value >> 24) & 0xFF, (value >> 16) & 0xFF, (value >> 8) & 0xFF
    text = f"{major}.{minor}.{patch}"
    label = FIRMWARE_TYPES.get(value & 0xFF, "")
    return text if label in ("official", "") else f"{text}-{label}"


def param_request_read(name: str, *, target_system: int = 1, target_component: int = 1) -> Any:
    return mavlink2.MAVLink_param_request_read_message(
        target_system, target_component, name.encode("ascii"), -1
    )


def param_set(
    name: str,
    value: float,
    *,
    param_type: int = ParamType.REAL32,
    encoding: ParamEncoding = ParamEncoding.C_CAST,
    target_system: int = 1,
    target_component: int = 1,
) -> Any:
    """PARAM_SET with ``value`` encoded for ``param_type`` the way the vehicle reads it."""
    return mavlink2.MAVLink_param_set_message(
        target_system,
        target_component,
        name.encode("ascii"),
        encode_param_float(value, param_type, encoding),
        int(param_type),
    )


# ---------------------------------------------------------------------------------------------
# Telemetry, decoded
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Heartbeat:
    system_id: int
    component_id: int
    autopilot: Autopilot | int
    vehicle_type: int
    base_mode: int
    custom_mode: int
    system_status: int

    @property
    def armed(self) -> bool:
        return bool(self.base_mode & MAV_MODE_FLAG_SAFETY_ARMED)

    @property
    def is_vehicle(self) -> bool:
        return self.autopilot != Autopilot.INVALID and self.vehicle_type != MAV_TYPE_GCS

    @property
    def firmware(self) -> str:
        """ "px4", "ardupilot" or "other"."""
        if self.autopilot == Autopilot.PX4:
            return "px4"
        if self.autopilot == Autopilot.ARDUPILOT:
            return "ardupilot"
        return "other"


@dataclass(frozen=True)
class SysStatus:
    voltage_v: float | None
    current_a: float | None
    remaining_pct: int | None


@dataclass(frozen=True)
class BatteryStatus:
    battery_id: int
    voltages_v: tuple[float, ...]  # the present entries: cell voltages, or the total in [0]
    current_a: float | None
    temperature_c: float | None
    consumed_mah: float | None
    energy_consumed_j: float | None
    remaining_pct: int | None

    @property
    def total_voltage_v(self) -> float | None:
        return sum(self.voltages_v) if self.voltages_v else None

    @property
    def cell_voltages_v(self) -> tuple[float, ...]:
        """Per-cell voltages when the battery reports more than one entry, else ()."""
        return self.voltages_v if len(self.voltages_v) > 1 else ()


@dataclass(frozen=True)
class EscTelemetry:
    first_index: int  # 0 for ESC_TELEMETRY_1_TO_4, 4 for 5_TO_8, ...
    temperature_c: tuple[float, ...]
    voltage_v: tuple[float, ...]
    current_a: tuple[float, ...]
    consumed_mah: tuple[float, ...]
    rpm: tuple[float, ...]
    count: tuple[int, ...]


@dataclass(frozen=True)
class EscStatus:
    first_index: int
    time_s: float
    rpm: tuple[float, ...]
    voltage_v: tuple[float, ...]
    current_a: tuple[float, ...]


@dataclass(frozen=True)
class ServoOutputRaw:
    time_s: float
    port: int
    outputs_us: tuple[int, ...]  # servo1..servo16 raw µs (0 = output not used)


@dataclass(frozen=True)
class CommandAck:
    command: int
    result: MavResult | int
    progress: int = 0
    result_param2: int = 0

    @property
    def accepted(self) -> bool:
        return self.result == MavResult.ACCEPTED


@dataclass(frozen=True)
class StatusText:
    severity: Severity | int
    text: str


@dataclass(frozen=True)
class ParamValue:
    """A PARAM_VALUE as it came: the value field's 4 wire bytes and its MAV_PARAM_TYPE.

    There is deliberately no ``value``: an integer's number depends on the vehicle's encoding
    (see ``thrustmap.protocols.mavlink.params``); ask ``number(encoding)``.
    """

    name: str
    raw: bytes
    param_type: int
    index: int
    count: int

    def number(self, encoding: ParamEncoding) -> float:
        return decode_param(self.raw, self.param_type, encoding)


@dataclass(frozen=True)
class ParamError:
    """PARAM_ERROR (345): the vehicle has no such parameter (or could not read or set it)."""

    name: str
    index: int
    error: int


@dataclass(frozen=True)
class AutopilotVersion:
    capabilities: int
    flight_sw_version: int
    board_version: int

    @property
    def version_text(self) -> str:
        return decode_flight_sw_version(self.flight_sw_version)


Decoded = Union[  # noqa: UP007 - a runtime alias must work on Python 3.10
    Heartbeat,
    SysStatus,
    BatteryStatus,
    EscTelemetry,
    EscStatus,
    ServoOutputRaw,
    CommandAck,
    StatusText,
    ParamValue,
    ParamError,
    AutopilotVersion,
]


def decode_text(value: Any) -> str:
    if isinstance(value, (bytes, bytearray)):
        return bytes(value).split(b"\x00", 1)[0].decode("utf-8", errors="replace")
    return str(value).split("\x00", 1)[0]


def decode_heartbeat(msg: Any) -> Heartbeat:
    return Heartbeat(
        system_id=int(msg.get_srcSystem()),
        component_id=int(msg.get_srcComponent()),
        autopilot=_enum_or_int(Autopilot, msg.autopilot),
        vehicle_type=int(msg.type),
        base_mode=int(msg.base_mode),
        custom_mode=int(msg.custom_mode),
        system_status=int(msg.system_status),
    )


def decode_sys_status(msg: Any) -> SysStatus:
    mv, ca, pct = int(msg.voltage_battery), int(msg.current_battery), int(msg.battery_remaining)
    if ca == -100:  # PX4 sends its "no current sensor" (-1 A) as -100 cA, not MAVLink's -1
        ca = -1
    return SysStatus(
        voltage_v=None if mv == UINT16_MAX else mv / 1000.0,
        current_a=None if ca == -1 else ca / 100.0,
        remaining_pct=None if pct == -1 else pct,
    )


def decode_battery_status(msg: Any) -> BatteryStatus:
    cells = [int(v) for v in msg.voltages if int(v) != UINT16_MAX]
    cells += [
        int(v) for v in getattr(msg, "voltages_ext", ()) or () if int(v) not in (0, UINT16_MAX)
    ]
    ca, temp = int(msg.current_battery), int(msg.temperature)
    if ca == -100:  # PX4 sends its "no current sensor" (-1 A) as -100 cA, not MAVLink's -1
        ca = -1
    consumed, energy, pct = (
        int(msg.current_consumed),
        int(msg.energy_consumed),
        int(msg.battery_remaining),
    )
    return BatteryStatus(
        battery_id=int(msg.id),
        voltages_v=tuple(mv / 1000.0 for mv in cells),
        current_a=None if ca == -1 else ca / 100.0,
        temperature_c=None if temp == INT16_MAX else temp / 100.0,
        consumed_mah=None if consumed == -1 else float(consumed),
        energy_consumed_j=None if energy == -1 else energy * 100.0,
        remaining_pct=None if pct == -1 else pct,
    )


def decode_esc_telemetry(msg: Any) -> EscTelemetry:
    return EscTelemetry(
        first_index=ESC_TELEMETRY_FIRST_INDEX.get(int(msg.get_msgId()), 0),
        temperature_c=tuple(float(t) for t in msg.temperature),
        voltage_v=tuple(v / 100.0 for v in msg.voltage),
        current_a=tuple(c / 100.0 for c in msg.current),
        consumed_mah=tuple(float(c) for c in msg.totalcurrent),
        rpm=tuple(float(r) for r in msg.rpm),
        count=tuple(int(c) for c in msg.count),
    )


def decode_esc_status(msg: Any) -> EscStatus:
    return EscStatus(
        first_index=int(msg.index),
        time_s=int(msg.time_usec) / 1e6,
        rpm=tuple(float(r) for r in msg.rpm),
        voltage_v=tuple(float(v) for v in msg.voltage),
        current_a=tuple(float(c) for c in msg.current),
    )


def decode_servo_output_raw(msg: Any) -> ServoOutputRaw:
    outputs = tuple(int(getattr(msg, f"servo{i}_raw", 0) or 0) for i in range(1, 17))
    return ServoOutputRaw(time_s=int(msg.time_usec) / 1e6, port=int(msg.port), outputs_us=outputs)


def decode_command_ack(msg: Any) -> CommandAck:
    return CommandAck(
        command=int(msg.command),
        result=_enum_or_int(MavResult, msg.result),
        progress=int(getattr(msg, "progress", 0) or 0),
        result_param2=int(getattr(msg, "result_param2", 0) or 0),
    )


def decode_statustext(msg: Any) -> StatusText:
    return StatusText(severity=_enum_or_int(Severity, msg.severity), text=decode_text(msg.text))


def _param_value_bytes(msg: Any) -> bytes:
    """The value field's wire bytes (from the frame when there is one: exact even for NaNs)."""
    try:
        frame = bytes(msg.get_msgbuf())
    except (AttributeError, TypeError):
        frame = b""
    header = {0xFD: 10, 0xFE: 6}.get(frame[0], 0) if frame else 0
    if header:
        payload_len = frame[1]
        return frame[header : header + min(4, payload_len)].ljust(4, b"\x00")
    return float_field_bytes(float(msg.param_value))


def decode_param_value(msg: Any) -> ParamValue:
    return ParamValue(
        name=decode_text(msg.param_id),
        raw=_param_value_bytes(msg),
        param_type=int(msg.param_type),
        index=int(msg.param_index),
        count=int(msg.param_count),
    )


def decode_param_error(msg: Any) -> ParamError:
    return ParamError(
        name=decode_text(msg.param_id), index=int(msg.param_index), error=int(msg.error)
    )


def decode_autopilot_version(msg: Any) -> AutopilotVersion:
    return AutopilotVersion(
        capabilities=int(msg.capabilities),
        flight_sw_version=int(msg.flight_sw_version),
        board_version=int(msg.board_version),
    )


_DECODERS: dict[str, Callable[[Any], Decoded]] = {
    "HEARTBEAT": decode_heartbeat,
    "SYS_STATUS": decode_sys_status,
    "BATTERY_STATUS": decode_battery_status,
    "ESC_TELEMETRY_1_TO_4": decode_esc_telemetry,
    "ESC_TELEMETRY_5_TO_8": decode_esc_telemetry,
    "ESC_TELEMETRY_9_TO_12": decode_esc_telemetry,
    "ESC_STATUS": decode_esc_status,
    "SERVO_OUTPUT_RAW": decode_servo_output_raw,
    "COMMAND_ACK": decode_command_ack,
    "STATUSTEXT": decode_statustext,
    "PARAM_VALUE": decode_param_value,
    "PARAM_ERROR": decode_param_error,
    "AUTOPILOT_VERSION": decode_autopilot_version,
}


def decode(msg: Any) -> Decoded | None:
    """The SI dataclass for a pymavlink message this module knows, else None."""
    decoder = _DECODERS.get(msg.get_type())
    return decoder(msg) if decoder is not None else None


# ---------------------------------------------------------------------------------------------
# Bytes <-> messages
# ---------------------------------------------------------------------------------------------
class MavlinkCodec:
    """Pure MAVLink 2 encoder/parser for one endpoint (system/component id, sequence numbers)."""

    def __init__(self, system_id: int = 255, component_id: int = 0) -> None:
        self._mav = mavlink2.MAVLink(None, srcSystem=system_id, srcComponent=component_id)
        self._mav.robust_parsing = True
        self.bad_frames = 0

    @property
    def mav(self) -> Any:
        """The underlying pymavlink ``MAVLink`` object."""
        return self._mav

    def encode(self, msg: Any) -> bytes:
        """Pack ``msg`` with this endpoint's ids and next sequence number (as ``MAVLink.send``)."""
        data = bytes(msg.pack(self._mav))
        self._mav.seq = (self._mav.seq + 1) % 256
        return data

    def feed(self, data: bytes) -> list[Any]:
        """Parse any chunk of bytes; returns the complete, CRC-valid messages in order."""
        messages = self._mav.parse_buffer(data) or []
        good = []
        for msg in messages:
            if msg.get_type() == "BAD_DATA" or msg.get_type().startswith("UNKNOWN_"):
                self.bad_frames += 1
            else:
                good.append(msg)
        return good
