"""Exact rescaling of maps into every throttle encoding, the export text, and bad requests."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from thrustmap.cli import cli
from thrustmap.core.errors import ConfigError
from thrustmap.core.units import SCALES
from thrustmap.fitting.export.encoding_yaml import export_encoding
from thrustmap.fitting.export.encodings import (
    ExportOptions,
    rescale,
    target_scale,
    to_percent,
)
from thrustmap.fitting.export.targets import export_map
from thrustmap.fitting.mapfile import Box, GammaCorrection, ThrustMap, ValidityBox
from thrustmap.fitting.models import MODELS
from thrustmap.fitting.names import ENCODINGS


def synthetic_map(model: str = "poly2", gamma: bool = False, native: str = "pwm") -> ThrustMap:
    """A map fitted on a physics-shaped surface over a 6S discharge (21..25.2 V)."""
    rng = np.random.default_rng(7)
    t = rng.uniform(0.3, 10.0, 300)
    b = rng.uniform(21.0, 25.2, 300)
    th = 2.0 + (150.0 + 300.0 * np.sqrt(t) + 40.0 * t) / b
    coef = MODELS[model].fit(t, b, th, "l2")
    corr = GammaCorrection((3.0, -0.17, 0.0035), Box(21.5, 25.0)) if gamma else None
    return ThrustMap(
        model=model,
        coefficients=tuple(float(c) for c in coef),
        throttle_scale=SCALES[native],
        validity=ValidityBox(Box(0.3, 10.0), Box(21.0, 25.2), Box(16.0, 72.0)),
        correction=corr,
    )


GRID_T, GRID_B = (
    a.ravel() for a in np.meshgrid(np.linspace(0.3, 10, 23), np.linspace(21, 25.2, 7))
)

CASES = [
    ("poly2", False),
    ("poly3", True),
    ("poly3-trunc", False),
    ("motor", True),
    ("la", False),
    ("linear", True),
]


@pytest.mark.parametrize("encoding", ENCODINGS)
@pytest.mark.parametrize(("model", "gamma"), CASES)
def test_exported_coefficients_equal_map_then_convert(
    encoding: str, model: str, gamma: bool
) -> None:
    tmap = synthetic_map(model, gamma)
    scale = SCALES[encoding]
    enc = rescale(tmap, scale)
    via_coefficients = enc.evaluate(GRID_T, GRID_B)
    map_then_convert = scale.from_pct(tmap.throttle_pct(GRID_T, GRID_B))
    np.testing.assert_allclose(
        via_coefficients, map_then_convert, rtol=1e-9, atol=1e-9 * scale.span
    )
    # and back: the percent coefficients come back (round trip)
    np.testing.assert_allclose(to_percent(enc), tmap.coefficients, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("encoding", ENCODINGS)
def test_export_text_carries_the_exact_coefficients(encoding: str) -> None:
    tmap = synthetic_map("poly3", gamma=True)
    # the 6S map is refused for the 1S Crazyflie (test_export_platform_checks); its encodings'
    # arithmetic is checked through the encoding export itself
    res = export_encoding(tmap, SCALES[encoding], ExportOptions(rotors=4))
    text = res.text
    coefs = json.loads(re.search(r"^coefficients: (\[.*\])$", text, re.M).group(1))  # type: ignore[union-attr]
    offset = float(re.search(r"^offset: (.*)$", text, re.M).group(1))  # type: ignore[union-attr]
    scale = SCALES[encoding]
    design = MODELS["poly3"].design(tmap.correction.gamma(GRID_B) * GRID_T, GRID_B)  # type: ignore[union-attr]
    from_text = offset + design @ np.array(coefs)
    expected = scale.from_pct(tmap.throttle_pct(GRID_T, GRID_B))
    np.testing.assert_allclose(from_text, expected, rtol=1e-9, atol=1e-9 * scale.span)
    assert "validity box: thrust 0.3..10 N per rotor, voltage 21..25.2 V" in text
    assert "map file sha256:" in text and "residual: 0 (exact affine" in text


def test_custom_range_pwm_endpoints() -> None:
    tmap = synthetic_map("motor")
    scale = target_scale("pwm", (1100.0, 1940.0))
    enc = rescale(tmap, scale)
    pct = tmap.throttle_pct(GRID_T, GRID_B)
    np.testing.assert_allclose(enc.evaluate(GRID_T, GRID_B), 1100 + pct / 100 * 840, rtol=1e-12)


def test_la_map_keeps_an_offset_because_it_has_no_constant_term() -> None:
    tmap = synthetic_map("la")
    enc = rescale(tmap, SCALES["dshot"])
    assert enc.offset == 48.0
    assert enc.coefficients[0] == pytest.approx(tmap.coefficients[0] * 1999 / 100, rel=1e-15)


def test_crazyflie_export_has_seed2_block() -> None:
    res = export_encoding(synthetic_map("poly2"), SCALES["crazyflie-cmd"], ExportOptions(rotors=4))
    assert "seed2_linearisation:" in res.text
    assert re.search(r"f_max_g: [0-9.e+-]+ +# the polynomial at u = 60000", res.text)


@pytest.mark.parametrize(
    ("target", "opts", "message"),
    [
        ("pwm", ExportOptions(range_=(2000.0, 1000.0)), "LO < HI"),
        ("pwm", ExportOptions(range_=(1500.0, 1500.0)), "LO < HI"),
        ("sbus", ExportOptions(), "unknown export target 'sbus'"),
        ("ardupilot", ExportOptions(), "has no voltage term"),
        ("px4", ExportOptions(voltage_v=30.0), "outside the map's voltage box"),
        ("betaflight", ExportOptions(), "needs --firmware"),
        ("c-header", ExportOptions(encoding="sbus"), "unknown encoding 'sbus'"),
        ("pwm", ExportOptions(encoding="dshot"), "conflicts"),
    ],
)
def test_bad_requests_are_config_errors(target: str, opts: ExportOptions, message: str) -> None:
    tmap = synthetic_map("linear") if target == "ardupilot" else synthetic_map("poly2")
    with pytest.raises(ConfigError, match=message):
        export_map(tmap, target, opts)


def test_single_voltage_map_refused_for_voltage_compensation() -> None:
    tmap = synthetic_map("poly2")
    from dataclasses import replace

    flat = replace(tmap, validity=ValidityBox(Box(0.3, 10.0), Box(24.0, 24.0), Box(16.0, 72.0)))
    with pytest.raises(ConfigError, match="one voltage"):
        export_map(flat, "ardupilot")


# -- CLI ----------------------------------------------------------------------------------------
def _run(args: list[str]) -> tuple[int, str, str]:
    res = CliRunner().invoke(cli, args, catch_exceptions=True)
    err = repr(res.exception) if res.exception is not None else ""
    return res.exit_code, res.output, err


def test_cli_writes_export_with_file_hash(tmp_path: Path) -> None:
    path = tmp_path / "m.json"
    synthetic_map("poly2", gamma=True).save(path)
    out = tmp_path / "m.yaml"
    code, _, err = _run(
        ["export", str(path), "--to", "oneshot125", "--range", "125:250", "-o", str(out)]
    )
    assert code == 0, err
    text = out.read_text()
    loaded = ThrustMap.load(path)
    assert f"map file sha256: {loaded.file_sha256}" in text
    assert "encoding: oneshot125" in text


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--to", "pwm", "--range", "2000:1000"], "expected LO < HI"),
        (["--to", "warp-drive"], "unknown target 'warp-drive'"),
        (["--to", "ardupilot"], "has no voltage term"),
    ],
)
def test_cli_bad_requests_are_one_line_errors(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: list[str], message: str
) -> None:
    path = tmp_path / "m.json"
    synthetic_map("linear").save(path)
    from thrustmap.cli import main

    with pytest.raises(SystemExit) as exc:
        main(["export", str(path), *extra])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: ") and message in err
