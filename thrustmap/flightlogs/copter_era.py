"""ArduCopter 3.2-3.4 (2014-2016) DataFlash field semantics: the rules of docs/old-arducopter.md.

Each rule was read from the firmware of that time (ArduPilot history: ArduCopter ``Log.pde``,
``inertia.pde``, ``AP_State.pde``, ``control_land.pde``, ``motors.pde`` at 8c488ebd87 (3.2,
2014-06) and 82481f30 (3.3-dev, 2014-08-28, the build of several fleet logs); ``Log.cpp``,
``inertia.cpp``, ``land_detector.cpp`` at 6737bc21b9 (3.4, 2016-06)), and each is named in the
extract report (a warning that starts with its name). The DataFlash reader (``dataflash.py``)
calls them with the columns it decoded; nothing here reads a file.
"""

from __future__ import annotations

import re

import numpy as np
import numpy.typing as npt

from thrustmap.core.units import ThrottleScale
from thrustmap.flightlogs.series import (
    FlightLog,
    FloatArray,
    Signal,
    nanmedian,
    sorted_signal,
)

#: EV ids (ArduCopter LogEvent)
EV_ARMED, EV_DISARMED, EV_LAND_COMPLETE, EV_NOT_LANDED = 10, 11, 18, 28


def land_state_from_events(
    t: FloatArray, ids: npt.NDArray[np.int64], notes: list[str]
) -> Signal | None:
    """Landed (1) / flying (0) from the land events: ground at each arming, airborne at
    NOT_LANDED, ground at LAND_COMPLETE.

    Rule "ev-burst" (ArduCopter 3.2-3.3 AP_State.pde set_land_complete writes an EV on every
    change of ap.land_complete; the 50 Hz land detector of control_land.pde sets it while an
    altitude-holding mode clears it again, so a burst of 18/28 pairs is written within one time
    stamp of the neighbours that time them): the state after a burst is its LAST event
    (keeping the first read a whole flight as landed)."""
    m = np.isin(ids, (EV_ARMED, EV_LAND_COMPLETE, EV_NOT_LANDED))
    if not m.any():
        return None
    tm = t[m]
    same = np.flatnonzero(np.diff(tm) == 0) if len(tm) > 1 else np.zeros(0, np.int64)
    if len(same):
        notes.append(
            f"ev-burst: {len(same) + len(np.unique(tm[same]))} land events written within "
            f"{len(np.unique(tm[same]))} time stamp(s) (the land detector and the altitude "
            "controller toggling the land flag): the state after each burst is its last event"
        )
    return sorted_signal(
        tm, ids[m] != EV_NOT_LANDED, "bool", "EV.Id 18 LAND_COMPLETE / 28 NOT_LANDED", state=True
    )


#: the inertial-navigation altitude (CTUN.Alt) may depart from the barometer's alone (BarAlt)
#: by this much (95th percentile, after their offset) before it is taken as diverged
INAV_BARO_DISAGREE_M = 10.0
#: the barometer's climb rate: altitude difference over this span (s)
BARO_CLIMB_SPAN_S = 1.0
#: an altitude climbing faster than this is jumping (a glitch or a broken sensor), not flying
BARO_CLIMB_MAX_MPS = 30.0


#: CTUN.CRt may differ from the logged altitude's own climb by this much (median, m/s)
CRT_ALT_DISAGREE_MPS = 0.3


def _climb(t: FloatArray, height_m: FloatArray, span_s: float) -> FloatArray:
    """Climb rate (m/s): the height difference over ``span_s`` centred on each sample."""
    half = 0.5 * span_s
    return np.asarray(
        (np.interp(t + half, t, height_m) - np.interp(t - half, t, height_m)) / span_s, float
    )


def climb_from_altitude(
    flight: FlightLog, t: FloatArray, crt_mps: FloatArray, alt_m: FloatArray
) -> None:
    """Rule "climb-crt": CTUN.CRt is the inertial-navigation vertical velocity (cm/s in every
    3.2-3.4 build: ``climb_rate = inertial_nav.get_velocity_z()``, inertia.pde / Log.pde), not
    the derivative of the altitude logged beside it. In the PXF 3.3-dev builds it carries an
    offset (an accelerometer off by 0.3 m/s² at rest integrates into it; the barometer pulls
    the altitude back but hardly the velocity): 75 % of a hover read |CRt| > 1 m/s while
    CTUN.Alt moved 0.1 m/s. When CRt departs from the climb of CTUN.Alt by more than
    CRT_ALT_DISAGREE_MPS (median), the climb rate is that of CTUN.Alt over BARO_CLIMB_SPAN_S."""
    ok = np.isfinite(crt_mps) & np.isfinite(alt_m)
    if ok.sum() < 20:
        return
    tt = t[ok]
    from_alt = _climb(tt, alt_m[ok], BARO_CLIMB_SPAN_S)
    off = float(nanmedian(np.abs(crt_mps[ok] - from_alt)))
    if off <= CRT_ALT_DISAGREE_MPS or np.abs(from_alt).max() > BARO_CLIMB_MAX_MPS:
        return  # CRt agrees, or the altitude itself jumps (judged downstream)
    flight.extras["climb_mps"] = sorted_signal(
        tt, from_alt, "m/s", f"CTUN.Alt climb over {BARO_CLIMB_SPAN_S:g} s"
    )
    flight.warnings.append(
        f"climb-crt: CTUN.CRt (inertial vertical velocity, cm/s) departs from the climb of "
        f"CTUN.Alt by {off:.2f} m/s (median, more than {CRT_ALT_DISAGREE_MPS:g}): the climb "
        "rate is taken from CTUN.Alt"
    )


def inertial_or_baro(
    flight: FlightLog, t: FloatArray, inav_m: FloatArray, baro_m: FloatArray, baro_origin: str
) -> None:
    """Rule "inav-baro": ArduCopter 3.2-3.4 log CTUN.Alt = current_loc.alt / 100 and CTUN.CRt =
    inertial_nav.get_velocity_z() (cm/s; Log.pde and inertia.pde of those builds), the
    accelerometers integrated and pulled toward the barometer, and CTUN.BarAlt the barometer
    alone (cm in the firmware, metres through its FMT 'e'). On boards whose barometer the
    filter did not follow (PXF/Erle 3.3-dev builds: CTUN.Alt ran 100+ m while the barometer
    moved 1 m) the inertial altitude and climb rate describe no motion of the vehicle. When the
    two altitudes depart by more than INAV_BARO_DISAGREE_M (a few metres of barometer drift are common; the
    inertial altitude is then the better one), height and climb rate come from the barometer
    (its climb over BARO_CLIMB_SPAN_S), unless the barometer itself jumps; the report says
    which."""
    ok = np.isfinite(inav_m) & np.isfinite(baro_m)
    if ok.sum() < 20:
        return
    diff = inav_m[ok] - baro_m[ok]
    dev = np.abs(diff - float(nanmedian(diff)))
    ranked = np.sort(dev)
    dev95 = float(ranked[min(len(ranked) - 1, int(0.95 * len(ranked)))])
    if dev95 <= INAV_BARO_DISAGREE_M:
        return
    tb, hb = t[ok], baro_m[ok]
    climb = _climb(tb, hb, BARO_CLIMB_SPAN_S)
    if np.abs(climb).max() > BARO_CLIMB_MAX_MPS:
        return  # the barometer jumps too: neither is the vehicle's height (judged downstream)
    flight.extras["height_m"] = sorted_signal(tb, hb, "m", f"{baro_origin} (barometer)")
    flight.extras["climb_mps"] = sorted_signal(
        tb, climb, "m/s", f"{baro_origin} climb over {BARO_CLIMB_SPAN_S:g} s (barometer)"
    )
    flight.warnings.append(
        f"inav-baro: CTUN.Alt (inertial navigation) departs from {baro_origin} (barometer) by "
        f"{dev95:.1f} m (95th percentile, more than {INAV_BARO_DISAGREE_M:g} m): height and "
        "climb rate taken from the barometer (CTUN.CRt is the inertial climb rate, cm/s)"
    )


#: a stretch without samples longer than this is the log pausing (Copter logs only while armed)
LOG_PAUSE_S = 2.0


def armed_spin_us(params: dict[str, float], scale: ThrottleScale) -> tuple[float, str]:
    """The output the motors hold when armed at zero throttle (µs above the scale's low end):
    MOT_SPIN_ARMED (Copter ≤ 3.3, µs above the minimum) or MOT_SPIN_ARM (3.4+, fraction of the
    range); 3 % of the range when the log gives neither."""
    span = scale.hi - scale.lo
    if (v := params.get("MOT_SPIN_ARMED")) is not None and v > 0:
        return float(v), f"MOT_SPIN_ARMED {v:g} us"
    if (v := params.get("MOT_SPIN_ARM")) is not None and v > 0:
        return float(v) * span, f"MOT_SPIN_ARM {v:g}"
    return 0.03 * span, "assumed 3 % of the output range (no MOT_SPIN_ARMED/MOT_SPIN_ARM)"


#: the land detector's trigger: LAND_DETECTOR_TRIGGER 50 iterations of the 50 Hz throttle loop
#: (config.h, control_land.pde update_land_detector of 3.2-3.3)
LAND_DETECTOR_S = 1.0
#: THR_MID's default (config.h THR_MID_DEFAULT, throttle output 0..1000 at mid stick)
THR_MID_DEFAULT = 500.0


def land_detector_era(firmware: str | None) -> str:
    """Which land detector a build ran: "3.2" (and older: the flag clears when the pilot's
    throttle leaves zero, control_land.pde to 2014-07-17) or "3.3" (3.3-dev from 11678ba936,
    2014-07-17: it clears when the throttle output exceeds THR_MID/2). Unnamed builds: "3.3",
    the builds of the 2014-2016 PXF/Erle fleet."""
    hit = re.search(r"V(\d+)\.(\d+)", firmware or "")
    if hit and (int(hit.group(1)), int(hit.group(2))) <= (3, 2):
        return "3.2"
    return "3.3"


def landed_from_throttle(
    cmd: Signal,
    params: dict[str, float],
    resumes_s: FloatArray,
    *,
    pilot_in: Signal | None = None,
) -> tuple[Signal, str]:
    """Rule "throttle-zero": the land state the 3.2-3.3 land detector kept, from CTUN.ThrOut.

    With its output at zero the firmware cuts the motors to the armed spin
    (AP_MotorsMatrix::output_armed: ``servo_out == 0`` puts every motor at ``radio_min +
    spin_when_armed``, and sets ``limit.throttle_lower``), which cannot carry the vehicle;
    update_land_detector (control_land.pde, 50 Hz) then sets ap.land_complete after
    LAND_DETECTOR_TRIGGER (50) iterations at the lower limit. 3.3-dev clears it once the output
    exceeds get_non_takeoff_throttle() = THR_MID / 2 (Attitude.pde; since 11678ba936,
    2014-07-17); 3.2 as soon as the pilot's throttle (CTUN.ThrIn = rc_3.control_in) is off zero
    with the output off its lower limit (the ``else if`` of its detector): pass it as
    ``pilot_in`` for a 3.2 build. Disarming sets the flag (init_disarm_motors,
    motors.pde), so each logging stretch (logging starts at arming) starts landed. The
    detector's other conditions (|climb rate| < 40 cm/s; from 2014-08-25 the barometer's climb
    and the gyros too) are left out: CRt carries an offset on these boards (rule climb-crt),
    and a vehicle whose motors sit at the armed spin for a second is not in steady flight
    either way. ``cmd`` is CTUN.ThrOut / 1000; ``resumes_s`` the times logging starts again
    after each pause."""
    mid = params.get("THR_MID", THR_MID_DEFAULT)
    if not 0 < mid <= 1000:
        mid = THR_MID_DEFAULT
    t, v = cmd.time_s, np.nan_to_num(cmd.values, nan=0.0)
    zero = v <= 0.0
    sets: list[float] = [float(t[0]) - 1e-3] if len(t) else []
    edges = np.diff(np.concatenate([[0], zero.astype(np.int8), [0]]))
    for a, b in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True):
        if t[b - 1] - t[a] >= LAND_DETECTOR_S:
            sets.append(float(t[a]) + LAND_DETECTOR_S)
    sets += [float(x) for x in resumes_s]
    if pilot_in is not None:
        stick = np.nan_to_num(pilot_in.hold(t), nan=0.0)
        clears = t[(stick != 0) & (v > 0.0)]  # the else branch: not at the lower limit
        until = "the pilot's throttle (CTUN.ThrIn) leaves 0 (3.2)"
    else:
        clears = t[v > 0.5 * mid / 1000.0]
        until = f"CTUN.ThrOut exceeds THR_MID/2 = {mid / 2:g} (3.3)"
    times = np.concatenate([np.asarray(sets, float), clears])
    values = np.concatenate([np.ones(len(sets)), np.zeros(len(clears))])
    order = np.argsort(times, kind="stable")
    origin = (
        f"rebuilt by throttle-zero: CTUN.ThrOut 0 for ≥ {LAND_DETECTOR_S:g} s, flying once " + until
    )
    landed = sorted_signal(times[order], values[order], "bool", origin, state=True)
    # how long the throttle was up while landed (ground runs, or a THR_MID above the hover
    # throttle, which keeps the flag set in the firmware too): said, so a reader can judge
    up = (landed.hold(t) > 0.5) & (v > 0.0)
    dt = np.diff(t, append=t[-1]) if len(t) else np.zeros(0)
    up_s = float(np.sum(np.where(up, np.minimum(dt, LAND_DETECTOR_S), 0.0)))
    why = (
        f"throttle-zero: the land state rebuilt as the land detector of the build kept it: "
        f"landed once CTUN.ThrOut has been 0 (motors cut to the armed spin) for "
        f"{LAND_DETECTOR_S:g} s and at each arming, flying once {until}; "
        f"{up_s:.0f} s with the throttle up read as landed"
    )
    return landed, why


def untimed_events(
    flight: FlightLog,
    params: dict[str, float],
    *,
    ev_untimed: bool,
    throttle: Signal | None,
    pilot_throttle: Signal | None = None,
) -> None:
    """Copter ≤ 3.3 writes EV without a time stamp, and a log that pauses while disarmed writes
    the events of the pause when it resumes: timed by their neighbours they land at the wrong
    flight. Then the armed state comes from the motor outputs (every motor at or above half
    the armed spin), each pause is a flight boundary (disarmed), and the land detector's events
    are not used: the land state is rebuilt from the throttle output (``landed_from_throttle``,
    rule "throttle-zero") when the log has CTUN.ThrOut (and, for a 3.2 build, the pilot's
    throttle CTUN.ThrIn: ``pilot_throttle``), else ground contact is judged from physics."""
    if not ev_untimed:
        return
    ref = flight.accel_up_mps2 or flight.motor_outputs
    if ref is None or len(ref) < 2:
        return
    pauses = np.flatnonzero(np.diff(ref.time_s) > LOG_PAUSE_S)
    if not len(pauses):
        return  # written as they happened: their neighbours time them
    mo, sc = flight.motor_outputs, flight.motor_output_scale
    if mo is None or sc is None or mo.values.ndim != 2:
        flight.warnings.append(
            "EV has no time stamps and the log pauses: the arming events cannot be timed and "
            "there are no motor outputs to tell armed state from"
        )
        return
    spin, spin_src = armed_spin_us(params, sc)
    spinning = np.nanmin(mo.values, axis=1) >= sc.lo + 0.5 * spin
    t = mo.time_s
    gap_t = ref.time_s[pauses] + 1e-3  # disarmed from just after the last sample of a stretch
    times = np.concatenate([t, gap_t])
    vals = np.concatenate([spinning.astype(float), np.zeros(len(gap_t))])
    order = np.argsort(times, kind="stable")
    flight.armed = Signal(
        times[order],
        vals[order],
        "bool",
        f"motor outputs ≥ half the armed spin ({spin_src}); log pauses disarmed",
    )
    flight.landed = None
    ground = "ground contact judged from physics"
    if throttle is not None and len(throttle) > 1:
        era = land_detector_era(flight.metadata.get("firmware"))
        flight.landed, why = landed_from_throttle(
            throttle, params, ref.time_s[pauses + 1],
            pilot_in=pilot_throttle if era == "3.2" else None,
        )  # fmt: skip
        flight.warnings.append(why)
        ground = "the land state rebuilt from the throttle output (throttle-zero)"
    flight.warnings.append(
        f"events untimed: EV has no time stamps and the log pauses {len(pauses)} time(s), so "
        "the arming events written on resuming cannot be placed; armed state taken from the "
        f"motor outputs, each pause a flight boundary, {ground}"
    )
