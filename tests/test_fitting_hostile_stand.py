"""Hostile stand and Ds files (issue 14, items 5 and 8): a torn last row, numbers in the wrong
unit, sidecars that contradict their log. Each is either converted with a warning saying what
was assumed, or refused with one line naming the file, line or field."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pytest

from thrustmap.cli import main
from thrustmap.core.stand_recording import DsWriter
from thrustmap.core.units import SCALES
from thrustmap.fitting.loaders.load import load_dataset

RCB_HEADER = (
    "Time (s),ESC signal (µs),Servo 1 (µs),Thrust (N),Voltage (V),Current (A),"
    "Motor Electrical Speed (RPM),App message,"
)


def rcb_rows(n: int = 30, volt_scale: float = 1.0) -> list[str]:
    rows = []
    for k in range(n):
        us = 1100 + 100 * (k // 10)
        thrust = -(0.5 + 1.5 * (k // 10)) - 0.0123456789 * (k % 3)
        volt = (16.012345678 - 0.01 * k) * volt_scale
        cur = 2.0123456 + 3 * (k // 10)
        rows.append(f"{0.1 * k:.4f},{us},,{thrust:.9f},{volt:.9f},{cur:.7f},{5000 + 100 * k},,")
    return rows


def write(path: Path, lines: list[str], *, end: str = "\n") -> Path:
    path.write_bytes(("\ufeff" + "\n".join(lines) + end).encode("utf-8"))
    return path


def one_line_error(
    path: Path, capsys: pytest.CaptureFixture[str], named: Path | None = None
) -> str:
    with pytest.raises(SystemExit) as exc:
        main(["inspect", str(path)])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(named or path) in err, err
    return err


# -- item 5: a full disk tears the last row ---------------------------------------------------


def test_torn_final_row_with_missing_fields_is_dropped_with_a_warning(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    rows = rcb_rows()
    torn = rows[-1][:25]  # the write stopped in the middle of the row
    p = write(tmp_path / "torn.csv", [RCB_HEADER, *rows[:-1], torn], end="")
    with caplog.at_level(logging.WARNING):
        ds = load_dataset(p)
    assert len(ds) == 29 and ds.line[-1] == 30
    assert "no line end and is cut short: dropped" in caplog.text
    assert "dropped" in ds.meta["read_notes"][0]


def test_torn_row_that_still_parses_is_not_loaded_truncated(tmp_path: Path) -> None:
    header = "t,cmd,load_g,vbus"
    rows = [f"{k},{1100 + 100 * k},{100.25 + k},12.{k}5" for k in range(6)]
    rows[-1] = rows[-1][:-2]  # '12.55' torn to '12.' — all four fields, still a number
    from thrustmap.fitting.loaders.load import ColumnMap

    cm = ColumnMap(throttle="cmd", thrust="load_g", voltage="vbus", thrust_unit="g")
    ds = load_dataset(write(tmp_path / "t.csv", [header, *rows], end=""), cm)
    assert len(ds) == 5 and ds.voltage_v[-1] == pytest.approx(12.45)
    # the same row WITH its line end is complete and kept
    rows[-1] = "5,1600,105.25,12.5"
    assert len(load_dataset(write(tmp_path / "u.csv", [header, *rows]), cm)) == 6


def test_torn_final_ds_row_is_dropped(tmp_path: Path) -> None:
    w = DsWriter(tmp_path / "run.csv", SCALES["pwm"], {})
    for k in range(6):
        w.write(0.1 * k, 1300, {"thrust_n": 1.234567, "voltage_v": 16.12345, "step": 0})
    w.finish("aborted", "the disk is full")
    with open(tmp_path / "run.csv", "a", encoding="utf-8") as f:
        f.write("0.600000,1300,1.234567,16")  # all the leading fields, torn in the voltage
    ds = load_dataset(tmp_path / "run.csv")
    assert len(ds) == 6 and float(ds.voltage_v.min()) == pytest.approx(16.12345)


# -- item 8: silent wrong meaning ---------------------------------------------------------------


def test_voltage_in_millivolts_is_converted_and_said(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    p = write(tmp_path / "mv.csv", [RCB_HEADER, *rcb_rows(volt_scale=1000.0)])
    with caplog.at_level(logging.WARNING):
        ds = load_dataset(p)
    assert float(np.max(ds.voltage_v)) == pytest.approx(16.012345678)
    assert "taken as mV" in ds.meta["voltage_note"] and "taken as mV" in caplog.text


@pytest.mark.parametrize("volts", [0.4, 180.0, 90000.0])
def test_voltage_no_battery_gives_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], volts: float
) -> None:
    p = write(tmp_path / "v.csv", [RCB_HEADER, *rcb_rows(volt_scale=volts / 16.0)])
    err = one_line_error(p, capsys)
    assert "is not a battery voltage; expected 2.5..63 V" in err and ":2:" in err


def test_excel_thousands_separator_in_a_decimal_comma_file(tmp_path: Path) -> None:
    header = "ESC signal (µs);Thrust (N);Voltage (V);Current (A)"
    rows = [f"1.{100 + 100 * (k // 5):03d};-{1 + k // 5},{k % 5}5;22,{k};3,5" for k in range(20)]
    ds = load_dataset(write(tmp_path / "de.csv", [header, *rows]))
    assert ds.throttle_native.tolist()[::5] == [1100, 1200, 1300, 1400]
    assert ds.voltage_v[3] == pytest.approx(22.3)
    assert "thousands separator" in ds.meta["read_notes"][0]


def test_excel_thousands_separator_in_a_decimal_point_file(tmp_path: Path) -> None:
    header = "Time (s),ESC signal (µs),Thrust (N),Voltage (V)"
    rows = [f"{k},{'1.500' if k % 2 else '1.600'},-{2 + k % 2}.5,16.{k}" for k in range(10)]
    ds = load_dataset(write(tmp_path / "x.csv", [header, *rows]))
    assert set(ds.throttle_native.tolist()) == {1500.0, 1600.0}
    assert "'1.600' read as 1600 µs" in ds.meta["read_notes"][0]


def test_pulse_that_is_no_pulse_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rows = rcb_rows()
    rows[4] = rows[4].replace(",1100,", ",15,")
    err = one_line_error(write(tmp_path / "p.csv", [RCB_HEADER, *rows]), capsys)
    assert ":6: column 'ESC signal (µs)': '15' is not an ESC pulse" in err


def test_thrust_in_the_wrong_unit_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # grams written under a newton header: 100x the thrust a watt can make
    rows = [
        ",".join(c if i != 3 else str(float(c) * 100) for i, c in enumerate(r.split(",")))
        for r in rcb_rows()
    ]
    err = one_line_error(write(tmp_path / "g.csv", [RCB_HEADER, *rows]), capsys)
    assert "gf/W" in err and "thrust (or current) unit" in err


def test_infinite_voltage_in_a_sparse_log_is_refused_not_dropped(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    header = (
        "Time (s),Powertrain 1 - ESC throttle (μs),Powertrain 1 - force Fz (thrust) (N),"
        "Powertrain 1 - voltage (V)"
    )
    rows = ["0.00,1500,,22.0", "0.01,,3.0,", "0.02,,3.1,inf", "0.03,1600,,", "0.04,,4.2,"]
    err = one_line_error(write(tmp_path / "fs.csv", [header, *rows]), capsys)
    assert ":4: column 'Powertrain 1 - voltage (V)': 'inf' is not a finite number" in err


def _ds(tmp_path: Path, rows: int = 39) -> Path:
    w = DsWriter(tmp_path / "run.csv", SCALES["pwm"], {"rotors_on_esc": 1})
    for k in range(rows):
        w.write(0.02 * k, 1300 + 100 * (k // 13), {"thrust_n": 1.0 + k // 13, "voltage_v": 16.0})
    w.finish("completed")
    return tmp_path / "run.csv"


def _edit_sidecar(csv: Path, **changes: object) -> None:
    side = csv.with_name(csv.stem + ".meta.json")
    side.write_text(json.dumps({**json.loads(side.read_text()), **changes}))


def test_sidecar_scale_contradicting_the_column_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    p = _ds(tmp_path)
    _edit_sidecar(p, throttle_scale={"name": "dshot", "lo": 48, "hi": 2047, "unit": "dshot"})
    err = one_line_error(p, capsys)
    assert "gives throttle scale 'dshot' in dshot, but the log's column is 'throttle_us'" in err


def test_sidecar_range_far_from_the_values_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    p = _ds(tmp_path)
    _edit_sidecar(p, throttle_scale={"name": "oneshot125", "lo": 125, "hi": 250, "unit": "us"})
    err = one_line_error(p, capsys)
    assert "far outside the scale 'oneshot125'" in err and ":2:" in err


def test_sidecar_promising_more_samples_than_the_log_has(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, capsys: pytest.CaptureFixture[str]
) -> None:
    p = _ds(tmp_path)
    _edit_sidecar(p, samples=5000)
    with caplog.at_level(logging.WARNING):
        ds = load_dataset(p)
    assert len(ds) == 39 and "recorded 5000 samples but the log has 39 rows" in ds.meta["partial"]
    assert "cut short" in caplog.text
    _edit_sidecar(p, samples=12)  # fewer than the rows: it is another log's sidecar
    assert "recorded 12 samples" in one_line_error(p, capsys)


def test_sidecar_rotors_on_esc_must_be_a_number(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    p = _ds(tmp_path)
    _edit_sidecar(p, rotors_on_esc="four")
    err = one_line_error(p, capsys, named=p.with_name("run.meta.json"))
    assert "run.meta.json: field 'rotors_on_esc': expected an integer" in err


def test_real_files_pass_the_physics_checks(shared_data: Path) -> None:
    for f in sorted((shared_data / "xnova-thrust-stand").glob("*/*.csv")):
        ds = load_dataset(f)
        assert "voltage_note" not in ds.meta and "read_notes" not in ds.meta, f
    for f in sorted((shared_data / "third-party-stands" / "strawson-5inch").glob("*.csv")):
        ds = load_dataset(f)
        assert 6.5 < float(np.median(ds.voltage_v)) < 12.6, f
