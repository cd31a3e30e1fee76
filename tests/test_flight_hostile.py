"""Hostile inputs around flight logs (issue 21, item 6): a Df sidecar whose rotor count is not
a whole number, a stand CSV with one enormous field, a flight CSV whose accelerometer is in g.
Each is refused with one line (exit 2) or converted with a warning and a physical result."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from thrustmap.cli import main
from thrustmap.fitting.df.extraction import extract
from thrustmap.fitting.df.options import G0
from thrustmap.fitting.df_options import DfOptions
from thrustmap.flightlogs.detect import read_log

FL = Path(__file__).resolve().parent.parent / "fixtures" / "flightlogs"


def _exit2(argv: list[str], capsys: pytest.CaptureFixture[str], named: str) -> str:
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and named in err, err
    assert "internal error" not in err
    return err


@pytest.fixture
def df_csv(tmp_path: Path) -> Path:
    out = tmp_path / "df.csv"
    code = main(
        ["flightlog", "extract", str(FL / "sim_hover.bin"), "--mass-kg", "1", "-o", str(out)]
    )
    assert code in (0, None) and out.exists()
    return out


@pytest.mark.parametrize("rotors", [4.5, "four", True, 0, -4])
def test_df_sidecar_rotor_count_not_a_whole_number(
    df_csv: Path, rotors: object, capsys: pytest.CaptureFixture[str]
) -> None:
    side = df_csv.with_suffix(".json")
    data = json.loads(side.read_text())
    for meta in data["flights"].values():
        meta["rotors"] = rotors
    side.write_text(json.dumps(data))
    capsys.readouterr()
    err = _exit2(
        ["gamma", "fit", str(df_csv), "--map", str(FL / "sim_map.json"), "-o",
         str(df_csv.with_name("g.json"))],
        capsys,
        "df.json",
    )  # fmt: skip
    assert "rotor count" in err and repr(rotors) in err


def test_df_sidecar_whole_rotor_count_as_float_is_fine(df_csv: Path) -> None:
    from thrustmap.fitting.df.dffile import read_df

    side = df_csv.with_suffix(".json")
    data = json.loads(side.read_text())
    for meta in data["flights"].values():
        meta["rotors"] = 4.0
    side.write_text(json.dumps(data))
    table, s = read_df(df_csv)
    assert len(table) > 50 and next(iter(s["flights"].values()))["rotors"] == 4.0


def test_stand_csv_with_a_30mb_field(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    p = tmp_path / "stand.csv"
    p.write_text(
        "Time (s),ESC signal (µs),Thrust (N),Voltage (V)\n0,1100,"
        + "1" * 30_000_000
        + ",16\n0.1,1200,1.5,16\n",
        encoding="utf-8",
    )
    err = _exit2(["inspect", str(p)], capsys, "stand.csv:2")
    assert "30000000 characters" in err


def _flight_csv_in_g(tmp_path: Path) -> Path:
    src = (FL / "sim_hover_paper.csv").read_text(encoding="utf-8").splitlines()
    head = src[0].split(",")
    k = head.index("Acc (m/s²)")
    rows = [src[0]]
    for line in src[1:]:
        cells = line.split(",")
        cells[k] = f"{float(cells[k]) / G0:.6f}"
        rows.append(",".join(cells))
    p = tmp_path / "hover_in_g.csv"
    p.write_text("\n".join(rows) + "\n", encoding="utf-8")
    return p


def test_flight_csv_accelerometer_in_g_is_converted_with_a_warning(tmp_path: Path) -> None:
    (fl,) = read_log(_flight_csv_in_g(tmp_path))
    (ref,) = read_log(FL / "sim_hover_paper.csv")
    assert fl.accel_up_mps2 is not None and ref.accel_up_mps2 is not None
    assert any("taken as g" in w for w in fl.warnings), fl.warnings
    assert np.allclose(fl.accel_up_mps2.values, ref.accel_up_mps2.values, atol=1e-4)
    df = extract([fl], DfOptions())
    assert len(df.table) > 100
    assert df.table["accel_up_mps2"].mean() == pytest.approx(G0, abs=0.3)


def test_generic_csv_in_g_and_a_downward_axis(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    src = FL / "sim_hover_generic.csv"
    lines = src.read_text(encoding="utf-8").splitlines()
    g_rows = [lines[0]]
    for line in lines[1:]:
        c = line.split(",")
        c[2] = f"{float(c[2]) / G0:.6f}"
        g_rows.append(",".join(c))
    p = tmp_path / "g.csv"
    p.write_text("\n".join(g_rows) + "\n", encoding="utf-8")
    cols = {"time_s": "t_us", "voltage_v": "vbat", "accel_up_mps2": "acc_z_frd",
            "thrust_cmd_norm": "thr_norm", "armed": "armed", "landed": "landed"}  # fmt: skip
    (fl,) = read_log(p, format="csv", columns=cols, time_scale=1e-6, accel_scale=-1.0)
    assert fl.accel_up_mps2 is not None
    assert float(np.mean(fl.accel_up_mps2.values)) == pytest.approx(G0, abs=0.5)
    assert any("taken as g" in w for w in fl.warnings)
    # the FRD column mapped without its sign: refused with one line naming the column
    down = tmp_path / "down.csv"
    shutil.copy(src, down)
    from thrustmap.core.errors import DataFormatError

    with pytest.raises(DataFormatError, match="downward axis"):
        read_log(down, format="csv", columns=cols, time_scale=1e-6)
