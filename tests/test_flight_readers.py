"""Flight-log readers: the shared real samples and the project's own simulated fixtures."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from support import simulate_flight as sim

from thrustmap.flightlogs.detect import detect, read_log
from thrustmap.flightlogs.series import FlightLog

FL = Path(__file__).resolve().parent.parent / "fixtures" / "flightlogs"


@pytest.fixture(scope="module")
def truth() -> sim.SimFlight:
    return sim.simulate_hover(sim.FIXTURE_SIM)


def one(path: Path, **kw: object) -> FlightLog:
    flights = read_log(path, **kw)  # type: ignore[arg-type]
    assert len(flights) == 1
    return flights[0]


# -- shared real logs ----------------------------------------------------------------------------


def test_px4_v115_sitl_modern_topics(shared_data: Path) -> None:
    path = shared_data / "flightlogs/px4/sitl_v1.15_sample_px4_events.ulg"
    assert detect(path).name == "ulog"
    fl = one(path)
    assert fl.metadata["px4_version"] == "v1.15.0"
    assert fl.voltage_v is not None and fl.voltage_v.origin == "battery_status.voltage_v"
    assert fl.voltage_v.values.min() > 15.7 and fl.voltage_v.values.max() < 16.25  # 4S SITL
    assert fl.thrust_cmd_norm is not None
    assert fl.thrust_cmd_norm.origin == "-vehicle_thrust_setpoint.xyz[2]"
    assert 0.5 < fl.thrust_cmd_norm.values.max() < 0.6
    acc = fl.accel_up_mps2
    assert acc is not None and abs(float(np.median(acc.values)) - 9.81) < 0.05  # up is +g
    assert fl.motor_outputs is not None and fl.motor_outputs.values.shape[1] == 4
    assert fl.motor_output_scale is not None and fl.motor_output_scale.name == "norm"
    assert fl.armed is not None and fl.armed.values.max() == 1.0 and fl.armed.values[0] == 0.0
    assert fl.hover_thrust_estimate is not None
    ht = fl.hover_thrust_estimate.values
    assert 0.47 < np.nanmedian(ht) < 0.5


def test_px4_v19_legacy_topics(shared_data: Path) -> None:
    fl = one(shared_data / "flightlogs/px4/fmuv3_v1.9_esc_status.ulg")
    assert fl.metadata["px4_version"] == "v1.9.0"
    assert fl.thrust_cmd_norm is not None
    assert fl.thrust_cmd_norm.origin == "actuator_controls_0.control[3]"
    airborne = fl.thrust_cmd_norm.values[fl.thrust_cmd_norm.values > 0.1]
    assert 0.3 < float(np.median(airborne)) < 0.4
    assert fl.voltage_v is not None and 21.5 < float(np.median(fl.voltage_v.values)) < 22.5  # 6S
    assert fl.hover_thrust_estimate is None  # the topic did not exist in v1.9
    assert fl.motor_outputs is not None and fl.motor_outputs.values.shape[1] == 4
    assert fl.landed is not None and fl.landed.values[-1] == 1.0


def test_ardupilot_copter34_dataflash(shared_data: Path) -> None:
    path = shared_data / "flightlogs/ardupilot/copter3.4_pxf_3s.bin"
    assert detect(path).name == "dataflash"
    fl = one(path)
    assert fl.warnings == []
    assert fl.metadata["firmware"].startswith("APM:Copter V3.4")
    assert fl.metadata["message_counts"]["IMU"] == 23375
    v = fl.voltage_v
    assert v is not None and v.origin == "CURR.Volt"
    assert v.values[0] == pytest.approx(12.37)  # 1237 centivolts
    assert 9.8 < v.values.min() < 10.0 and 12.3 < v.values.max() < 12.45
    assert fl.accel_up_mps2 is not None
    assert fl.accel_up_mps2.values[0] == pytest.approx(9.842037, abs=1e-5)  # -IMU.AccZ
    assert fl.motor_outputs is not None and fl.motor_outputs.origin == "RCOU.Ch1,Ch2,Ch3,Ch4"
    assert fl.motor_output_scale is not None
    assert (fl.motor_output_scale.lo, fl.motor_output_scale.hi) == (1100.0, 1922.0)  # RC3_MIN/MAX
    assert fl.thrust_cmd_norm is not None and fl.thrust_cmd_norm.values[0] == pytest.approx(0.085)
    assert fl.landed is not None and {0.0, 1.0} <= set(fl.landed.values.tolist())


# -- the project's simulated fixtures ------------------------------------------------------------


def _at(truth_t: np.ndarray, truth_v: np.ndarray, t: np.ndarray) -> np.ndarray:
    return np.interp(t, truth_t, truth_v)


@pytest.mark.parametrize(
    ("name", "reader"),
    [
        ("sim_hover.bin", "dataflash"),
        ("sim_hover_copter3.bin", "dataflash"),
        ("sim_hover.ulg", "ulog"),
        ("sim_hover_v1.9.ulg", "ulog"),
        ("sim_hover.tlog", "tlog"),
        ("sim_hover_paper.csv", "paper-csv"),
    ],
)
def test_fixture_values_match_the_simulation(name: str, reader: str, truth: sim.SimFlight) -> None:
    path = FL / name
    assert detect(path).name == reader
    fl = one(path)
    assert fl.warnings == []
    t_off = truth.time_s[0] - fl.accel_up_mps2.time_s[0] if fl.accel_up_mps2 else 0.0
    v = fl.voltage_v
    assert v is not None
    expect_v = _at(truth.time_s, truth.voltage_v, v.time_s + t_off)
    tol_v = 0.006 if name in ("sim_hover_copter3.bin",) else 1e-3  # centivolts in old CURR
    assert np.max(np.abs(v.values - expect_v)) < tol_v
    a = fl.accel_up_mps2
    assert a is not None
    assert (
        np.max(np.abs(a.values - _at(truth.time_s, truth.accel_up_mps2, a.time_s + t_off))) < 1e-3
    )
    if fl.thrust_cmd_norm is not None:
        n = fl.thrust_cmd_norm
        expect = _at(truth.time_s, truth.thrust_norm, n.time_s + t_off)
        assert np.max(np.abs(n.values - expect)) < 1e-4
    if fl.thrust_cmd_n is not None:
        expect = _at(truth.time_s, truth.thrust_cmd_n, fl.thrust_cmd_n.time_s + t_off)
        assert np.max(np.abs(fl.thrust_cmd_n.values - expect)) < 1e-4
    if fl.motor_outputs is not None and fl.motor_output_scale is not None:
        pct = fl.motor_output_scale.to_pct(fl.motor_outputs.values)
        if fl.motor_output_scale.unit == truth.stand_map.throttle_scale.unit:
            # native units (µs) compared in the map's scale: the log's own range was used
            pct = truth.stand_map.throttle_scale.to_pct(fl.motor_outputs.values)
        idx = np.searchsorted(truth.time_s, fl.motor_outputs.time_s + t_off - 1e-6)
        expect_pct = truth.throttle_pct[idx]
        if pct.shape[1] == 1:
            expect_pct = expect_pct.mean(axis=1, keepdims=True)
        assert np.max(np.abs(pct - expect_pct)) < 0.06  # µs rounding = 0.05 %
    if fl.landed is not None:
        airborne = fl.landed.hold(fl.landed.time_s) < 0.5
        assert airborne.any() and not airborne.all()


def test_generic_csv_with_column_map(truth: sim.SimFlight) -> None:
    fl = one(
        FL / "sim_hover_generic.csv",
        format="csv",
        columns={
            "time_s": "t_us",
            "voltage_v": "vbat",
            "accel_up_mps2": "acc_z_frd",
            "thrust_cmd_norm": "thr_norm",
            "armed": "armed",
            "landed": "landed",
        },
        time_scale=1e-6,
        accel_scale=-1.0,
    )
    assert fl.accel_up_mps2 is not None and fl.voltage_v is not None
    assert np.allclose(fl.accel_up_mps2.values, truth.accel_up_mps2, atol=1e-5)
    assert np.allclose(fl.voltage_v.time_s, truth.time_s, atol=1e-6)
    assert fl.thrust_cmd_norm is not None
    assert np.allclose(fl.thrust_cmd_norm.values, truth.thrust_norm, atol=1e-5)


def test_paper_csv_keeps_mass_and_collective_throttle() -> None:
    fl = one(FL / "sim_hover_paper.csv")
    assert fl.metadata["mass_kg"] == pytest.approx(sim.FIXTURE_SIM.mass_kg)
    assert fl.metadata["motor_outputs_collective"] is True
    assert fl.motor_outputs is not None and fl.motor_outputs.values.shape[1] == 1


def test_fixtures_regenerate_to_the_same_values(tmp_path: Path) -> None:
    """fixtures/flightlogs is what `python -m support.simulate_flight` writes."""
    sim.write_fixtures(tmp_path)
    for name in sim.FIXTURE_FILES:
        shipped, fresh = FL / name, tmp_path / name
        assert shipped.exists(), f"{name} missing: regenerate the fixtures"
        if name.endswith((".csv", ".json")):
            assert shipped.read_text() == fresh.read_text(), name
            continue
        a, b = one(shipped), one(fresh)
        assert a.voltage_v is not None and b.voltage_v is not None
        assert np.array_equal(a.voltage_v.values, b.voltage_v.values), name
        assert a.accel_up_mps2 is not None and b.accel_up_mps2 is not None
        assert np.array_equal(a.accel_up_mps2.values, b.accel_up_mps2.values), name


def _ulogs() -> list[Path]:
    fixtures = sorted(
        (Path(__file__).resolve().parent.parent / "fixtures/flightlogs").glob("*.ulg")
    )
    shared = Path(__file__).resolve().parent.parent.parent / "shared/data/flightlogs/px4"
    return fixtures + (sorted(shared.glob("*.ulg")) if shared.is_dir() else [])


@pytest.mark.parametrize("path", _ulogs(), ids=lambda p: p.name)
def test_vectorised_ulog_parse_equals_pyulog(path: Path) -> None:
    """The vectorised ULog path gives pyulog's topics, fields, dtypes, values, parameters and
    info exactly (or declines, e.g. for appended data, and pyulog is used)."""
    import contextlib
    import io

    from pyulog import ULog

    from thrustmap.flightlogs import ulog, ulog_fast

    raw = path.read_bytes()
    fast = ulog_fast.parse(raw, ulog.TOPICS)
    if fast is None:
        assert "appended" in path.name  # the only shared/fixture log pyulog must handle
        return
    with contextlib.redirect_stdout(io.StringIO()):
        ref = ULog(io.BytesIO(raw), message_name_filter_list=ulog.TOPICS)
    mine = {(d.name, d.multi_id): d.data for d in fast.data_list}
    theirs = {(d.name, d.multi_id): d.data for d in ref.data_list}
    assert mine.keys() == theirs.keys() and mine
    for key, cols in mine.items():
        assert cols.keys() == theirs[key].keys()
        for c, v in cols.items():
            assert v.dtype == theirs[key][c].dtype
            assert np.array_equal(v, theirs[key][c], equal_nan=True), (key, c)
    assert (fast.start_timestamp, fast.last_timestamp) == (ref.start_timestamp, ref.last_timestamp)
    assert fast.initial_parameters == ref.initial_parameters
    assert fast.msg_info_dict == ref.msg_info_dict


def test_vectorised_ulog_parse_reports_a_truncated_tail(tmp_path: Path) -> None:
    from thrustmap.flightlogs import ulog, ulog_fast

    raw = (FL / "sim_hover.ulg").read_bytes()
    fast = ulog_fast.parse(raw[: len(raw) - 5], ulog.TOPICS)
    assert fast is not None and fast.problem is not None and "truncated" in fast.problem
    assert ulog_fast.parse(raw[:20] + b"\xff" * 40, ulog.TOPICS) is None  # corrupt: pyulog
