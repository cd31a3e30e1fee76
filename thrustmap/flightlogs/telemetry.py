"""MAVLink telemetry -> FlightLog, one message at a time: the code shared by the .tlog reader
and the live γ(B) fit (``thrustmap gamma live``).

``Telemetry.add(msg, time_s)`` takes decoded pymavlink messages in arrival order, each with the
time it was received (a .tlog's record time, or the live receive time rounded to the µs a .tlog
stores, so a recording replays to the same numbers). ``Telemetry.flight_log()`` builds the
FlightLog ``fitting.df.extract_flight`` reads, at any moment: the same code serves a whole file
and a stream in progress.

Fields (docs/flight-logs.md): SYS_STATUS.voltage_battery (mV), HEARTBEAT.base_mode & 128 (armed),
EXTENDED_SYS_STATE.landed_state (1 = on the ground; 2 in air, 3 taking off and 4 landing are
airborne, as a log's land detector has them: the Df filters drop the climbs and the margins;
0 = undefined is not used),
SERVO_OUTPUT_RAW.servoN_raw (µs), HIGHRES_IMU.zacc (m/s², FRD) or SCALED_IMU.zacc (mG),
ATTITUDE_TARGET.thrust (0..1), ATTITUDE roll/pitch (tilt). Telemetry rates are low (a few Hz).
Only messages from the vehicle are used (the first system whose HEARTBEAT is not a GCS).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

import numpy as np

from thrustmap.core.units import ThrottleScale
from thrustmap.flightlogs.series import FlightLog, FloatArray, Signal

log = logging.getLogger(__name__)

G0 = 9.80665
TYPES = (
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
)
MAV_AUTOPILOT_ARDUPILOTMEGA = 3
MAV_AUTOPILOT_PX4 = 12
#: HEARTBEAT.type (MAV_TYPE) -> rotor count, multirotors only
MAV_TYPE_ROTORS = {2: 4, 3: 2, 13: 6, 14: 8, 15: 3}
MAV_TYPE_GCS, MAV_AUTOPILOT_INVALID = 6, 8
MAV_LANDED_STATE_UNDEFINED, MAV_LANDED_STATE_ON_GROUND = 0, 1
ARMED_FLAG = 128
#: rows kept per message type at most (a day of 50 Hz IMU); past it the oldest half is dropped
#: and a warning says so, so a stream left running never grows without bound
MAX_ROWS_PER_TYPE = 4_000_000
#: STATUSTEXT lines kept per system (the frame is announced in the first ones)
MAX_TEXTS = 1000


@dataclass(frozen=True)
class Vehicle:
    system_id: int
    autopilot: int
    mav_type: int


def is_vehicle_heartbeat(msg: Any) -> bool:
    return bool(
        msg.get_type() == "HEARTBEAT"
        and msg.type != MAV_TYPE_GCS
        and msg.autopilot != MAV_AUTOPILOT_INVALID
    )


class Telemetry:
    """Rows of the telemetry fields, per message type, from the vehicle; see the module doc."""

    def __init__(self, path: str, format: str = "tlog") -> None:  # noqa: A002 - FlightLog's name
        self.path = path
        self.format = format
        self.rows: dict[str, list[tuple[float, Any]]] = {k: [] for k in TYPES}
        self.vehicle: Vehicle | None = None
        self.params_by_src: dict[int, dict[str, float]] = {}
        self.texts_by_src: dict[int, list[str]] = {}
        self.messages = 0  # decoded messages of any type and source
        self.bad_bytes = 0
        self.dropped_rows = 0
        self.counts: dict[str, int] = {}  # vehicle messages by type (all types)

    def add_bad_data(self, nbytes: int) -> None:
        self.bad_bytes += nbytes

    def add(self, m: Any, t: float) -> None:
        """One decoded message received at ``t`` (s)."""
        mtype = m.get_type()
        if mtype == "BAD_DATA":
            self.bad_bytes += len(getattr(m, "data", b""))
            return
        self.messages += 1
        src = m.get_srcSystem()
        if self.vehicle is None and is_vehicle_heartbeat(m):
            self.vehicle = Vehicle(src, int(m.autopilot), int(m.type))
        if self.vehicle is not None and src == self.vehicle.system_id:
            self.counts[mtype] = self.counts.get(mtype, 0) + 1
        if mtype not in self.rows:
            return
        if mtype == "PARAM_VALUE":  # kept per system: a cut recording may lack the first
            pid = m.param_id  # heartbeat, and parameters are fetched once, early
            name = pid.decode("ascii", "replace") if isinstance(pid, bytes) else str(pid)
            self.params_by_src.setdefault(src, {})[name.rstrip("\x00")] = float(m.param_value)
            return
        if mtype == "STATUSTEXT":
            texts = self.texts_by_src.setdefault(src, [])
            if len(texts) < MAX_TEXTS:
                txt = m.text
                texts.append(txt.decode("ascii", "replace") if isinstance(txt, bytes) else str(txt))
            return
        if self.vehicle is None or src != self.vehicle.system_id:
            return
        value = self._value(mtype, m)
        if value is None:
            return
        rows = self.rows[mtype]
        if len(rows) >= MAX_ROWS_PER_TYPE:
            del rows[: MAX_ROWS_PER_TYPE // 2]
            self.dropped_rows += MAX_ROWS_PER_TYPE // 2
        rows.append((t, value))

    @staticmethod
    def _value(mtype: str, m: Any) -> Any:
        if mtype == "HEARTBEAT":
            return 1.0 if m.base_mode & ARMED_FLAG else 0.0
        if mtype == "SYS_STATUS":
            if m.voltage_battery in (0, 0xFFFF):
                return None
            return m.voltage_battery / 1000.0
        if mtype == "EXTENDED_SYS_STATE":
            if m.landed_state == MAV_LANDED_STATE_UNDEFINED:
                return None
            return 1.0 if m.landed_state == MAV_LANDED_STATE_ON_GROUND else 0.0
        if mtype == "SERVO_OUTPUT_RAW":
            if getattr(m, "port", 0) != 0:
                return None
            return [getattr(m, f"servo{i}_raw") for i in range(1, 9)]
        if mtype == "HIGHRES_IMU":
            return -float(m.zacc)
        if mtype in ("SCALED_IMU", "SCALED_IMU2", "RAW_IMU"):
            # mG (ArduPilot fills RAW_IMU in mG too; other autopilots' RAW_IMU is raw ADC)
            return -float(m.zacc) * G0 / 1000.0
        if mtype == "VFR_HUD":
            return [float(m.throttle) / 100.0, float(m.climb)]
        if mtype == "GLOBAL_POSITION_INT":
            return float(m.relative_alt) / 1000.0
        if mtype == "ATTITUDE_TARGET":
            return float(m.thrust)
        if mtype == "ATTITUDE":
            c = np.cos(m.roll) * np.cos(m.pitch)
            return float(np.degrees(np.arccos(np.clip(c, -1, 1))))
        return None

    # -- what the stream holds -----------------------------------------------------------------
    @property
    def params(self) -> dict[str, float]:
        return {} if self.vehicle is None else self.params_by_src.get(self.vehicle.system_id, {})

    def last(self, mtype: str) -> tuple[float, Any] | None:
        rows = self.rows.get(mtype)
        return rows[-1] if rows else None

    def has_voltage(self) -> bool:
        return bool(self.rows["SYS_STATUS"])

    def acceleration_source(self) -> str | None:
        for name in self._imus():
            if self.rows[name]:
                return name
        return None

    def _imus(self) -> list[str]:
        imus = ["HIGHRES_IMU", "SCALED_IMU", "SCALED_IMU2"]
        if self.vehicle is not None and self.vehicle.autopilot == MAV_AUTOPILOT_ARDUPILOTMEGA:
            imus.append("RAW_IMU")
        return imus

    # -- the FlightLog ----------------------------------------------------------------------
    def flight_log(self) -> FlightLog:
        """The FlightLog of everything received so far (times from the first row, s)."""
        vehicle = self.vehicle
        autopilot = vehicle.autopilot if vehicle else None
        vehicle_type = vehicle.mav_type if vehicle else None
        params = self.params
        texts = [] if vehicle is None else self.texts_by_src.get(vehicle.system_id, [])
        firsts = [r[0][0] for r in self.rows.values() if r]
        t0 = min(firsts) if firsts else 0.0
        rows = {k: [(t - t0, v) for t, v in r] for k, r in self.rows.items()}
        warnings: list[str] = []
        if self.bad_bytes:
            warnings.append(f"{self.bad_bytes} bytes of corrupt data skipped (bad MAVLink frames)")
        if self.dropped_rows:
            warnings.append(f"{self.dropped_rows} oldest telemetry rows dropped (memory bound)")
        flight = FlightLog(path=self.path, format=self.format, warnings=warnings)
        flight.metadata.update(
            {
                "system_id": vehicle.system_id if vehicle else None,
                "messages": self.messages,
                "t0_unix_s": t0,
            }
        )
        flight.voltage_v = _signal(rows["SYS_STATUS"], "V", "SYS_STATUS.voltage_battery/1000")
        flight.armed = _signal(rows["HEARTBEAT"], "bool", "HEARTBEAT.base_mode & 128")
        flight.landed = _signal(
            rows["EXTENDED_SYS_STATE"], "bool", "EXTENDED_SYS_STATE.landed_state == ON_GROUND"
        )
        for name in self._imus():
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
            flight.extras["climb_mps"] = Signal(
                hud.time_s, hud.values[:, 1], "m/s", "VFR_HUD.climb"
            )
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
            self._motors(flight, servo, autopilot, vehicle_type, params, texts, warnings)
        return flight

    @staticmethod
    def _motors(
        flight: FlightLog,
        servo: Signal,
        autopilot: int | None,
        vehicle_type: int | None,
        params: dict[str, float],
        texts: list[str],
        warnings: list[str],
    ) -> None:
        outs: FloatArray = servo.values
        flight.extras["outputs_all"] = Signal(
            servo.time_s, outs, "us", "SERVO_OUTPUT_RAW.servo1..8"
        )
        layout = None
        if autopilot == MAV_AUTOPILOT_ARDUPILOTMEGA:
            from thrustmap.flightlogs.dataflash import motor_layout

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
        if not chans:
            return
        flight.motor_outputs = Signal(
            servo.time_s,
            outs[:, [c - 1 for c in chans]],
            "us",
            "SERVO_OUTPUT_RAW.servo" + ",".join(map(str, chans)) + "_raw",
        )
        if autopilot == MAV_AUTOPILOT_ARDUPILOTMEGA and params:
            from thrustmap.flightlogs.dataflash import pwm_scale

            scale, src = pwm_scale(params)
        else:
            scale = ThrottleScale("pwm", 1000.0, 2000.0, "us")
            src = "assumed 1000..2000 us (no ESC range parameters in the telemetry)"
        flight.motor_output_scale = scale
        flight.metadata["motor_output_scale_source"] = src


def _signal(rows: list[tuple[float, Any]], unit: str, origin: str) -> Signal | None:
    if not rows:
        return None
    t = np.array([r[0] for r in rows], float)
    v = np.array([r[1] for r in rows], float)
    order = np.argsort(t, kind="stable")
    t, v = t[order], v[order]
    keep = np.concatenate([[True], np.diff(t) > 0])
    return Signal(t[keep], v[keep], unit, origin)
