"""A line stand's load-cell calibration: computed from tare + a known mass, written once, read
back by the preset; careless input refused in one line."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from thrustmap.core.errors import ConfigError
from thrustmap.core.physical import G0
from thrustmap.protocols.stands.line import LineStandDecoder
from thrustmap.protocols.stands.line_presets import preset
from thrustmap.rig.stand.line_calibration import (
    calibration_from_counts,
    load_line_calibration,
    write_line_calibration,
)

ROOT = Path(__file__).resolve().parents[1]
VH = preset("victorhook-thruststand")


def test_counts_per_newton_from_a_known_mass_and_read_back_by_the_preset(tmp_path: Path) -> None:
    rest = [1000.0 + d for d in (-3, 1, 2, -1, 0, 1)]
    loaded = [v - 400.0 * 200.0 for v in rest]  # 200 g at -400 counts/g
    cal = calibration_from_counts(VH, rest, loaded, 0.2)
    assert cal.tare_counts == pytest.approx(1000.0)
    assert cal.counts_per_n == pytest.approx(-400.0 * 1000.0 / G0)
    path = tmp_path / "cal.json"
    write_line_calibration(path, cal)
    spec = load_line_calibration(path).apply(VH, str(path))
    (s,) = LineStandDecoder(spec).feed(b"5, 1000, -79000\n")  # 200 g pull less the tare
    assert s.thrust_n == pytest.approx(0.2 * G0, rel=1e-3)
    with pytest.raises(ConfigError, match="exists; not overwritten"):
        write_line_calibration(path, cal)


def test_a_mass_the_cell_does_not_see_is_questioned() -> None:
    rest = [0.0, 50.0, -50.0, 20.0]
    with pytest.raises(ConfigError, match="within its noise.*is it on the cell"):
        calibration_from_counts(VH, rest, [r + 30 for r in rest], 0.2)
    with pytest.raises(ConfigError, match="--mass-g 0.1: expected 1..50000 g"):
        calibration_from_counts(VH, rest, rest, 0.0001)


def test_another_stands_calibration_is_refused(tmp_path: Path) -> None:
    cal = calibration_from_counts(VH, [0.0, 1.0, 2.0], [-900.0, -901.0, -899.0], 0.1)
    with pytest.raises(ConfigError, match="calibration of 'victorhook-thruststand'.*tiny"):
        cal.apply(preset("tiny-thrust-stand"))


@pytest.mark.parametrize(
    ("data", "said"),
    [
        ({"format": "x"}, 'expected "format": "thrustmap-line-calibration"'),
        ({"format": "thrustmap-line-calibration", "version": 9}, "version 9: expected 1"),
        (
            {"format": "thrustmap-line-calibration", "version": 1, "tare_counts": 1,
             "counts_per_n": 0, "mass_kg": 0.1, "preset": "p", "field": "thrust_n"},
            "key 'counts_per_n': expected a finite non-zero number",
        ),
    ],
)  # fmt: skip
def test_a_bad_calibration_file_is_one_line(tmp_path: Path, data: dict, said: str) -> None:
    path = tmp_path / "cal.json"
    path.write_text(json.dumps(data))
    with pytest.raises(ConfigError, match=said.replace("(", r"\(")) as err:
        load_line_calibration(path)
    assert str(path) in str(err.value)


def run(*args: str, stdin: str = "") -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "thrustmap", *args],
        input=stdin, capture_output=True, text=True, cwd=ROOT,
    )  # fmt: skip


def test_calibrate_cli_refuses_to_start_a_sequence_stand_without_the_motor_unplugged(
    tmp_path: Path,
) -> None:
    r = run("stand", "calibrate", "sim://line-stand?preset=tiny-thrust-stand",
            "--line-preset", "tiny-thrust-stand", "--mass-g", "10", "-o", str(tmp_path / "c.json"))  # fmt: skip
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1
    assert "--motor-unplugged" in r.stderr and not (tmp_path / "c.json").exists()


def test_calibrate_cli_questions_a_mass_that_never_reached_the_cell(tmp_path: Path) -> None:
    r = run("stand", "calibrate", "sim://line-stand?preset=victorhook-thruststand",
            "--line-preset", "victorhook-thruststand", "--mass-g", "200", "--settle", "0.5",
            "-o", str(tmp_path / "c.json"), stdin="\n\n")  # fmt: skip
    assert r.returncode == 2, r.stderr
    assert "is it on the cell?" in r.stderr and not (tmp_path / "c.json").exists()


def test_probe_reads_a_line_stand_with_its_calibration(tmp_path: Path) -> None:
    cal = calibration_from_counts(VH, [0.0, 1.0, 2.0], [-900.0, -901.0, -899.0], 0.1)
    path = tmp_path / "cal.json"
    write_line_calibration(path, cal)
    r = run("probe", "sim://line-stand?preset=victorhook-thruststand", "--calibration", str(path))
    assert r.returncode == 0, r.stderr
    assert "spec: victorhook-thruststand" in r.stdout and "mean thrust" in r.stdout
    other = run("probe", "sim://line-stand?preset=tiny-thrust-stand", "--calibration", str(path))
    assert other.returncode == 2 and "calibration of 'victorhook-thruststand'" in other.stderr


@pytest.mark.parametrize("name", ["tiny-thrust-stand", "victorhook-thruststand"])
def test_a_firmware_preset_is_declarable_in_json_and_reads_back_equal(
    tmp_path: Path, name: str
) -> None:
    from thrustmap.rig.stand.line_spec import line_spec_to_dict, load_line_spec

    path = tmp_path / "spec.json"
    path.write_text(json.dumps(line_spec_to_dict(preset(name))))
    assert load_line_spec(path) == preset(name)
