"""Firmware rules as data, the measured spin-up, and refusals: an export that would break a rule
of its firmware is refused in one line with exit 2 and nothing is written."""

from __future__ import annotations

import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from test_export_encodings import synthetic_map

from thrustmap.core.errors import ConfigError
from thrustmap.core.units import SCALES
from thrustmap.fitting.dataset import Dataset
from thrustmap.fitting.export import rules
from thrustmap.fitting.export.encodings import ExportOptions
from thrustmap.fitting.export.firmware.ardupilot import ardupilot_spin_min
from thrustmap.fitting.export.targets import export_map
from thrustmap.fitting.mapfile import ThrustMap
from thrustmap.fitting.spinup import SpinUp, file_spin_up, spin_up


# -- rules --------------------------------------------------------------------------------------
def test_arducopter_prearm_rules_as_in_the_source() -> None:
    fw = rules.ARDUCOPTER_4
    ok = {"MOT_SPIN_MIN": 0.13, "MOT_PWM_MIN": 1000, "MOT_PWM_MAX": 2000}
    assert fw.violations(ok) == []
    # the bug of issue 19: a fitted MOT_SPIN_MIN below the default MOT_SPIN_ARM 0.10
    bad = fw.violations({"MOT_SPIN_MIN": 0.0063})
    assert len(bad) == 1 and "MOT_SPIN_ARM > MOT_SPIN_MIN" in bad[0]
    assert "MOT_SPIN_MIN too high" in fw.violations({"MOT_SPIN_MIN": 0.31})[0]
    assert "Check MOT_PWM_MIN" in fw.violations({"MOT_PWM_MIN": 2000, "MOT_PWM_MAX": 2000})[0]
    assert "Check MOT_PWM_MIN" in fw.violations({"MOT_PWM_MIN": 0})[0]
    assert fw.violations({"MOT_THST_EXPO": 1.2})[0].startswith("MOT_THST_EXPO = 1.2 is outside")
    assert fw.violations({"MOT_BAT_VOLT_MAX": 0.0}) == []  # 0 = compensation disabled
    assert fw.violations({"MOT_BAT_VOLT_MAX": 4.2})  # a 1S pack: outside 6..53
    assert "silently off" in fw.violations({"MOT_BAT_VOLT_MAX": 22, "MOT_BAT_VOLT_MIN": 23})[-1]
    assert fw.violations({"MOT_PWM_MIN": 1100.5})[0].endswith("must be a whole number")


def test_spin_min_from_data_with_the_firmware_margin() -> None:
    fw = rules.ARDUCOPTER_4
    assert ardupilot_spin_min(None, fw) == 0.15  # cannot tell: the default
    assert ardupilot_spin_min(0.05, fw) == pytest.approx(0.13)  # SPIN_ARM 0.10 + 0.03
    assert ardupilot_spin_min(0.14321, fw) == pytest.approx(0.1433)  # rounded up, never down
    assert ardupilot_spin_min(0.31, fw) > 0.3  # refused later by the pre-arm rule


def test_versions_choose_names_and_unknown_versions_are_refused() -> None:
    assert rules.betaflight_rules("4.5.5") is rules.BETAFLIGHT_45
    assert rules.betaflight_rules("4.6") is rules.BETAFLIGHT_46
    assert rules.betaflight_rules("2025.12.1") is rules.BETAFLIGHT_46
    assert rules.betaflight_rules("2026.6") is rules.BETAFLIGHT_2026
    for bad in ("3.5", "4.4", "2027.1", "four"):
        with pytest.raises(ConfigError):
            rules.betaflight_rules(bad)
    assert rules.px4_rules(None) is rules.PX4_114
    assert rules.px4_rules("1.13.3") is rules.PX4_113
    assert rules.BETAFLIGHT_46.param("motor_idle").default == 550
    assert rules.PX4_114.param("PWM_MAIN_MIN3").lo == 800
    with pytest.raises(ConfigError):
        rules.ardupilot_rules("3.6")
    # 4.6 PWM: the low end min_command + motor_idle / 10 must stay below max_throttle
    assert rules.BETAFLIGHT_46.violations({"motor_idle": 2000, "max_throttle": 1150})


def test_changes_list_values_against_defaults() -> None:
    lines = rules.ARDUCOPTER_4.changes({"MOT_SPIN_MIN": 0.13, "MOT_SPIN_MAX": 0.95})
    assert lines[0] == "MOT_SPIN_MIN = 0.13 of MOT_PWM_MIN..MAX (default 0.15: -0.02)"
    assert lines[1].endswith("(the default)")


# -- spin-up from raw samples -------------------------------------------------------------------
def _stand(
    cmds_us: list[float], spin_from_us: float, *, rpm: bool = True, glitch_us: float | None = None
) -> Dataset:
    """Steps of 40 samples each, 10 us apart from 1000: thrust and rpm start at ``spin_from_us``;
    stand noise 3 mN at rest."""
    rng = np.random.default_rng(1)
    c = np.repeat(np.asarray(cmds_us, float), 40)
    on = c >= spin_from_us
    thrust = np.where(on, 0.3 + 0.01 * (c - spin_from_us), 0.02) + rng.normal(0, 0.003, c.size)
    speed = np.where(on, 1500 + 10 * (c - spin_from_us), 0.0)
    if glitch_us is not None:  # one row logged mid-change, motor not yet turning
        c = np.append(c, glitch_us)
        thrust = np.append(thrust, 0.02)
        speed = np.append(speed, 0.0)
    n = c.size
    return Dataset(
        path="synthetic.csv", format="test", throttle_scale=SCALES["pwm"], throttle_native=c,
        thrust_n=thrust, voltage_v=np.full(n, 16.0), line=np.arange(1, n + 1),
        time_s=np.arange(n) * 0.1, rpm=speed if rpm else None,
    )  # fmt: skip


def test_spin_up_is_the_lowest_command_spinning_in_every_sweep() -> None:
    cmds = [1000.0, *np.arange(1050.0, 1400.0, 10.0)]
    d = _stand(cmds, 1120.0)
    assert file_spin_up(d)["throttle_pct"] == pytest.approx(12.0)
    # thrust alone tells the same when the file starts at the stop command
    assert file_spin_up(_stand(cmds, 1120.0, rpm=False))["throttle_pct"] == pytest.approx(12.0)
    # a lone row logged while the command changed does not move it
    assert file_spin_up(_stand(cmds, 1120.0, glitch_us=1300.0))["throttle_pct"] == pytest.approx(
        12.0
    )
    # two sweeps: the one that spins later decides
    both = spin_up([d, _stand(cmds, 1160.0)])
    assert both.throttle_pct == pytest.approx(16.0)
    assert "highest over 2 file(s)" in both.reason


def test_each_sweep_has_its_own_rest_level() -> None:
    # one file, two sweeps recorded with different load-cell tares (a re-saved concatenation):
    # the second sweep's rest reads 0.3 N; noise is measured against each sweep's own rest
    cmds = [1000.0, *np.arange(1050.0, 1400.0, 10.0)]
    a, b = _stand(cmds, 1120.0, rpm=False), _stand(cmds, 1120.0, rpm=False)
    both = replace(
        a,
        throttle_native=np.concatenate([a.throttle_native, b.throttle_native]),
        thrust_n=np.concatenate([a.thrust_n, b.thrust_n + 0.3]),
        voltage_v=np.concatenate([a.voltage_v, b.voltage_v]),
        line=np.arange(1, 2 * len(a) + 1),
        time_s=np.arange(2 * len(a)) * 0.1,
    )
    r = file_spin_up(both)
    assert r["sweeps"] == 2 and r["throttle_pct"] == pytest.approx(12.0)


def test_a_dithering_command_is_bounded_work() -> None:
    n = 200_000
    rng = np.random.default_rng(3)
    c = np.where(rng.random(n) < 0.5, 1000.0, 1000.0 + rng.random(n) * 900)
    thrust = np.where(c > 1100, (c - 1100) / 100, 0.0) + rng.normal(0, 0.01, n)
    d = Dataset(
        path="dither.csv", format="test", throttle_scale=SCALES["pwm"], throttle_native=c,
        thrust_n=thrust, voltage_v=np.full(n, 16.0), line=np.arange(1, n + 1),
        time_s=np.arange(n) * 0.01,
    )  # fmt: skip
    r = file_spin_up(d)
    assert "taken as one" in r["note"] and 10.0 < r["throttle_pct"] < 12.0


def test_spin_up_cannot_tell_without_low_throttle_points() -> None:
    cmds = list(np.arange(1200.0, 1500.0, 10.0))
    r = file_spin_up(_stand(cmds, 1100.0))  # lowest command already spins (rpm)
    assert r["throttle_pct"] is None and "already spins" in r["reason"]
    r = file_spin_up(_stand(cmds, 1100.0, rpm=False))  # thrust only, no stop-command samples
    assert r["throttle_pct"] is None and "no sample at the stop command" in r["reason"]
    s = spin_up([_stand(cmds, 1100.0)])
    assert s.throttle_pct is None and s.reason.startswith("the stand data cannot tell")


def test_spin_up_block_round_trips_through_the_map_file(tmp_path: Path) -> None:
    block = spin_up([_stand([1000.0, *np.arange(1050.0, 1400.0, 10.0)], 1120.0)]).to_dict()
    tmap = replace(synthetic_map("motor"), spin_up=block)
    path = tmp_path / "map.json"
    tmap.save(path)
    back = ThrustMap.load(path)
    assert back.spin_up == block
    got = SpinUp.from_dict(back.spin_up)
    assert got is not None and got.throttle_pct == pytest.approx(12.0)
    assert "spin_up" not in synthetic_map("motor").to_dict()  # old maps keep their bytes


# -- exports use it, and refuse what their firmware refuses --------------------------------------
def test_ardupilot_without_spin_up_keeps_the_default_and_says_so() -> None:
    res = export_map(synthetic_map("motor"), "ardupilot")
    assert res.values["MOT_SPIN_MIN"] == 0.15
    assert "MOT_SPIN_MIN kept at the firmware default 0.15" in res.text
    assert "stand data cannot tell" in res.text


def test_betaflight_idle_and_px4_minimum_follow_the_spin_up() -> None:
    tmap = replace(synthetic_map("motor"), spin_up={"throttle_pct": 9.0})
    bf = export_map(tmap, "betaflight", ExportOptions(firmware="4.6"))
    assert "set motor_idle = 900\n" in bf.text  # 9 % of the DShot range, above the 5.5 % default
    bf_pwm = export_map(tmap, "betaflight", ExportOptions(firmware="4.5", encoding="pwm"))
    assert "set min_throttle = 1090\n" in bf_pwm.text
    px4 = export_map(tmap, "px4")
    assert "1\t1\tPWM_MAIN_MIN1\t1090\t6\n" in px4.text
    assert "PWM minimum raised from 1000 to 1090" in px4.text


CASES = [
    (["--to", "ardupilot", "--range", "1000:2100"], "MOT_PWM_MAX = 2100 is outside"),
    (["--to", "ardupilot", "--mass-kg", "8"], "MOT_THST_HOVER = 0.8499 is outside its range"),
    (["--to", "ardupilot", "--mass-kg", "40"], "grams typed as kilograms, or the wrong map?"),
    (["--to", "px4", "--range", "1100:2300"], "PWM_MAIN_MAX1 = 2300 is outside"),
    (["--to", "px4", "--range", "1050:2000"], "below 1087, the lowest command the stand saw"),
    (["--to", "betaflight", "--firmware", "3.5"], "knows the rules of 4.5, 4.6"),
    (
        ["--to", "betaflight", "--firmware", "4.6", "--range", "60:2047"],
        "is below 221.913, the lowest command",
    ),
]


@pytest.mark.parametrize(("args", "expected"), CASES)
def test_refusals_are_one_line_exit_2_and_write_nothing(
    tmp_path: Path, args: list[str], expected: str
) -> None:
    path = tmp_path / "map.json"
    replace(synthetic_map("motor"), spin_up={"throttle_pct": 8.7}).save(path)
    out = tmp_path / "out.txt"
    res = _thrustmap("export", str(path), *args, "-o", str(out))
    assert res.returncode == 2, res.stderr
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and expected in lines[0], res.stderr
    assert not out.exists() and res.stdout == ""


def test_spin_up_above_the_prearm_limit_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "map.json"
    replace(synthetic_map("motor"), spin_up={"throttle_pct": 35.0}).save(path)
    res = _thrustmap("export", str(path), "--to", "ardupilot")
    assert res.returncode == 2 and res.stdout == ""
    assert "MOT_SPIN_MIN too high" in res.stderr and "MOT_SPIN_MIN = 0.35" in res.stderr


def _thrustmap(*args: str) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]))
    return subprocess.run(
        [sys.executable, "-m", "thrustmap", *args],
        env=env, capture_output=True, text=True, timeout=60,
    )  # fmt: skip
