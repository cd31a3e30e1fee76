"""An ArduCopter 3.3-dev DataFlash log of a simulated hover, with the defects the 2014-2016
PXF/Erle fleet shows (issue 34), each switchable, so a test knows the truth.

The layout is the firmware's own (ArduCopter 82481f30, 2014-08-28, Log.pde): IMU and CURR with
TimeMS, RCOU ``TimeMS,Ch1..Ch12`` (DataFlash.h), CTUN ``Ihhhffecchh`` = TimeMS, ThrIn, AngBst, ThrOut (0..1000), DAlt, Alt (inertial
altitude, m), BarAlt (barometer, cm through 'e'), DSAlt, SAlt, DCRt, CRt (inertial climb rate,
cm/s), and EV with an Id only (no time), written as it happens, none while the log is paused.

Defects:
- ``ev-burst``: at liftoff the land detector and the altitude controller fight for one loop:
  LAND_COMPLETE / NOT_LANDED pairs written between two timed messages, ending NOT_LANDED.
- ``crt-offset``: CRt carries an offset (an accelerometer bias integrated by the inertial
  filter), the logged altitude does not.
- ``inav-diverged``: the inertial altitude (Alt) and its climb rate (CRt) run away at
  ``DRIFT_MPS`` while the barometer (BarAlt) follows the vehicle.
- ``accel-scale``: the IMU reads ``ACCEL_SCALE`` × the true specific force (8.34 m/s² at rest).
- ``vibration``: as ``accel-scale`` at rest, and in the air the IMU reads ``VIBRATION_DROP_MPS2``
  less again (vibration clipped by the sensor: a real PXF flight reads 8.7 m/s² at rest and
  5-6 in a hover), so the log's mean specific force is below 7 m/s² until the rest calibrates
  it.
- ``log-pause``: the vehicle lands, disarms (logging stops, as the firmware suspends writes on
  disarm) for ``PAUSE_S`` and arms again for a second flight; the EVs of the pause are written
  when logging resumes.
- ``ground-run``: after the flight(s) logging pauses ``PAUSE_S``, then the vehicle is armed
  again and stays on the ground: 2 s at zero throttle (motors at the armed spin), then
  ``GROUND_RUN_S`` at the throttle an altitude-holding mode holds on the ground before takeoff
  (get_throttle_pre_takeoff: ``GROUND_THROTTLE``, below THR_MID/2), the IMU reading g, the inertial altitude sinking at
  ``GROUND_DRIFT_MPS`` for 2 s after arming (as the real log's: an accelerometer off at rest
  integrated), so the altitude is not trusted; no EV says landed (they are untimed). A real PXF log (18-03-2014 althold_error2) has 28 s of it.
Every log starts with ``REST_S`` of ground rest, armed at idle, before the takeoff.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from support.flightlog_writers import DataFlashWriter
from support.simulate_flight import HoverSim, SimFlight, simulate_hover
from thrustmap.flightlogs.series import FloatArray

G0 = 9.80665
REST_S = 6.0
DRIFT_MPS = 1.5
CRT_OFFSET_MPS = 1.5
ACCEL_SCALE = 0.85
PAUSE_S = 40.0
VIBRATION_DROP_MPS2 = 2.0
GROUND_RUN_S = 30.0
GROUND_THROTTLE = 0.22
GROUND_DRIFT_MPS = 2.0
DEFECTS = ("ev-burst", "crt-offset", "inav-diverged", "accel-scale", "log-pause", "vibration",
           "ground-run")  # fmt: skip


@dataclass
class Copter33:
    path: Path
    flight: SimFlight  # the true flight (without the rest before it)
    time_s: FloatArray  # log time of each true sample (the rest and any pause added)
    airborne_s: float  # true airborne seconds
    ground_run_s: tuple[float, float] | None = None  # log time of the ground run (ground-run)


def _ev(w: DataFlashWriter, *ids: int) -> None:
    for i in ids:
        w.write("EV", i)


def write_copter33(
    path: Path,
    defects: tuple[str, ...] = (),
    *,
    seed: int = 4,
    vibration_drop_mps2: float = VIBRATION_DROP_MPS2,
) -> Copter33:
    for d in defects:
        if d not in DEFECTS:
            raise ValueError(f"unknown defect {d!r}")
    flight = simulate_hover(_sim(seed))
    scale = flight.stand_map.throttle_scale
    n = len(flight.time_s)
    rate = flight.sim.rate_hz
    # log time: REST_S of armed rest, then the flight (twice, a pause between, for log-pause)
    rest_n = int(REST_S * rate)
    copies = 2 if "log-pause" in defects else 1
    rng = np.random.default_rng(seed + 100)
    rows: list[tuple[float, float, float, float, float, FloatArray, float, bool]] = []
    log_t: list[float] = []
    t0 = 1.0
    for c in range(copies):
        start = t0 + c * (REST_S + flight.time_s[-1] + PAUSE_S)
        for k in range(rest_n):  # on the ground, armed, idle: the IMU reads g
            t = start + k / rate
            idle = np.full(flight.throttle_pct.shape[1], 8.0)
            rows.append((t, G0 + rng.normal(0, 0.05), 0.0, 0.08, flight.voltage_v[0], idle,
                         0.0, False))  # fmt: skip
        for k in range(n):
            t = start + REST_S + flight.time_s[k]
            air = flight.landed[k] < 0.5
            rows.append((t, float(flight.accel_up_mps2[k]), float(flight.height_m[k]),
                         float(flight.thrust_norm[k]), float(flight.voltage_v[k]),
                         flight.throttle_pct[k], float(flight.tilt_deg[k]), bool(air)))  # fmt: skip
            log_t.append(t)
    ground_run: tuple[float, float] | None = None
    if "ground-run" in defects:
        start = rows[-1][0] + PAUSE_S
        idle = np.full(flight.throttle_pct.shape[1], 8.0)
        ground_n = int((2.0 + GROUND_RUN_S) * rate)
        for k in range(ground_n):
            thr = 0.0 if k < 2.0 * rate else GROUND_THROTTLE
            # just armed, the motors still at the minimum (AP_Motors ramps spin_when_armed
            # up from 0 after arming), then the pre-takeoff throttle
            pct = np.zeros(len(idle)) if thr == 0.0 else np.full(len(idle), 100 * thr)
            rows.append((start + k / rate, G0 + rng.normal(0, 0.05), 0.0, thr,
                         flight.voltage_v[-1], pct, 0.0, False))  # fmt: skip
        ground_run = (start, start + ground_n / rate)
    t_all = np.array([r[0] for r in rows])
    h_all = np.array([r[2] for r in rows])
    true_climb = np.gradient(h_all, t_all)
    with open(path, "wb") as f:
        w = DataFlashWriter(f)
        w.define("PARM", "INf", "TimeMS,Name,Value")
        w.define("MSG", "IZ", "TimeMS,Message")
        w.define("IMU", "Iffffff", "TimeMS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ")
        w.define("CURR", "IhhhHfh", "TimeMS,ThrIn,ThrInt,Volt,Curr,Vcc,CurrTot")
        w.define("CTUN", "Ihhhffecchh", "TimeMS,ThrIn,AngBst,ThrOut,DAlt,Alt,BarAlt,DSAlt,SAlt,"
                 "DCRt,CRt")  # fmt: skip
        # RCOU as DataFlash.h of 82481f30 defines it: TimeMS and 12 outputs Ch1..Ch12
        w.define("RCOU", "I" + "h" * 12, "TimeMS," + ",".join(f"Ch{i}" for i in range(1, 13)))
        w.define("ATT", "Iccccc", "TimeMS,RollIn,Roll,PitchIn,Pitch,YawIn")
        w.define("EV", "B", "Id")
        w.write("MSG", 0, b"ArduCopter V3.3-dev (82481f30)")
        w.write("MSG", 0, b"Frame: QUAD")
        for name, value in (("RC3_MIN", scale.lo), ("RC3_MAX", scale.hi),
                            ("MOT_SPIN_ARMED", 70.0)):  # fmt: skip
            w.write("PARM", 0, name.encode(), value)
        was_air = False
        prev_t = -1.0
        for i, (t, a_up, h, thr, volt, th, tilt, air) in enumerate(rows):
            if t - prev_t > 1.0:  # (re)start of logging: armed now (EV 11 of the pause first)
                if prev_t > 0:
                    _ev(w, 11)
                _ev(w, 10)
            prev_t = t
            if air and not was_air:
                if "ev-burst" in defects:
                    _ev(w, 18, 28, 18, 28, 18, 28, 18, 28)
                else:
                    _ev(w, 28)
            if was_air and not air:
                _ev(w, 18)
            was_air = air
            ms = int(round(t * 1e3))
            a_meas = a_up * (ACCEL_SCALE if "accel-scale" in defects else 1.0)
            if "vibration" in defects:
                a_meas = ACCEL_SCALE * (a_up - (vibration_drop_mps2 if air else 0.0))
            w.write("IMU", ms, 0.0, 0.0, 0.0, 0.0, 0.0, -a_meas)
            if i % 5 == 0:
                w.write("CURR", ms, 0, 0, int(round(volt * 100)), 0, 5000, 0)
            inav, crt = h, float(true_climb[i])
            if ground_run is not None and t >= ground_run[0]:  # the inertial altitude sinks
                inav = -min(GROUND_DRIFT_MPS * (t - ground_run[0]), 2.0 * GROUND_DRIFT_MPS)
                crt = -GROUND_DRIFT_MPS if t - ground_run[0] < 2.0 else 0.0
            if "inav-diverged" in defects:
                inav, crt = h + DRIFT_MPS * (t - t_all[0]), crt + DRIFT_MPS
            if "crt-offset" in defects:
                crt += CRT_OFFSET_MPS
            baro_cm = int(round((h + rng.normal(0, 0.05)) * 100))
            w.write("CTUN", ms, 0, 0, int(round(thr * 1000)), 0.0, inav, baro_cm, 0, 0, 0,
                    int(round(crt * 100)))  # fmt: skip
            pwm = scale.from_pct(np.asarray(th, float))
            chans = [int(round(x)) for x in pwm] + [0] * (12 - len(pwm))
            w.write("RCOU", ms, *chans)
            w.write("ATT", ms, 0, int(round(tilt * 100)), 0, 0, 0)
        _ev(w, 11)
    airborne = float((flight.landed < 0.5).sum() / rate) * copies
    return Copter33(path, flight, np.array(log_t), airborne, ground_run)


def _sim(seed: int) -> HoverSim:
    return HoverSim(duration_s=90.0, rate_hz=50.0, accel_noise_mps2=0.2, seed=seed)
