"""PX4 ULog flight logs, via pyulog, across the topic renames.

| need               | v1.14+                                | before v1.14                  |
|--------------------|---------------------------------------|-------------------------------|
| collective thrust  | vehicle_thrust_setpoint.xyz[2] (-1..0) | actuator_controls_0.control[3] |
| motor outputs      | actuator_motors.control[i] (0..1)      | actuator_outputs.output[i]     |

Battery: battery_status.voltage_v (voltage_filtered_v only in older firmware, used only when
voltage_v is missing). Upward specific force: -sensor_combined.accelerometer_m_s2[2] (FRD).
Armed: vehicle_status.arming_state == 2; landed: vehicle_land_detected.landed.
"""

from __future__ import annotations

import contextlib
import io
import logging
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from thrustmap.core.errors import DataFormatError
from thrustmap.core.units import SCALES, ThrottleScale
from thrustmap.flightlogs import ulog_fast
from thrustmap.flightlogs.series import FlightLog, FloatArray, Signal, nanmedian

log = logging.getLogger(__name__)

MAGIC = b"ULog\x01\x12\x35"
TOPICS = [
    "battery_status",
    "sensor_combined",
    "vehicle_acceleration",
    "vehicle_thrust_setpoint",
    "actuator_controls_0",
    "actuator_motors",
    "actuator_outputs",
    "vehicle_status",
    "vehicle_land_detected",
    "hover_thrust_estimate",
    "vehicle_attitude",
    "vehicle_local_position",
]
ARMING_STATE_ARMED = 2
#: PX4 UAVCAN ESC raw command range
UAVCAN_RAW = ThrottleScale("uavcan-raw", 0.0, 8191.0, "raw")


def sniff(path: Path, head: bytes) -> bool:
    return head.startswith(MAGIC)


Data = dict[str, npt.NDArray[Any]]
#: a topic's first instance by name, or None when the log lacks it (or it is empty)
Topic = Callable[[str], Data | None]


def _topics(ulog: Any) -> dict[tuple[str, int], Data]:
    return {(d.name, d.multi_id): d.data for d in ulog.data_list}


def _time(data: Data, t0_us: int) -> FloatArray:
    return (np.asarray(data["timestamp"], dtype=np.int64) - int(t0_us)).astype(float) * 1e-6


def _state_time(data: Data, t0_us: int) -> FloatArray:
    """Times of a state topic (armed, landed). A log with appended data may hold state samples
    stamped before its first data; the last of them still holds at the start, so it is stamped
    at the start instead of being dropped (samples with timestamp 0 were never published)."""
    raw = np.asarray(data["timestamp"], dtype=np.int64)
    t = _time(data, t0_us)
    early = np.flatnonzero((raw > 0) & (t < 0))
    if len(early) and not (t == 0).any():
        t = t.copy()
        t[early[np.argmax(raw[early])]] = 0.0
    return t


def _signal(t: FloatArray, values: npt.ArrayLike, unit: str, origin: str) -> Signal:
    v = np.asarray(values, dtype=float)
    ok = t >= 0  # timestamp 0 marks "never published" samples
    t, v = t[ok], v[ok]
    order = np.argsort(t, kind="stable")
    t, v = t[order], v[order]
    keep = np.concatenate([[True], np.diff(t) > 0]) if len(t) else np.zeros(0, bool)
    return Signal(t[keep], v[keep], unit, origin)


def _indexed(data: Data, prefix: str) -> list[str]:
    pat = re.compile(re.escape(prefix) + r"\[(\d+)\]$")
    keys = [(int(m.group(1)), k) for k in data if (m := pat.match(k))]
    return [k for _, k in sorted(keys)]


def _pwm_outputs(
    topics: dict[tuple[str, int], Data], t0: int, armed: Signal | None, rotors: int | None = None
) -> tuple[Signal, ThrottleScale] | None:
    """The actuator_outputs instance that drives the motors (pre-v1.14 logs)."""
    best: tuple[float, Signal, ThrottleScale] | None = None
    for (name, inst), data in topics.items():
        if name != "actuator_outputs" or not len(data["timestamp"]):
            continue
        keys = _indexed(data, "output")[:8]
        if not keys:
            continue
        t = _time(data, t0)
        outs = np.stack([np.asarray(data[k], float) for k in keys], axis=1)
        mask = armed.hold(t) > 0.5 if armed is not None else np.ones(len(t), bool)
        if not mask.any():
            continue
        active = outs[mask]
        moving = np.flatnonzero(np.std(active, axis=0) > 1.0)
        # motors: the frame's rotor count, else the leading block of moving channels
        n = 0
        while n < len(keys) and n in set(moving.tolist()):
            n += 1
        if rotors is not None:
            if n < min(rotors, 2) or rotors > len(keys):
                continue
            n = rotors
        elif n < 3:
            continue
        med = nanmedian(active[:, :n])
        if 800.0 <= med <= 2200.0:
            scale = SCALES["pwm"]
        elif 0.0 < med <= 8191.0 and float(np.max(active[:, :n])) <= 8191.0 and med > 2200.0:
            scale = UAVCAN_RAW
        else:
            continue
        score = float(np.mean(np.std(active[:, :n], axis=0))) / scale.span
        sig = _signal(t, outs[:, :n], scale.unit, f"actuator_outputs[{inst}].output[0..{n - 1}]")
        if best is None or score > best[0]:
            best = (score, sig, scale)
    return None if best is None else (best[1], best[2])


#: MAV_TYPE -> rotor count (multirotors only), for logs before control allocation
MAV_TYPE_ROTORS = {2: 4, 3: 2, 13: 6, 14: 8, 15: 3}
#: output function codes of PX4 control allocation: Motor 1..12
MOTOR_FUNCTION_FIRST, MOTOR_FUNCTION_LAST = 101, 112


def rotor_count(params: dict[str, Any]) -> tuple[int, str] | None:
    """Rotors from the log's parameters: CA_ROTOR_COUNT (v1.14+), else the MAV_TYPE frame."""
    n = params.get("CA_ROTOR_COUNT")
    if isinstance(n, (int, float)) and n > 0:
        return int(n), f"CA_ROTOR_COUNT {int(n)}"
    mt = params.get("MAV_TYPE")
    if isinstance(mt, (int, float)) and int(mt) in MAV_TYPE_ROTORS:
        return MAV_TYPE_ROTORS[int(mt)], f"MAV_TYPE {int(mt)} ({MAV_TYPE_ROTORS[int(mt)]} rotors)"
    return None


def _p(params: dict[str, Any], key: str) -> float | None:
    v = params.get(key)
    return float(v) if isinstance(v, (int, float)) and v >= 0 else None


def motor_output_range(params: dict[str, Any], motor: int) -> tuple[ThrottleScale, str] | None:
    """The range control allocation maps motor ``motor`` (1-based) onto: the output whose
    PWM_MAIN/PWM_AUX/UAVCAN_EC FUNCn is that motor gives its MINn/MAXn (v1.14+)."""
    code = MOTOR_FUNCTION_FIRST + motor - 1
    for group, unit, name in (
        ("PWM_MAIN", "us", "pwm"),
        ("PWM_AUX", "us", "pwm"),
        ("UAVCAN_EC", "raw", "uavcan-raw"),
    ):
        for k in range(1, 17):
            if params.get(f"{group}_FUNC{k}") == code:
                lo = _p(params, f"{group}_MIN{k}")
                hi = _p(params, f"{group}_MAX{k}")
                if lo is None or hi is None or not hi > lo:
                    return None  # this build has no range for the output (e.g. SITL)
                return ThrottleScale(name, lo, hi, unit), (
                    f"{group}_MIN{k}/MAX{k} {lo:g}..{hi:g} {unit} ({group}_FUNC{k}={code})"
                )
    return None


def legacy_pwm_range(params: dict[str, Any], n: int) -> tuple[ThrottleScale, str]:
    """PWM range of outputs before control allocation: PWM_MAIN_MINn/MAXn (v1.13), else
    PWM_MIN/PWM_MAX (<= v1.12), else 1000..2000 assumed."""
    lo, hi = _p(params, "PWM_MAIN_MIN1"), _p(params, "PWM_MAIN_MAX1")
    if lo is not None and hi is not None and hi > lo:
        los = {_p(params, f"PWM_MAIN_MIN{k}") for k in range(1, n + 1)}
        note = "" if len(los) == 1 else " (motors differ; motor 1's range used)"
        return SCALES["pwm"].with_range(lo, hi), f"PWM_MAIN_MIN1/MAX1 {lo:g}..{hi:g} us{note}"
    lo, hi = _p(params, "PWM_MIN"), _p(params, "PWM_MAX")
    if lo is not None and hi is not None and hi > lo:
        return SCALES["pwm"].with_range(lo, hi), f"PWM_MIN/PWM_MAX {lo:g}..{hi:g} us"
    return SCALES["pwm"], "assumed 1000..2000 us (no PWM_MIN/MAX parameters in the log)"


_ULOG_TYPES = frozenset(b"BFIMPQARDLCSO")
_DEFINITION_TYPES = frozenset(b"BFIMPQ")
_BASE_SIZES = {
    "int8_t": 1, "uint8_t": 1, "char": 1, "bool": 1, "int16_t": 2, "uint16_t": 2,
    "int32_t": 4, "uint32_t": 4, "float": 4, "int64_t": 8, "uint64_t": 8, "double": 8,
}  # fmt: skip
#: a ULog message payload is at most 65535 bytes, so no format can describe more
MAX_FORMAT_BYTES = 0xFFFF
#: budget of flattened fields pyulog expands over all subscriptions, per byte of file
FIELDS_PER_BYTE = 8


@dataclass
class _Walk:
    good_end: int  # bytes that form an intact chain of messages (pyulog gets only these)
    problem: str | None  # why the rest is not used (None when the whole file is intact)


def _format_sizes(formats: dict[str, list[tuple[str, int]]]) -> dict[str, int]:
    """Flattened payload size of every format; -1 for a cyclic, unknown or oversized one."""
    sizes: dict[str, int] = {}

    def size_of(name: str, stack: tuple[str, ...]) -> int:
        if name in _BASE_SIZES:
            return _BASE_SIZES[name]
        if name in sizes:
            return sizes[name]
        if name in stack or name not in formats or len(stack) > 32:
            return -1
        total = 0
        for type_name, count in formats[name]:
            one = size_of(type_name, (*stack, name))
            if one < 0:
                total = -1
                break
            total += one * max(count, 1)
            if total > MAX_FORMAT_BYTES:
                total = -1
                break
        sizes[name] = total
        return total

    for name in formats:
        size_of(name, ())
    return sizes


def _parse_format(payload: bytes) -> tuple[str, list[tuple[str, int]]] | None:
    text = payload.decode("utf-8", "replace")
    name, sep, body = text.partition(":")
    if not sep or not name:
        return None
    fields: list[tuple[str, int]] = []
    for item in body.split(";"):
        item = item.strip()
        if not item:
            continue
        type_part, _, _field = item.partition(" ")
        count = 0
        if "[" in type_part:
            type_part, _, rest = type_part.partition("[")
            digits = rest.rstrip("]")
            if not digits.isdigit() or len(digits) > 5:
                return None
            count = int(digits)
        fields.append((type_part, count))
    return name, fields


def walk(raw: bytes) -> _Walk:
    """Check a ULog's message chain before pyulog sees it (pyulog can loop forever or expand
    crafted formats without bound on corrupt input): every header must have a known type and fit
    in the file, definitions must come before data, and the formats the log subscribes to must
    be finite and no larger than a ULog message can be. The intact prefix is what gets parsed."""
    import struct

    n, pos = len(raw), 16
    unpack = struct.Struct("<HB").unpack_from
    formats: dict[str, list[tuple[str, int]]] = {}
    sizes: dict[str, int] | None = None
    in_data = False
    field_budget = max(200_000, FIELDS_PER_BYTE * n)
    while pos + 3 <= n:
        size, kind = unpack(raw, pos)
        if kind not in _ULOG_TYPES or (in_data and kind == ord("F")):
            return _Walk(
                pos,
                f"corrupt data at byte {pos} (message type {kind:#04x}); "
                f"the {n - pos} bytes after it are not used",
            )
        if pos + 3 + size > n:
            return _Walk(pos, f"corrupt tail: last message truncated at byte {n}; ignored")
        payload = raw[pos + 3 : pos + 3 + size]
        if kind == ord("F") and not in_data:
            parsed = _parse_format(payload)
            if parsed is None:
                return _Walk(pos, f"corrupt format definition at byte {pos}; the rest is not used")
            formats[parsed[0]] = parsed[1]
        elif kind == ord("A"):
            if sizes is None:
                sizes = _format_sizes(formats)
            name = payload[3:].decode("utf-8", "replace")
            cost = sizes.get(name, -1)
            if cost < 0 or cost > field_budget:
                return _Walk(
                    pos,
                    f"corrupt subscription at byte {pos} (format '{name[:40]}' is undefined, "
                    f"cyclic or too large); the {n - pos} bytes after it are not used",
                )
            field_budget -= cost
        if kind not in _DEFINITION_TYPES:
            in_data = True
        pos += 3 + size
    if pos < n:
        return _Walk(pos, f"corrupt tail: {n - pos} stray bytes at the end; ignored")
    return _Walk(n, None)


def check_integrity(path: Path, raw: bytes | None = None) -> str | None:
    """Walk the ULog message headers; describe a truncated or corrupt tail (None when intact)."""
    return walk(raw if raw is not None else path.read_bytes()).problem


def _release(code: Any) -> str | None:
    """PX4's ver_sw_release word (0xMMmmpptt) as 'v1.15.0'."""
    if not isinstance(code, int) or code <= 0:
        return None
    return f"v{(code >> 24) & 0xFF}.{(code >> 16) & 0xFF}.{(code >> 8) & 0xFF}"


def read(path: Path, **_: Any) -> list[FlightLog]:
    warnings: list[str] = []
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise DataFormatError(f"cannot read ULog: {exc.strerror}", file=str(path)) from None
    if not raw.startswith(MAGIC) or len(raw) < 16:
        raise DataFormatError("not a ULog file (expected the 'ULog' header)", file=str(path))
    ulog, problem = _parse(raw, path)
    if problem is not None:
        warnings.append(problem)
    elif getattr(ulog, "file_corruption", False):
        warnings.append("corrupt data in the log (pyulog resynchronised); the good part is used")
    topics = _topics(ulog)
    if not topics:
        raise DataFormatError(
            "ULog holds none of the needed topics (" + ", ".join(TOPICS[:4]) + ", ...)",
            file=str(path),
        )
    t0 = int(ulog.start_timestamp)
    params = dict(ulog.initial_parameters)
    flight = FlightLog(path=str(path), format="ulog", warnings=warnings)
    _metadata(flight, ulog, topics, params)

    def topic(name: str) -> Data | None:
        d = topics.get((name, 0))
        return d if d is not None and len(d.get("timestamp", ())) else None

    _power_and_thrust(flight, topic, t0)
    _armed_and_landed(flight, topic, t0)
    _position_and_attitude(flight, topic, t0)
    _motors(flight, topics, topic, t0, params)
    _finish(flight)
    return [flight]


def _parse(raw: bytes, path: Path) -> tuple[Any, str | None]:
    """The log's topics: the vectorised reader, else pyulog on the intact part; and the problem
    found in the file, if any."""
    ulog: Any = ulog_fast.parse(raw, TOPICS)  # vectorised; None: something pyulog must handle
    if ulog is not None:
        problem = ulog.problem
    else:  # pyulog is imported only here: the vectorised reader needs numpy alone
        try:
            from pyulog import ULog
        except ImportError:  # pragma: no cover - exercised only without pyulog
            raise DataFormatError(
                "reading this PX4 ULog needs pyulog (pip install pyulog)", file=str(path)
            ) from None
        intact = walk(raw)
        problem = intact.problem
        chatter = io.StringIO()
        try:  # pyulog prints its diagnostics: keep them off stdout (it carries --json output)
            with contextlib.redirect_stdout(chatter):
                ulog = ULog(
                    io.BytesIO(raw[: intact.good_end]),
                    message_name_filter_list=TOPICS,
                    disable_str_exceptions=True,
                )
        except Exception as exc:  # pyulog raises bare exceptions on malformed headers
            raise DataFormatError(f"not a readable ULog file: {exc}", file=str(path)) from None
        finally:
            for line in chatter.getvalue().splitlines()[:5]:
                log.debug("%s: pyulog: %s", path, line)
    return ulog, problem


def _metadata(
    flight: FlightLog, ulog: Any, topics: dict[tuple[str, int], Data], params: dict[str, Any]
) -> None:
    """What the log says about itself: versions, topics, duration, the parameters kept."""
    t0 = int(ulog.start_timestamp)
    info = ulog.msg_info_dict
    flight.metadata.update(
        {
            "ver_sw": info.get("ver_sw"),
            "ver_sw_release": info.get("ver_sw_release"),
            "px4_version": _release(info.get("ver_sw_release")),
            "sys_name": info.get("sys_name"),
            "ver_hw": info.get("ver_hw"),
            "topics": sorted({f"{n}[{i}]" for n, i in topics}),
            "duration_s": (int(ulog.last_timestamp) - t0) * 1e-6,
            "params": {
                k: v
                for k, v in params.items()
                if k.startswith(("MC_BAT_SCALE", "THR_MDL", "MPC_THR", "BAT_N_CELLS"))
            },
        }
    )
    if params.get("MC_BAT_SCALE_EN", 0):
        flight.warnings.append(
            "MC_BAT_SCALE_EN=1: PX4 already scaled the thrust setpoint by battery_status.scale"
        )


def _power_and_thrust(flight: FlightLog, topic: Topic, t0: int) -> None:
    """Battery voltage, upward specific force and the collective thrust command."""
    if (b := topic("battery_status")) is not None:
        key = "voltage_v" if "voltage_v" in b else "voltage_filtered_v"
        v = np.asarray(b[key], float)
        ok = v > 0.5  # 0 V until the first ADC reading
        flight.voltage_v = _signal(_time(b, t0)[ok], v[ok], "V", f"battery_status.{key}")
    if (s := topic("sensor_combined")) is not None:
        flight.accel_up_mps2 = _signal(
            _time(s, t0),
            -np.asarray(s["accelerometer_m_s2[2]"], float),
            "m/s^2",
            "-sensor_combined.accelerometer_m_s2[2]",
        )
    elif (a := topic("vehicle_acceleration")) is not None:
        flight.accel_up_mps2 = _signal(
            _time(a, t0), -np.asarray(a["xyz[2]"], float), "m/s^2", "-vehicle_acceleration.xyz[2]"
        )
    if (ts := topic("vehicle_thrust_setpoint")) is not None:
        flight.thrust_cmd_norm = _signal(
            _time(ts, t0), -np.asarray(ts["xyz[2]"], float), "1", "-vehicle_thrust_setpoint.xyz[2]"
        )
    elif (ac := topic("actuator_controls_0")) is not None:
        flight.thrust_cmd_norm = _signal(
            _time(ac, t0), ac["control[3]"], "1", "actuator_controls_0.control[3]"
        )


def _armed_and_landed(flight: FlightLog, topic: Topic, t0: int) -> None:
    """Armed, landed and ground contact (step signals: the state since its last sample)."""
    if (vs := topic("vehicle_status")) is not None:
        flight.armed = _signal(
            _state_time(vs, t0),
            np.asarray(vs["arming_state"]) == ARMING_STATE_ARMED,
            "bool",
            "vehicle_status.arming_state == 2",
        )
    ld = topic("vehicle_land_detected")
    if ld is not None:
        flight.landed = _signal(
            _state_time(ld, t0), ld["landed"], "bool", "vehicle_land_detected.landed"
        )
    if ld is not None:
        contact = [k for k in ("ground_contact", "maybe_landed") if k in ld]
        if contact:
            on_ground = np.zeros(len(ld["timestamp"]), bool)
            for k in contact:
                on_ground |= np.asarray(ld[k], bool)
            flight.extras["ground_contact"] = _signal(
                _state_time(ld, t0),
                on_ground,
                "bool",
                "vehicle_land_detected." + " | ".join(contact),
            )


def _position_and_attitude(flight: FlightLog, topic: Topic, t0: int) -> None:
    """Height, range, climb rate, the hover-thrust estimate and the tilt."""
    if (lp := topic("vehicle_local_position")) is not None:
        t_lp = _time(lp, t0)
        ok = np.asarray(lp.get("z_valid", np.ones(len(t_lp))), bool)
        flight.extras["height_m"] = _signal(
            t_lp[ok], -np.asarray(lp["z"], float)[ok], "m", "-vehicle_local_position.z"
        )
        if "dist_bottom" in lp and "dist_bottom_valid" in lp:  # range sensor (or terrain est.)
            rng = np.where(
                np.asarray(lp["dist_bottom_valid"], bool),
                np.asarray(lp["dist_bottom"], float),
                np.nan,
            )
            if np.isfinite(rng).any():
                flight.extras["range_m"] = _signal(
                    t_lp, rng, "m", "vehicle_local_position.dist_bottom (valid only)"
                )
        if "vz" in lp:
            flight.extras["climb_mps"] = _signal(
                t_lp[ok], -np.asarray(lp["vz"], float)[ok], "m/s", "-vehicle_local_position.vz"
            )
    if (h := topic("hover_thrust_estimate")) is not None:
        valid = np.asarray(h.get("valid", np.ones(len(h["timestamp"]))), bool)
        ht = np.where(valid, np.asarray(h["hover_thrust"], float), np.nan)
        flight.hover_thrust_estimate = _signal(
            _time(h, t0), ht, "1", "hover_thrust_estimate.hover_thrust (valid only)"
        )
        if "valid" in h:
            flight.extras["hover_estimate_valid"] = _signal(
                _state_time(h, t0), valid, "bool", "hover_thrust_estimate.valid"
            )
    if (att := topic("vehicle_attitude")) is not None:
        q0, q1, q2, q3 = (np.asarray(att[f"q[{i}]"], float) for i in range(4))
        # body z axis vs earth z: R[2,2] = 1 - 2(q1² + q2²)
        cos_tilt = np.clip(1.0 - 2.0 * (q1 * q1 + q2 * q2), -1.0, 1.0)
        flight.extras["tilt_deg"] = _signal(
            _time(att, t0), np.degrees(np.arccos(cos_tilt)), "deg", "vehicle_attitude.q"
        )


def _motors(
    flight: FlightLog,
    topics: dict[tuple[str, int], Data],
    topic: Topic,
    t0: int,
    params: dict[str, Any],
) -> None:
    """The motor outputs: actuator_motors in the motors' output ranges, else the PWM or UAVCAN
    outputs; which outputs are motors (the frame, else those that move)."""
    warnings = flight.warnings
    frame = rotor_count(params)
    if frame is not None:
        flight.metadata["motor_channels"] = frame[1]
    if (am := topic("actuator_motors")) is not None:
        keys = _indexed(am, "control")
        ctl = np.stack([np.asarray(am[k], float) for k in keys], axis=1)
        used = [
            k
            for k in range(ctl.shape[1])
            if np.isfinite(ctl[:, k]).any() and np.nanmax(np.abs(ctl[:, k])) > 0
        ]
        n = frame[0] if frame is not None else (max(used) + 1 if used else 0)
        if frame is None and used:
            warnings.append(
                "no CA_ROTOR_COUNT / MAV_TYPE in the log: motors taken as the actuator_motors "
                f"controls that move (0..{n - 1}); check --rotors"
            )
        if n and n <= ctl.shape[1]:
            ctl = np.nan_to_num(ctl[:, :n], nan=0.0)
            origin = f"actuator_motors.control[0..{n - 1}] (NaN disarmed -> 0)"
            ranges = [motor_output_range(params, m + 1) for m in range(n)]
            if all(r is not None for r in ranges):
                # control 0..1 is spread over each motor's own output range: report native units
                scales = [r[0] for r in ranges if r is not None]
                native = np.stack([scales[m].from_pct(ctl[:, m] * 100.0) for m in range(n)], 1)
                flight.motor_outputs = _signal(
                    _time(am, t0), native, scales[0].unit, origin + " -> output range"
                )
                flight.motor_output_scale = scales[0]
                same = len({(sc.lo, sc.hi) for sc in scales}) == 1
                src = next(r[1] for r in ranges if r is not None)
                flight.metadata["motor_output_scale_source"] = src + (
                    "" if same else " (motors differ; each converted with its own range)"
                )
            else:
                flight.motor_outputs = _signal(_time(am, t0), ctl, "1", origin)
                flight.motor_output_scale = SCALES["norm"]
                flight.metadata["motor_output_scale_source"] = (
                    "normalised actuator_motors (no PWM_MAIN/PWM_AUX/UAVCAN_EC MINn/MAXn for the "
                    "motors' outputs in the log: output range unknown)"
                )
    else:
        found = _pwm_outputs(topics, t0, flight.armed, frame[0] if frame else None)
        if found is not None:
            flight.motor_outputs, flight.motor_output_scale = found
            if flight.motor_output_scale.unit == "us":
                n = flight.motor_outputs.values.shape[1]
                flight.motor_output_scale, src = legacy_pwm_range(params, n)
            else:
                src = "UAVCAN raw command range 0..8191"
            flight.metadata["motor_output_scale_source"] = src
        if frame is None and found is not None:
            warnings.append(
                "no MAV_TYPE in the log: motors taken as the leading moving outputs; check --rotors"
            )


def _finish(flight: FlightLog) -> None:
    """An empty step signal is absent; say what is missing."""
    warnings = flight.warnings
    for state in ("armed", "landed"):  # an empty step signal holds nothing: treat as absent
        sig = getattr(flight, state)
        if sig is not None and not len(sig):
            setattr(flight, state, None)
            warnings.append(f"{sig.origin}: no sample within the log's time span; not used")
    if flight.accel_up_mps2 is None:
        warnings.append("no sensor_combined / vehicle_acceleration: no upward specific force")
    if flight.voltage_v is None:
        warnings.append("no battery_status: no battery voltage")
