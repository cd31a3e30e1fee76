"""Map files: non-finite numbers and malformed boxes are rejected where they enter, naming the
field (issue 14 item 7); a map is never written with NaN."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from thrustmap.cli import main
from thrustmap.core.errors import DataFormatError, FitError
from thrustmap.core.units import SCALES
from thrustmap.fitting.mapfile import Box, GammaCorrection, ThrustMap, ValidityBox
from thrustmap.fitting.models import MODELS


def good_map(gamma: bool = True) -> ThrustMap:
    t = np.linspace(0.2, 8.0, 40)
    b = np.linspace(21.0, 25.0, 40)
    th = 5 + (60 * np.sqrt(t) + 20 * t) / b * 10
    coef = MODELS["motor"].fit(t, b, th, "l2")
    corr = GammaCorrection((1.1, -0.004), Box(21.0, 25.0)) if gamma else None
    return ThrustMap(
        "motor",
        tuple(float(c) for c in coef),
        SCALES["pwm"],
        ValidityBox(Box(0.2, 8.0), Box(21.0, 25.0), Box(10.0, 90.0)),
        correction=corr,
    )


def doc() -> dict[str, Any]:
    out: dict[str, Any] = good_map().to_dict()
    return out


def test_a_good_map_round_trips(tmp_path: Path) -> None:
    p = tmp_path / "m.json"
    good_map().save(p)
    back = ThrustMap.load(p)
    assert back.coefficients == good_map().coefficients
    assert back.correction is not None and back.correction.coefficients == (1.1, -0.004)
    assert len(back.file_sha256) == 64


def _set(d: dict[str, Any], path: str, value: Any) -> None:
    keys = path.split(".")
    for k in keys[:-1]:
        d = d[k]
    d[keys[-1]] = value


@pytest.mark.parametrize(
    ("path", "value", "field"),
    [
        ("coefficients", [1.0, float("nan"), 3.0, 4.0], "coefficients"),
        ("coefficients", [1.0, 2.0, float("inf"), 4.0], "coefficients"),
        ("coefficients", [1.0, 2.0], "coefficients"),
        ("validity.voltage_v", [25.0, 21.0], "validity.voltage_v"),
        ("validity.thrust_n", [float("nan"), 8.0], "validity.thrust_n"),
        ("validity.voltage_v", [0.0, 25.0], "validity.voltage_v"),
        ("validity.throttle_pct", [90.0, 10.0], "validity.throttle_pct"),
        ("correction.coefficients", [float("nan"), 0.0], "correction.coefficients"),
        ("correction.voltage_v", [25.0, 21.0], "correction.voltage_v"),
        ("model", "nosuch", "model"),
        ("interval", {"half_width_pct": float("nan"), "growth_per_span": 1.0}, "interval"),
    ],
)
def test_bad_numbers_are_rejected_naming_the_field(path: str, value: Any, field: str) -> None:
    d = doc()
    _set(d, path, value)
    with pytest.raises(DataFormatError, match=f"field '{field}"):
        ThrustMap.from_dict(d, source="m.json")


@pytest.mark.parametrize("token", ["NaN", "Infinity", "-Infinity", "1e999"])
def test_map_files_with_non_finite_tokens_fail_in_one_line(
    tmp_path: Path, token: str, capsys: pytest.CaptureFixture[str]
) -> None:
    d = doc()
    text = json.dumps(d, indent=2).replace(json.dumps(d["coefficients"][0]), token, 1)
    p = tmp_path / "m.json"
    p.write_text(text)
    with pytest.raises(DataFormatError):
        ThrustMap.load(p)
    with pytest.raises(SystemExit) as exc:
        main(["predict", str(p), "--thrust-n", "2", "--voltage-v", "23"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and str(p) in err
    with pytest.raises(SystemExit) as exc:
        main(["export", str(p), "--to", "c-header"])
    assert exc.value.code == 2


def test_reversed_box_in_a_file_fails_through_the_cli(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    d = doc()
    d["validity"]["voltage_v"] = [25.0, 21.0]
    p = tmp_path / "m.json"
    p.write_text(json.dumps(d))
    with pytest.raises(SystemExit) as exc:
        main(["predict", str(p), "--thrust-n", "2", "--voltage-v", "23"])
    assert exc.value.code == 2
    assert "validity.voltage_v" in capsys.readouterr().err


def test_a_map_with_nan_is_never_written(tmp_path: Path) -> None:
    m = good_map()
    bad = ThrustMap(
        m.model,
        (m.coefficients[0], math.nan, *m.coefficients[2:]),
        m.throttle_scale,
        m.validity,
    )
    with pytest.raises(FitError, match="coefficients"):
        bad.save(tmp_path / "bad.json")
    assert not (tmp_path / "bad.json").exists()
    bad_gamma = m.with_correction(GammaCorrection((math.nan,), Box(21.0, 25.0)))
    with pytest.raises(FitError, match="correction.coefficients"):
        bad_gamma.dumps()


def _region_doc() -> dict[str, Any]:
    d = doc()
    d["supported_region"] = {
        "voltage_v": [21.0, 23.0, 25.0],
        "thrust_lo_n": [0.0, 0.0, 0.1],
        "thrust_hi_n": [6.0, 8.0, 9.0],
        "voltage_lo_v": 21.0,
        "voltage_hi_v": 25.0,
    }
    d["interval"] = {
        "half_width_pct": 1.0,
        "growth_per_span": 1.0,
        "parameter_covariance": [[0.0] * 4 for _ in range(4)],
    }
    return d


def test_supported_region_round_trips_and_decides_validity() -> None:
    tmap = ThrustMap.from_dict(_region_doc(), source="m.json")
    assert tmap.supported is not None
    assert bool(tmap.in_box(7.0, 24.0)) and not bool(tmap.in_box(7.0, 21.5))
    back = ThrustMap.from_dict(json.loads(tmap.dumps()), source="m.json")
    assert back.supported == tmap.supported


@pytest.mark.parametrize(
    ("path", "value", "field"),
    [
        ("supported_region.voltage_v", [25.0, 23.0, 21.0], "supported_region.voltage_v"),
        ("supported_region.thrust_hi_n", [6.0, 8.0], "supported_region.voltage_v"),
        ("supported_region.thrust_lo_n", [7.0, 0.0, 0.1], "supported_region.thrust_lo_n"),
        ("supported_region.voltage_hi_v", float("nan"), "supported_region.voltage_hi_v"),
        ("interval.parameter_covariance", [[1.0, 2.0]] * 4, "interval.parameter_covariance"),
        ("interval.parameter_covariance", [[0.0] * 3] * 3, "interval"),
        ("interval.parameter_covariance", [[float("nan")] * 4] * 4, "interval.parameter_cov"),
    ],
)
def test_bad_regions_and_covariances_are_rejected_naming_the_field(
    path: str, value: Any, field: str
) -> None:
    d = _region_doc()
    _set(d, path, value)
    with pytest.raises(DataFormatError, match=f"field '{field}"):
        ThrustMap.from_dict(d, source="m.json")
