"""Logs without a battery voltage, and logs without steady flight, still give a Df (issue 13).

A vehicle without a voltage sensor (ArduCopter CURR.Volt = 0 V throughout, a ULog without
battery_status) gives a Df whose voltage_v column is empty, with one warning saying what that
costs: γ can only be a constant and the map's forward direction (which needs B) cannot give T_c.
A log with no steady flight gives an empty Df with its filter accounting; ``gamma fit`` refuses it.
"""

from __future__ import annotations

import contextlib
import io
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from support import simulate_flight as sim

from thrustmap.cli import main
from thrustmap.fitting.df.dffile import read_df
from thrustmap.fitting.mapfile import ThrustMap


@dataclass
class Result:
    exit_code: int
    stdout: str
    stderr: str

    @property
    def output(self) -> str:
        return self.stdout + self.stderr


def _run(group: str, args: list[str]) -> Result:
    """The console entry point (errors become one line and exit 2), with its output captured."""
    out, err = io.StringIO(), io.StringIO()
    code = 0
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            main([group, *args])
        except SystemExit as exc:
            code = int(exc.code or 0)
    return Result(code, out.getvalue(), err.getvalue())


def _flight(seed: int = 3) -> sim.SimFlight:
    return sim.simulate_hover(sim.HoverSim(seed=seed, duration_s=60.0, rate_hz=25.0))


@pytest.fixture(scope="module")
def no_volt_bin(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """An old-firmware ArduCopter log whose CURR.Volt reads 0 V throughout, and the stand map."""
    d = tmp_path_factory.mktemp("novolt")
    fl = _flight()
    fl.voltage_v[:] = 0.0
    sim.write_dataflash(fl, d / "novolt.bin", old_firmware=True)
    fl.stand_map.save(d / "map.json")
    return d / "novolt.bin", d / "map.json"


def test_dataflash_without_voltage_gives_a_df_with_an_empty_voltage_column(
    no_volt_bin: tuple[Path, Path], tmp_path: Path
) -> None:
    log, _ = no_volt_bin
    out = tmp_path / "df.csv"
    res = _run("flightlog", ["extract", str(log), "--mass-kg", "1.0", "-o", str(out)])
    assert res.exit_code == 0, res.output
    warned = [ln for ln in res.stderr.splitlines() if "battery voltage unknown" in ln]
    assert len(warned) == 1, res.stderr
    assert "CURR.Volt reads 0 V throughout" in warned[0]
    assert "γ can only be fitted as a constant" in warned[0] and "needs B" in warned[0]
    assert "battery voltage unknown" not in res.stdout  # said once, on stderr
    raw = out.read_text(encoding="utf-8").splitlines()
    assert raw[0].split(",")[2] == "voltage_v" and raw[1].split(",")[2] == ""
    table, side = read_df(out)
    assert len(table) >= 50
    assert table["voltage_v"].isna().all()
    assert (table["force_n"] > 0).all() and (table["thrust_cmd_norm"] > 0).all()
    assert side["columns"]["voltage_v"] is None
    meta = next(iter(side["flights"].values()))
    assert meta["voltage_source"] is None and "CURR.Volt reads 0 V" in meta["voltage_unknown"]


def test_map_needing_voltage_is_refused_in_one_line(
    no_volt_bin: tuple[Path, Path], tmp_path: Path
) -> None:
    log, tmap = no_volt_bin
    out = tmp_path / "df.csv"
    res = _run(
        "flightlog",
        ["extract", str(log), "--mass-kg", "1.0", "--map", str(tmap), "-o", str(out)],
    )
    assert res.exit_code == 2, res.output
    line = res.stderr.strip().splitlines()[-1]
    assert "needs the battery voltage" in line and "motor outputs" in line
    assert not out.exists()


def test_ulog_without_battery_status_gives_a_df(tmp_path: Path) -> None:
    fl = _flight(seed=4)
    sim.write_ulog(fl, tmp_path / "f.ulg", battery=False)
    out = tmp_path / "df.csv"
    res = _run("flightlog", ["extract", str(tmp_path / "f.ulg"), "--mass-kg", "1", "-o", str(out)])
    assert res.exit_code == 0, res.output
    assert "no battery_status" in res.stderr and "battery voltage unknown" in res.stderr
    table, side = read_df(out)
    assert len(table) >= 50 and table["voltage_v"].isna().all()
    # the normalised command still matches the simulated flight's
    assert 0.2 < float(table["thrust_cmd_norm"].median()) < 0.9


@pytest.fixture(scope="module")
def df_with_tc(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A Df with T_c in newtons (extracted through the map) and the map."""
    d = tmp_path_factory.mktemp("tc")
    fl = _flight(seed=5)
    sim.write_dataflash(fl, d / "f.bin")
    fl.stand_map.save(d / "map.json")
    res = _run(
        "flightlog",
        ["extract", str(d / "f.bin"), "--mass-kg", "1", "--map", str(d / "map.json"),
         "-o", str(d / "df.csv")],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    return d / "df.csv", d / "map.json"


def _blank_voltage(src: Path, dst: Path, rows: slice) -> None:
    table = pd.read_csv(src)
    table.loc[table.index[rows], "voltage_v"] = np.nan
    table.to_csv(dst, index=False)
    dst.with_suffix(".json").write_text(src.with_suffix(".json").read_text())


def test_gamma_fit_without_voltage_is_a_constant(
    df_with_tc: tuple[Path, Path], tmp_path: Path
) -> None:
    df, tmap = df_with_tc
    nov = tmp_path / "nov.csv"
    _blank_voltage(df, nov, slice(None))
    out = tmp_path / "corrected.json"
    res = _run("gamma", ["fit", str(nov), "--map", str(tmap), "-o", str(out)])
    assert res.exit_code == 0, res.output
    warned = [
        ln for ln in res.output.splitlines() if "no battery voltage" in ln and "constant" in ln
    ]
    assert len(warned) == 1, res.output
    assert "(degree 0," in res.output and "flown voltage unknown" in res.output
    corr = ThrustMap.load(out).correction
    assert corr is not None and len(corr.coefficients) == 1
    table = pd.read_csv(df)
    expected = float(np.median(table["thrust_cmd_n"] / table["force_n"]))
    assert corr.coefficients[0] == pytest.approx(expected, rel=0.01)  # l1: median of γ_j
    assert corr.gamma(np.array([10.0, 25.0])).tolist() == [corr.coefficients[0]] * 2
    # a slope cannot be asked for without B
    res = _run("gamma", ["fit", str(nov), "--map", str(tmap), "-o", str(out), "--degree", "1"])
    assert res.exit_code == 2 and "degree-1 γ(B) needs B" in res.output


def test_gamma_fit_drops_rows_without_voltage(
    df_with_tc: tuple[Path, Path], tmp_path: Path
) -> None:
    df, tmap = df_with_tc
    part = tmp_path / "part.csv"
    _blank_voltage(df, part, slice(0, 20))
    out = tmp_path / "corrected.json"
    res = _run("gamma", ["fit", str(part), "--map", str(tmap), "-o", str(out), "--json"])
    assert res.exit_code == 0, res.output
    fit = json.loads(res.stdout)
    n = len(pd.read_csv(df))
    assert fit["samples"] == n - 20
    assert f"20 of {n} Df samples have no battery voltage: dropped" in fit["warnings"]


def test_gamma_fit_refuses_voltage_free_df_without_newtons(
    no_volt_bin: tuple[Path, Path], tmp_path: Path
) -> None:
    log, tmap = no_volt_bin
    df = tmp_path / "df.csv"
    assert _run("flightlog", ["extract", str(log), "--mass-kg", "1", "-o", str(df)]).exit_code == 0
    res = _run("gamma", ["fit", str(df), "--map", str(tmap), "-o", str(tmp_path / "m.json")])
    assert res.exit_code == 2
    assert "no battery voltage and no thrust_cmd_n" in res.output
    assert len(res.output.strip().splitlines()) == 1


def test_no_steady_flight_writes_an_empty_df_and_gamma_refuses_it(tmp_path: Path) -> None:
    fl = _flight(seed=6)
    fl.accel_up_mps2[:] += 3.0  # never near hover (a climb, or a mass far off): nothing is kept
    log = tmp_path / "idle.bin"
    sim.write_dataflash(fl, log)
    fl.stand_map.save(tmp_path / "map.json")
    out = tmp_path / "df.csv"
    res = _run("flightlog", ["extract", str(log), "--mass-kg", "1", "-o", str(out)])
    assert res.exit_code == 0, res.output
    warned = [ln for ln in res.stderr.splitlines() if "no steady flight" in ln]
    assert len(warned) == 1 and "idle.bin" in warned[0] and "not near hover" in warned[0]
    table, side = read_df(out)
    assert len(table) == 0 and "voltage_v" in table.columns and "force_n" in table.columns
    steps = side["reports"][0]["steps"]
    assert side["reports"][0]["samples"] == 0
    assert any(s["name"] == "hover" and s["dropped_s"] > 30 for s in steps)
    res = _run(
        "gamma",
        ["fit", str(out), "--map", str(tmp_path / "map.json"), "-o", str(tmp_path / "m.json")],
    )
    assert res.exit_code == 2
    line = res.output.strip()
    assert (
        len(line.splitlines()) == 1 and "no samples in df.csv" in line and "not near hover" in line
    )
    assert not (tmp_path / "m.json").exists()
