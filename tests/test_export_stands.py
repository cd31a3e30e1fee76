"""Exports of every shared real stand map (../shared/data: xNova, third-party stands) checked
against the firmware's own rules, encoded HERE independently of fitting/export/rules.py:

ArduCopter 4.x pre-arm (libraries/AP_Motors/AP_MotorsMulticopter.cpp, ``arming_checks`` and
``check_mot_pwm_params``), with MOT_SPIN_ARM at its default 0.10:
    if (spin_min > 0.3)            -> "MOT_SPIN_MIN too high"
    if (_spin_arm > spin_min)      -> "MOT_SPIN_ARM > MOT_SPIN_MIN"
    if (_pwm_min < 1 || _pwm_min >= _pwm_max) -> "Check MOT_PWM_MIN and MOT_PWM_MAX"
plus the parameter table's ranges (MOT_THST_EXPO -1..1, MOT_BAT_VOLT_MAX 6..53, _MIN 6..42) and
the wiki's margin (MOT_SPIN_MIN about MOT_SPIN_ARM + 0.03). PX4: THR_MDL_FAC 0..1, MPC_THR_HOVER
0.1..0.8, PWM_MAIN_MINn 800..1400, PWM_MAIN_MAXn 1600..2200 (pwm_out/module.yaml).

Skipped when the shared data is absent.
"""

from __future__ import annotations

import re

import numpy as np
import pytest
from support.stand_maps import shared_data, stand_map, stand_sets

from thrustmap.fitting.export.encodings import ExportOptions
from thrustmap.fitting.export.targets import export_map
from thrustmap.fitting.loaders.load import load_dataset

SPIN_ARM_DEFAULT = 0.10
SPIN_MARGIN = 0.03

NAMES = sorted(stand_sets())
needs_data = pytest.mark.skipif(shared_data() is None, reason="../shared/data is absent")


def _params(text: str, sep: str = ",") -> dict[str, float]:
    out: dict[str, float] = {}
    for line in text.splitlines():
        if line and not line.startswith("#"):
            name, value = line.split(sep)[:2]
            out[name] = float(value)
    return out


def arducopter_prearm(p: dict[str, float]) -> list[str]:
    """ArduCopter's motor pre-arm checks (and parameter ranges) on a loaded .param file."""
    fails = []
    spin_min = p.get("MOT_SPIN_MIN", 0.15)
    spin_arm = p.get("MOT_SPIN_ARM", SPIN_ARM_DEFAULT)
    if spin_min > 0.3:
        fails.append("MOT_SPIN_MIN too high")
    if spin_arm > spin_min:
        fails.append("MOT_SPIN_ARM > MOT_SPIN_MIN")
    pwm_min, pwm_max = p.get("MOT_PWM_MIN", 1000), p.get("MOT_PWM_MAX", 2000)
    if pwm_min < 1 or pwm_min >= pwm_max:
        fails.append("Check MOT_PWM_MIN and MOT_PWM_MAX")
    if not -1 <= p.get("MOT_THST_EXPO", 0.65) <= 1:
        fails.append("MOT_THST_EXPO out of range")
    if not 6 <= p["MOT_BAT_VOLT_MAX"] <= 53 or not 6 <= p["MOT_BAT_VOLT_MIN"] <= 42:
        fails.append("MOT_BAT_VOLT out of range")
    if not p["MOT_BAT_VOLT_MIN"] < p["MOT_BAT_VOLT_MAX"]:
        fails.append("voltage compensation off (MIN >= MAX)")
    return fails


def spinning_share_at_or_above(name: str, command_us: float) -> float:
    """Independent look at the raw samples: the share of samples at or above ``command_us``
    whose rpm (where logged) or thrust shows the motor turning."""
    spinning, total = 0, 0
    for f in stand_sets()[name]:
        d = load_dataset(f)
        sel = d.throttle_native >= command_us
        rest = d.throttle_native <= d.throttle_native.min() + 5
        thrust_on = d.thrust_n[sel] > float(np.mean(d.thrust_n[rest])) + 0.03
        rpm_on = (d.rpm[sel] > 0) if d.rpm is not None else np.zeros(int(sel.sum()), bool)
        spinning += int(np.sum(thrust_on | rpm_on))
        total += int(sel.sum())
    return spinning / max(total, 1)


@needs_data
@pytest.mark.parametrize("name", NAMES)
def test_ardupilot_export_passes_prearm_with_measured_spin_min(name: str) -> None:
    tmap = stand_map(name)
    res = export_map(tmap, "ardupilot")
    p = _params(res.text)
    assert arducopter_prearm(p) == [], res.text
    # above the default MOT_SPIN_ARM by the firmware's margin ...
    assert p["MOT_SPIN_MIN"] >= SPIN_ARM_DEFAULT + SPIN_MARGIN - 1e-9
    # ... and at or above the lowest command where the stand saw reliable thrust
    spin = tmap.spin_up["throttle_pct"]
    if spin is not None:
        assert p["MOT_SPIN_MIN"] * 100 >= spin - 1e-6
        assert p["MOT_SPIN_MIN"] == pytest.approx(max(spin / 100, 0.13), abs=1e-4)
    else:
        assert p["MOT_SPIN_MIN"] == 0.15 and "stand data cannot tell" in res.text
    command = 1000 + 1000 * p["MOT_SPIN_MIN"]
    assert spinning_share_at_or_above(name, command) >= 0.98
    # the residual of ArduPilot's curve against the map is reported, and it is a curve that fits
    assert re.search(r"^# residual: ArduPilot curve vs map .* RMS \d+\.\d+ %", res.text, re.M)
    assert 0 < res.residual["rms_pct"] < 5.0
    assert "# firmware: for ArduCopter 4.x" in res.text
    assert "#   MOT_SPIN_MIN = " in res.text  # the change against the default is listed


@needs_data
@pytest.mark.parametrize("name", NAMES)
def test_px4_aerostack2_c_header_values_inside_documented_ranges(name: str) -> None:
    tmap = stand_map(name)
    mass_kg = 4 * 0.4 * tmap.validity.thrust_n.hi / 9.80665  # hovers at 40 % of the top thrust
    res = export_map(tmap, "px4", ExportOptions(mass_kg=mass_kg))
    p = _params(res.text, "\t")
    rows = {
        k: v
        for k, v in (
            (ln.split("\t")[2], ln.split("\t")[3])
            for ln in res.text.splitlines()
            if ln.startswith("1\t")
        )
    }
    vals = {k: float(v) for k, v in rows.items()}
    assert p  # the header line is a comment; rows start with the vehicle id
    assert 0.0 <= vals["THR_MDL_FAC"] <= 1.0
    assert 0.1 <= vals["MPC_THR_HOVER"] <= 0.8
    for n in range(1, 5):
        assert 800 <= vals[f"PWM_MAIN_MIN{n}"] <= 1400
        assert 1600 <= vals[f"PWM_MAIN_MAX{n}"] <= 2200
    spin = tmap.spin_up["throttle_pct"]
    if spin is not None:  # PX4 idles at PWM_MAIN_MINn: where the motor spins
        assert vals["PWM_MAIN_MIN1"] >= 1000 + 10 * spin - 1e-6
    assert "# firmware: for PX4 v1.14+" in res.text
    as2 = export_map(tmap, "aerostack2")
    lo = float(re.search(r"min_throttle: (\S+)", as2.text).group(1))  # type: ignore[union-attr]
    hi = float(re.search(r"max_throttle: (\S+)", as2.text).group(1))  # type: ignore[union-attr]
    assert 0 <= lo < hi <= 65535
    assert "firmware: for Aerostack2" in as2.text
    header = export_map(tmap, "c-header", ExportOptions(encoding="pwm"))
    assert "firmware: for C99" in header.text
