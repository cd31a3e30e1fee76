"""γ(B) never makes the map worse: in every voltage bin with 20+ Df samples the corrected map
is no worse than the uncorrected one, or the output says which bin, by how much, and what was
kept instead."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from thrustmap.cli import main
from thrustmap.cli.flight import flightlog_group, gamma_group
from thrustmap.fitting.gamma import MIN_BIN_SAMPLES, GammaFit, GammaOptions, fit_gamma, worse_bins


def falling(seed: int, n: int = 1000, noise: float = 0.03) -> pd.DataFrame:
    """One flight down a 3S battery: fast at first, then a long stretch near the bottom (as a
    real log), with γ falling 4 % over the flown 1.1 V."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.5
    b = 10.3 + 1.1 * np.exp(-t / 60.0) + rng.normal(0, 0.02, n)
    g = 1.012 + 0.04 * (11.4 - b) / 1.1 + rng.normal(0, noise, n)
    force = np.full(n, 11.8)
    return pd.DataFrame({"flight": "f#0", "time_s": t, "voltage_v": b, "force_n": force,
                         "thrust_cmd_n": g * force})  # fmt: skip


def flat(seed: int, n: int = 600) -> pd.DataFrame:
    """γ = 1 plus noise: the map is right, no correction can help."""
    rng = np.random.default_rng(seed)
    b = np.linspace(11.4, 10.3, n)
    force = np.full(n, 11.8)
    return pd.DataFrame({"flight": "f#0", "time_s": np.arange(n) * 0.5, "voltage_v": b,
                         "force_n": force,
                         "thrust_cmd_n": (1.0 + rng.normal(0, 0.03, n)) * force})  # fmt: skip


def assert_no_worse_or_said(fit: GammaFit) -> None:
    """Every populated bin is no worse after γ, or the fit says which bin and by how much."""
    worse = worse_bins(fit.metrics)
    text = " ".join(fit.warnings)
    for w in worse:
        assert f"{w['voltage_v'][0]:.2f}..{w['voltage_v'][1]:.2f} V" in text, (w, text)
        assert f"{w['before_pct']:.3f} → {w['after_pct']:.3f} %" in text


@pytest.mark.parametrize("seed", range(8))
def test_automatic_gamma_is_never_worse_in_a_populated_bin(seed: int) -> None:
    fit = fit_gamma(falling(seed), {}, None)
    assert worse_bins(fit.metrics) == []
    for row in fit.metrics["by_voltage"]:
        if row["samples"] >= MIN_BIN_SAMPLES:
            assert row["e_T_after_pct"]["mean"] <= row["e_T_before_pct"]["mean"]
    assert fit.to_dict()["no_worse_check"]["min_bin_samples"] == MIN_BIN_SAMPLES


def test_the_held_out_choice_is_replaced_when_it_is_worse_somewhere() -> None:
    """Seed 3: the one-standard-error rule picks a constant γ, which over-corrects the top
    voltage bins; the linear γ is kept and the output names the bins and the numbers."""
    fit = fit_gamma(falling(3), {}, None)
    rejected = fit.guard["rejected"]
    assert [r["degree"] for r in rejected] == [0]
    assert fit.degree == 1 and fit.corrected
    bins = rejected[0]["worse"]
    assert bins and all(b["samples"] >= MIN_BIN_SAMPLES for b in bins)
    assert all(b["after_pct"] > b["before_pct"] for b in bins)
    note = next(w for w in fit.warnings if "not used" in w)
    assert note.startswith("degree 0 (the held-out choice) not used: corrected map worse")
    b0 = bins[-1]
    assert f"e_T {b0['before_pct']:.3f} → {b0['after_pct']:.3f} %" in note
    assert "kept degree 1" in note
    # per-bin errors of the rejected degree are kept for the report's figure
    assert len(rejected[0]["by_voltage_after"]) == len(fit.metrics["by_voltage"])


def test_a_requested_degree_is_kept_but_its_worse_bins_are_said() -> None:
    fit = fit_gamma(falling(3), {}, None, GammaOptions(degree=0))
    assert fit.degree == 0 and len(fit.correction.coefficients) == 1
    assert worse_bins(fit.metrics)  # it is worse at the top ...
    assert any(
        w.startswith("the requested degree-0 γ(B) makes the map worse") for w in fit.warnings
    )
    assert_no_worse_or_said(fit)  # ... and says where


def test_uncorrected_map_kept_when_every_gamma_is_worse_somewhere() -> None:
    """γ = 1 plus noise: each fitted curve is a little worse in some bin; γ = 1 is kept."""
    fit = fit_gamma(flat(0), {}, None)
    assert not fit.corrected and fit.correction.coefficients == (1.0,)
    assert fit.guard["kept"] == "γ = 1 (none)"
    assert {r["degree"] for r in fit.guard["rejected"]} == {0, 1, 2, 3}
    assert any("kept the uncorrected map (γ = 1)" in w for w in fit.warnings)
    for row in fit.metrics["by_voltage"]:  # γ = 1: after is before
        assert row["e_T_after_pct"]["mean"] == pytest.approx(row["e_T_before_pct"]["mean"])


# -- the shared real logs, end to end through the CLI as the README describes ---------------------

STRAWSON = "third-party-stands/strawson-5inch"


def _end_to_end(
    shared_data: Path, tmp_path: Path, log: str, motor: str, mass_kg: str
) -> tuple[dict, str]:
    stand = shared_data / STRAWSON
    files = [stand / f"{motor}_7.csv", stand / f"{motor}_11.csv"]
    if not all(f.is_file() for f in files) or not (shared_data / "flightlogs" / log).is_file():
        pytest.skip("shared stand or flight log absent")
    map_path = tmp_path / "map.json"
    main(["fit", *map(str, files), "-o", str(map_path)])
    df = tmp_path / "df.csv"
    runner = CliRunner()
    res = runner.invoke(
        flightlog_group,
        [
            "extract",
            str(shared_data / "flightlogs" / log),
            "--mass-kg",
            mass_kg,
            "--map",
            str(map_path),
            "-o",
            str(df),
        ],  # fmt: skip
    )
    assert res.exit_code == 0, res.output
    text = runner.invoke(gamma_group, ["fit", str(df), "--map", str(map_path), "-o",
                                       str(tmp_path / "c.json")])  # fmt: skip
    assert text.exit_code == 0, text.output
    res = runner.invoke(gamma_group, ["fit", str(df), "--map", str(map_path), "-o",
                                      str(tmp_path / "c.json"), "--json"])  # fmt: skip
    assert res.exit_code == 0, res.output
    return json.loads(res.stdout), text.output


def _check_bins(fit: dict, output: str) -> None:
    populated = [r for r in fit["metrics"]["by_voltage"] if r["samples"] >= MIN_BIN_SAMPLES]
    if not populated:  # nothing to judge: the output must say so, not claim a pass
        assert "no voltage bin has 20+ samples, so none could be judged" in output
        return
    for r in populated:
        before, after = r["e_Th_before_pct"]["mean"], r["e_Th_after_pct"]["mean"]
        if after > before:  # allowed only when the output names the bin and the numbers
            lo, hi = r["voltage_v"]
            assert re.search(rf"{lo:.2f}\.\.{hi:.2f} V .*{before:.3f} → {after:.3f} %", output)
    assert "no-worse check (e_Th, bins with 20+ samples)" in output


@pytest.mark.parametrize("motor", ["a4", "a1", "b1"])
def test_ardupilot_log_gamma_no_worse(shared_data: Path, tmp_path: Path, motor: str) -> None:
    fit, output = _end_to_end(shared_data, tmp_path, "ardupilot/copter3.4_pxf_3s.bin", motor, "1.2")
    _check_bins(fit, output)
    if motor == "a4":  # the case: a constant γ over-corrected the top voltage bins
        assert fit["corrected"] is True
        assert "no-worse check: degree 0 makes e_Th worse at" in output


@pytest.mark.parametrize("motor", ["a4", "b1"])
def test_betaflight_log_gamma_no_worse(shared_data: Path, tmp_path: Path, motor: str) -> None:
    fit, output = _end_to_end(shared_data, tmp_path, "betaflight/bf4.2.8_4s.bbl", motor, "0.6")
    _check_bins(fit, output)


def test_errors_by_voltage_figure_shows_both_maps_and_the_rejected_degree() -> None:
    from types import SimpleNamespace

    from thrustmap.report.data import GammaData
    from thrustmap.report.figures import errors_by_voltage

    fit = fit_gamma(falling(3), {}, None)
    c = fit.correction
    g = GammaData(c.coefficients, (c.voltage_v.lo, c.voltage_v.hi), c.loss, dict(c.metrics), [])
    fig = errors_by_voltage(SimpleNamespace(gamma=g))  # type: ignore[arg-type]
    _, ax_t = fig.axes
    labels = ax_t.get_legend_handles_labels()[1]
    assert "map (uncorrected)" in labels and "map + γ(B), degree 1" in labels
    assert "degree 0 (not kept: worse in 2 bins)" in labels
    rejected = next(ln for ln in ax_t.get_lines() if ln.get_label().startswith("degree 0"))
    assert np.allclose(rejected.get_ydata(), fit.guard["rejected"][0]["by_voltage_after"])
