"""Ds loaders: every supported format decodes to the right values; bad input gets one clear line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from thrustmap.cli import main
from thrustmap.errors import DataFormatError
from thrustmap.fitting.dsformat import DsWriter
from thrustmap.fitting.loaders import ColumnMap, load_dataset
from thrustmap.units import SCALES

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
    ("short row", "\n".join([RCB_HEADER, *_rcb_rows()[:5], "0.6,1100"]), ":7: row has 2 fields"),
    ("json instead of csv", '{"format": "x"}\n', "single column"),
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
