"""Ds loaders: every supported format decodes to the right values; bad input gets one clear line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from thrustmap.cli import main
from thrustmap.core.errors import DataFormatError
from thrustmap.core.stand_recording import DsWriter
from thrustmap.core.units import SCALES
from thrustmap.fitting.loaders.load import ColumnMap, load_dataset

RCB_HEADER = (
    "Time (s),ESC signal (µs),Servo 1 (µs),Servo 2 (µs),Servo 3 (µs),AccX (g),AccY (g),AccZ (g),"
    "Torque (N·m),Thrust (N),Voltage (V),Current (A),Motor Electrical Speed (RPM),"
    "Motor Optical Speed (RPM),Electrical Power (W),App message,"
)


def _rcb_rows(n: int = 40) -> list[str]:
    rows = []
    for k in range(n):
        us = 1100 + 50 * (k // 10)
        thrust = -(0.5 + 1.5 * (k // 10))  # a pulling propeller reads negative on this stand
        volt = 24.0 - 0.1 * (k // 10) - 0.001 * k
        rows.append(
            f"{0.1 * k:.2f},{us},,,,0,0,-1,0.01,{thrust},{volt:.3f},{1 + k // 10},{5000 + 100 * k},0,10,,"
        )
    return rows


def write(path: Path, text: str, encoding: str = "utf-8") -> Path:
    path.write_bytes(text.encode(encoding))
    return path


def test_rcbenchmark_bom_trailing_comma_sign_flip(tmp_path: Path) -> None:
    p = write(tmp_path / "rcb.csv", "\ufeff" + "\n".join([RCB_HEADER, *_rcb_rows()]) + "\n")
    ds = load_dataset(p)
    assert ds.format == "rcbenchmark"
    assert ds.throttle_scale == SCALES["pwm"]
    assert ds.meta["thrust_sign_flipped"] is True
    assert ds.thrust_n[0] == pytest.approx(0.5) and ds.thrust_n[-1] == pytest.approx(5.0)
    assert ds.throttle_native[-1] == 1250
    assert ds.voltage_v[0] == pytest.approx(24.0)
    assert ds.line[0] == 2 and ds.line[-1] == 41
    assert ds.time_s is not None and ds.time_s[1] == pytest.approx(0.1)
    assert ds.rpm is not None and ds.rpm[0] == 5000


def test_rcbenchmark_old_header_greek_mu_and_kgf(tmp_path: Path) -> None:
    header = "Time (s),ESC (\u03bcs),Servo (µs),Thrust (kgf),Voltage (V),Current (A)"
    rows = [f"{k},{1200 + 10 * k},,{-0.1 * (k + 1)},16.{k},2" for k in range(6)]
    ds = load_dataset(write(tmp_path / "old.csv", "\n".join([header, *rows])))
    assert ds.thrust_n[2] == pytest.approx(0.3 * 9.80665)
    assert ds.throttle_native[5] == 1250


def test_resaved_semicolon_crlf_without_time(tmp_path: Path) -> None:
    header = "ESC signal (µs);Torque (N·m);Thrust (N);Voltage (V);Current (A);Motor Electrical Speed (RPM)"
    rows = [f"{1300 + k};0.01;{-1 - 0.01 * k};22.{k};3;0" for k in range(5)]
    ds = load_dataset(write(tmp_path / "tm.csv", "\r\n".join([header, *rows]) + "\r\n"))
    assert ds.format == "rcbenchmark-resaved" and ds.time_s is None
    assert ds.thrust_n.tolist() == pytest.approx([1.0, 1.01, 1.02, 1.03, 1.04])


def test_flight_stand_sparse_rows(tmp_path: Path) -> None:
    header = (
        "Time (s),Powertrain 1 - ESC throttle (μs),Powertrain 1 - force Fz (thrust) (N),"
        "Powertrain 1 - torque MZ (torque) (N⋅m),Powertrain 1 - voltage (V),Powertrain 1 - current (A)"
    )
    rows = [
        "0.00,1500,,,22.0,",
        "0.01,,3.0,0.05,,8",
        "0.02,,3.1,,21.9,",
        "0.03,1600,,,,",
        "0.04,,4.2,,,",
    ]
    ds = load_dataset(write(tmp_path / "fs.csv", "\n".join([header, *rows])))
    assert ds.format == "flight-stand"
    assert ds.thrust_n.tolist() == [3.0, 3.1, 4.2]
    assert ds.throttle_native.tolist() == [1500, 1500, 1600]
    assert ds.voltage_v.tolist() == [22.0, 21.9, 21.9]
    assert ds.line.tolist() == [3, 4, 6]


def test_crazyflie_total_weight_becomes_per_rotor_thrust(tmp_path: Path) -> None:
    header = "weight[g],pwm,vbat[V],rpm1,rpm2,rpm3,rpm4,v[V],i[A],p[W]"
    rows = [f"{4 * k},{6000 * k},4.{k},0,0,0,0,4,{0.1 * k},1" for k in range(1, 8)]
    ds = load_dataset(write(tmp_path / "cf.csv", "\n".join([header, *rows])))
    assert ds.throttle_scale == SCALES["crazyflie"] and ds.rotors_on_esc == 4
    assert ds.thrust_n[0] == pytest.approx(4 * 9.80665 / 1000 / 4)


def test_own_format_roundtrip_and_partial_run_marked(tmp_path: Path) -> None:
    w = DsWriter(tmp_path / "run.csv", SCALES["dshot"], {"rotors_on_esc": 4, "strategy": "MR"})
    for k in range(5):
        w.write(0.1 * k, 100 + 10 * k, {"thrust_n": 0.5 * k, "voltage_v": 16.0, "phase": "step"})
    # no finish(): the process "died" -> the sidecar still says running
    ds = load_dataset(tmp_path / "run.csv")
    assert ds.format == "thrustmap" and ds.throttle_scale == SCALES["dshot"]
    assert ds.rotors_on_esc == 4 and "partial" in ds.meta
    assert ds.throttle_native.tolist() == [100, 110, 120, 130, 140]
    w.finish("completed")
    assert "partial" not in load_dataset(tmp_path / "run.csv").meta


def test_column_map(tmp_path: Path) -> None:
    p = write(
        tmp_path / "diy.csv",
        "t,cmd,load_g,vbus\n"
        + "\n".join(f"{k},{1100 + 100 * k},{100 * k},12.{k}" for k in range(5)),
    )
    ds = load_dataset(
        p, ColumnMap(throttle="cmd", thrust="load_g", voltage="vbus", time="t", thrust_unit="g")
    )
    assert ds.thrust_n[3] == pytest.approx(0.3 * 9.80665)
    assert ds.format == "column-map"


GOOD = "\n".join([RCB_HEADER, *_rcb_rows()])


def _rows_with(line_index: int, field: int, value: str) -> str:
    rows = _rcb_rows()
    cells = rows[line_index].split(",")
    cells[field] = value
    rows[line_index] = ",".join(cells)
    return "\n".join([RCB_HEADER, *rows])


# (name, file content (str or bytes), text the one-line error must contain)
MALFORMED: list[tuple[str, str | bytes, str]] = [
    ("empty", "", "file is empty"),
    ("blank lines only", "\n\n  \n", "file is empty"),
    ("header only", RCB_HEADER + "\n", "header only"),
    ("missing voltage column", GOOD.replace("Voltage (V)", "Volts"), "no 'Voltage (V)' column"),
    (
        "unknown thrust unit",
        GOOD.replace("Thrust (N)", "Thrust (stone)"),
        "unknown thrust unit 'stone'",
    ),
    ("text in numbers", _rows_with(4, 9, "abc"), ":6: column 'Thrust (N)': 'abc' is not a number"),
    ("empty required cell", _rows_with(2, 10, ""), ":4: column 'Voltage (V)': empty cell"),
    (
        "nan value",
        _rows_with(7, 1, "nan"),
        ":9: column 'ESC signal (µs)': 'nan' is not a finite number",
    ),
    (
        "infinite value",
        _rows_with(7, 10, "inf"),
        ":9: column 'Voltage (V)': 'inf' is not a finite number",
    ),
    ("binary garbage", bytes(range(256)) * 4, "binary data (NUL byte"),
    ("wrong delimiter", GOOD.replace(",", "|"), "single column"),
    ("duplicated headers", GOOD.replace("Current (A)", "Thrust (N)"), "duplicated header"),
    ("unknown format", "a,b,c\n1,2,3\n", "unrecognised stand log header"),
    (
        "short row",
        "\n".join([RCB_HEADER, *_rcb_rows()[:5], "0.6,1100", *_rcb_rows()[5:]]),
        ":7: row has 2 fields",
    ),
    ("json instead of csv", '{"format": "x"}\n', "a JSON file"),  # named as one (issue 44 item 10)
]


@pytest.mark.parametrize(("name", "content", "expected"), MALFORMED, ids=[m[0] for m in MALFORMED])
def test_malformed_input_one_line_error(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    name: str,
    content: str | bytes,
    expected: str,
) -> None:
    p = tmp_path / "bad.csv"
    p.write_bytes(content if isinstance(content, bytes) else content.encode("utf-8"))
    with pytest.raises(SystemExit) as exc:
        main(["fit", str(p), "-o", str(tmp_path / "m.json")])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert err.startswith("error: ") and str(p) in err, err
    assert expected in err, err
    assert "Traceback" not in err


FIT_ERRORS = [
    (
        "single voltage level",
        lambda k: f"{k},{1100 + 20 * k},,,,0,0,0,0,{-(0.3 + 0.2 * k)},22.0,1,0,0,0,,",
        "one battery voltage",
    ),
    ("fewer points than coefficients", None, "cannot determine"),
    (
        "one thrust level",
        lambda k: f"{k},1300,,,,0,0,0,0,-2.0,{22 + 0.1 * k},1,0,0,0,,",
        "one thrust level",
    ),
]


@pytest.mark.parametrize(("name", "row", "expected"), FIT_ERRORS, ids=[f[0] for f in FIT_ERRORS])
def test_unfittable_data_one_line_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], name: str, row: object, expected: str
) -> None:
    p = tmp_path / "few.csv"
    if row is None:
        text = "\n".join([RCB_HEADER, *_rcb_rows(40)])
        args = [
            "fit",
            str(p),
            "-o",
            str(tmp_path / "m.json"),
            "--model",
            "poly4",
        ]  # 15 coefs, 4 plateaus
    else:
        text = "\n".join([RCB_HEADER, *[row(k) for k in range(30)]])  # type: ignore[operator]
        args = ["fit", str(p), "-o", str(tmp_path / "m.json"), "--all-samples"]
        if name == "single voltage level":  # the default `motor` takes 1/B from physics there
            args += ["--model", "poly2"]
    p.write_text(text)
    with pytest.raises(SystemExit) as exc:
        main(args)
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and expected in err and str(p) in err, err


def test_missing_file_and_directory(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    for target, expected in ((tmp_path / "nope.csv", "cannot read"), (tmp_path, "is a directory")):
        with pytest.raises(DataFormatError, match=expected):
            load_dataset(target)


def test_bad_range_option(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    p = write(tmp_path / "rcb.csv", GOOD)
    with pytest.raises(SystemExit) as exc:
        main(["fit", str(p), "-o", str(tmp_path / "m.json"), "--throttle-range", "1500:1300"])
    assert exc.value.code == 2
    assert "--throttle-range: expected LO < HI" in capsys.readouterr().err


def test_real_stand_files_load(shared_data: Path) -> None:
    root = shared_data / "xnova-thrust-stand"
    sr = load_dataset(root / "single_rotor" / "xNova-TM-SR.csv")
    assert sr.format == "rcbenchmark-resaved" and len(sr) == 11826
    assert sr.meta.get("thrust_sign_flipped") is True
    assert float(np.max(sr.thrust_n)) > 8.0  # pulling is positive after normalisation
    steps = load_dataset(root / "single_rotor" / "xNova-SR-steps.csv")
    assert steps.format == "rcbenchmark" and steps.time_s is not None
    assert 21.0 < float(np.median(steps.voltage_v)) < 23.0


# -- sparse continuous logs, Crazyflie time base, rpm/current kept -----------------------------


def _sparse_rcb(path: Path, gap_s: float = 0.0) -> Path:
    """An RCbenchmark continuous log where each sensor is written when it updates: the ESC
    command on change, the voltage every 4th row, thrust on most rows, rpm every other row."""
    header = (
        "Time (s),ESC signal (µs),Servo 1 (µs),Thrust (N),Voltage (V),Current (A),"
        "Motor Electrical Speed (RPM),App message,"
    )
    rows = []
    t = 0.0
    for k in range(80):
        us = 1200 + 100 * (k // 20)
        cmd = str(us) if k % 20 == 0 else ""
        volt = f"{16.0 - 0.01 * k:.2f}" if k % 4 == 0 else ""
        thrust = f"{-(us - 1000) / 100:.2f}" if k % 5 != 4 else ""
        rpm = str(10 * (us - 1000)) if k % 2 == 0 else ""
        cur = f"{(us - 1000) / 50:.1f}" if k % 3 == 0 else ""
        rows.append(f"{t:.3f},{cmd},,{thrust},{volt},{cur},{rpm},,")
        t += 0.1 if k != 40 else gap_s + 0.1
    path.write_text("\ufeff" + "\n".join([header, *rows]) + "\n", encoding="utf-8")
    return path


def test_sparse_rcbenchmark_continuous_log_loads_with_bounded_carry(tmp_path: Path) -> None:
    ds = load_dataset(_sparse_rcb(tmp_path / "sparse.csv"))
    assert ds.format == "rcbenchmark"
    # commands are written once per 20 rows (2 s): carried at most 0.5 s, so only the rows
    # within 0.5 s of a command row with a thrust reading are kept
    assert set(ds.throttle_native.tolist()) == {1200, 1300, 1400, 1500}
    assert len(ds) == 4 * 5  # rows k % 20 in 0..5 minus the one without thrust (k % 5 == 4)
    assert ds.thrust_n.tolist()[:5] == pytest.approx([2.0, 2.0, 2.0, 2.0, 2.0])
    assert ds.voltage_v[1] == pytest.approx(16.0)  # carried from row 0 (0.1 s old)
    assert ds.rpm is not None and ds.rpm[1] == pytest.approx(2000)  # carried, not dropped
    assert ds.current_a is not None and np.isfinite(ds.current_a).all()
    note = ds.meta["sparse"]
    assert "throttle carried forward" in note and "at most 0.5s old" in note
    assert "44 thrust rows dropped" in note


def test_sparse_log_never_carries_across_a_long_gap(tmp_path: Path) -> None:
    ds = load_dataset(_sparse_rcb(tmp_path / "gap.csv", gap_s=5.0))
    # the 1400 µs command is written on row 40, then the log pauses 5 s: the rows after the
    # pause have no command that recent and are dropped (and the drop is said)
    assert ds.throttle_native.tolist().count(1400) == 1
    assert ds.throttle_native.tolist().count(1300) == 5
    assert "48 thrust rows dropped" in ds.meta["sparse"]  # 44 without the pause


def test_dense_log_with_one_hole_is_still_an_error(tmp_path: Path) -> None:
    p = write(
        tmp_path / "hole.csv", "\n".join([RCB_HEADER, *_rcb_rows()]).replace(",24.000,", ",,")
    )
    with pytest.raises(DataFormatError, match=":2: column 'Voltage \\(V\\)': empty cell"):
        load_dataset(p)


def test_flight_stand_keeps_rpm_and_current(tmp_path: Path) -> None:
    header = (
        "Time (s),Powertrain 1 - ESC throttle (μs),Powertrain 1 - force Fz (thrust) (kgf),"
        "Powertrain 1 - voltage (V),Powertrain 1 - current (A),Powertrain 1 - rotation speed (rpm)"
    )
    rows = [
        f"{0.1 * k:.1f},1500,{-0.5 - 0.001 * k},22.0,{8 + 0.1 * k},{12000 + k}" for k in range(8)
    ]
    ds = load_dataset(write(tmp_path / "fs.csv", "\n".join([header, *rows])))
    assert ds.rpm is not None and ds.rpm.tolist() == [12000 + k for k in range(8)]
    assert ds.current_a is not None and ds.current_a[2] == pytest.approx(8.2)
    assert ds.thrust_n[0] == pytest.approx(0.5 * 9.80665)
    assert "sparse" not in ds.meta


def test_crazyflie_time_base_rpm_and_current(tmp_path: Path) -> None:
    header = "weight[g],pwm,vbat[V],rpm1,rpm2,rpm3,rpm4,v[V],i[A],p[W]"
    rows = [
        f"{4 * k},{6000 * k},4.{k},{1000 * k},{1000 * k + 4},{1000 * k},{1000 * k},4,{0.4 * k},1"
        for k in range(1, 8)
    ]
    ds = load_dataset(write(tmp_path / "cf.csv", "\n".join([header, *rows])))
    assert ds.time_s is not None and ds.time_s.tolist() == pytest.approx(
        [0.01 * k for k in range(7)]
    )
    assert ds.rpm is not None and ds.rpm[1] == pytest.approx(2001.0)
    assert ds.current_a is not None and ds.current_a[1] == pytest.approx(0.2)  # 0.8 A / 4 rotors
    assert "10 ms" in ds.meta["time_note"]


def test_column_map_keeps_rpm_and_current(tmp_path: Path) -> None:
    p = write(
        tmp_path / "diy.csv",
        "t,cmd,load_g,vbus,amps,erpm\n"
        + "\n".join(f"{k},{1100 + 100 * k},{100 * k},12.{k},{k},{900 * k}" for k in range(5)),
    )
    cm = ColumnMap(
        throttle="cmd", thrust="load_g", voltage="vbus", current="amps", rpm="erpm", thrust_unit="g"
    )
    ds = load_dataset(p, cm)
    assert ds.rpm is not None and ds.rpm[3] == 2700
    assert ds.current_a is not None and ds.current_a[4] == 4


def test_ds_log_keeps_rpm_and_current(tmp_path: Path) -> None:
    w = DsWriter(tmp_path / "run.csv", SCALES["pwm"], {})
    for k in range(5):
        w.write(
            0.1 * k, 1300, {"thrust_n": 1.0, "voltage_v": 16.0, "rpm": 9000 + k, "current_a": 3}
        )
    w.finish("completed")
    ds = load_dataset(tmp_path / "run.csv")
    assert ds.rpm is not None and ds.rpm.tolist() == [9000, 9001, 9002, 9003, 9004]
    assert ds.current_a is not None and ds.current_a.tolist() == [3.0] * 5


def test_real_files_keep_rpm_and_current(shared_data: Path) -> None:
    for f in (
        shared_data / "xnova-thrust-stand" / "single_rotor" / "xNova-SR-steps.csv",
        shared_data / "third-party-stands" / "strawson-5inch" / "c3_11.csv",
    ):
        ds = load_dataset(f)
        assert ds.rpm is not None and float(np.nanmax(ds.rpm)) > 1000, f
        assert ds.current_a is not None and float(np.nanmax(ds.current_a)) > 1.0, f


def test_dense_log_time_column_stays_strict(tmp_path: Path) -> None:
    rows = _rcb_rows()
    rows[6] = "," + rows[6].split(",", 1)[1]  # no time on one row of a dense log
    with pytest.raises(DataFormatError, match=":8: column 'Time \\(s\\)': empty cell"):
        load_dataset(write(tmp_path / "t.csv", "\n".join([RCB_HEADER, *rows])))


def test_flight_stand_with_two_powertrains_loads_the_first_and_says_so(tmp_path: Path) -> None:
    header = (
        "Time (s),Top - ESC throttle (μs),Top - force Fz (thrust) (N),Top - voltage (V),"
        "Bottom - ESC throttle (μs),Bottom - force Fz (thrust) (N),Bottom - voltage (V)"
    )
    rows = [f"{0.1 * k:.1f},1500,-3.{k},22.0,1600,-4.{k},22.0" for k in range(6)]
    ds = load_dataset(write(tmp_path / "coax.csv", "\n".join([header, *rows])))
    assert ds.meta["powertrain"] == "top" and ds.thrust_n[2] == pytest.approx(3.2)
    assert "ignored 'Bottom - ESC throttle (μs)'" in ds.meta["powertrain_note"]


def _sparse_rcb_at(path: Path, times: list[float]) -> Path:
    """A continuous Tyto log: the command and voltage on every row, thrust on every third."""
    rows = [RCB_HEADER]
    for k, t in enumerate(times):
        us = 1100 + 100 * (k // 30)
        thrust = f"{-(0.5 + 1.5 * (k // 30))}" if k % 3 == 0 else ""
        rows.append(f"{t:.3f},{us},,,,0,0,-1,,{thrust},{24.0 - 0.001 * k:.3f},1,,,,,")
    path.write_text("\n".join(rows) + "\n", encoding="utf-8")
    return path


def test_a_sparse_log_with_a_row_a_few_ms_out_of_order_loads(tmp_path: Path) -> None:
    """alspitz/esc_test's Tyto log: 4 of 15 875 rows logged up to 10 ms out of order (was
    refused: "time goes backwards"); a sparse log out of order everywhere still is."""
    times = [0.01 * k for k in range(120)]
    times[61], times[62] = times[62], times[61] - 0.008  # one row 18 ms behind its neighbour
    ds = load_dataset(_sparse_rcb_at(tmp_path / "jitter.csv", times))
    assert len(ds) == 40  # the thrust rows
    assert ds.thrust_n[-1] == pytest.approx(0.5 + 1.5 * 3)
    shuffled = list(np.random.default_rng(3).permutation(times))
    with pytest.raises(DataFormatError, match="time goes backwards"):
        load_dataset(_sparse_rcb_at(tmp_path / "shuffled.csv", shuffled))
