"""MAVLink telemetry encoders (SI units in, pymavlink messages out) for simulators and tests.

The inverse of the decoders in ``thrustmap.protocols.mavlink.codec``: unknown values become the
MAVLink sentinels (UINT16_MAX mV, -1 cA, INT16_MAX cdegC, ...). Functions only, no I/O.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from thrustmap.core.errors import ConfigError
from thrustmap.protocols.mavlink.codec import (
    INT16_MAX,
    MAV_MODE_FLAG_SAFETY_ARMED,
    MAV_TYPE_QUADROTOR,
    UINT16_MAX,
    Severity,
)
from thrustmap.protocols.mavlink.ext import MAVLink_esc_status_message

__all__ = [
    "heartbeat_message",
    "sys_status_message",
    "battery_status_message",
    "esc_telemetry_message",
    "esc_status_message",
    "servo_output_raw_message",
    "command_ack_message",
    "statustext_message",
    "param_value_message",
]


# ---------------------------------------------------------------------------------------------
def _u16(value: float | None, scale: float, unknown: int = UINT16_MAX) -> int:
    return unknown if value is None else max(0, min(UINT16_MAX - 1, round(value * scale)))


def heartbeat_message(
    autopilot: int,
    *,
    armed: bool,
    vehicle_type: int = MAV_TYPE_QUADROTOR,
    custom_mode: int = 0,
    system_status: int = 3,  # MAV_STATE_STANDBY
) -> Any:
    base_mode = 1 | (MAV_MODE_FLAG_SAFETY_ARMED if armed else 0)  # CUSTOM_MODE_ENABLED
    return mavlink2.MAVLink_heartbeat_message(
        vehicle_type, autopilot, base_mode, custom_mode, system_status, 3
    )


def sys_status_message(
    voltage_v: float | None, current_a: float | None, remaining_pct: int | None = None
) -> Any:
    mv = UINT16_MAX if voltage_v is None else _u16(voltage_v, 1000.0)
    ca = -1 if current_a is None else max(-1, min(INT16_MAX, round(current_a * 100.0)))
    pct = -1 if remaining_pct is None else remaining_pct
    return mavlink2.MAVLink_sys_status_message(0, 0, 0, 0, mv, ca, pct, 0, 0, 0, 0, 0, 0)


def battery_status_message(
    voltages_v: Sequence[float],
    current_a: float | None,
    *,
    battery_id: int = 0,
    temperature_c: float | None = None,
    consumed_mah: float | None = None,
    remaining_pct: int | None = None,
) -> Any:
    """``voltages_v``: up to 10 cell voltages, or one total (pymavlink packs 10 entries)."""
    if len(voltages_v) > 10:
        raise ConfigError(f"BATTERY_STATUS carries at most 10 voltages here, got {len(voltages_v)}")
    cells = [_u16(v, 1000.0) for v in voltages_v] + [UINT16_MAX] * (10 - len(voltages_v))
    ca = -1 if current_a is None else max(-1, min(INT16_MAX, round(current_a * 100.0)))
    temp = INT16_MAX if temperature_c is None else round(temperature_c * 100.0)
    consumed = -1 if consumed_mah is None else round(consumed_mah)
    pct = -1 if remaining_pct is None else remaining_pct
    return mavlink2.MAVLink_battery_status_message(
        battery_id, 0, 0, temp, cells, ca, consumed, -1, pct
    )


def _four(values: Sequence[float], fill: float = 0.0) -> list[float]:
    return [float(v) for v in values[:4]] + [fill] * (4 - min(4, len(values)))


def esc_telemetry_message(
    *,
    rpm: Sequence[float],
    voltage_v: Sequence[float],
    current_a: Sequence[float],
    temperature_c: Sequence[float],
    consumed_mah: Sequence[float] = (),
    count: Sequence[int] = (),
) -> Any:
    """ESC_TELEMETRY_1_TO_4 (ardupilotmega): °C, cV, cA, mAh, rpm."""
    return mavlink2.MAVLink_esc_telemetry_1_to_4_message(
        [max(0, min(255, round(t))) for t in _four(temperature_c)],
        [_u16(v, 100.0, 0) for v in _four(voltage_v)],
        [_u16(c, 100.0, 0) for c in _four(current_a)],
        [_u16(c, 1.0, 0) for c in _four(consumed_mah)],
        [_u16(r, 1.0, 0) for r in _four(rpm)],
        [int(c) & 0xFFFF for c in _four([float(c) for c in count])],
    )


def esc_status_message(
    *,
    time_s: float,
    rpm: Sequence[float],
    voltage_v: Sequence[float],
    current_a: Sequence[float],
    first_index: int = 0,
) -> Any:
    return MAVLink_esc_status_message(
        first_index,
        max(0, round(time_s * 1e6)),
        [round(r) for r in _four(rpm)],
        _four(voltage_v),
        _four(current_a),
    )


def servo_output_raw_message(time_s: float, outputs_us: Sequence[int], *, port: int = 0) -> Any:
    values = [int(v) for v in outputs_us[:16]] + [0] * (16 - min(16, len(outputs_us)))
    return mavlink2.MAVLink_servo_output_raw_message(
        max(0, round(time_s * 1e6)) & 0xFFFFFFFF, port, *values
    )


def command_ack_message(
    command: int, result: int, *, target_system: int = 0, target_component: int = 0
) -> Any:
    return mavlink2.MAVLink_command_ack_message(
        command, int(result), 0, 0, target_system, target_component
    )


def statustext_message(text: str, severity: int = Severity.INFO) -> Any:
    return mavlink2.MAVLink_statustext_message(int(severity), text.encode("utf-8")[:50])


def param_value_message(
    name: str, value: float, index: int, count: int, *, param_type: int = 9
) -> Any:
    """PARAM_VALUE; ``value`` is the float field as sent (already encoded for integer types)."""
    return mavlink2.MAVLink_param_value_message(
        name.encode("ascii")[:16], float(value), int(param_type), count, index
    )
