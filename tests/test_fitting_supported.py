"""Predictions that know their limits (issue 18, items 2-3): the supported region replaces the
bounding box, predict refuses bad numbers and never answers with a throttle outside the scale,
and fit, predict, the map file and the report give one prediction interval."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from test_fitting_identification import bldc_throttle_pct

from thrustmap.cli import main
from thrustmap.fitting.interval import Region
from thrustmap.fitting.mapfile import ThrustMap


def write_sweep(path: Path, voltage_v: float, top_n: float, seed: int) -> Path:
    """A step-summary file of a BLDC motor: 11 steps to ``top_n`` with sag and a little noise."""
    rng = np.random.default_rng(seed)
    thrust = np.linspace(0.15, top_n, 11)
    volts = voltage_v - 0.06 * thrust
    th = bldc_throttle_pct(thrust, volts) + rng.normal(0, 0.4, len(thrust))
    us = 1000.0 + 10.0 * th
    rows = [
        f"{1.5 * k:.1f},{a:.2f},{b:.5f},{c:.4f},"
        for k, (a, b, c) in enumerate(zip(us, thrust, volts, strict=True))
    ]
    path.write_text(RCB + "\n" + "\n".join(rows) + "\n", encoding="utf-8")
    return path


RCB = "Time (s),ESC signal (\u00b5s),Thrust (N),Voltage (V),"


COLS = ["--col-throttle", "throttle", "--col-thrust", "thrust", "--col-voltage", "volts"]


@pytest.fixture
def two_voltage_map(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> tuple[Path, str]:
    """A small motor fitted on 2S (reaching 3.5 N, ~76 % throttle) and 3S (10 N, ~99 %)."""
    a = write_sweep(tmp_path / "s2.csv", 7.4, 3.5, 1)
    b = write_sweep(tmp_path / "s3.csv", 11.1, 10.0, 2)
    m = tmp_path / "m.json"
    main(["fit", str(a), str(b), "-o", str(m), "--all-samples"])
    return m, capsys.readouterr().out


def run(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = 0
    try:
        main(args)
    except SystemExit as exc:
        code = int(exc.code or 0)
    cap = capsys.readouterr()
    return code, cap.out, cap.err


@pytest.mark.parametrize(
    ("args", "named"),
    [
        (["--thrust-n", "-2", "--voltage-v", "7.3"], "--thrust-n"),
        (["--throttle", "-50", "--voltage-v", "7.3"], "--throttle"),
        (["--throttle-pct", "-1", "--voltage-v", "7.3"], "--throttle-pct"),
        (["--throttle-pct", "150", "--voltage-v", "7.3"], "--throttle-pct"),
        (["--thrust-n", "nan", "--voltage-v", "7.3"], "--thrust-n"),
        (["--thrust-n", "1", "--voltage-v", "inf"], "--voltage-v"),
        (["--thrust-n", "1", "--voltage-v", "-7"], "--voltage-v"),
    ],
)
def test_predict_refuses_bad_numbers(
    two_voltage_map: tuple[Path, str],
    capsys: pytest.CaptureFixture[str],
    args: list[str],
    named: str,
) -> None:
    code, out, err = run(["predict", str(two_voltage_map[0]), *args], capsys)
    assert code == 2 and out == ""
    assert len(err.strip().splitlines()) == 1 and named in err, err


def test_predict_outside_the_scale_is_unreachable_not_an_answer(
    two_voltage_map: tuple[Path, str], capsys: pytest.CaptureFixture[str]
) -> None:
    m = str(two_voltage_map[0])
    code, out, _ = run(["predict", m, "--thrust-n", "8", "--voltage-v", "7.19"], capsys)
    assert code == 1 and "unreachable" in out and "nearest reachable thrust" in out
    assert not re.search(r"throttle \d+\.\d+ ±", out)
    code, out, _ = run(["predict", m, "--thrust-n", "8", "--voltage-v", "7.19", "--json"], capsys)
    doc = json.loads(out)
    assert code == 1 and doc["reachable"] is False and doc["throttle_pct"] is None
    assert doc["required_throttle_pct"] > 100
    tmap = ThrustMap.load(m)
    nearest = doc["nearest_reachable_thrust_n"]
    assert 0 < nearest < 8
    assert float(tmap.throttle_pct(nearest, 7.19)) == pytest.approx(100.0, abs=1e-6)
    # the nearest reachable thrust is itself an answer within the scale
    code, out, _ = run(
        ["predict", m, "--thrust-n", f"{nearest - 1e-5:.6f}", "--voltage-v", "7.19"]
        + ["--extrapolate"],
        capsys,
    )
    assert code == 0 and re.search(r"throttle (99\.99\d|100\.000) ±", out), out


def test_supported_region_not_the_box(
    two_voltage_map: tuple[Path, str], capsys: pytest.CaptureFixture[str]
) -> None:
    """4.4 N at 7.2 V is inside the (T, B) box of a 2S+3S fit but the motor only reached 3.5 N
    on 2S: predict calls it extrapolation and says how much the interval widened."""
    m, fit_text = two_voltage_map
    assert "supported region" in fit_text and "valid for" not in fit_text
    doc = json.loads(m.read_text())
    region = doc["supported_region"]
    assert max(region["thrust_hi_n"]) > 9.9 and min(region["thrust_hi_n"]) < 3.7
    code, out, err = run(
        ["predict", str(m), "--thrust-n", "2.0", "--voltage-v", "7.2", "--json"], capsys
    )
    inside = json.loads(out)
    assert code == 0 and inside["inside_supported_region"] and inside["inside_validity_box"]
    assert inside["interval_widening"] == pytest.approx(1.0)
    code, out, err = run(
        ["predict", str(m), "--thrust-n", "4.4", "--voltage-v", "7.2", "--json"], capsys
    )
    outside = json.loads(out)
    assert code == 0
    assert not outside["inside_supported_region"] and not outside["inside_validity_box"]
    assert outside["interval_widening"] > 1.0
    assert "outside the map's supported region" in err and "interval widened ×" in err
    base, half = outside["interval_at_region_pct"], outside["interval_pct"]
    assert f"from ±{base:.2f} % to ±{half:.2f} %" in err
    # the old box would have called it inside
    assert ThrustMap.load(m).validity.contains(4.4, 7.2)


def test_one_interval_in_fit_predict_map_and_report(
    two_voltage_map: tuple[Path, str], capsys: pytest.CaptureFixture[str]
) -> None:
    m, fit_text = two_voltage_map
    doc = json.loads(m.read_text())
    iv = doc["interval"]
    lo, hi = iv["over_region_pct"]
    # fit prints the range over the supported region the map file records
    assert f"trustworthy to ±{lo:.2f}..{hi:.2f} %" in fit_text
    # the report states the same range
    html = m.with_suffix(".html")
    code, _, err = run(["report", str(m), "-o", str(html)], capsys)
    assert code == 0, err
    assert f"±{lo:.2f}..{hi:.2f} % throttle" in html.read_text()
    # predict's half-width is the map file's formula, evaluated here from the JSON alone
    region = Region(
        tuple(doc["supported_region"]["voltage_v"]),
        tuple(doc["supported_region"]["thrust_lo_n"]),
        tuple(doc["supported_region"]["thrust_hi_n"]),
        doc["supported_region"]["voltage_lo_v"],
        doc["supported_region"]["voltage_hi_v"],
    )
    cov = np.asarray(iv["parameter_covariance"])
    assert cov.shape == (4, 4)
    for t, b in ((1.0, 7.3), (8.0, 10.9), (4.4, 7.2), (1.0, 14.0)):
        code, out, _ = run(
            ["predict", str(m), "--thrust-n", str(t), "--voltage-v", str(b), "--json"]
            + ["--extrapolate"],
            capsys,
        )
        got = json.loads(out)["interval_pct"]
        x = np.array([1.0, 1.0 / b, np.sqrt(t) / b, t / b])
        vs = iv["voltage_support"]
        b_lo = np.interp(t, vs["thrust_n"], vs["voltage_lo_v"])
        b_hi = np.interp(t, vs["thrust_n"], vs["voltage_hi_v"])
        rho = abs(np.log(b / np.clip(b, b_lo, b_hi)))
        base = np.sqrt(
            iv["half_width_pct"] ** 2
            + iv["z"] ** 2 * (x @ cov @ x)
            + iv["systematic_pct"] ** 2
            + iv.get("recording_pct", 0.0) ** 2
            + (iv["voltage_pct_per_log"] * rho) ** 2
        )
        t_lo, t_hi = region.thrust_range(b)
        e = max(float(t_lo) - t, t - float(t_hi), 0.0) / float(t_hi)
        assert got == pytest.approx(base * (1 + iv["growth_per_reach"] * np.sqrt(e)), rel=1e-9)
    # and the range over the region is the minimum and maximum of that same function
    tmap = ThrustMap.load(m)
    tt, bb = tmap.supported_region().grid()
    half = tmap.interval_pct(tt, bb)
    assert half is not None
    assert (float(half.min()), float(half.max())) == pytest.approx((lo, hi))


def test_report_proposes_only_reachable_points(tmp_path: Path) -> None:
    from thrustmap.report.data import where_to_test

    a = write_sweep(tmp_path / "s2.csv", 7.4, 3.5, 1)
    b = write_sweep(tmp_path / "s3.csv", 11.1, 10.0, 2)
    m = tmp_path / "m.json"
    main(["fit", str(a), str(b), "-o", str(m), "--all-samples"])
    tmap = ThrustMap.load(m)
    v = tmap.validity
    gt, gb = np.meshgrid(
        np.linspace(v.thrust_n.lo, v.thrust_n.hi, 30),
        np.linspace(v.voltage_v.lo, v.voltage_v.hi, 30),
    )
    th = tmap.throttle_pct(gt, gb)
    pi = tmap.interval_pct(gt, gb)
    assert pi is not None
    assert (th > 100).any()  # the box's high-thrust, low-voltage corner is out of reach
    assert float(pi[th > 100].max()) > float(pi[th <= 100].max())  # and widest there
    t, b = where_to_test(tmap, gt, gb, th, pi) or (np.nan, np.nan)
    assert 0 <= float(tmap.throttle_pct(t, b)) <= 100


def test_grams_read_as_newtons_are_questioned(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A 6S stand file whose gram column is read as newtons: 50..760 N per rotor."""
    g = np.linspace(50, 760, 12)
    rows = [f"{1100 + 80 * k},{x:.1f},{24.5 - 0.003 * x:.3f}" for k, x in enumerate(g)]
    p = tmp_path / "grams.csv"
    p.write_text("throttle,thrust,volts\n" + "\n".join(rows) + "\n")
    code, out, err = run(["fit", str(p), "-o", str(tmp_path / "g.json"), *COLS], capsys)
    assert code == 2 and out == ""
    assert len(err.strip().splitlines()) == 1 and "grams.csv" in err
    assert "N per volt" in err and "20 N/V" in err
    # the same file in grams loads
    code, _, _ = run(
        ["fit", str(p), "-o", str(tmp_path / "g.json"), *COLS, "--thrust-unit", "gf"], capsys
    )
    assert code == 0


def test_a_gamma_corrected_map_judges_its_region_at_gamma_times_thrust(
    two_voltage_map: tuple[Path, str], capsys: pytest.CaptureFixture[str]
) -> None:
    from thrustmap.fitting.mapfile import Box, GammaCorrection

    m, _ = two_voltage_map
    tmap = ThrustMap.load(m)
    corrected = tmap.with_correction(GammaCorrection((1.2,), Box(7.0, 11.5)))
    c_path = m.with_name("corrected.json")
    corrected.save(c_path)
    _, hi = tmap.supported_region().thrust_range(9.0)
    t = float(hi) / 1.1  # inside for the bench map, outside once γ = 1.2 scales it
    args = ["--thrust-n", f"{t:.4f}", "--voltage-v", "9.0", "--json"]
    code, out, _ = run(["predict", str(c_path), *args, "--no-correction"], capsys)
    assert code == 0 and json.loads(out)["inside_supported_region"]
    code, out, err = run(["predict", str(c_path), *args], capsys)
    doc = json.loads(out)
    assert code == 0 and doc["corrected"] and not doc["inside_supported_region"]
    assert doc["supported_thrust_n"][1] == pytest.approx(float(hi) / 1.2)
    assert "outside the map's supported region" in err


def test_a_thrust_reached_at_one_voltage_is_supported_at_every_higher_one(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 31 item 6: an adaptive run measured its high thrusts early (25.1 V) and its low
    ones late in the discharge (24.0 V). Before, the region at 25.1 V was 6.7..7.2 N and
    predict 1 N at 25.09 V was called extrapolation; a thrust reached at 24.0 V is within
    reach at every higher voltage."""

    hi_t = np.linspace(6.7, 7.2, 12)
    lo_t = np.linspace(0.05, 0.42, 12)
    t = np.r_[hi_t, lo_t]
    b = np.r_[np.linspace(25.1, 24.9, 12), np.linspace(24.2, 24.0, 12)]
    th = 4.0 + (30.0 * np.sqrt(t) + 150.0 * t) / b
    region = Region.from_points(t, b)
    lo, hi = region.thrust_range(25.09)
    assert float(lo) <= 0.1 and float(hi) >= 7.1
    assert bool(region.contains(1.0, 25.09))
    # a thrust beyond anything reached at or below 24.1 V is still outside there
    assert not bool(region.contains(7.0, 24.05))
    lines = ["ESC signal (µs),Thrust (N),Voltage (V)"] + [
        f"{1000 + 10 * x:.3f},{y:.5f},{v:.4f}" for x, y, v in zip(th, t, b, strict=True)
    ]
    f = tmp_path / "adaptive.csv"
    f.write_text("\n".join(lines) + "\n")
    m = tmp_path / "a.json"
    main(["fit", str(f), "--all-samples", "-o", str(m)])
    capsys.readouterr()
    main(["predict", str(m), "--thrust-n", "1", "--voltage-v", "25.09", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert out["inside_supported_region"] is True
