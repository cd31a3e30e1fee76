"""A simulated flight's MAVLink telemetry, as a vehicle streams it to `gamma live`.

``flight_messages()`` turns ``simulate_flight.simulate_hover`` (known γ(B)) into the messages
PX4 streams when asked for the Df's rates (HEARTBEAT with the armed flag, SYS_STATUS,
EXTENDED_SYS_STATE, HIGHRES_IMU at 20 Hz, SERVO_OUTPUT_RAW, ATTITUDE_TARGET, ATTITUDE,
GLOBAL_POSITION_INT, PARAM_VALUE MPC_THR_HOVER), from arming on the ground to the disarm after
landing, each with its time. ``write_fixture()`` records them with thrustmap's own recorder
(``rig.fc.telemetry_stream.TlogWriter``, what `gamma live --record` writes) into
fixtures/flightlogs/live_hover.tlog. ``without()`` leaves message types out (a stream lacking
voltage or acceleration). The live tests send the same messages over UDP.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import common

from support.simulate_flight import HoverSim, SimFlight, simulate_hover

#: 50 s hover flight at 20 Hz: long enough for a γ fit by the default filters
LIVE_SIM = HoverSim(duration_s=50.0, rate_hz=20.0, seed=11)
T0_UNIX_S = 1.75e9
FIXTURE = "live_hover.tlog"
DISARM_AFTER_S = 1.0  # the vehicle disarms this long after the flight's last sample


def flight_messages(
    flight: SimFlight | None = None, *, t0_unix_s: float = T0_UNIX_S
) -> Iterator[tuple[float, Any]]:
    """(unix time s, pymavlink message) in send order; the vehicle is system 1."""
    fl = flight or simulate_hover(LIVE_SIM)
    pwm = fl.stand_map.throttle_scale.from_pct(fl.throttle_pct)
    hz = fl.sim.rate_hz
    slow = max(1, int(round(hz / 10.0)))  # 10 Hz streams
    for k in range(len(fl.time_s)):
        t = t0_unix_s + float(fl.time_s[k])
        t_us = int(fl.time_s[k] * 1e6)
        if k % int(hz) == 0:
            yield t, common.MAVLink_heartbeat_message(2, 12, 128 | 1, 0, 4, 3)
        if k == 0:
            hover = float(np.median(fl.hover_thrust))
            yield t, common.MAVLink_param_value_message(b"MPC_THR_HOVER", hover, 9, 1, 0)
        yield (
            t,
            common.MAVLink_highres_imu_message(
                t_us, 0, 0, -float(fl.accel_up_mps2[k]), 0, 0, 0, 0, 0, 0, 1013, 0, 0, 20, 0
            ),
        )
        if k % slow:
            continue
        volt_mv = int(round(fl.voltage_v[k] * 1000))
        yield (
            t,
            common.MAVLink_sys_status_message(0, 0, 0, 500, volt_mv, 2000, 80, 0, 0, 0, 0, 0, 0),
        )
        yield t, common.MAVLink_extended_sys_state_message(0, 1 if fl.landed[k] > 0.5 else 2)
        servos = [int(round(x)) for x in pwm[k]] + [0] * (8 - pwm.shape[1])
        yield t, common.MAVLink_servo_output_raw_message(t_us & 0xFFFFFFFF, 0, *servos)
        norm = float(fl.thrust_norm[k])
        yield (
            t,
            common.MAVLink_attitude_target_message(t_us // 1000, 0, [1, 0, 0, 0], 0, 0, 0, norm),
        )
        r = float(np.radians(fl.tilt_deg[k]))
        yield t, common.MAVLink_attitude_message(t_us // 1000, r, 0.0, 0.0, 0.0, 0.0, 0.0)
        h_mm = int(round(float(fl.height_m[k]) * 1000))
        yield (
            t,
            common.MAVLink_global_position_int_message(t_us // 1000, 0, 0, h_mm, h_mm, 0, 0, 0, 0),
        )
    # landed: disarmed, heartbeats for 12 s more
    t_end = t0_unix_s + float(fl.time_s[-1])
    for j in range(1, 13):
        t = t_end + DISARM_AFTER_S * j
        yield t, common.MAVLink_heartbeat_message(2, 12, 1, 0, 3, 3)
        yield t, common.MAVLink_extended_sys_state_message(0, 1)


def without(
    messages: Iterator[tuple[float, Any]], types: tuple[str, ...]
) -> Iterator[tuple[float, Any]]:
    return ((t, m) for t, m in messages if m.get_type() not in types)


def packed(messages: Iterator[tuple[float, Any]]) -> Iterator[tuple[int, bytes]]:
    """(µs, MAVLink 2 frame) with a sequence number per frame, as system 1 sends them."""
    mav = common.MAVLink(None, srcSystem=1, srcComponent=1)
    for t, m in messages:
        yield int(round(t * 1e6)), bytes(m.pack(mav))


def write_tlog(messages: Iterator[tuple[float, Any]], path: Path) -> Path:
    from thrustmap.rig.fc.telemetry_stream import TlogWriter

    path.unlink(missing_ok=True)
    w = TlogWriter(path)
    try:
        for t_us, frame in packed(messages):
            w.write(t_us, frame)
    finally:
        w.close()
    return path


def write_fixture(out_dir: str | Path) -> list[Path]:
    d = Path(out_dir)
    d.mkdir(parents=True, exist_ok=True)
    return [write_tlog(flight_messages(), d / FIXTURE)]
