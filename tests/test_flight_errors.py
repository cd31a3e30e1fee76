"""Truncated, empty and corrupted flight logs: clear errors, or a reported tail and the good part."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from thrustmap.core.errors import ConfigError, DataFormatError
from thrustmap.flightlogs import dataflash
from thrustmap.flightlogs.detect import detect, read_log

FL = Path(__file__).resolve().parent.parent / "fixtures" / "flightlogs"
BINARY = ["sim_hover.bin", "sim_hover.ulg", "sim_hover.tlog"]


@pytest.mark.parametrize("name", [*BINARY, "sim_hover_paper.csv"])
def test_empty_file(tmp_path: Path, name: str) -> None:
    p = tmp_path / name
    p.write_bytes(b"")
    with pytest.raises(DataFormatError, match="empty"):
        read_log(p)


def test_missing_and_unknown(tmp_path: Path) -> None:
    with pytest.raises(DataFormatError, match="not found"):
        read_log(tmp_path / "nope.bin")
    p = tmp_path / "x.dat"
    p.write_bytes(b"hello, this is not a flight log\n")
    with pytest.raises(DataFormatError, match="unrecognised flight-log format"):
        read_log(p)
    with pytest.raises(ConfigError, match="unknown flight-log format"):
        read_log(FL / "sim_hover.bin", format="nosuch")


@pytest.mark.parametrize("name", BINARY)
def test_truncated_tail_is_reported_and_the_good_part_used(tmp_path: Path, name: str) -> None:
    raw = (FL / name).read_bytes()
    p = tmp_path / name
    p.write_bytes(raw[: len(raw) // 2 + 7])
    (full,) = read_log(FL / name)
    (half,) = read_log(p)
    assert half.voltage_v is not None and full.voltage_v is not None
    n = len(half.voltage_v)
    assert 0.3 * len(full.voltage_v) < n < 0.7 * len(full.voltage_v)
    assert np.array_equal(half.voltage_v.values, full.voltage_v.values[:n])
    if name != "sim_hover.tlog":  # a tlog frame cut short is indistinguishable from EOF
        assert any("truncated" in w for w in half.warnings), half.warnings


@pytest.mark.parametrize("name", BINARY)
def test_garbage_tail_is_reported(tmp_path: Path, name: str) -> None:
    raw = (FL / name).read_bytes()
    p = tmp_path / name
    p.write_bytes(raw + bytes(range(256)) * 3)
    (fl,) = read_log(p)
    assert fl.warnings, "a corrupt tail must be reported"
    (full,) = read_log(FL / name)
    assert fl.voltage_v is not None and full.voltage_v is not None
    assert np.array_equal(fl.voltage_v.values, full.voltage_v.values)


def test_dataflash_corrupt_middle_resyncs(tmp_path: Path) -> None:
    raw = (FL / "sim_hover.bin").read_bytes()
    mid = len(raw) // 2
    p = tmp_path / "mid.bin"
    p.write_bytes(raw[:mid] + b"\xff" * 100 + raw[mid + 100 :])
    log = dataflash.parse(p)
    assert any(w.startswith("skipped") for w in log.warnings)
    full = dataflash.parse(FL / "sim_hover.bin")
    lost = full.counts()["IMU"] - log.counts()["IMU"]
    assert 0 < lost <= 3  # only the messages the 100 bytes overwrote


def test_dataflash_without_fmt_header(tmp_path: Path) -> None:
    p = tmp_path / "x.bin"
    p.write_bytes(b"\xa3\x95\x81" + bytes(200))
    assert not dataflash.sniff(p, p.read_bytes())
    with pytest.raises(DataFormatError, match="FMT"):
        dataflash.parse(p)


def test_truncated_header_gives_clear_error(tmp_path: Path) -> None:
    for name in ("sim_hover.bin", "sim_hover.ulg"):
        p = tmp_path / name
        p.write_bytes((FL / name).read_bytes()[:20])
        with pytest.raises(DataFormatError) as exc:
            read_log(p)
        assert str(p) in str(exc.value)


def test_csv_errors_name_the_line(tmp_path: Path) -> None:
    lines = (FL / "sim_hover_paper.csv").read_text().splitlines()
    bad = list(lines)
    bad[10] = bad[10] + ",1,2"
    p = tmp_path / "bad.csv"
    p.write_text("\n".join(bad) + "\n")
    with pytest.raises(DataFormatError) as exc:
        read_log(p)
    assert exc.value.line == 11
    bad = list(lines)
    bad[5] = bad[5].replace(bad[5].split(",")[2], "abc", 1)
    p.write_text("\n".join(bad) + "\n")
    with pytest.raises(DataFormatError) as exc:
        read_log(p)
    assert exc.value.line == 6 and exc.value.column == "Voltage (V)"
    # a row cut mid-write at the end is a reported corrupt tail
    p.write_text("\n".join(lines) + "\n" + lines[-1][:9])
    (fl,) = read_log(p)
    assert any("corrupt tail" in w for w in fl.warnings)
    assert fl.voltage_v is not None and len(fl.voltage_v) == len(lines) - 1


def test_detection_is_by_content_not_suffix(tmp_path: Path) -> None:
    for name, reader in (("sim_hover.bin", "dataflash"), ("sim_hover.ulg", "ulog"),
                         ("sim_hover.tlog", "tlog")):  # fmt: skip
        p = tmp_path / (name + ".log")
        p.write_bytes((FL / name).read_bytes())
        assert detect(p).name == reader
