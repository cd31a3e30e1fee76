"""A simulated hover flight with a known correction factor γ(B), written in the supported formats.

The plant is built so that γ is exact (seed paper eq. 9-10): the flight controller asks for a
collective thrust T_c, the stand map turns T_c/n into a throttle per rotor, and each rotor really
pushes map_forward(throttle, B) / γ(B). So the measured force is F = T_c/γ(B), and the
controller, holding the profile, commands T_c = γ(B)·m·(g + a)/cos(tilt). Per-motor throttles
differ by a zero-sum thrust split (attitude control), so summing the map's forward direction over
the rotors gives T_c back exactly. The accelerometer adds white noise; the battery sags with load.

``simulate_hover()`` returns the true series; ``write_*`` put them into each log format.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from support import flightlog_writers as writers
from support.flightlog_writers import DataFlashWriter, TlogWriter, ULogTopic
from thrustmap.core.units import SCALES
from thrustmap.fitting.mapfile import Box, ThrustMap, ValidityBox
from thrustmap.flightlogs.series import FloatArray

G0 = 9.80665


def sim_stand_map() -> ThrustMap:
    """A plausible per-rotor 6S 5-inch stand map (motor model): ~2.5 N at 40 % on 23 V."""
    return ThrustMap(
        model="motor",
        coefficients=(0.0, 100.0, 200.0, 201.0),
        throttle_scale=SCALES["pwm"],
        validity=ValidityBox(Box(0.0, 11.0), Box(20.4, 25.2), Box(0.0, 100.0)),
        strategy="SR",
        created_utc="2024-01-01T00:00:00+00:00",
    )


def default_gamma(b_ref: float = 24.6) -> tuple[float, ...]:
    """γ(B) = 1 + 0.025·(b_ref − B) + 0.003·(b_ref − B)², as ascending powers of B."""
    p = np.polynomial.Polynomial([1.0, 0.025, 0.003])
    q = p(np.polynomial.Polynomial([b_ref, -1.0]))  # substitute (b_ref − B)
    return tuple(float(c) for c in q.coef)


@dataclass(frozen=True)
class HoverSim:
    mass_kg: float = 1.0
    rotors: int = 4
    duration_s: float = 60.0
    rate_hz: float = 50.0
    voltage_start_v: float = 24.6
    voltage_end_v: float = 21.8
    sag_v: float = 0.4  # voltage drop at hover load vs idle
    gamma: tuple[float, ...] = field(default_factory=default_gamma)
    accel_noise_mps2: float = 0.3
    tilt_amplitude_deg: float = 3.0
    seed: int = 0


@dataclass
class SimFlight:
    """True series of a simulated flight (one row per sample)."""

    sim: HoverSim
    stand_map: ThrustMap
    time_s: FloatArray
    voltage_v: FloatArray
    accel_up_mps2: FloatArray  # measured (noisy)
    force_n: FloatArray  # true collective force
    thrust_cmd_n: FloatArray  # collective command, N
    throttle_pct: FloatArray  # (n, rotors), percent of the map's scale
    tilt_deg: FloatArray
    height_m: FloatArray
    armed: FloatArray
    landed: FloatArray
    hover_thrust: FloatArray  # normalised collective throttle needed to hover

    def gamma(self, voltage_v: FloatArray) -> FloatArray:
        return np.asarray(np.polynomial.polynomial.polyval(voltage_v, self.sim.gamma), float)

    @property
    def thrust_norm(self) -> FloatArray:
        """Normalised collective command: the mean motor throttle, 0..1."""
        cached = self.__dict__.get("_thrust_norm")
        if cached is None:
            cached = np.asarray(self.throttle_pct.mean(axis=1) / 100.0, float)
            self.__dict__["_thrust_norm"] = cached
        return np.asarray(cached)


def _height_profile(t: FloatArray, duration: float) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Height, airborne flag and takeoff/landing times: idle, climb, hover steps, land, idle."""
    t_up, t_down = 2.0, duration - 3.0
    levels = [1.5, 2.5, 1.0, 2.0, 1.5]
    knots = np.linspace(t_up + 2.0, t_down - 2.0, len(levels) + 1)
    z = np.zeros_like(t)

    def smooth(x: FloatArray) -> FloatArray:  # 0..1 cosine step
        return 0.5 - 0.5 * np.cos(np.pi * np.clip(x, 0.0, 1.0))

    z += levels[0] * smooth((t - t_up) / 2.0)
    for k in range(1, len(levels)):
        z += (levels[k] - levels[k - 1]) * smooth((t - knots[k]) / 1.5)
    z -= levels[-1] * smooth((t - (t_down - 2.0)) / 2.0)
    airborne = ((t > t_up + 0.3) & (t < t_down - 0.3)).astype(float)
    return z, airborne, np.array([t_up, t_down])


def simulate_hover(sim: HoverSim | None = None, stand_map: ThrustMap | None = None) -> SimFlight:
    sim = sim or HoverSim()
    tmap = stand_map or sim_stand_map()
    rng = np.random.default_rng(sim.seed)
    n = int(sim.duration_s * sim.rate_hz)
    t = np.arange(n) / sim.rate_hz
    dt = 1.0 / sim.rate_hz
    z, airborne, _ = _height_profile(t, sim.duration_s)
    a_kin = np.gradient(np.gradient(z, dt), dt)
    tilt = sim.tilt_amplitude_deg * np.abs(np.sin(0.37 * t)) * airborne
    cos_t = np.cos(np.radians(tilt))
    force = np.where(airborne > 0, sim.mass_kg * (G0 + a_kin) / cos_t, 0.15 * sim.mass_kg * G0)
    hover_f = sim.mass_kg * G0
    frac = t / sim.duration_s
    ocv = sim.voltage_start_v + (sim.voltage_end_v - sim.voltage_start_v) * frac
    voltage = ocv - sim.sag_v * force / hover_f + rng.normal(0, 0.01, n)
    gamma = np.polynomial.polynomial.polyval(voltage, sim.gamma)
    t_cmd = gamma * force
    # zero-sum per-rotor split (attitude control), then each rotor's throttle from the map
    split = 0.03 * np.sin(np.outer(t, [1.1, 1.7, 2.3, 0.7][: sim.rotors]) + np.arange(sim.rotors))
    split -= split.mean(axis=1, keepdims=True)
    per_rotor = np.clip(t_cmd[:, None] / sim.rotors * (1.0 + split), 1e-4, None)
    th = tmap.throttle_pct(per_rotor, voltage[:, None], corrected=False)
    # ground contact: the ground carries the weight, the IMU still reads ≈ g
    a_meas = np.where(airborne > 0, force / sim.mass_kg, G0) + rng.normal(
        0, sim.accel_noise_mps2, n
    )
    hover_per_rotor = gamma * hover_f / sim.rotors
    hover_th = tmap.throttle_pct(hover_per_rotor, voltage, corrected=False) / 100.0
    # recompute the command from the throttles so that Σ forward(throttle) == T_c exactly
    t_cmd = tmap.thrust_n(th, voltage[:, None], corrected=False).sum(axis=1)
    force = np.where(airborne > 0, t_cmd / gamma, force)
    return SimFlight(
        sim=sim,
        stand_map=tmap,
        time_s=t,
        voltage_v=voltage,
        accel_up_mps2=a_meas,
        force_n=force,
        thrust_cmd_n=t_cmd,
        throttle_pct=th,
        tilt_deg=tilt,
        height_m=z,
        armed=np.ones(n),
        landed=1.0 - airborne,
        hover_thrust=hover_th,
    )


# -- writers -------------------------------------------------------------------------------------


def write_paper_csv(flight: SimFlight, path: str | Path) -> None:
    """The seed paper's flight CSV schema (collective N)."""
    with open(path, "w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(
            ["Thrust sended (N)", "Thrust measured (N)", "Voltage (V)", "Acc (m/s²)", "m (Kg)",
             "Throttle (%)", "Position_z (m)", "Time (s)"]
        )  # fmt: skip
        m = flight.sim.mass_kg
        for k in range(len(flight.time_s)):
            a = flight.accel_up_mps2[k]
            w.writerow(
                [f"{flight.thrust_cmd_n[k]:.5f}", f"{m * a:.5f}", f"{flight.voltage_v[k]:.4f}",
                 f"{a:.5f}", f"{m:g}", f"{flight.throttle_pct[k].mean():.4f}",
                 f"{flight.height_m[k]:.4f}", f"{flight.time_s[k]:.4f}"]
            )  # fmt: skip


def write_generic_csv(flight: SimFlight, path: str | Path) -> None:
    """A CSV in the project's canonical column names, with µs time and FRD accel (for maps)."""
    with open(path, "w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(["t_us", "vbat", "acc_z_frd", "thr_norm", "armed", "landed"])
        for k in range(len(flight.time_s)):
            w.writerow(
                [int(flight.time_s[k] * 1e6), f"{flight.voltage_v[k]:.4f}",
                 f"{-flight.accel_up_mps2[k]:.5f}", f"{flight.thrust_norm[k]:.5f}",
                 int(flight.armed[k]), int(flight.landed[k])]
            )  # fmt: skip


def write_dataflash(flight: SimFlight, path: str | Path, *, old_firmware: bool = False) -> None:
    """ArduCopter-style .bin: IMU, BAT (or old CURR + TimeMS), RCOU, CTUN, ATT, EV, PARM, MSG."""
    scale = flight.stand_map.throttle_scale
    with open(path, "wb") as f:
        w = DataFlashWriter(f)
        tcol, tfmt = ("TimeMS", "I") if old_firmware else ("TimeUS", "Q")
        tmul = 1e3 if old_firmware else 1e6
        w.define("PARM", tfmt + "Nf", f"{tcol},Name,Value")
        w.define("MSG", tfmt + "Z", f"{tcol},Message")
        w.define("IMU", tfmt + "ffffff", f"{tcol},GyrX,GyrY,GyrZ,AccX,AccY,AccZ")
        if old_firmware:
            w.define("CURR", tfmt + "hhhHf", f"{tcol},Throttle,Volt,Curr,Vcc,CurrTot")
            w.define("CTUN", tfmt + "hhfff", f"{tcol},ThrIn,AngBst,ThrOut,DAlt,Alt")
            w.define(
                "RCOU", tfmt + "hhhhhhhh", f"{tcol}," + ",".join(f"Ch{i}" for i in range(1, 9))
            )
        else:
            w.define("BAT", tfmt + "fffff", f"{tcol},Volt,VoltR,Curr,CurrTot,Temp")
            w.define("CTUN", tfmt + "fffff", f"{tcol},ThI,ABst,ThO,ThH,Alt")
            w.define("RCOU", tfmt + "hhhhhhhh", f"{tcol}," + ",".join(f"C{i}" for i in range(1, 9)))
        w.define("ATT", tfmt + "cccc", f"{tcol},DesRoll,Roll,DesPitch,Pitch")
        if old_firmware:  # Copter <= 3.3 writes EV without any timestamp (LOG_EVENT_MSG: Id only)
            w.define("EV", "B", "Id")
        else:
            w.define("EV", tfmt + "B", f"{tcol},Id")

        def event(t_s: float, ev_id: int) -> None:
            if old_firmware:
                w.write("EV", ev_id)
            else:
                w.write("EV", int(round((t_s + 1.0) * tmul)), ev_id)

        w.write("MSG", 0, b"ArduCopter V4.5.0-sim (thrustmap simulate)")
        for name, value in (
            ("MOT_PWM_MIN", scale.lo),
            ("MOT_PWM_MAX", scale.hi),
            ("FRAME_CLASS", 1.0),
        ):
            w.write("PARM", 0, name.encode(), value)
        t_air = flight.time_s[flight.landed < 0.5]
        events = [(flight.time_s[0] + 0.01, 10), (t_air[0], 28), (t_air[-1], 18),
                  (flight.time_s[-1], 11)]  # fmt: skip
        ev_k = 0
        pwm = scale.from_pct(flight.throttle_pct)
        for k in range(len(flight.time_s)):
            tk = flight.time_s[k] + 1.0
            while ev_k < len(events) and events[ev_k][0] <= flight.time_s[k]:
                event(*events[ev_k])
                ev_k += 1
            ts = int(round(tk * tmul))
            w.write("IMU", ts, 0.0, 0.0, 0.0, 0.0, 0.0, -float(flight.accel_up_mps2[k]))
            if k % 5 == 0:
                v = float(flight.voltage_v[k])
                if old_firmware:
                    w.write("CURR", ts, 0, int(round(v * 100)), 0, 5000, 0.0)
                else:
                    w.write("BAT", ts, v, v + 0.3, 20.0, 0.0, 25.0)
            th = float(flight.thrust_norm[k])
            if old_firmware:
                w.write("CTUN", ts, 0, 0, th * 1000.0, 0.0, float(flight.height_m[k]))
            else:
                w.write(
                    "CTUN",
                    ts,
                    th,
                    0.0,
                    th,
                    float(flight.hover_thrust[k]),
                    float(flight.height_m[k]),
                )
            chans = [int(round(x)) for x in pwm[k]] + [0] * (8 - pwm.shape[1])
            w.write("RCOU", ts, *chans)
            tilt = int(round(flight.tilt_deg[k] * 100))
            w.write("ATT", ts, 0, tilt, 0, 0)
        while ev_k < len(events):
            event(*events[ev_k])
            ev_k += 1


def write_ulog(
    flight: SimFlight, path: str | Path, *, legacy: bool = False, battery: bool = True
) -> None:
    """PX4-style ULog; ``legacy`` uses actuator_controls_0 / actuator_outputs (before v1.14);
    ``battery=False`` leaves battery_status out (a vehicle without a voltage sensor)."""
    us = (flight.time_s * 1e6).astype(np.int64) + 1_000_000
    n = len(us)
    rot = flight.sim.rotors
    batt = ULogTopic("battery_status", [("float", "voltage_v", 0), ("float", "scale", 0)])
    if legacy:
        batt.fields[0] = ("float", "voltage_filtered_v", 0)
    sc = ULogTopic("sensor_combined", [("float", "accelerometer_m_s2", 3)])
    vs = ULogTopic("vehicle_status", [("uint8_t", "arming_state", 0)])
    ld = ULogTopic("vehicle_land_detected", [("bool", "landed", 0)])
    att = ULogTopic("vehicle_attitude", [("float", "q", 4)])
    topics = [batt, sc, vs, ld, att]
    if legacy:
        thr = ULogTopic("actuator_controls_0", [("float", "control", 8)])
        outs = ULogTopic("actuator_outputs", [("uint32_t", "noutputs", 0), ("float", "output", 16)])
        topics += [thr, outs]
    else:
        thr = ULogTopic("vehicle_thrust_setpoint", [("float", "xyz", 3)])
        mot = ULogTopic("actuator_motors", [("float", "control", 12)])
        hte = ULogTopic(
            "hover_thrust_estimate", [("float", "hover_thrust", 0), ("bool", "valid", 0)]
        )
        topics += [thr, mot, hte]
    # the ESC range the log's parameters give (PWM_MAIN_MINn/MAXn, v1.14+; PWM_MIN/MAX before):
    # deliberately not 1000..2000, so a reader that assumes it is caught
    pwm = flight.stand_map.throttle_scale.from_pct(flight.throttle_pct)
    lo_us, hi_us = (1075.0, 1950.0) if legacy else (1100.0, 1900.0)
    params: dict[str, float | int] = {"MC_BAT_SCALE_EN": 0, "MPC_THR_HOVER": 0.4}
    if legacy:
        params.update({"MAV_TYPE": 2, "PWM_MIN": int(lo_us), "PWM_MAX": int(hi_us)})
    else:
        params["CA_ROTOR_COUNT"] = rot
        for m in range(1, rot + 1):
            params.update({f"PWM_MAIN_FUNC{m}": 100 + m, f"PWM_MAIN_MIN{m}": int(lo_us),
                           f"PWM_MAIN_MAX{m}": int(hi_us)})  # fmt: skip
    for k in range(n):
        u = int(us[k])
        sc.rows.append((u, [0.0, 0.0, -float(flight.accel_up_mps2[k])]))
        half = np.radians(flight.tilt_deg[k]) / 2
        att.rows.append((u, [float(np.cos(half)), float(np.sin(half)), 0.0, 0.0]))
        tn = float(flight.thrust_norm[k])
        norm = [float(x) for x in (pwm[k] - lo_us) / (hi_us - lo_us)]  # control 0..1
        if legacy:
            thr.rows.append((u, [0.0, 0.0, 0.0, tn, 0.0, 0.0, 0.0, 0.0]))
            outs.rows.append((u, rot, [float(x) for x in pwm[k]] + [900.0] * (16 - rot)))
        else:
            thr.rows.append((u, [0.0, 0.0, -tn]))
            mot.rows.append((u, norm + [float("nan")] * (12 - rot)))
        if k % 5 == 0:
            batt.rows.append((u, float(flight.voltage_v[k]), 1.0))
            if not legacy and flight.landed[k] < 0.5:
                hte.rows.append((u, float(flight.hover_thrust[k]), True))
        if k == 0 or flight.landed[k] != flight.landed[k - 1]:
            ld.rows.append((u, bool(flight.landed[k] > 0.5)))
        if k % 50 == 0:
            vs.rows.append((u, 2))
    release = (1 << 24) | ((9 if legacy else 15) << 16) | 0xFF
    writers.write_ulog(
        path,
        topics if battery else [t for t in topics if t is not batt],
        info={"sys_name": "PX4", "ver_hw": "SITL_SIM", "ver_sw_release": release},
        params=params,
    )


def write_tlog(
    flight: SimFlight, path: str | Path, *, t0_unix_s: float = 1.7e9, ardupilot: bool = False
) -> None:
    """MAVLink telemetry at 10 Hz: HEARTBEAT, SYS_STATUS, EXTENDED_SYS_STATE, SERVO_OUTPUT_RAW,
    HIGHRES_IMU, ATTITUDE_TARGET, ATTITUDE (PX4-like). ``ardupilot``: what ArduCopter streams
    instead: RAW_IMU and SCALED_IMU2 in mG (no HIGHRES_IMU), VFR_HUD (throttle %, climb),
    GLOBAL_POSITION_INT, PARAM_VALUE (FRAME_CLASS, MOT_PWM_MIN/MAX), no ATTITUDE_TARGET."""
    scale = flight.stand_map.throttle_scale
    pwm = scale.from_pct(flight.throttle_pct)
    step = max(1, int(round(flight.sim.rate_hz / 10.0)))
    with open(path, "wb") as f:
        w = TlogWriter(f)
        mav = w.encoder()
        gcs = TlogWriter(f, system_id=255, component_id=190).encoder()
        autopilot = 3 if ardupilot else 12
        for k in range(0, len(flight.time_s), step):
            t = t0_unix_s + float(flight.time_s[k])
            if k % (step * 10) == 0:
                w.write(t, mav.heartbeat_encode(2, autopilot, 128 | 1, 0, 4))
            if ardupilot and k == 0:  # the parameters a ground station fetched after connecting
                for i, (name, value) in enumerate(
                    (("FRAME_CLASS", 1.0), ("MOT_PWM_MIN", scale.lo), ("MOT_PWM_MAX", scale.hi))
                ):
                    w.write(t, mav.param_value_encode(name.encode(), value, 9, 3, i))
                w.write(t, gcs.heartbeat_encode(6, 8, 0, 0, 0))
                state = 1 if flight.landed[k] > 0.5 else 2
                w.write(t, mav.extended_sys_state_encode(0, state))
            volt_mv = int(round(flight.voltage_v[k] * 1000))
            w.write(t, mav.sys_status_encode(0, 0, 0, 500, volt_mv, 2000, 80, 0, 0, 0, 0, 0, 0))
            a = float(flight.accel_up_mps2[k])
            if ardupilot:
                mg = int(round(-a / G0 * 1000.0))
                us = int(flight.time_s[k] * 1e6)
                w.write(t, mav.raw_imu_encode(us, 0, 0, mg, 0, 0, 0, 0, 0, 0))
                w.write(t, mav.scaled_imu2_encode(us // 1000, 0, 0, mg, 0, 0, 0, 0, 0, 0))
                th = float(flight.thrust_norm[k])
                w.write(t, mav.vfr_hud_encode(0.0, 0.0, 0, int(round(th * 100)), 0.0, 0.0))
                h_mm = int(round(float(flight.height_m[k]) * 1000))
                w.write(t, mav.global_position_int_encode(us // 1000, 0, 0, h_mm, h_mm, 0, 0, 0, 0))
            else:
                w.write(
                    t,
                    mav.highres_imu_encode(
                        int(t * 1e6), 0, 0, -a, 0, 0, 0, 0, 0, 0, 1013, 0, 0, 20, 0
                    ),
                )
            servos = [int(round(x)) for x in pwm[k]] + [0] * (8 - pwm.shape[1])
            w.write(
                t, mav.servo_output_raw_encode(int(flight.time_s[k] * 1e6) & 0xFFFFFFFF, 0, *servos)
            )
            if not ardupilot:
                w.write(
                    t,
                    mav.attitude_target_encode(
                        0, 0, [1, 0, 0, 0], 0, 0, 0, float(flight.thrust_norm[k])
                    ),
                )
            r = float(np.radians(flight.tilt_deg[k]))
            w.write(t, mav.attitude_encode(0, r, 0.0, 0.0, 0.0, 0.0, 0.0))


# -- fixtures ------------------------------------------------------------------------------------

#: the small simulated flight the project ships as fixtures/flightlogs/* (30 s at 20 Hz)
FIXTURE_SIM = HoverSim(duration_s=30.0, rate_hz=20.0, seed=7)
FIXTURE_FILES = (
    "sim_hover.bin",
    "sim_hover_copter3.bin",
    "sim_hover.ulg",
    "sim_hover_v1.9.ulg",
    "sim_hover.tlog",
    "sim_hover_paper.csv",
    "sim_hover_generic.csv",
    "sim_map.json",
)


def write_fixtures(out_dir: str | Path) -> list[Path]:
    """(Re)generate the shipped flight-log fixtures from ``FIXTURE_SIM``."""
    d = Path(out_dir)
    d.mkdir(parents=True, exist_ok=True)
    flight = simulate_hover(FIXTURE_SIM)
    write_dataflash(flight, d / "sim_hover.bin")
    write_dataflash(flight, d / "sim_hover_copter3.bin", old_firmware=True)
    write_ulog(flight, d / "sim_hover.ulg")
    write_ulog(flight, d / "sim_hover_v1.9.ulg", legacy=True)
    write_tlog(flight, d / "sim_hover.tlog")
    write_paper_csv(flight, d / "sim_hover_paper.csv")
    write_generic_csv(flight, d / "sim_hover_generic.csv")
    flight.stand_map.save(d / "sim_map.json")
    return [d / name for name in FIXTURE_FILES]


if __name__ == "__main__":  # python -m support.simulate_flight fixtures/flightlogs
    import sys

    for p in write_fixtures(sys.argv[1] if len(sys.argv) > 1 else "fixtures/flightlogs"):
        sys.stdout.write(f"{p} {p.stat().st_size} bytes\n")
