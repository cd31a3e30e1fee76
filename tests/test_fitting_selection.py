"""Steady-state extraction: plateaus, settling, and up/down ramp pairing that cancels rotor lag."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from thrustmap.cli import main
from thrustmap.core.units import SCALES
from thrustmap.fitting.dataset import STEP_SUMMARY, Dataset
from thrustmap.fitting.loaders.load import load_dataset
from thrustmap.fitting.selection.options import Selection
from thrustmap.fitting.selection.plateaus import plateaus
from thrustmap.fitting.selection.points import select


def lagged(throttle_us: np.ndarray, dt_s: float, tau_s: float) -> tuple[np.ndarray, np.ndarray]:
    """True steady thrust, and what a rotor with first-order lag ``tau_s`` produces."""
    u = (throttle_us - 1000) / 1000
    steady = 12.0 * u**2
    out = np.empty_like(steady)
    out[0] = steady[0]
    a = np.exp(-dt_s / tau_s)
    for k in range(1, len(steady)):
        out[k] = steady[k] + (out[k - 1] - steady[k]) * a
    return steady, out


def ramp_dataset(rate_us_s: float = 50.0, dt_s: float = 0.05, tau_s: float = 0.15) -> Dataset:
    up = np.arange(1100, 1700, rate_us_s * dt_s)
    throttle = np.concatenate(
        [np.full(40, 1100.0), up, np.full(40, 1700.0), up[::-1], np.full(40, 1100.0)]
    )
    _, thrust = lagged(throttle, dt_s, tau_s)
    n = len(throttle)
    return Dataset(
        path="ramp.csv",
        format="synthetic",
        throttle_scale=SCALES["pwm"],
        throttle_native=throttle,
        thrust_n=thrust,
        voltage_v=np.full(n, 22.0),
        line=np.arange(n, dtype=np.int64) + 2,
        time_s=np.arange(n) * dt_s,
    )


def test_ramp_pairs_cancel_rotor_lag() -> None:
    ds = ramp_dataset()
    pts = select(ds, Selection())
    pair = pts.kind == "ramp-pair"
    assert pair.sum() > 50 and pts.report["ramp_pair_points"] == int(pair.sum())
    true = 12.0 * ((ds.throttle_scale.from_pct(pts.throttle_pct[pair]) - 1000) / 1000) ** 2
    paired_err = np.abs(pts.thrust_n[pair] - true).mean()
    # the up-ramp alone lags: compare the raw up-ramp samples against the truth
    steady, lag = lagged(ds.throttle_native, 0.05, 0.15)
    rising = np.gradient(ds.throttle_native) > 0
    raw_err = np.abs(lag[rising] - steady[rising]).mean()
    assert paired_err < 0.1 * raw_err, (paired_err, raw_err)
    # the hold levels still come out as plateaus, with the settling dropped
    assert (pts.kind == "plateau").sum() == 3


def test_fast_transitions_between_steps_are_not_paired() -> None:
    step = np.repeat([1100.0, 1300.0, 1100.0, 1500.0, 1100.0], 30)
    throttle = np.convolve(step, np.ones(5) / 5, mode="same")  # 0.2 s transitions, not ramps
    _, thrust = lagged(throttle, 0.05, 0.05)
    n = len(throttle)
    ds = Dataset(
        path="s.csv",
        format="synthetic",
        throttle_scale=SCALES["pwm"],
        throttle_native=throttle,
        thrust_n=thrust,
        voltage_v=np.full(n, 22.0),
        line=np.arange(n, dtype=np.int64) + 2,
        time_s=np.arange(n) * 0.05,
    )
    pts = select(ds, Selection())
    assert pts.report["ramp_pair_points"] == 0
    assert (pts.kind == "plateau").sum() == 5


def test_plateaus_split_on_command_changes_only() -> None:
    th = np.array([10.0] * 5 + [10.01] * 3 + [12.0] * 6)
    assert plateaus(th, 0.05) == [(0, 8), (8, 14)]


# -- step-summary exports (one averaged row per throttle step) --------------------------------

STEP_HEADER = (
    "Time (s),ESC signal (µs),Servo 1 (µs),Servo 2 (µs),Servo 3 (µs),Thrust (gf),Voltage (V),"
    "Current (A),Motor Electrical Speed (RPM),Motor Optical Speed (RPM),Electrical Power (W),"
    "Overall Efficiency (gf/W),App message,"
)


def _step_summary(path: Path, dt_s: float = 1.7, repeat: int = 1) -> Path:
    rows = []
    k = 0
    for i, us in enumerate(range(1050, 2001, 95)):
        for _ in range(repeat):
            thrust_gf = 300.0 * ((us - 1000) / 1000) ** 2
            rows.append(
                f"{k * dt_s:.3f},{us},,,,{thrust_gf:.3f},{7.4 - 0.02 * i:.3f},{0.4 + i},"
                f"{3000 + 1200 * i},0,10,3,,"
            )
            k += 1
    path.write_text("\ufeff" + "\n".join([STEP_HEADER, *rows]) + "\n", encoding="utf-8")
    return path


def test_step_summary_detected_and_every_row_is_a_point(tmp_path: Path) -> None:
    ds = load_dataset(_step_summary(tmp_path / "s_7.csv"))
    assert ds.meta["layout"] == STEP_SUMMARY
    pts = select(ds, Selection())
    assert len(pts) == 11 and set(pts.kind.tolist()) == {"step-summary"}
    assert pts.report["step_summary_rows"] == 11
    assert pts.thrust_n[-1] == pytest.approx(300.0 * 9.80665e-3)
    # the same levels logged continuously (each command repeated at the logging rate) are not
    for dt, rep in ((0.12, 8), (1.7, 2)):
        cont = load_dataset(_step_summary(tmp_path / f"c{rep}.csv", dt_s=dt, repeat=rep))
        assert "layout" not in cont.meta


def test_step_summary_said_by_inspect(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    p = _step_summary(tmp_path / "s_7.csv")
    main(["inspect", str(p)])
    out = capsys.readouterr().out
    assert "layout: step-summary (one averaged row per throttle step" in out
    assert "step_summary_rows=11" in out


def test_real_step_summaries_give_points_by_default(shared_data: Path) -> None:
    folder = shared_data / "third-party-stands" / "strawson-5inch"
    files = sorted(folder.glob("*.csv"))
    assert len(files) == 96
    for f in files:
        ds = load_dataset(f)
        assert ds.meta.get("layout") == STEP_SUMMARY, f
        pts = select(ds, Selection())
        assert len(pts) >= 9, (f, pts.report)
    # the stand's own continuous logs (steps, ramps, re-saved) are not step summaries
    for f in sorted((shared_data / "xnova-thrust-stand").glob("*/*.csv")):
        assert "layout" not in load_dataset(f).meta, f


# -- sensors, trends, staircases and tare -----------------------------------------------------


def crazyflie_staircase(
    stall_levels: int = 2,
    hold_every: int = 10,
    tau_s: float = 0.1,
    with_time: bool = False,
    phase: int = 3,
) -> tuple[Dataset, np.ndarray]:
    """A Crazyflie-style system-id staircase: 10 ms samples, the command raised every 10
    samples up to 70 % and back down, a rotor with lag ``tau_s``, a load cell that updates every
    ``hold_every`` samples and holds, a rotor that does not start on the first ``stall_levels``
    stairs going up, and 20 samples at command 0 first (the load cell reads its offset)."""
    levels = np.arange(10.0, 71.0, 5.0)
    cmd_pct = np.concatenate([np.zeros(20), np.repeat(levels, 10), np.repeat(levels[::-1], 10)])
    steady = 0.15 * (cmd_pct / 100.0) ** 2  # N per rotor
    n = len(cmd_pct)
    rotor = np.zeros(n)
    a = np.exp(-0.01 / tau_s)
    for k in range(1, n):
        rotor[k] = steady[k] + (rotor[k - 1] - steady[k]) * a
    going_up = np.arange(n) < 20 + 10 * len(levels)
    stalled = going_up & (cmd_pct > 0) & (cmd_pct < levels[stall_levels])
    rotor[stalled] = 0.0
    offset_n = 0.002
    cell = rotor + offset_n + np.random.default_rng(3).normal(0.0, 2e-5, n)  # load-cell noise
    held = cell.copy()
    for k in range(n):
        held[k] = cell[k - (k - phase) % hold_every] if k >= phase else cell[0]
    ds = Dataset(
        path="cf_stairs.csv",
        format="synthetic",
        throttle_scale=SCALES["crazyflie"],
        throttle_native=SCALES["crazyflie"].from_pct(cmd_pct),
        thrust_n=held,
        voltage_v=np.full(n, 4.0),
        line=np.arange(n, dtype=np.int64) + 2,
        time_s=np.arange(n) * 0.01 if with_time else None,
        rotors_on_esc=4,
    )
    return ds, steady


def test_held_load_cell_staircase_pairs_legs_without_time() -> None:
    ds, _ = crazyflie_staircase()
    pts = select(ds, Selection(drop_tare_points=True))
    r = pts.report
    assert r["sample_and_hold_sensor"] is True and r["samples_per_update"] == pytest.approx(
        10, abs=1
    )
    assert r["plateaus"] == 0  # a 10-sample stair is ONE load-cell update, not a plateau
    assert set(pts.kind.tolist()) == {"stair-pair"}
    assert r["stair_pairs_dropped_stalled"] == 2  # the rotor had not started on the way up
    assert r["stair_pairs"] == len(pts) == 10
    # 20 rest samples of a cell holding each reading for 10 are 3 readings: too few to measure
    # its zero against its noise, so nothing is subtracted
    assert "zero_subtracted_n" not in r
    true = 0.15 * (pts.throttle_pct / 100.0) ** 2 + 0.002
    paired_err = np.abs(pts.thrust_n / true - 1.0)
    # the up-leg alone (the old reading: every stair a "plateau") lags by far more
    up_pct = ds.throttle_pct[20 : 20 + 130].reshape(13, 10).mean(axis=1)[2:]
    up_t = ds.thrust_n[20 : 20 + 130].reshape(13, 10).mean(axis=1)[2:]
    up_err = np.abs(up_t / (0.15 * (up_pct / 100) ** 2 + 0.002) - 1.0)
    assert float(np.median(paired_err)) < 0.2 * float(np.median(up_err))
    # the zero-command samples were the load cell's offset: tare information
    assert r["tare_points"] >= 1 and r["tare_offset_n"] == pytest.approx(0.002, abs=1e-4)
    # the same with the loader's 10 ms time base: the same pairs, no ramp points invented
    timed = select(crazyflie_staircase(with_time=True)[0], Selection(drop_tare_points=True))
    assert timed.report["stair_pairs"] == 10 and set(timed.kind.tolist()) == {"stair-pair"}


def test_crazyflie_file_updates_in_step_with_the_command(tmp_path: Path) -> None:
    """The load cell may update on the very sample the command changes: nothing in the numbers
    tells it from a constant plateau, but the loader knows this stand's load cell holds."""
    ds, _ = crazyflie_staircase(phase=0)
    weight_g = ds.thrust_n * 4 / 9.80665e-3
    rows = [
        f"{float(w)!r},{int(round(c))},4.0,0,0,0,0,4.0,0.5,2"
        for w, c in zip(weight_g, ds.throttle_native, strict=True)
    ]
    p = tmp_path / "cf.csv"
    p.write_text("weight[g],pwm,vbat[V],rpm1,rpm2,rpm3,rpm4,v[V],i[A],p[W]\n" + "\n".join(rows))
    loaded = load_dataset(p)
    r = select(loaded, Selection(drop_tare_points=True)).report
    assert r["sample_and_hold_sensor"] is True and r["stair_pairs"] == 10
    # the same numbers from an unknown stand are not assumed to be held
    unknown = Dataset(**{**loaded.__dict__, "meta": {}})
    assert "sample_and_hold_sensor" not in select(unknown, Selection()).report


def test_continuous_sensor_is_not_taken_for_held() -> None:
    ds = ramp_dataset()
    assert "sample_and_hold_sensor" not in select(ds, Selection()).report


def _plateau_dataset(drift_n: float, noise_n: float = 0.002) -> Dataset:
    rng = np.random.default_rng(1)
    throttle = np.repeat([1300.0, 1500.0], 60)
    thrust = np.repeat([2.0, 4.0], 60) + rng.normal(0, noise_n, 120)
    thrust[60:] += np.linspace(0.0, drift_n, 60)  # the second level creeps the whole time
    return Dataset(
        path="trend.csv",
        format="synthetic",
        throttle_scale=SCALES["pwm"],
        throttle_native=throttle,
        thrust_n=thrust,
        voltage_v=np.full(120, 16.0),
        line=np.arange(120, dtype=np.int64) + 2,
    )


def test_plateau_that_still_trends_is_dropped() -> None:
    pts = select(_plateau_dataset(drift_n=0.2), Selection())
    assert pts.report["plateaus_dropped_still_trending"] == 1 and len(pts) == 1
    assert pts.thrust_n[0] == pytest.approx(2.0, abs=0.01)
    steady = select(_plateau_dataset(drift_n=0.0), Selection())
    assert "plateaus_dropped_still_trending" not in steady.report and len(steady) == 2


def test_rotor_not_turning_at_a_positive_command_is_not_a_map_point() -> None:
    ds, _ = crazyflie_staircase(stall_levels=0)
    rpm = np.where(ds.throttle_pct > 12.0, 20000.0 * ds.throttle_pct / 100, 0.0)
    from dataclasses import replace

    # not turning: 0 rpm and the load cell at its rest reading (0.002 N)
    thrust = np.where(ds.throttle_pct > 12.0, ds.thrust_n, 0.002)
    pts = select(replace(ds, rpm=rpm, thrust_n=thrust), Selection())
    assert pts.report["stopped_rotor_points_dropped"] >= 1
    assert float(pts.throttle_pct.min()) > 12.0


def test_selection_rules_on_real_data(shared_data: Path) -> None:
    xn = shared_data / "xnova-thrust-stand"
    for f in sorted(xn.glob("*/*.csv")):
        r = select(load_dataset(f), Selection()).report
        assert "sample_and_hold_sensor" not in r and "stair_pairs" not in r, f
    # the long transmission-map log has plateaus that never stop creeping
    tm = select(load_dataset(xn / "single_rotor" / "xNova-TM-SR.csv"), Selection()).report
    assert tm["plateaus_dropped_still_trending"] >= 5 and tm["kept_points"] >= 250
    # the 1000 µs rest level is tare information
    steps = select(load_dataset(xn / "single_rotor" / "xNova-SR-steps.csv"), Selection()).report
    assert steps["tare_points"] >= 1 and abs(steps["tare_offset_n"]) < 0.1
    # a strawson step at 1050 µs reading 0 rpm makes 6 gf at 0.38 A (0.1 A at rest): the rpm
    # probe is below its lowest speed, the rotor turns, and the step is a map point
    a1 = load_dataset(shared_data / "third-party-stands" / "strawson-5inch" / "a1_7.csv")
    pts = select(a1, Selection())
    assert "stopped_rotor_points_dropped" not in pts.report and len(pts) == 11


def _offset_steps(offset_n: float, rest_samples: int = 24) -> tuple[Dataset, np.ndarray]:
    """A step sweep whose load cell reads ``offset_n`` with the rotor at rest (tared off zero),
    starting with ``rest_samples`` at command 0; returns the file and the true steady thrust."""
    levels = [1000.0] * (rest_samples > 0) + [1150.0, 1300.0, 1450.0, 1600.0]
    throttle = np.concatenate([np.full(rest_samples if lv == 1000.0 else 30, lv) for lv in levels])
    steady = 12.0 * ((throttle - 1000) / 1000) ** 2
    noise = np.random.default_rng(5).normal(0.0, 0.002, len(throttle))
    n = len(throttle)
    ds = Dataset(
        path="offset.csv",
        format="synthetic",
        throttle_scale=SCALES["pwm"],
        throttle_native=throttle,
        thrust_n=steady + offset_n + noise,
        voltage_v=np.full(n, 22.0),
        line=np.arange(n, dtype=np.int64) + 2,
        time_s=np.arange(n) * 0.05,
    )
    return ds, steady


def test_load_cell_zero_from_the_rest_plateau_is_subtracted() -> None:
    """A rotor at rest makes no thrust: a rest plateau reading 0.06 N is the load cell's zero
    (the xNova steps file: 0.061 N, its sister file 0.004 N), and every point is read from it."""
    ds, steady = _offset_steps(0.06)
    pts = select(ds, Selection())
    assert pts.report["zero_subtracted_n"] == pytest.approx(0.06, abs=0.003)
    assert (pts.throttle_pct > 0).all()  # the rest plateau is the zero, not a map point
    true = 12.0 * (pts.throttle_pct / 100.0) ** 2
    assert np.abs(pts.thrust_n - true).max() < 0.005
    # no rest plateau (or a zero inside its own noise): nothing is subtracted
    assert "zero_subtracted_n" not in select(_offset_steps(0.06, 0)[0], Selection()).report
    assert "zero_subtracted_n" not in select(_offset_steps(0.0)[0], Selection()).report


def test_step_summary_rest_row_is_not_taken_for_the_zero(tmp_path: Path) -> None:
    """One averaged rest row has no noise to judge it by: the stand software's tare stands."""
    rows = ["Time (s),ESC signal (µs),Thrust (N),Voltage (V)"] + [
        f"{i * 2.0},{1000 + 100 * i},{0.05 + 12.0 * (i / 10) ** 2},22.0" for i in range(11)
    ]
    p = tmp_path / "summary.csv"
    p.write_text("\n".join(rows) + "\n")
    ds = load_dataset(p)
    if ds.meta.get("layout") != STEP_SUMMARY:
        pytest.skip("not detected as a step summary")
    assert "zero_subtracted_n" not in select(ds, Selection()).report


def test_rpm_probe_reading_zero_on_a_rotor_making_thrust_keeps_the_point(tmp_path: Path) -> None:
    """The RCbenchmark stand's electrical rpm reads 0 below its lowest speed: at 1050 µs on 2S
    the rows say 0 rpm with 6 gf and 0.38 A (0.1 A at rest). Such a row is a turning rotor and
    a point of the map; a row at 0 rpm whose thrust is the rest reading is still dropped."""
    rows = []
    for i, us in enumerate(range(1050, 2001, 95)):
        thrust_gf = 6.0 + 290.0 * ((us - 1050) / 950) ** 2
        rpm = 0 if i == 0 else 3800 + 1150 * i
        rows.append(
            f"{i * 1.7:.3f},{us},,,,{thrust_gf:.3f},{7.4 - 0.02 * i:.3f},{0.4 + i},{rpm},0,1,1,,"
        )
    p = tmp_path / "s_7.csv"
    p.write_text("\ufeff" + "\n".join([STEP_HEADER, *rows]) + "\n", encoding="utf-8")
    ds = load_dataset(p)
    pts = select(ds, Selection())
    assert len(pts) == 11 and pts.throttle_pct[0] == pytest.approx(5.0)
    assert "stopped_rotor_points_dropped" not in pts.report
    # the same row reading no thrust (the rest level) is a rotor that did not turn
    rows[0] = rows[0].replace(",6.000,", ",0.000,")
    p.write_text("\ufeff" + "\n".join([STEP_HEADER, *rows]) + "\n", encoding="utf-8")
    still = select(load_dataset(p), Selection())
    assert len(still) == 10 and still.report["stopped_rotor_points_dropped"] == 1


def test_load_cell_zero_counts_a_held_cells_readings_not_its_samples() -> None:
    """A sample-and-hold cell repeats each reading: 60 rest samples holding 12 readings of pure
    noise are judged on 12 readings, so noise is not taken for an offset; a real 0.06 N is."""
    from dataclasses import replace

    ds, _ = _offset_steps(0.0, rest_samples=60)
    held = ds.thrust_n.copy()
    held[:60] = np.repeat(np.random.default_rng(1).normal(0.0, 0.002, 12), 5)
    assert "zero_subtracted_n" not in select(replace(ds, thrust_n=held), Selection()).report
    held[:60] += 0.06
    r = select(replace(ds, thrust_n=held), Selection()).report
    assert r["zero_subtracted_n"] == pytest.approx(0.06, abs=0.003)
