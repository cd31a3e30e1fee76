"""One number per question (issue 40 items 2-4, issue 44 items 5 and 8): the full-throttle
thrust, the hover throttle and the spin-up are computed once (``fitting.mapvalues``) and every
export, the report and ``predict`` write the same values, each saying when it is extrapolated
and with what interval; firmware battery ranges follow the documented rule; a map is checked
against the platform it is exported to and against the voltage it is asked at.

The map here is shaped like the demo's single-rotor map: a 6S motor measured up to 70 %
throttle (about 8.4 N), with a prediction interval and a supported region, so full throttle
lies outside the data.
"""

from __future__ import annotations

import io
import json
import re
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from click.testing import CliRunner

import thrustmap.fitting.export.firmware.ardupilot as ardupilot
import thrustmap.fitting.export.firmware.px4 as firmware_px4
from thrustmap.cli import cli, main
from thrustmap.core import physical
from thrustmap.core.units import SCALES
from thrustmap.fitting.export.encodings import ExportOptions
from thrustmap.fitting.export.targets import export_map
from thrustmap.fitting.interval import Interval, Region
from thrustmap.fitting.mapfile import Box, ThrustMap, ValidityBox
from thrustmap.fitting.mapvalues import map_values
from thrustmap.fitting.models import MODELS
from thrustmap.report.html import _map_values


def _motor_points(volts: tuple[float, float], top_pct: float) -> tuple[np.ndarray, ...]:
    """(T, B, throttle %) of a motor-physics surface, kept up to ``top_pct`` throttle."""
    t, b = (a.ravel() for a in np.meshgrid(np.linspace(0.05, 14.0, 60), np.linspace(*volts, 6)))
    scale = volts[1] / 24.86
    th = 2.0 + (60.0 + 330.0 * np.sqrt(t / scale) + 25.0 * t / scale) * scale / b * 24.86 / 25.0
    keep = th <= top_pct
    return t[keep], b[keep], th[keep]


def demo_like_map(volts: tuple[float, float] = (23.16, 24.86), model: str = "motor") -> ThrustMap:
    """A map with an interval and a supported region, data up to 70 % throttle."""
    t, b, th = _motor_points(volts, 70.0)
    coef = MODELS[model].fit(t, b, th, "l2")
    region = Region.from_points(t, b)
    iv = Interval(
        half_width_pct=1.0, growth_per_span=0.5, thrust_unit_n=region.thrust_span_n,
        voltage_unit_v=region.voltage_unit_v, region=region, basis="test",
        voltage_pct_per_log=12.5,
    )  # fmt: skip
    box = ValidityBox(Box(float(t.min()), float(t.max())), Box(*volts), Box(float(th.min()), 70.0))
    return ThrustMap(
        model, tuple(float(c) for c in coef), SCALES["pwm"], box,
        interval=iv.to_dict(), supported=region, spin_up={"throttle_pct": 4.0, "signal": "rpm"},
    )  # fmt: skip


@pytest.fixture(scope="module")
def tmap() -> ThrustMap:
    return demo_like_map()


EXPORTS = [
    ("px4", ExportOptions()),
    ("ardupilot", ExportOptions()),
    ("betaflight", ExportOptions(firmware="4.6")),
    ("betaflight", ExportOptions(firmware="2026.6")),
    ("dshot", ExportOptions()),
    ("c-header", ExportOptions(encoding="pwm")),
    ("aerostack2", ExportOptions()),
]


def test_the_map_values_are_extrapolated_with_an_interval(tmap: ThrustMap) -> None:
    mv = map_values(tmap)
    full = mv.full_throttle
    assert full is not None and full.extrapolated and full.distance > 0
    assert full.lo is not None and full.hi is not None and full.lo < full.value < full.hi
    # the interval is the set of thrusts whose throttle interval holds 100 %
    for edge, sign in ((full.lo, 1.0), (full.hi, -1.0)):
        h = float(tmap.interval_pct(edge, mv.voltage_v))  # type: ignore[arg-type]
        assert float(tmap.throttle_pct(edge, mv.voltage_v)) + sign * h == pytest.approx(100.0)
    assert float(tmap.throttle_pct(full.value, mv.voltage_v)) == pytest.approx(100.0, abs=1e-9)
    assert mv.spin_up is not None and mv.spin_up.value == 4.0 and mv.spin_up.lo is None


@pytest.mark.parametrize(("target", "opts"), EXPORTS, ids=[f"{t}-{o.firmware}" for t, o in EXPORTS])
def test_every_export_writes_the_one_full_throttle_thrust(
    tmap: ThrustMap, target: str, opts: ExportOptions
) -> None:
    full = map_values(tmap).full_throttle
    assert full is not None
    res = export_map(tmap, target, opts)
    assert res.values["full_throttle_thrust_n"] == pytest.approx(full.value, rel=0.005)
    # the header names it extrapolated, with its interval, and lists it outside the region
    head = res.text.split("written values outside the supported region")[0]
    line = next(ln for ln in head.splitlines() if "full-throttle thrust at" in ln)
    assert "EXTRAPOLATED" in line and f"95 % interval {full.lo:.4g}..{full.hi:.4g} N" in line
    tail = res.text.split("written values outside the supported region (extrapolated):")[1]
    assert "full-throttle thrust:" in tail.split("firmware:")[0]


def test_each_firmware_curve_ends_at_the_one_full_throttle_thrust(tmap: ThrustMap) -> None:
    full = map_values(tmap).full_throttle
    assert full is not None
    px4 = export_map(tmap, "px4")
    assert px4.values["thrust_max_n"] == pytest.approx(full.value, rel=1e-12)  # s = 1
    for firmware in ("4.6", "2026.6"):
        bf = export_map(tmap, "betaflight", ExportOptions(firmware=firmware))
        assert bf.values["thrust_max_n"] == pytest.approx(full.value, rel=1e-12)  # m = 1
    ap = export_map(tmap, "ardupilot")
    p = ardupilot.ArduPilotParams(
        ap.values["MOT_THST_EXPO"], ap.values["MOT_SPIN_MIN"], ap.values["MOT_SPIN_MAX"],
        ap.values["MOT_BAT_VOLT_MAX"], ap.values["MOT_BAT_VOLT_MIN"], ap.values["thrust_max_n"],
    )  # fmt: skip
    # ArduPilot's full lift is the map's thrust at MOT_SPIN_MAX and MOT_BAT_VOLT_MAX
    at_spin_max = float(tmap.thrust_n(95.0, ap.values["MOT_BAT_VOLT_MAX"]))
    assert ap.values["thrust_max_n"] == pytest.approx(at_spin_max, rel=1e-6)
    # ArduPilot never commands past MOT_SPIN_MAX; its curve carried on to MOT_PWM_MAX stays
    # near the map's full-throttle thrust (within 1 % here), the export says the map's own
    top = float(ardupilot.ardupilot_thrust(1.0, full.voltage_v, p))
    assert top == pytest.approx(full.value, rel=0.01)


def test_crazyflie_f_max_is_the_one_full_throttle_thrust_in_grams() -> None:
    one_cell = demo_like_map((3.5, 4.15))
    res = export_map(one_cell, "crazyflie", ExportOptions(rotors=4))
    full = map_values(one_cell).full_throttle
    assert full is not None
    f_max_g = float(re.search(r"f_max_g: (\S+)", res.text).group(1))  # type: ignore[union-attr]
    assert f_max_g == pytest.approx(full.value * 4 * 1000 / 9.80665, rel=1e-9)
    assert "full_throttle_thrust_n: {value: " in res.text and "extrapolated: true" in res.text


def test_predict_answers_the_same_full_throttle_thrust(tmap: ThrustMap, tmp_path: Path) -> None:
    path = tmp_path / "map.json"
    tmap.save(path)
    full = map_values(ThrustMap.load(path)).full_throttle
    assert full is not None
    b = f"{full.voltage_v!r}"
    res = CliRunner().invoke(
        cli, ["predict", str(path), "--throttle-pct", "100", "--voltage-v", b, "--json"]
    )
    doc = json.loads(res.stdout[res.stdout.index("{") :])
    assert doc["thrust_n"] == pytest.approx(full.value, rel=1e-6)
    assert doc["thrust_extrapolated"] is True
    assert doc["thrust_interval_n"] == pytest.approx([full.lo, full.hi], rel=1e-6)
    text = CliRunner().invoke(cli, ["predict", str(path), "--throttle-pct", "100",
                                    "--voltage-v", b]).stdout  # fmt: skip
    assert f"95 % interval {full.lo:.4g}..{full.hi:.4g} N; EXTRAPOLATED" in text


def test_the_report_shows_the_same_values(tmap: ThrustMap) -> None:
    mv = map_values(tmap)
    html = _map_values(SimpleNamespace(map_values=mv))  # type: ignore[arg-type]
    assert mv.full_throttle is not None
    assert f"{mv.full_throttle.value:.4g} N" in html and "EXTRAPOLATED" in html


def test_hover_is_one_value_in_each_firmware_unit(tmap: ThrustMap) -> None:
    """The map's hover throttle, written as the value each firmware turns back into it."""
    opts = ExportOptions(mass_kg=2.0, rotors=4)
    hover = map_values(tmap, hover_thrust_n=2.0 * 9.80665 / 4).hover
    assert hover is not None and not hover.extrapolated
    hover_us = 1000.0 + 10.0 * hover.value
    px4 = export_map(tmap, "px4", opts)
    lo_us, f = px4.values["PWM_MAIN_MIN1"], px4.values["THR_MDL_FAC"]
    s = float(firmware_px4.px4_throttle(px4.values["MPC_THR_HOVER"], f))  # PX4's mixer output
    assert lo_us + s * (2000.0 - lo_us) == pytest.approx(hover_us, abs=1.0)  # 3-digit param
    ap = export_map(tmap, "ardupilot", opts)
    p = ardupilot.ArduPilotParams(
        ap.values["MOT_THST_EXPO"], ap.values["MOT_SPIN_MIN"], ap.values["MOT_SPIN_MAX"],
        ap.values["MOT_BAT_VOLT_MAX"], ap.values["MOT_BAT_VOLT_MIN"], ap.values["thrust_max_n"],
    )  # fmt: skip
    demand_n = ap.values["MOT_THST_HOVER"] * p.thrust_max_n  # ArduPilot's throttle x full lift
    act = float(ardupilot.ardupilot_actuator(demand_n, hover.voltage_v, p))
    assert 1000.0 + 1000.0 * act == pytest.approx(hover_us, abs=0.2)
    for res in (px4, ap):
        assert f"hover throttle at {hover.voltage_v:.4g} V: {hover.value:.4g} %" in res.text


# -- firmware parameters beyond the stand's range (issue 40 item 3) ------------------------------
def test_ardupilot_battery_range_is_the_documented_per_cell_range_for_a_physics_map(
    tmap: ThrustMap,
) -> None:
    res = export_map(tmap, "ardupilot")
    assert res.values["MOT_BAT_VOLT_MAX"] == 25.2  # 4.2 V x 6 cells, not the stand's 24.86
    assert res.values["MOT_BAT_VOLT_MIN"] == 19.8  # 3.3 V x 6 cells, not the stand's 23.16
    assert "documented 4.2/3.3 V a cell x 6 cells" in res.text
    assert "# pack: 6S, read from the map's 23.16..24.86 V" in res.text  # the frame named
    out = res.text.split("written values outside the supported region (extrapolated):")[1]
    line = next(ln for ln in out.splitlines() if "MOT_BAT_VOLT_MIN = 19.8 V" in ln)
    assert "below the voltages measured" in line and "95 % interval" in line


def test_ardupilot_keeps_the_stand_band_for_a_polynomial_map() -> None:
    poly = demo_like_map(model="poly2")
    res = export_map(poly, "ardupilot")
    assert (res.values["MOT_BAT_VOLT_MIN"], res.values["MOT_BAT_VOLT_MAX"]) == (23.16, 24.86)
    assert "no evidence outside the voltages measured" in res.text
    assert "below MOT_BAT_VOLT_MIN ArduPilot holds the compensation" in res.text


def test_px4_says_how_far_below_the_stand_its_battery_scaling_reaches(tmap: ThrustMap) -> None:
    res = export_map(tmap, "px4")
    out = res.text.split("written values outside the supported region (extrapolated):")[1]
    assert "MC_BAT_SCALE_EN compensates down to V_charged/1.3 = 19.12 V" in out


# -- platform and pack checks (issue 40 item 4, issue 44 items 5 and 8) --------------------------
def _cli(*args: str) -> tuple[int, str]:
    """``thrustmap ARGS`` through :func:`thrustmap.cli.main` (where exit codes are decided):
    (exit code, stdout + stderr)."""
    out, err = io.StringIO(), io.StringIO()
    old = sys.stdout, sys.stderr
    sys.stdout, sys.stderr = out, err
    try:
        try:
            main(list(args))
            code = 0
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    finally:
        sys.stdout, sys.stderr = old
    return code, out.getvalue() + err.getvalue()


@pytest.mark.parametrize(
    "args",
    [
        ["--to", "crazyflie"],
        ["--to", "crazyflie-cmd"],
        ["--to", "c-header", "--encoding", "crazyflie"],
    ],  # fmt: skip
)
def test_a_six_cell_map_is_refused_for_the_crazyflie(
    tmap: ThrustMap, tmp_path: Path, args: list[str]
) -> None:
    path, out = tmp_path / "map.json", tmp_path / "out.yaml"
    tmap.save(path)
    code, text = _cli("export", str(path), *args, "-o", str(out))
    lines = [ln for ln in text.splitlines() if ln.strip()]
    assert code == 2 and len(lines) == 1, text
    assert "6S pack (23.16..24.86 V)" in lines[0] and "flies on 1S" in lines[0]
    assert not out.exists()


def test_a_one_cell_map_goes_to_the_crazyflie(tmp_path: Path) -> None:
    path = tmp_path / "map.json"
    demo_like_map((3.5, 4.15)).save(path)
    code, text = _cli("export", str(path), "--to", "crazyflie")
    assert code == 0 and "f_max_g:" in text


def test_predict_names_a_voltage_that_is_one_cell(tmap: ThrustMap, tmp_path: Path) -> None:
    path = tmp_path / "map.json"
    tmap.save(path)
    code, text = _cli("predict", str(path), "--thrust-n", "4", "--voltage-v", "4.1")
    assert code == 2 and "unreachable" not in text
    assert "4.1 V is one cell of the map's 6S pack" in text and "--voltage-v 24.6" in text


def test_predict_on_a_per_cell_map_says_which_pack(tmp_path: Path) -> None:
    path = tmp_path / "map.json"
    demo_like_map((3.86, 4.14)).save(path)
    code, text = _cli("predict", str(path), "--thrust-n", "1", "--voltage-v", "4.0")
    assert code == 0 and "read as a 1S pack (or the per-cell voltage of a larger pack)" in text
    code, text = _cli("predict", str(path), "--thrust-n", "1", "--voltage-v", "24.6")
    assert code == 2 and "24.6 V is a 6S pack but the map's voltages" in text


def test_physical_pack_checks() -> None:
    assert physical.cells_from_voltage(23.16, 24.86) == 6
    assert physical.target_cells_problem(23.16, 24.86, "crazyflie") is not None
    assert physical.target_cells_problem(3.5, 4.15, "crazyflie") is None
    assert physical.target_cells_problem(23.16, 24.86, "ardupilot") is None
    assert physical.voltage_against_pack(24.0, 23.16, 24.86) is None
    assert "one cell" in (physical.voltage_against_pack(3.9, 23.16, 24.86) or "")
    assert physical.voltage_against_pack(4.0, 3.86, 4.14) is None
    assert physical.pack_assumed(23.16, 24.86) is None
    assert physical.pack_assumed(3.86, 4.14) is not None


def test_the_terminal_is_told_what_the_file_extrapolates(tmap: ThrustMap, tmp_path: Path) -> None:
    path, out = tmp_path / "map.json", tmp_path / "px4.params"
    tmap.save(path)
    code, text = _cli("export", str(path), "--to", "px4", "-o", str(out))
    full = map_values(tmap).full_throttle
    assert code == 0 and full is not None
    assert f"extrapolated: full-throttle thrust {full.value:.4g} N, 95 % interval" in text
