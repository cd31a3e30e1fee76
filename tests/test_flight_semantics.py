"""What real logs mean (issue 13): event timing on old ArduCopter, in-air evidence, which
outputs are motors, the throttle scale from the log's parameters."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from support import simulate_flight as sim

from thrustmap.core.errors import ConfigError
from thrustmap.fitting.df.extraction import extract
from thrustmap.fitting.df.options import G0
from thrustmap.fitting.df_options import DfOptions
from thrustmap.fitting.mapfile import ThrustMap
from thrustmap.flightlogs import dataflash
from thrustmap.flightlogs.detect import read_log
from thrustmap.flightlogs.series import FlightLog, Signal

FL = Path(__file__).resolve().parent.parent / "fixtures" / "flightlogs"
ARDU = "flightlogs/ardupilot"


# -- 1. ArduCopter <= 3.3: EV has no timestamp ---------------------------------------------------


def test_copter33_events_are_timed_by_their_neighbours(shared_data: Path) -> None:
    """Copter 3.3 EV = Id only. Ids 10 ARMED, 15, 28 NOT_LANDED, 18 LAND_COMPLETE, 28, 18; each
    takes the time of the timestamped message written just before it."""
    path = shared_data / ARDU / "copter3.3_althold_pxf.bin"
    log = dataflash.parse(path)
    assert log.by_name["EV"].columns == ("Id",)
    t_ev = log.time_s("EV")
    assert log.columns("EV")["Id"].tolist() == [10, 15, 28, 18, 28, 18]
    assert np.all(np.diff(t_ev) >= 0)
    assert t_ev[2] == pytest.approx(10.49, abs=0.02) and t_ev[3] == pytest.approx(242.95, abs=0.02)
    (fl,) = read_log(path)
    assert fl.landed is not None
    assert fl.landed.hold(np.array([5.0, 100.0, 243.5]))[1:].tolist() == [0.0, 1.0]
    assert fl.armed is not None and fl.armed.hold(np.array([100.0]))[0] == 1.0


def test_copter3_fixture_writes_ev_without_time_like_the_firmware() -> None:
    truth = sim.simulate_hover(sim.FIXTURE_SIM)
    path = FL / "sim_hover_copter3.bin"
    log = dataflash.parse(path)
    assert log.by_name["EV"].columns == ("Id",) and log.by_name["EV"].format == "B"
    (fl,) = read_log(path)
    assert fl.landed is not None
    air = truth.time_s[truth.landed < 0.5] + 1.0  # the writer's clock starts at 1 s
    flips = fl.landed.time_s[np.flatnonzero(np.diff(fl.landed.values)) + 1]
    assert flips[0] == pytest.approx(air[0], abs=0.06)  # within one 20 Hz sample
    assert flips[-1] == pytest.approx(air[-1], abs=0.06)


# -- 2. spool-up on the ground and the takeoff ramp ----------------------------------------------


def _spoolup_flight(*, height: bool, contact: bool) -> FlightLog:
    """On the ground until 8 s with the land detector already saying 'flying' from 5 s and the
    command ramping 0.1 -> 0.45 (hover 0.5): a_up = g there. Liftoff at 8 s, hover to 60 s."""
    t = np.arange(0.0, 70.0, 0.02)
    hover = 0.5
    cmd = np.where(t < 5, 0.1, np.where(t < 8, 0.1 + (t - 5) / 3 * 0.35, hover))
    cmd = np.where(t > 62, 0.1, cmd)
    rng = np.random.default_rng(1)
    acc = G0 + rng.normal(0, 0.05, len(t))
    volt = 16.4 - 0.02 * t
    fl = FlightLog(path="spoolup.sim", format="sim")
    fl.voltage_v = Signal(t, volt, "V", "sim")
    fl.accel_up_mps2 = Signal(t, acc, "m/s^2", "sim")
    fl.thrust_cmd_norm = Signal(t, cmd, "1", "sim")
    fl.armed = Signal(np.array([0.0, 1.0, 66.0]), np.array([0.0, 1.0, 0.0]), "bool", "sim")
    fl.landed = Signal(np.array([0.0, 5.0, 62.0]), np.array([1.0, 0.0, 1.0]), "bool", "sim")
    if height:
        z = np.clip((t - 8.0) * 1.0, 0.0, 2.0) * (t < 61) + 0.01 * np.sin(t)
        fl.extras["height_m"] = Signal(t, z, "m", "sim altitude")
    if contact:
        fl.extras["ground_contact"] = Signal(
            np.array([0.0, 8.2, 61.5]), np.array([1.0, 0.0, 1.0]), "bool", "sim contact"
        )
    return fl


@pytest.mark.parametrize(
    ("height", "contact"), [(False, False), (True, False), (False, True), (True, True)]
)
def test_spool_up_on_the_ground_is_not_kept(height: bool, contact: bool) -> None:
    df = extract([_spoolup_flight(height=height, contact=contact)], DfOptions(mass_kg=1.0))
    t = df.table["time_s"].to_numpy()
    assert len(t) > 400
    assert t.min() > 8.0 + 2.0 - 0.05  # liftoff at 8 s plus the 2 s margin
    assert np.all(df.table["thrust_cmd_norm"] > 0.45)
    steps = {s.name: s.dropped_s for s in df.reports[0].steps}
    # the seconds each in-air filter dropped are reported by name
    dropped = sum(steps.get(k, 0.0) for k in ("liftoff", "height", "ground-contact"))
    assert dropped >= 2.5


def test_altitude_that_drifts_on_the_ground_is_questioned_not_used() -> None:
    fl = _spoolup_flight(height=True, contact=False)
    assert fl.extras["height_m"] is not None
    hs = fl.extras["height_m"]
    fl.extras["height_m"] = Signal(hs.time_s, hs.values - 10.0 * hs.time_s, "m", "hot baro")
    df = extract([fl], DfOptions(mass_kg=1.0))
    assert any("hot baro not used" in w for w in df.reports[0].warnings)
    assert df.table["time_s"].min() > 10.0  # the command still marks liftoff


def test_saturated_command_is_not_steady_flight() -> None:
    fl = _spoolup_flight(height=False, contact=False)
    assert fl.thrust_cmd_norm is not None
    c = fl.thrust_cmd_norm
    sat = np.where((c.time_s > 30) & (c.time_s < 40), 1.0, c.values)
    fl.thrust_cmd_norm = Signal(c.time_s, sat, "1", "sim")
    df = extract([fl], DfOptions(mass_kg=1.0, steady_tol=0.0))
    t = df.table["time_s"]
    assert not ((t > 30.1) & (t < 39.9)).any()
    assert {s.name: s.dropped_s for s in df.reports[0].steps}["saturation"] > 9.5


def test_copter34_spool_up_is_cut_from_the_real_log(shared_data: Path) -> None:
    """On the 3.4 log NOT_LANDED flips at half of hover throttle; its baro drifts by hundreds
    of metres (PXF), so the command marks liftoff. Kept commands are all near hover."""
    (fl,) = read_log(shared_data / ARDU / "copter3.4_pxf_3s.bin")
    df = extract([fl], DfOptions(mass_kg=1.2))
    rep = df.reports[0]
    steps = {s.name: s.dropped_s for s in rep.steps}
    assert steps["liftoff"] > 30.0
    assert any("CTUN.Alt" in w and "not used" in w for w in rep.warnings)
    ratio = df.table["thrust_cmd_norm"] / df.table["accel_up_mps2"] * G0
    assert ratio.min() > 0.45  # spool-up samples went down to 0.2


# -- 3. which outputs are motors -----------------------------------------------------------------


def test_servo_channels_are_not_rotors(shared_data: Path) -> None:
    """Copter 3.4-rc2 quad: RCOU C5 is a servo, C6 moves, C7 sits at 1500 us; 'Frame: QUAD'."""
    (fl,) = read_log(shared_data / ARDU / "copter3.4rc2_erlebrain3_servo_channels.bin")
    assert fl.motor_outputs is not None
    assert fl.motor_outputs.origin == "RCOU.C1,C2,C3,C4"
    assert "Frame: QUAD" in fl.metadata["motor_channels"]
    df = extract([fl], DfOptions(mass_kg=1.0))
    assert df.sources["flights"][f"{Path(fl.path).name}#0"]["rotors"] == 4


def test_motor_layout_from_parameters() -> None:
    servo = {"SERVO1_FUNCTION": 33.0, "SERVO2_FUNCTION": 34.0, "SERVO3_FUNCTION": 1.0,
             "SERVO4_FUNCTION": 36.0, "SERVO5_FUNCTION": 35.0}  # fmt: skip
    chans, how = dataflash.motor_layout(servo, [])  # type: ignore[misc]
    assert chans == [1, 2, 5, 4] and "SERVOn_FUNCTION" in how
    hexa = dataflash.motor_layout({"FRAME_CLASS": 2.0, "SERVO7_FUNCTION": 7.0}, [])
    assert hexa is not None and hexa[0] == [1, 2, 3, 4, 5, 6]
    old = dataflash.motor_layout({"FRAME": 1.0, "RC5_FUNCTION": 7.0}, ["Frame: HEXA"])
    assert old is not None and old[0] == [1, 2, 3, 4, 6, 7]  # output 5 drives a mount
    assert dataflash.motor_layout({"FRAME": 1.0}, ["ArduCopter V3.3"]) is None


def test_rotors_option_changes_what_is_summed() -> None:
    tmap = ThrustMap.load(FL / "sim_map.json")
    (fl,) = read_log(FL / "sim_hover.bin")
    four = extract([fl], DfOptions(mass_kg=1.0), tmap)
    three = extract([fl], DfOptions(mass_kg=1.0, rotors=3), tmap)
    assert [c for c in three.table.columns if c.startswith("motor")] == [
        "motor0_pct", "motor1_pct", "motor2_pct"
    ]  # fmt: skip
    ratio = (three.table["thrust_cmd_n"] / four.table["thrust_cmd_n"]).to_numpy()
    assert 0.7 < float(np.median(ratio)) < 0.8  # three of four near-equal rotors
    assert any("--rotors 3" in w for w in three.reports[0].warnings)
    six = extract([fl], DfOptions(mass_kg=1.0, rotors=6), tmap)  # outputs 5, 6 are 0 us
    assert "RCOU.C1..6" in six.sources["columns"]["motor_pct"]
    with pytest.raises(ConfigError, match="only 4 motor outputs"):
        extract(read_log(FL / "sim_hover.ulg"), DfOptions(mass_kg=1.0, rotors=6), tmap)


# -- 6. ULog with appended data ------------------------------------------------------------------


def test_ulog_with_appended_data_inspects(shared_data: Path) -> None:
    """vehicle_land_detected's only sample is stamped before the first data: it still holds."""
    from thrustmap.cli.flight import inspect_flight

    path = shared_data / "flightlogs/px4/pyulog_sample_appended_multiple.ulg"
    (fl,) = read_log(path)
    assert fl.landed is not None and fl.landed.time_s.tolist() == [0.0]
    assert fl.landed.values.tolist() == [1.0]
    info = inspect_flight(fl)
    assert info["airborne_windows_s"] == []
    assert info["fields"]["landed"]["samples"] == 1
    # no battery_status in this log: the Df has an empty voltage column and the report says why
    df = extract([fl], DfOptions(mass_kg=1.0))
    (report,) = df.reports
    assert report.voltage_unknown is not None and "no battery_status" in report.voltage_unknown
    assert df.table["voltage_v"].isna().all()
    assert df.sources["columns"]["voltage_v"] is None


# -- 4. throttle scale from the log's own parameters ---------------------------------------------


def test_px4_motor_range_from_pwm_main_min_max() -> None:
    """actuator_motors 0..1 spans PWM_MAIN_MINn..MAXn (1100..1900 in the fixture): through a
    1000..2000 us stand map the hover throttle must be the ESC's, not the control value."""
    truth = sim.simulate_hover(sim.FIXTURE_SIM)
    (fl,) = read_log(FL / "sim_hover.ulg")
    sc = fl.motor_output_scale
    assert sc is not None and (sc.lo, sc.hi, sc.unit) == (1100.0, 1900.0, "us")
    assert fl.metadata["motor_output_scale_source"].startswith("PWM_MAIN_MIN1/MAX1 1100..1900")
    assert fl.metadata["motor_channels"] == "CA_ROTOR_COUNT 4"
    tmap = ThrustMap.load(FL / "sim_map.json")
    df = extract([fl], DfOptions(mass_kg=1.0), tmap)
    t = df.table
    expect = np.interp(t["time_s"], truth.time_s, truth.throttle_pct.mean(axis=1))
    assert float(np.median(np.abs(t["throttle_pct"] - expect))) < 0.05  # 1000..1900 read: 2.5
    assert "PWM_MAIN_MIN1/MAX1" in df.sources["columns"]["motor_output_scale_source"]
    (legacy,) = read_log(FL / "sim_hover_v1.9.ulg")
    assert legacy.motor_output_scale is not None
    assert (legacy.motor_output_scale.lo, legacy.motor_output_scale.hi) == (1075.0, 1950.0)
    assert legacy.metadata["motor_output_scale_source"].startswith("PWM_MIN/PWM_MAX")


def test_ardupilot_scale_names_its_parameters(shared_data: Path) -> None:
    (fl,) = read_log(shared_data / ARDU / "copter3.4rc2_erlebrain3_servo_channels.bin")
    src = fl.metadata["motor_output_scale_source"]
    assert src.startswith("RC3_MIN/MAX 1079..1919 us (MOT_PWM_MIN/MAX unset)")
    assert "MOT_SPIN_MIN 0.15" in src
    (sim_fl,) = read_log(FL / "sim_hover.bin")
    assert sim_fl.metadata["motor_output_scale_source"].startswith("MOT_PWM_MIN/MAX 1000..2000")


# -- 5. ArduPilot telemetry logs -----------------------------------------------------------------


def test_ardupilot_tlog_raw_imu_in_mg_and_a_mid_frame_start(tmp_path: Path) -> None:
    """ArduCopter streams RAW_IMU / SCALED_IMU2 in mG, not HIGHRES_IMU; a recording joined
    mid-frame is still a tlog (found by a chain of valid records, not by its first bytes)."""
    from thrustmap.flightlogs.detect import detect

    truth = sim.simulate_hover(sim.FIXTURE_SIM)
    full = tmp_path / "ap.tlog"
    sim.write_tlog(truth, full, ardupilot=True)
    cut = tmp_path / "cut.tlog"
    cut.write_bytes(full.read_bytes()[5:])  # starts inside the first record
    assert detect(cut).name == "tlog"
    for path in (full, cut):
        (fl,) = read_log(path)
        a = fl.accel_up_mps2
        assert a is not None and a.origin.startswith(("-SCALED_IMU2", "-RAW_IMU"))
        idx = np.round((a.time_s - a.time_s[0]) * sim.FIXTURE_SIM.rate_hz).astype(int)
        idx += int(round(truth.time_s[-1] * sim.FIXTURE_SIM.rate_hz)) - idx[-1] - 1  # cut start
        expect = truth.accel_up_mps2[idx]
        assert np.max(np.abs(a.values - expect)) < G0 / 1000 + 1e-6  # 1 mG steps
        assert fl.thrust_cmd_norm is not None and "VFR_HUD" in fl.thrust_cmd_norm.origin
        assert "height_m" in fl.extras and "climb_mps" in fl.extras
        assert fl.metadata["motor_channels"].startswith("FRAME_CLASS 1")
        assert fl.metadata["motor_output_scale_source"].startswith("MOT_PWM_MIN/MAX 1000..2000")
        assert fl.motor_outputs is not None and fl.motor_outputs.values.shape[1] == 4


# -- 8. extrapolating the stand map --------------------------------------------------------------


def test_df_outside_the_maps_validity_box_is_reported(tmp_path: Path) -> None:
    """The sim map is valid for 20.4..25.2 V and 0..11 N per rotor; this flight drains to 19.6 V
    and the map is cut to 0..2.3 N, below the hover thrust per rotor (~2.5 N)."""
    from dataclasses import replace

    from thrustmap.fitting.gamma import fit_gamma
    from thrustmap.fitting.mapfile import Box

    flight = sim.simulate_hover(
        sim.HoverSim(duration_s=60.0, rate_hz=25.0, voltage_start_v=21.5, voltage_end_v=19.6)
    )
    sim.write_dataflash(flight, tmp_path / "low.bin")
    tmap = flight.stand_map
    tmap = replace(tmap, validity=replace(tmap.validity, thrust_n=Box(0.0, 2.3)))
    df = extract(read_log(tmp_path / "low.bin"), DfOptions(mass_kg=1.0), tmap)
    warnings = df.reports[0].warnings
    volt = [w for w in warnings if "battery voltage below the map's validity box" in w]
    assert volt and "20.4..25.2 V, by up to" in volt[0]
    far = float(volt[0].split("by up to ")[1].split(" V")[0])
    assert far == pytest.approx(20.4 - float(df.table["voltage_v"].min()), abs=1e-3)
    assert far > 0.3
    assert any("per-rotor thrust (F_m / rotors) above" in w for w in warnings)
    fit = fit_gamma(df.table, df.sources, tmap)
    assert any("validity box" in w for w in fit.warnings)


def test_flight_cli_module_starts_without_numpy() -> None:
    """`thrustmap flightlog --help` must not pay for numpy/pandas/the readers."""
    import subprocess
    import sys

    code = (
        "import sys, thrustmap.cli.flight; "
        "print(sorted(m for m in ('numpy', 'pandas', 'pyulog') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_px4_in_air_evidence_is_read(shared_data: Path) -> None:
    """PX4 v1.15 SITL: landed flips at 16.7 s, ground_contact / maybe_landed at 16.85 s, the
    hover-thrust estimate becomes valid at 22.5 s; altitude and climb from the local position."""
    (fl,) = read_log(shared_data / "flightlogs/px4/sitl_v1.15_sample_px4_events.ulg")
    gc = fl.extras["ground_contact"]
    assert gc.hold(np.array([16.8, 16.9, 27.5]))[:2].tolist() == [1.0, 0.0]
    assert gc.hold(np.array([27.5]))[0] == 1.0  # touchdown
    hv = fl.extras["hover_estimate_valid"]
    assert hv.hold(np.array([22.4, 22.6])).tolist() == [0.0, 1.0]
    assert fl.extras["height_m"].values.max() == pytest.approx(2.2, abs=0.1)
    assert "vehicle_local_position.vz" in fl.extras["climb_mps"].origin
    df = extract([fl], DfOptions(mass_kg=1.5, settle_s=0.5))
    assert df.table["time_s"].min() > 22.4  # nothing before the autopilot's own evidence


def test_slow_accelerometer_logging_is_reported(shared_data: Path) -> None:
    """PX4 v1.9 FMUv3 log: sensor_combined at ~9 Hz."""
    df = extract(read_log(shared_data / "flightlogs/px4/fmuv3_v1.9_esc_status.ulg"),
                 DfOptions(mass_kg=2.0))  # fmt: skip
    assert any("logged at only 9 Hz" in w for w in df.reports[0].warnings)
    assert any(
        re.search(r"only [1-4]\d samples of steady flight", w) for w in df.reports[0].warnings
    )
