"""Old ArduCopter (3.2-3.4) field semantics, each rule read from that era's firmware (issue 34
item 2): a simulated 3.3-dev log per defect, against the same flight without it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from support.copter33 import ACCEL_SCALE, GROUND_RUN_S, PAUSE_S, Copter33, write_copter33

from thrustmap.core.errors import DataFormatError
from thrustmap.fitting.df.extraction import extract
from thrustmap.fitting.df.options import G0
from thrustmap.fitting.df.table import Df
from thrustmap.fitting.df_options import DfOptions
from thrustmap.flightlogs.detect import read_log
from thrustmap.flightlogs.series import FlightLog, Signal

OPTS = DfOptions(mass_kg=1.0)


def df_of(log: Copter33) -> Df:
    return extract(read_log(log.path), OPTS)


@pytest.fixture(scope="module")
def clean(tmp_path_factory: pytest.TempPathFactory) -> tuple[Copter33, Df]:
    log = write_copter33(tmp_path_factory.mktemp("clean") / "clean.bin")
    return log, df_of(log)


def steps(df: Df) -> dict[str, float]:
    return {s.name: s.dropped_s for s in df.reports[0].steps}


def rule_lines(df: Df, name: str) -> list[str]:
    return [w for w in df.reports[0].warnings if w.startswith(name)]


def test_the_clean_log_keeps_most_of_its_hover_and_names_every_rule(
    clean: tuple[Copter33, Df],
) -> None:
    log, df = clean
    assert len(df) >= 0.5 * log.airborne_s * OPTS.rate_hz
    names = steps(df)
    assert names["accel-calibration"] == 0.0  # checked, nothing to change (it reads g at rest)
    assert "log-pause" in names and names["log-pause"] == 0.0
    reason = next(s.reason for s in df.reports[0].steps if s.name == "accel-calibration")
    assert "not changed" in reason
    assert not rule_lines(df, "climb-crt") and not rule_lines(df, "inav-baro")


def test_ev_burst_at_liftoff_leaves_the_vehicle_flying(
    clean: tuple[Copter33, Df], tmp_path: Path
) -> None:
    """AP_State.pde set_land_complete writes an EV on every change; untimed, a burst of 18/28
    takes one neighbour's time. Its first event (LAND_COMPLETE) read the whole flight as landed
    (94.8 of 96 s on a real PXF log)."""
    log = write_copter33(tmp_path / "burst.bin", ("ev-burst",))
    (fl,) = read_log(log.path)
    assert fl.landed is not None
    mid = float(log.time_s[len(log.time_s) // 2])
    assert fl.landed.hold(np.array([mid]))[0] == 0.0
    df = df_of(log)
    assert len(df) >= 0.95 * len(clean[1])
    (line,) = rule_lines(df, "ev-burst")
    assert "8 land events written within 1 time stamp" in line


def test_a_climb_rate_with_an_offset_gives_way_to_the_altitudes(
    clean: tuple[Copter33, Df], tmp_path: Path
) -> None:
    """CTUN.CRt = inertial_nav.get_velocity_z() (cm/s, inertia.pde): an accelerometer bias
    integrates into it while the barometer holds the altitude (75 % of a real hover read
    |CRt| > 1 m/s while CTUN.Alt moved 0.1 m/s)."""
    df = df_of(write_copter33(tmp_path / "crt.bin", ("crt-offset",)))
    (line,) = rule_lines(df, "climb-crt")
    assert "1.5" in line  # the offset, measured
    assert len(df) >= 0.9 * len(clean[1])
    assert steps(df)["climb"] <= steps(clean[1])["climb"] + 2.0


def test_a_diverged_inertial_altitude_gives_way_to_the_barometer(
    clean: tuple[Copter33, Df], tmp_path: Path
) -> None:
    df = df_of(write_copter33(tmp_path / "inav.bin", ("inav-diverged",)))
    assert len(rule_lines(df, "inav-baro")) == 1
    climb = next(s.reason for s in df.reports[0].steps if s.name == "climb")
    assert "(barometer)" in climb
    assert len(df) >= 0.8 * len(clean[1])


def test_an_accelerometer_off_at_rest_is_calibrated_before_takeoff(
    clean: tuple[Copter33, Df], tmp_path: Path
) -> None:
    log = write_copter33(tmp_path / "acc.bin", ("accel-scale",))
    df = df_of(log)
    (line,) = rule_lines(df, "accelerometer calibrated at rest")
    assert f"{G0 * ACCEL_SCALE:.2f}" in line  # what it read at rest, said
    assert len(df) >= 0.9 * len(clean[1])
    # the calibrated a_up is the true one: F_m = m·a_up within 0.5 % of the clean log's
    ratio = float(np.median(df.table["accel_up_mps2"])) / float(
        np.median(clean[1].table["accel_up_mps2"])
    )
    assert ratio == pytest.approx(1.0, abs=0.005)


def test_the_rest_calibrates_before_the_specific_force_is_questioned(tmp_path: Path) -> None:
    """A PXF log reading 8.7 m/s² at rest and 5-6 in the air (vibration) has a mean below
    7 m/s²: it used to be refused before the ground-rest calibration (issue 34's crash on
    31-3-2015_83). Calibrated first, it is read; the hover filter then drops what reads off g."""
    log = write_copter33(tmp_path / "vib.bin", ("vibration",))
    (fl,) = read_log(log.path)
    assert fl.accel_up_mps2 is not None and float(np.mean(fl.accel_up_mps2.values)) < 7.0
    df = df_of(log)
    (line,) = rule_lines(df, "accelerometer calibrated at rest")
    assert f"{G0 * ACCEL_SCALE:.2f}" in line
    assert steps(df)["hover"] > 0.5 * log.airborne_s  # in the air it still reads 2 m/s² low


def test_what_the_rest_calibration_cannot_explain_is_refused(tmp_path: Path) -> None:
    log = write_copter33(tmp_path / "vib.bin", ("vibration",), vibration_drop_mps2=3.5)
    with pytest.raises(DataFormatError, match="after its calibration at rest") as exc:
        df_of(log)
    assert "-IMU.AccZ" in str(exc.value) and "vib.bin" in str(exc.value)


def test_without_rest_before_takeoff_the_accelerometer_is_left_alone() -> None:
    from test_flight_semantics import _spoolup_flight

    fl = _spoolup_flight(height=False, contact=False)
    assert fl.accel_up_mps2 is not None
    acc = fl.accel_up_mps2
    fl.accel_up_mps2 = type(acc)(acc.time_s, acc.values * 0.9, acc.unit, acc.origin)
    t = acc.time_s
    assert fl.thrust_cmd_norm is not None  # the log starts in the air (logging began late)
    c = fl.thrust_cmd_norm
    fl.thrust_cmd_norm = type(c)(t, np.where(t < 8, 0.5, c.values), "1", "sim")
    df = extract([fl], OPTS)
    reason = next(s.reason for s in df.reports[0].steps if s.name == "accel-calibration")
    assert "not calibrated" in reason
    assert not rule_lines(df, "accelerometer calibrated")


def test_a_log_pause_is_named_and_both_flights_are_kept(
    clean: tuple[Copter33, Df], tmp_path: Path
) -> None:
    """ArduCopter 3.2-3.3 suspend writes on disarm (motors.pde): a pause in the log is
    disarmed time, named "log-pause" in the report, not an IMU gap, and the flights on both
    sides of it are kept."""
    df = df_of(write_copter33(tmp_path / "pause.bin", ("log-pause",)))
    names = steps(df)
    assert names["log-pause"] == pytest.approx(PAUSE_S, abs=2.0)
    assert names.get("data", 0.0) < 0.5
    assert len(df) >= 1.8 * len(clean[1])


def test_a_ground_run_after_a_pause_is_landed_by_the_throttle(
    clean: tuple[Copter33, Df], tmp_path: Path
) -> None:
    """Untimed EVs cannot say when the vehicle sits on the ground; armed there at the throttle
    an altitude-holding mode holds before takeoff, it reads g, holds its command steady and
    passed every filter (a real PXF log gave 275 "clean" samples, all on the ground). Rule
    "throttle-zero": the 3.2-3.3 land detector (control_land.pde) sets land_complete after 1 s
    with the output at zero and clears it above THR_MID/2; disarming sets it."""
    log = write_copter33(tmp_path / "ground.bin", ("log-pause", "ground-run"))
    assert log.ground_run_s is not None
    df = df_of(log)
    t = np.asarray(df.column("time_s"))
    a, b = log.ground_run_s
    assert not ((t >= a) & (t <= b)).any()  # nothing of the ground run kept
    (line,) = rule_lines(df, "throttle-zero")
    assert "THR_MID/2 = 250" in line
    up_s = float(line.split("; ")[-1].split(" s ")[0])  # the ground run's throttle, said
    assert up_s >= GROUND_RUN_S  # (with the armed rests before each takeoff)
    assert len(df) >= 1.8 * len(clean[1])  # both flights still kept


def test_every_defect_together(clean: tuple[Copter33, Df], tmp_path: Path) -> None:
    df = df_of(write_copter33(tmp_path / "all.bin", ("ev-burst", "crt-offset", "accel-scale")))
    assert len(df) >= 0.85 * len(clean[1])


def test_the_land_detector_of_each_build_clears_the_flag_its_own_way() -> None:
    """3.2's update_land_detector (8c488ebd87) clears land_complete as soon as the pilot's
    throttle leaves zero; 3.3-dev's (from 11678ba936, 2014-07-17) once the throttle output
    exceeds THR_MID/2. Both set it after 1 s with the output at zero (50 loops at 50 Hz)."""
    from thrustmap.flightlogs.copter_era import land_detector_era, landed_from_throttle
    from thrustmap.flightlogs.series import Signal

    assert land_detector_era("ArduCopter V3.2.1 (36b405fb)") == "3.2"
    assert land_detector_era("APM:Copter V3.1.5 (3c57e771)") == "3.2"
    assert land_detector_era("ArduCopter V3.3-dev (82481f30)") == "3.3"
    assert land_detector_era(None) == "3.3"
    t = np.arange(0.0, 20.0, 0.1)
    out = np.where(t < 5, 0.0, np.where(t < 10, 0.2, 0.5))  # idle, ramp below mid/2, flying
    out[(t >= 15) & (t < 17)] = 0.0  # cut for 2 s in the air: landed by the detector
    pilot = np.where(t < 5, 0.0, 0.3)
    cmd, stick = Signal(t, out, "1", "CTUN.ThrOut/1000"), Signal(t, pilot, "1", "CTUN.ThrIn")
    probe = np.array([2.0, 7.0, 12.0, 15.5, 16.5, 18.0])
    landed33, why = landed_from_throttle(cmd, {"THR_MID": 500.0}, np.zeros(0))
    assert landed33.hold(probe).tolist() == [1, 1, 0, 0, 1, 0]
    assert why.startswith("throttle-zero") and "THR_MID/2 = 250" in why
    landed32, why = landed_from_throttle(cmd, {}, np.zeros(0), pilot_in=stick)
    assert landed32.hold(probe).tolist() == [1, 0, 0, 0, 1, 0]  # flying once the stick is up
    assert "CTUN.ThrIn" in why


def _hover_then_armed_idle() -> FlightLog:
    """An armed stretch no state signal splits (EVs untimed, the land flag never set): 10 s at
    idle, 30 s of hover at 0.5, 130 s armed at idle between two hops (ThrOut 0, motors at the
    armed spin, the IMU reading g on the ground), 20 s of hover, 10 s idle: the stretch's
    median command is 0."""
    rng = np.random.default_rng(7)
    t = np.arange(0.0, 200.0, 0.02)
    hover = ((t >= 10.0) & (t < 40.0)) | ((t >= 170.0) & (t < 190.0))
    cmd = np.where(hover, 0.5 + 0.01 * np.sin(t), 0.0)
    acc = G0 + rng.normal(0.0, 0.05, len(t))
    return FlightLog(
        path="idle.bin",
        format="dataflash",
        voltage_v=Signal(t, np.full(len(t), 12.0), "V", "CURR.Volt"),
        accel_up_mps2=Signal(t, acc, "m/s^2", "-IMU.AccZ"),
        thrust_cmd_norm=Signal(t, cmd, "1", "CTUN.ThrOut/1000"),
        armed=Signal(np.array([0.0]), np.array([1.0]), "bool", "motor outputs"),
    )


def test_an_armed_wait_at_idle_does_not_set_the_hover_level() -> None:
    """A command of 0 holds the motors at the armed spin (AP_MotorsMatrix::output_armed):
    it cannot fly, so idle bins do not set the level of the liftoff, ground-physics and level
    filters. With a stretch whose median command was 0, every idle bin passed liftoff
    (c ≥ 0.9 × 0) and ground-physics, and the level filter's median was 0: every hover bin
    was dropped (pxf_copter_29-09-2014_4 kept idle bins this way)."""
    df = extract([_hover_then_armed_idle()], OPTS)
    t = np.asarray(df.column("time_s"))
    assert len(df) >= 0.7 * 50.0 * OPTS.rate_hz  # the hovers, less settle and transients
    assert not ((t > 40.0) & (t < 170.0)).any() and t.min() >= 10.0 and t.max() <= 190.0
    names = steps(df)
    assert names["ground-physics"] >= 120.0  # the idle wait placed on the ground by physics
    assert names["liftoff"] >= 19.0  # and the idle before and after, as spool-up/down


def test_the_airborne_step_names_where_the_land_state_came_from(tmp_path: Path) -> None:
    """The "airborne" step said "log's land detector" even when throttle-zero rebuilt it."""
    log = write_copter33(tmp_path / "ground.bin", ("log-pause", "ground-run"))
    reason = next(s.reason for s in df_of(log).reports[0].steps if s.name == "airborne")
    assert "rebuilt by throttle-zero" in reason and "log's land detector" not in reason
    timed = write_copter33(tmp_path / "timed.bin")
    reason = next(s.reason for s in df_of(timed).reports[0].steps if s.name == "airborne")
    assert "EV.Id 18 LAND_COMPLETE" in reason
