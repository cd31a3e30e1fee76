"""MAVLink telemetry logs (.tlog: 8-byte big-endian µs timestamp + MAVLink frame), via pymavlink.

Fields (flight-logs.md): SYS_STATUS.voltage_battery (mV), HEARTBEAT.base_mode & 128 (armed),
EXTENDED_SYS_STATE.landed_state (2 = in air; takeoff/landing count as not airborne),
SERVO_OUTPUT_RAW.servoN_raw (µs), HIGHRES_IMU.zacc (m/s², FRD) or SCALED_IMU.zacc (mG),
ATTITUDE_TARGET.thrust (0..1), ATTITUDE roll/pitch (tilt). Telemetry rates are low (a few Hz).
Only messages from the vehicle are used (the first system whose HEARTBEAT is not a GCS).
"""

from __future__ import annotations

import logging
import struct
from pathlib import Path
from typing import Any

import numpy as np

from thrustmap.core.errors import DataFormatError
from thrustmap.core.units import ThrottleScale
from thrustmap.fitting.flightlogs.series import FlightLog, FloatArray, Signal

log = logging.getLogger(__name__)

G0 = 9.80665
TYPES = [
    "HEARTBEAT",
    "SYS_STATUS",
    "EXTENDED_SYS_STATE",
    "SERVO_OUTPUT_RAW",
    "HIGHRES_IMU",
    "SCALED_IMU",
    "SCALED_IMU2",
    "RAW_IMU",
    "ATTITUDE_TARGET",
    "ATTITUDE",
    "VFR_HUD",
    "GLOBAL_POSITION_INT",
    "PARAM_VALUE",
    "STATUSTEXT",
]
MAV_AUTOPILOT_ARDUPILOTMEGA = 3
#: HEARTBEAT.type (MAV_TYPE) -> rotor count, multirotors only
MAV_TYPE_ROTORS = {2: 4, 3: 2, 13: 6, 14: 8, 15: 3}
MAV_TYPE_GCS, MAV_AUTOPILOT_INVALID = 6, 8
MAV_LANDED_STATE_IN_AIR = 2
ARMED_FLAG = 128
#: plausible tlog timestamps: 2005-01-01 .. 2100-01-01 in µs
_T_MIN_US, _T_MAX_US = 1_104_537_600_000_000, 4_102_444_800_000_000


def _record_end(head: bytes, pos: int) -> int | None:
    """End of the tlog record (8-byte timestamp + MAVLink frame) starting at ``pos``, or None
    when there is no plausible record there."""
    if pos + 10 > len(head):
        return None
    (t_us,) = struct.unpack_from(">Q", head, pos)
    magic, length = head[pos + 8], head[pos + 9]
    if not _T_MIN_US <= t_us <= _T_MAX_US:
        return None
    if magic == 0xFE:
        return pos + 8 + length + 8
    if magic == 0xFD and pos + 11 <= len(head):
        signed = head[pos + 10] & 0x01
        return pos + 8 + length + 12 + (13 if signed else 0)
    return None


#: consecutive records that must chain for a tlog to be recognised
_CHAIN = 3


def sniff(path: Path, head: bytes) -> bool:
    """A tlog is a chain of (timestamp, frame) records; it may start mid-record (a recording
    joined late, or cut), so look for a chain of valid records anywhere in the head."""
    for start in range(min(len(head), 512)):
        pos, ok = start, 0
        while ok < _CHAIN:
            end = _record_end(head, pos)
            if end is None or end > len(head):
                break
            pos, ok = end, ok + 1
        if ok >= _CHAIN or (ok and pos == len(head) and start == 0):
            return True
    return False


def _signal(rows: list[tuple[float, Any]], unit: str, origin: str) -> Signal | None:
    if not rows:
        return None
    t = np.array([r[0] for r in rows], float)
    v = np.array([r[1] for r in rows], float)
    order = np.argsort(t, kind="stable")
    t, v = t[order], v[order]
    keep = np.concatenate([[True], np.diff(t) > 0])
    return Signal(t[keep], v[keep], unit, origin)


def read(path: Path, **_: Any) -> list[FlightLog]:
    from pymavlink import mavutil

    if path.stat().st_size == 0:
        raise DataFormatError("telemetry log is empty (0 bytes)", file=str(path))
    try:
        mlog = mavutil.mavlink_connection(str(path), robust_parsing=True)
    except Exception as exc:
        raise DataFormatError(
            f"cannot open telemetry log ({type(exc).__name__}: {exc})", file=str(path)
        ) from None
    rows: dict[str, list[tuple[float, Any]]] = {k: [] for k in TYPES}
    vehicle: int | None = None
    autopilot: int | None = None
    vehicle_type: int | None = None
    params_by_src: dict[int, dict[str, float]] = {}
    texts_by_src: dict[int, list[str]] = {}
    bad_bytes = 0
    total = 0
    try:
        while True:
            try:
                m = mlog.recv_match(blocking=False)
            except Exception as exc:  # pymavlink raises assorted errors on garbage
                if total == 0:
                    raise DataFormatError(
                        f"not a readable telemetry log ({type(exc).__name__}: {exc})",
                        file=str(path),
                    ) from None
                bad_bytes += 1
                break
            if m is None:
                break
            mtype = m.get_type()
            if mtype == "BAD_DATA":
                bad_bytes += len(getattr(m, "data", b""))
                continue
            total += 1
            if mtype not in rows:
                continue
            src = m.get_srcSystem()
            if (
                mtype == "HEARTBEAT"
                and vehicle is None
                and m.type != MAV_TYPE_GCS
                and m.autopilot != MAV_AUTOPILOT_INVALID
            ):
                vehicle = src
                autopilot = int(m.autopilot)
                vehicle_type = int(m.type)
            if mtype == "PARAM_VALUE":  # kept per system: a cut recording may lack the first
                pid = m.param_id  # heartbeat, and parameters are fetched once, early
                name = pid.decode("ascii", "replace") if isinstance(pid, bytes) else str(pid)
                params_by_src.setdefault(src, {})[name.rstrip("\x00")] = float(m.param_value)
                continue
            if mtype == "STATUSTEXT":
                txt = m.text
                texts_by_src.setdefault(src, []).append(
                    txt.decode("ascii", "replace") if isinstance(txt, bytes) else str(txt)
                )
                continue
            if vehicle is None or src != vehicle:
                continue
            t = float(m._timestamp)
            if mtype == "HEARTBEAT":
                rows[mtype].append((t, 1.0 if m.base_mode & ARMED_FLAG else 0.0))
            elif mtype == "SYS_STATUS":
                if m.voltage_battery not in (0, 0xFFFF):
                    rows[mtype].append((t, m.voltage_battery / 1000.0))
            elif mtype == "EXTENDED_SYS_STATE":
                rows[mtype].append((t, 0.0 if m.landed_state == MAV_LANDED_STATE_IN_AIR else 1.0))
            elif mtype == "SERVO_OUTPUT_RAW":
                if getattr(m, "port", 0) == 0:
                    rows[mtype].append((t, [getattr(m, f"servo{i}_raw") for i in range(1, 9)]))
            elif mtype == "HIGHRES_IMU":
                rows[mtype].append((t, -float(m.zacc)))
            elif mtype in ("SCALED_IMU", "SCALED_IMU2", "RAW_IMU"):
                # mG (ArduPilot fills RAW_IMU in mG too; other autopilots' RAW_IMU is raw ADC)
                rows[mtype].append((t, -float(m.zacc) * G0 / 1000.0))
            elif mtype == "VFR_HUD":
                rows[mtype].append((t, [float(m.throttle) / 100.0, float(m.climb)]))
            elif mtype == "GLOBAL_POSITION_INT":
                rows[mtype].append((t, float(m.relative_alt) / 1000.0))
            elif mtype == "ATTITUDE_TARGET":
                rows[mtype].append((t, float(m.thrust)))
            elif mtype == "ATTITUDE":
                c = np.cos(m.roll) * np.cos(m.pitch)
                rows[mtype].append((t, float(np.degrees(np.arccos(np.clip(c, -1, 1))))))
    finally:
        mlog.close()
    if total == 0:
        raise DataFormatError(
            f"no MAVLink messages decoded ({bad_bytes} bytes of bad data)", file=str(path)
        )
    if vehicle is None:
        raise DataFormatError("no vehicle HEARTBEAT in the telemetry log", file=str(path))
    params = params_by_src.get(vehicle, {})
    texts = texts_by_src.get(vehicle, [])
    t0 = min(r[0][0] for r in rows.values() if r)
    for r in rows.values():
        r[:] = [(t - t0, v) for t, v in r]
    warnings: list[str] = []
    if bad_bytes:
        warnings.append(f"{bad_bytes} bytes of corrupt data skipped (bad MAVLink frames)")
    flight = FlightLog(path=str(path), format="tlog", warnings=warnings)
    flight.metadata.update({"system_id": vehicle, "messages": total, "t0_unix_s": t0})
    flight.voltage_v = _signal(rows["SYS_STATUS"], "V", "SYS_STATUS.voltage_battery/1000")
    flight.armed = _signal(rows["HEARTBEAT"], "bool", "HEARTBEAT.base_mode & 128")
    flight.landed = _signal(
        rows["EXTENDED_SYS_STATE"], "bool", "EXTENDED_SYS_STATE.landed_state != IN_AIR"
    )
    imus = ["HIGHRES_IMU", "SCALED_IMU", "SCALED_IMU2"]
    if autopilot == MAV_AUTOPILOT_ARDUPILOTMEGA:
        imus.append("RAW_IMU")
    for name in imus:
        unit = "" if name == "HIGHRES_IMU" else " (mG -> m/s^2)"
        flight.accel_up_mps2 = _signal(rows[name], "m/s^2", f"-{name}.zacc{unit}")
        if flight.accel_up_mps2 is not None:
            break
    flight.thrust_cmd_norm = _signal(rows["ATTITUDE_TARGET"], "1", "ATTITUDE_TARGET.thrust")
    hud = _signal(rows["VFR_HUD"], "", "VFR_HUD")
    if hud is not None:
        if flight.thrust_cmd_norm is None:
            flight.thrust_cmd_norm = Signal(
                hud.time_s, hud.values[:, 0], "1", "VFR_HUD.throttle/100 (1 % steps)"
            )
        flight.extras["climb_mps"] = Signal(hud.time_s, hud.values[:, 1], "m/s", "VFR_HUD.climb")
    alt = _signal(rows["GLOBAL_POSITION_INT"], "m", "GLOBAL_POSITION_INT.relative_alt/1000")
    if alt is not None:
        flight.extras["height_m"] = alt
    if params:
        flight.metadata["params"] = {
            k: v for k, v in params.items() if k.startswith(("MOT_", "FRAME", "SERVO", "RC3_"))
        }
    tilt = _signal(rows["ATTITUDE"], "deg", "ATTITUDE.roll/pitch")
    if tilt is not None:
        flight.extras["tilt_deg"] = tilt
    servo = _signal(rows["SERVO_OUTPUT_RAW"], "us", "SERVO_OUTPUT_RAW")
    if servo is not None:
        outs: FloatArray = servo.values
        flight.extras["outputs_all"] = Signal(
            servo.time_s, outs, "us", "SERVO_OUTPUT_RAW.servo1..8"
        )
        layout = None
        if autopilot == MAV_AUTOPILOT_ARDUPILOTMEGA:
            from thrustmap.fitting.flightlogs.dataflash import motor_layout, pwm_scale

            layout = motor_layout(params, texts)
        if layout is None and vehicle_type in MAV_TYPE_ROTORS:
            n_rot = MAV_TYPE_ROTORS[vehicle_type]
            layout = (list(range(1, n_rot + 1)), f"HEARTBEAT.type {vehicle_type}: {n_rot} rotors")
        if layout is not None:
            chans = [c for c in layout[0] if c <= outs.shape[1]]
            flight.metadata["motor_channels"] = layout[1]
        else:
            n = 0
            while (
                n < outs.shape[1]
                and 800 <= np.median(outs[:, n]) <= 2200
                and np.std(outs[:, n]) > 0.5
            ):
                n += 1
            chans = list(range(1, n + 1))
            if n:
                flight.metadata["motor_channels"] = "leading moving outputs (no frame in the log)"
                warnings.append(
                    f"the telemetry names no frame: motors taken as servo1..{n}; check --rotors"
                )
        if chans:
            flight.motor_outputs = Signal(
                servo.time_s,
                outs[:, [c - 1 for c in chans]],
                "us",
                "SERVO_OUTPUT_RAW.servo" + ",".join(map(str, chans)) + "_raw",
            )
            if autopilot == MAV_AUTOPILOT_ARDUPILOTMEGA and params:
                scale, src = pwm_scale(params)
            else:
                scale = ThrottleScale("pwm", 1000.0, 2000.0, "us")
                src = "assumed 1000..2000 us (no ESC range parameters in the telemetry)"
            flight.motor_output_scale = scale
            flight.metadata["motor_output_scale_source"] = src
    return [flight]
