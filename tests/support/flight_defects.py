"""Simulated flights with the defects real fleets show (issue 21), as FlightLog objects with
their truth: a touchdown mid-log that no land flag reports, an altitude that drifts by a metre
toward landing, brief command dips the rotors do not follow.

The physics: a normalised collective command c gives an upward specific force
a_up = g · c_lag / h(t) in free flight (h: the hover command, rising as the battery sags;
c_lag: c through the rotor's first-order lag), and a_up = g on the ground whatever c is. So
in steady free flight c·g/a_up = h(t): the steady ratio a test checks Df against.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from thrustmap.flightlogs.series import FlightLog, FloatArray, Signal

G0 = 9.80665


@dataclass
class DefectFlight:
    log: FlightLog
    time_s: FloatArray
    hover: FloatArray  # true hover command h(t)
    steady: FloatArray  # 1 where the truth is steady free flight (what Df should keep)


def _smoothstep(x: FloatArray) -> FloatArray:
    return np.asarray(0.5 - 0.5 * np.cos(np.pi * np.clip(x, 0.0, 1.0)), float)


def _lag(x: FloatArray, dt: float, tau: float) -> FloatArray:
    out = np.empty_like(x)
    acc = x[0]
    k = dt / (tau + dt)
    for i, v in enumerate(x):
        acc += k * (v - acc)
        out[i] = acc
    return out


def simulate(
    kind: str,
    *,
    duration_s: float = 120.0,
    rate_hz: float = 50.0,
    seed: int = 3,
    rotor_tau_s: float = 0.08,
) -> DefectFlight:
    """``kind``: touchdown | drift | dips | clean."""
    rng = np.random.default_rng(seed)
    dt = 1.0 / rate_hz
    t = np.arange(int(duration_s * rate_hz)) * dt
    t_up, t_down = 4.0, duration_s - 4.0
    # height profile: climb to 1.5 m, gentle steps between 1 and 1.5 m, land
    # (drift: 2 m first, then 1.0..1.3 m, as the PX4 hover whose altitude drifted a metre)
    first_m, steps_m = (2.0, (-1.0, 0.3, -0.3)) if kind == "drift" else (1.5, (-0.5, 0.5))
    z = first_m * _smoothstep((t - t_up) / 2.0)
    for k, tk in enumerate(np.arange(t_up + 15.0, t_down - 15.0, 15.0)):
        step = steps_m[k] if k < len(steps_m) else steps_m[1 + (k - 1) % (len(steps_m) - 1)]
        z += step * _smoothstep((t - tk) / 2.0)
    z_end = z[np.searchsorted(t, t_down - 3.0)]
    z -= z_end * _smoothstep((t - (t_down - 3.0)) / 2.5)
    ground = (t < t_up + 0.2) | (t > t_down - 0.4)
    touch = (0.0, 0.0)
    if kind == "touchdown":  # back on the ground for 10 s at mid-log, then flies again
        touch = (0.45 * duration_s, 0.45 * duration_s + 10.0)
        lvl = np.interp(touch[0] - 3.0, t, z)
        dip = _smoothstep((t - (touch[0] - 3.0)) / 2.6) - _smoothstep((t - touch[1]) / 2.0)
        z = z - lvl * dip
        ground |= (t > touch[0] - 0.4) & (t < touch[1] + 0.2)
    z = np.where(ground, 0.0, z)
    a_kin = np.gradient(np.gradient(z, dt), dt)
    hover = 0.357 + 0.03 * t / duration_s  # the battery sags: hover needs more command
    cmd_air = hover * (G0 + a_kin) / G0
    cmd = cmd_air.copy()
    # on the ground: idle, the spool-up before and the spool-down after (ArduCopter 0.30→0.12)
    spool = np.where(t < t_up, 0.12 + 0.18 * np.clip((t - 1.0) / 3.0, 0, 1), 0.12)
    cmd = np.where(ground, spool, cmd)
    if kind == "touchdown":
        on = (t > touch[0] - 0.4) & (t < touch[1] + 0.2)
        fall = 0.30 - 0.18 * np.clip((t - touch[0]) / 3.0, 0, 1)
        rise = 0.12 + 0.18 * np.clip((t - (touch[1] - 3.0)) / 3.0, 0, 1)
        cmd = np.where(on, np.where(t < touch[1] - 3.0, fall, rise), cmd)
    dip_mask = np.zeros(len(t), bool)
    if kind == "dips":  # brief −20 % command dips the rotors do not follow (a_up unchanged)
        for k, tk in enumerate(np.arange(t_up + 8.0, t_down - 8.0, 4.0)):
            length = 0.2 + 1.3 * ((k * 0.37) % 1.0)
            m = (t >= tk) & (t < tk + length)
            dip_mask |= m
    thrust = _lag(cmd_air, dt, rotor_tau_s)  # the rotors follow the flight command, not a dip
    cmd = np.where(dip_mask, 0.8 * cmd, cmd)
    a_up = np.where(ground, G0, G0 * thrust / hover) + rng.normal(0, 0.3, len(t))
    volt = 16.4 - 1.4 * t / duration_s - 0.3 * (~ground) + rng.normal(0, 0.01, len(t))
    reading = z.copy()
    if kind == "drift":  # the local altitude drifts +1.2 m toward landing (baro, prop wash)
        reading = z + 1.2 * _smoothstep((t - (t_down - 3.5)) / 3.0)
    fl = FlightLog(path=f"{kind}.sim", format="sim")
    fl.voltage_v = Signal(t, volt, "V", "sim BAT.Volt")
    fl.accel_up_mps2 = Signal(t, a_up, "m/s^2", "sim -IMU.AccZ")
    fl.thrust_cmd_norm = Signal(t, cmd, "1", "sim CTUN.ThO")
    fl.armed = Signal(np.array([0.0, 0.5, duration_s - 0.5]), np.array([0.0, 1.0, 0.0]), "bool",
                      "sim EV")  # fmt: skip
    air = ~ground
    first, last = t[np.flatnonzero(air)[0]], t[np.flatnonzero(air)[-1]]
    # the land detector: airborne from liftoff to the final touchdown; the mid-log touchdown
    # is never reported
    fl.landed = Signal(np.array([0.0, first - 0.5, last + 0.5]), np.array([1.0, 0.0, 1.0]),
                       "bool", "sim EV 18/28")  # fmt: skip
    fl.extras["hover_throttle"] = Signal(t[::10], hover[::10], "1", "sim CTUN.ThH")
    fl.extras["height_m"] = Signal(t, reading + rng.normal(0, 0.03, len(t)), "m", "sim CTUN.Alt")
    # truth: steady free flight, away from the ground by 3 s, from climbs and from dips
    near_ground = np.convolve(ground.astype(float), np.ones(int(3 * rate_hz) * 2 + 1), "same") > 0
    near_dip = np.convolve(dip_mask.astype(float), np.ones(int(0.5 * rate_hz) * 2 + 1), "same") > 0
    steady = ~near_ground & ~near_dip & (np.abs(a_kin) < 0.3)
    return DefectFlight(fl, t, hover, steady.astype(float))


def off_ratio(table_t: FloatArray, cmd: FloatArray, a_up: FloatArray, sim: DefectFlight,
              tol: float = 0.05) -> float:  # fmt: skip
    """Fraction of Df rows whose command/force ratio is off the true steady one by > tol."""
    h = np.interp(table_t, sim.time_s, sim.hover)
    return float(np.mean(np.abs(cmd * G0 / (a_up * h) - 1.0) > tol)) if len(table_t) else 1.0


def kept_of_steady(table_t: FloatArray, sim: DefectFlight, rate_hz: float = 10.0) -> float:
    """Fraction of the truly steady flight (in Df bins) that Df kept."""
    edges = np.arange(sim.time_s[0], sim.time_s[-1] + 1.0 / rate_hz, 1.0 / rate_hz)
    centres = edges[:-1] + 0.5 / rate_hz
    steady = np.interp(centres, sim.time_s, sim.steady) > 0.999
    kept = np.zeros(len(centres), bool)
    idx = np.clip(np.searchsorted(centres, table_t - 0.25 / rate_hz), 0, len(centres) - 1)
    kept[idx] = True
    return float((kept & steady).sum() / max(int(steady.sum()), 1))


def write_copter33_paused(
    path: str, *, flights: int = 4, seed: int = 11
) -> list[tuple[float, DefectFlight]]:
    """An ArduCopter 3.3-style DataFlash log (TimeMS, CURR, EV without any time stamp) holding
    ``flights`` hover flights, logging paused while disarmed between them. As the firmware
    does, the events of the pause are written when logging resumes: the new ARMED before any
    timestamped message (timed by its neighbours: at the end of the previous flight), the
    previous flight's DISARMED flushed just after the first samples (so a reconstruction from
    the events holds the whole flight disarmed)."""
    from support.flightlog_writers import DataFlashWriter

    lo, hi, spin_armed = 1000.0, 2000.0, 70.0
    sims = [simulate("clean", duration_s=60.0 + 25.0 * k, seed=seed + k) for k in range(flights)]
    with open(path, "wb") as f:
        w = DataFlashWriter(f)
        w.define("PARM", "INf", "TimeMS,Name,Value")
        w.define("MSG", "IZ", "TimeMS,Message")
        w.define("IMU", "Iffffff", "TimeMS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ")
        w.define("CURR", "IhhhHf", "TimeMS,Throttle,Volt,Curr,Vcc,CurrTot")
        w.define("CTUN", "Ihhfff", "TimeMS,ThrIn,AngBst,ThrOut,DAlt,Alt")
        w.define("RCOU", "Ihhhhhhhh", "TimeMS," + ",".join(f"Ch{i}" for i in range(1, 9)))
        w.define("EV", "B", "Id")
        w.write("MSG", 0, b"APM:Copter V3.3-dev (thrustmap simulate)")
        for name, value in (("RC3_MIN", lo), ("RC3_MAX", hi), ("MOT_SPIN_ARMED", spin_armed),
                            ("FRAME", 1.0)):  # fmt: skip
            w.write("PARM", 0, name.encode(), value)
        t_start = 5.0
        out = []
        for k, s in enumerate(sims):
            out.append((t_start, s))
            fl = s.log
            assert fl.thrust_cmd_norm is not None and fl.accel_up_mps2 is not None
            assert fl.voltage_v is not None
            w.write("EV", 10)  # ARMED (this flight), before any timestamped message
            t = s.time_s
            cmd = fl.thrust_cmd_norm.values
            h = fl.extras["height_m"].values
            landed = fl.landed.hold(t) if fl.landed is not None else np.zeros(len(t))
            armed = fl.armed.hold(t) if fl.armed is not None else np.ones(len(t))
            ev_prev = landed[0]
            for i in range(len(t)):
                if landed[i] != ev_prev:
                    w.write("EV", 18 if landed[i] > 0.5 else 28)
                    ev_prev = landed[i]
                ms = int(round((t_start + t[i]) * 1e3))
                w.write("IMU", ms, 0.0, 0.0, 0.0, 0.0, 0.0, -float(fl.accel_up_mps2.values[i]))
                if i % 5 == 0:
                    v = float(fl.voltage_v.values[i])
                    w.write("CURR", ms, 0, int(round(v * 100)), 0, 5000, 0.0)
                w.write("CTUN", ms, 0, 0, float(cmd[i]) * 1000.0, 0.0, float(h[i]))
                if armed[i] > 0.5:
                    pwm = max(lo + spin_armed, lo + float(cmd[i]) * (hi - lo))
                    ch = [int(round(pwm + d)) for d in (3, -3, 2, -2)]
                else:
                    ch = [int(lo)] * 4
                w.write("RCOU", ms, *ch, 0, 0, 0, 0)
                if i == 2 and k > 0:  # the previous flight's DISARMED, flushed after resuming
                    w.write("EV", 11)
            t_start += float(t[-1]) + 40.0  # paused 40 s while disarmed
    return out
