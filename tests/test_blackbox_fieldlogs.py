"""Blackbox logs from everyone (issue 34): a flash dump with unusable logs, an accelerometer that
reads zero, INAV's own motor range and battery fields."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from support.blackbox_encode import (
    INAV_HOVER_MOTOR,
    sim_frame_values,
    simulate_hover_file,
    simulate_hover_log,
)
from support.public_data import PublicFiles, names

from thrustmap.cli import main
from thrustmap.fitting.df.extraction import extract
from thrustmap.fitting.df_options import DfOptions
from thrustmap.flightlogs.blackbox import read


def _extract(
    log: Path, out: Path, capsys: pytest.CaptureFixture[str], *extra: str
) -> tuple[int, str, str]:
    try:
        main(["flightlog", "extract", str(log), "--mass-kg", "1", "-o", str(out), *extra])
        code = 0
    except SystemExit as exc:
        code = int(exc.code or 0)
    cap = capsys.readouterr()
    return code, cap.out, cap.err


# a flash dump: a good hover, a downward accelerometer, one reading zero, a 1 s log, an empty
# log, and a second good hover
DUMP = ((12.0, 1.0), (12.0, -1.0), (12.0, 0.0), (1.0, 1.0), (0.0, 1.0), (12.0, 1.0))


def test_a_flash_dump_extracts_every_log_it_can_and_names_each_it_cannot(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = tmp_path / "dump.bbl"
    log.write_bytes(simulate_hover_file([d for d, _ in DUMP], [a for _, a in DUMP]))
    out = tmp_path / "df.csv"
    code, stdout, err = _extract(log, out, capsys)
    assert code == 0, err
    warned = [ln for ln in err.splitlines() if ln.startswith("warning: ") and "skipped" in ln]
    # one line per refused log (as the viewer numbers them: 1-based), naming file and why
    assert len(warned) == 4, err
    by_log = {int(re.search(r"log (\d+) of 6", ln).group(1)): ln for ln in warned}  # type: ignore[union-attr]
    assert sorted(by_log) == [2, 3, 4, 5]
    assert all(str(log) in ln for ln in warned)
    assert "mean upward specific force -9.8" in by_log[2]
    assert "no accelerometer data in this log (all zero: accelerometer disabled?)" in by_log[3]
    assert "too short: 1.0 s of data" in by_log[4]
    assert "empty (no data frames)" in by_log[5]
    assert "used 2 log(s), refused 4" in stdout
    side = json.loads(out.with_suffix(".json").read_text())
    assert [r["log"] for r in side["refused"]] == [2, 3, 4, 5]
    assert [r["flight"] for r in side["reports"]] == ["dump.bbl#0", "dump.bbl#5"]
    assert all(r["samples"] > 0 for r in side["reports"])
    # the samples are the two good logs' own: the same as each extracted alone
    rows = out.read_text().splitlines()[1:]
    assert {r.split(",")[0] for r in rows} == {"dump.bbl#0", "dump.bbl#5"}
    # --json lists the flights used and the logs refused
    code, stdout, _ = _extract(log, tmp_path / "df2.csv", capsys, "--json")
    items = json.loads(stdout)
    assert [i["status"] for i in items] == ["used", "used"] + ["refused"] * 4
    # inspect names the log the reader could not read, once
    try:
        main(["flightlog", "inspect", str(log)])
    except SystemExit as exc:
        assert not exc.code
    stdout = capsys.readouterr().out
    assert stdout.count("not read: ") == 1
    assert f"not read: {log}: log 5 of 6 skipped: empty (no data frames)" in stdout


def test_a_flash_dump_with_no_usable_log_exits_2_with_one_line_per_log(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = tmp_path / "bad.bbl"
    log.write_bytes(simulate_hover_file([12.0, 12.0, 0.0], [-1.0, 0.0]))
    out = tmp_path / "df.csv"
    code, _, err = _extract(log, out, capsys)
    assert code == 2
    refused = [ln for ln in err.splitlines() if ln.startswith("refused: ")]
    assert len(refused) == 3 and all(str(log) in ln for ln in refused)
    assert "log 1 of 3" in refused[0] and "log 2 of 3" in refused[1]
    assert err.splitlines()[-1].startswith("error: ") and "none of its 3 log(s)" in err
    assert not out.exists()


def test_a_single_log_file_keeps_its_one_line_refusal(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = tmp_path / "one.bbl"
    log.write_bytes(simulate_hover_log(12.0, acc_scale=-1.0))
    code, _, err = _extract(log, tmp_path / "df.csv", capsys)
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {log}")
    assert "mean upward specific force -9.8" in lines[0] and "downward axis" in lines[0]


def test_an_accelerometer_reading_zero_is_named_with_the_header_that_says_so(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = tmp_path / "noacc.bfl"
    headers = [("acc_hardware", "1"), ("acc_1G", "0")]  # Betaflight: ACC_NONE
    log.write_bytes(simulate_hover_log(12.0, acc_scale=0.0, headers=headers))
    (flight,) = read(log)
    assert flight.accel_up_mps2 is None  # not a specific force of 0
    code, _, err = _extract(log, tmp_path / "df.csv", capsys)
    assert code == 2
    assert (
        "no accelerometer data in this log (all zero: accelerometer disabled? header "
        "acc_hardware:1 is NONE, acc_1G:0)" in err
    )
    assert "mean upward specific force" not in err and "acc_1G" in err


def test_inav_motor_outputs_are_mincommand_to_maxthrottle_and_vbat_is_centivolts(
    tmp_path: Path,
) -> None:
    """INAV logs motor[] as its mixer computes them (1000..2000 µs-equivalent) even with DShot,
    and names the battery fields vbat/amperage (0.01 V, 0.01 A)."""
    log = tmp_path / "inav.TXT"
    log.write_bytes(simulate_hover_log(12.0, inav=True))
    (fl,) = read(log)
    sc = fl.motor_output_scale
    assert sc is not None and (sc.lo, sc.hi, sc.unit) == (1000.0, 2000.0, "us")
    assert fl.metadata["motor_idle"] == 1100.0
    pct = sc.to_pct(fl.motor_outputs.values)  # type: ignore[union-attr]
    expected = (INAV_HOVER_MOTOR + np.arange(4) * 7 - 1000.0) / 10.0  # ≈ 50 %, not DShot's 73 %
    assert np.allclose(np.median(pct, axis=0), expected, atol=0.5)
    assert fl.voltage_v is not None
    # 3000 frames at 250 Hz: the first and the last one's vbat
    raw = [sim_frame_values(k, 4096, 5_000_000, 12.0)[6] for k in (0, 2999)]
    assert fl.voltage_v.values[0] == pytest.approx(raw[0] * 0.01)
    assert fl.voltage_v.values[-1] == pytest.approx(raw[1] * 0.01)
    assert "getBatteryRawVoltage" in fl.metadata["vbat_scale_reason"]
    assert fl.extras["current_a"].values[0] == pytest.approx(12.34)
    df = extract([fl], DfOptions(mass_kg=1.0))
    assert len(df) > 0
    v = np.asarray(df.column("voltage_v"), float)
    assert np.all((v > 15.9) & (v < 16.5))


@pytest.mark.parametrize("name", names(source="xerox-inav"))
def test_real_inav_logs_read_with_inav_semantics(public_data: PublicFiles, name: str) -> None:
    """Real INAV 8.0.1 logs of benchmarks/public-data.toml, by name (sha256 checked)."""
    path = public_data(name)
    flights = read(path)
    assert flights
    for fl in flights:
        sc = fl.motor_output_scale
        assert sc is not None and sc.unit == "us" and sc.lo == 1000.0
        assert fl.voltage_v is not None and fl.voltage_v.origin.startswith("vbat (raw) × 0.01")
        v = float(np.median(fl.voltage_v.values))
        assert 3.0 <= v <= 4.45 * 6  # a pack, not centivolts read as volts
        raw = np.asarray(fl.motor_outputs.values, float)  # type: ignore[union-attr]
        # CHANGELOG (issue 34): a hover at 13-16 % that Betaflight's DShot 48..2047 read as 54 %
        hover_pct = float(np.median(np.median(sc.to_pct(raw), axis=1)))
        assert 12.5 <= hover_pct <= 16.5, hover_pct
        as_dshot_pct = (float(np.median(np.median(raw, axis=1))) - 48) / (2047 - 48) * 100
        assert 54.0 <= as_dshot_pct <= 56.0, as_dshot_pct
    assert len(extract(flights, DfOptions(mass_kg=1.0))) > 0


def test_the_public_44_log_flash_dump_gives_2_logs_and_56_samples(
    public_data: PublicFiles, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """CHANGELOG (issue 34): fc-blackbox's btfl_all.bbl, a flash dump of 44 Betaflight 4.2.8
    logs, was exit 2; now 2 logs used, 56 samples, the 42 others named as refused."""
    log = public_data("fcbb/btfl_all")
    out = tmp_path / "df.csv"
    code, stdout, _ = _extract(log, out, capsys)
    assert code == 0
    assert "used 2 log(s), refused 42" in stdout
    side = json.loads(out.with_suffix(".json").read_text())
    assert len(side["refused"]) == 42
    assert [(r["flight"], r["samples"]) for r in side["reports"]] == [
        ("btfl_all.bbl#3", 56),
        ("btfl_all.bbl#11", 0),
    ]
    assert len(out.read_text().splitlines()) == 1 + 56


def test_fleet_extract_keeps_a_flash_dump_with_some_usable_logs(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`fleet extract` (one row per file) applies the same per-log rule: the file's row is not
    refused when logs were usable; its warnings name each log skipped."""
    from thrustmap.fleet.table import read_table

    src = tmp_path / "logs"
    src.mkdir()
    (src / "dump.bbl").write_bytes(simulate_hover_file([12.0, 12.0, 12.0], [1.0, -1.0, 0.0]))
    out = tmp_path / "fleet"
    try:
        main(["fleet", "extract", str(src), "-o", str(out), "--mass-kg", "1", "--workers", "0",
              "--quiet"])  # fmt: skip
        code = 0
    except SystemExit as exc:
        code = int(exc.code or 0)
    capsys.readouterr()
    assert code == 0
    (row,) = read_table(out / "fleet.parquet")
    assert row.status == "ok" and row.samples > 0, row.reason
    skipped = [w for w in row.warnings if "skipped" in w]
    assert len(skipped) == 2
    assert "log 2 of 3" in skipped[0] and "mean upward specific force" in skipped[0]
    assert "log 3 of 3" in skipped[1] and "no accelerometer data" in skipped[1]
