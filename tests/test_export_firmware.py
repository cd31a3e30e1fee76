"""Firmware exports against the firmware's OWN numbers, not our formulas: every expected value
below was computed by hand from the firmware's source at a pinned version (its formula and
constants, in the firmware's float32 arithmetic), and is written here as a literal. A wrong
formula in ``thrustmap.fitting.export.firmware`` fails these; our own functions never produce
the expected values. Sources (file and line at the pinned commit):

- PX4-Autopilot 15c4f0887da95b50c9b17e2a64dabe42dbd7a683,
  src/lib/mixer_module/functions/FunctionMotors.hpp:81-99 (``updateValues``): with
  a = THR_MDL_FAC, b = 1 - a, the motor output for a relative thrust ``control`` is
  x = -b/(2a) + sqrt(b²/(4a²) + control/a), the inverse of rel_thrust = a·x² + b·x (line 85).
- ArduPilot 04dc0b71a37d744b653ff93ac4d02f8e0487a101,
  libraries/AP_Motors/AP_Motors_Thrust_Linearization.cpp: defaults MOT_THST_EXPO 0.65,
  MOT_SPIN_MIN 0.15, MOT_SPIN_MAX 0.95 (lines 28-30); MOT_BAT_VOLT_MAX "Recommend 4.2 * cell
  count", range 6..53 (lines 71-77), MOT_BAT_VOLT_MIN "Recommend 3.3 * cell count", range 6..42
  (lines 79-85); ``thrust_to_actuator`` (104-108), ``apply_thrust_curve_and_volt_scaling``
  (119-133), ``update_lift_max_from_batt_voltage`` (156-186: off when MAX <= 0, MIN >= MAX or the
  voltage is below MIN/4; MIN raised to 0.6·MAX; the ratio V/MAX clamped; lift_max = r·(1 − e) +
  e·r²). thrust_in is the demand already multiplied by ``get_compensation_gain`` = 1/lift_max
  (189-196), so thrust_in = T / (K·lift_max) for a thrust T and full lift K.
- Betaflight, src/main/flight/pid.c ``pidApplyThrustLinearization`` applied to the mixer output
  before it is scaled onto motorOutputMin..Max (mixer.c ``applyMixToMotors``):
  4.5.5 (4adbd3ef) pid.c:338-342 and 2025.12.5 = 4.6 (7348054f) pid.c:517-521:
  out = x·(1 + e·(1 − x)²); 2026.6.1 (6dbc4218) pid.c:509-515: inv = 1 − x,
  out = x·(1 + e·inv·(1 + e·(inv − x))); e = thrust_linear / 100 (pid_init.c: 4.5.5:392,
  2025.12.5:525, 2026.6.1:492), thrust_linear 0..150 (cli/settings.c 4.5.5:1210,
  2025.12.5:1348, 2026.6.1:1322).
"""

from __future__ import annotations

import re
from dataclasses import replace

import numpy as np
import pytest
from test_export_encodings import synthetic_map

import thrustmap.fitting.export.firmware.ardupilot as ardupilot
import thrustmap.fitting.export.firmware.betaflight as betaflight
import thrustmap.fitting.export.firmware.px4 as px4
from thrustmap.core.units import SCALES
from thrustmap.fitting.export import platforms as plat
from thrustmap.fitting.export.encodings import ExportOptions
from thrustmap.fitting.export.rules import ARDUCOPTER_4, ARDUPILOT_CELL_V, BETAFLIGHT_46
from thrustmap.fitting.export.targets import export_map
from thrustmap.fitting.mapfile import Box, ThrustMap, ValidityBox
from thrustmap.fitting.models import MODELS

FIRMWARE_FLOAT32 = 1e-6  # the firmware computes in float32; these are its values


def _map_from(
    t: np.ndarray, b: np.ndarray, pct: np.ndarray, model: str, box: ValidityBox
) -> ThrustMap:
    coef = MODELS[model].fit(t, b, pct, "l2")
    return ThrustMap(model, tuple(float(c) for c in coef), SCALES["pwm"], box)


# -- PX4: FunctionMotors::updateValues --------------------------------------------------------------
#: (THR_MDL_FAC, relative thrust ``control``) -> the motor output PX4 commands (0..1)
PX4_OUTPUT = [
    (0.2, 0.1, 0.12132024765014648), (0.2, 0.25, 0.291287899017334),
    (0.2, 0.5, 0.5495097637176514), (0.2, 0.75, 0.7838821411132812),
    (0.2, 0.9, 0.9154758453369141), (0.35, 0.1, 0.1428571343421936),
    (0.35, 0.25, 0.3270283341407776), (0.35, 0.5, 0.5849729180335999),
    (0.35, 0.75, 0.8049516081809998), (0.35, 0.9, 0.9244459271430969),
    (0.6, 0.1, 0.19371294975280762), (0.6, 0.25, 0.39314979314804077),
    (0.6, 0.5, 0.6384919881820679), (0.6, 0.75, 0.8333333134651184),
    (0.6, 0.9, 0.9359621405601501),
]  # fmt: skip


@pytest.mark.parametrize(("fac", "control", "output"), PX4_OUTPUT)
def test_px4_throttle_is_the_firmware_output(fac: float, control: float, output: float) -> None:
    assert px4.px4_throttle(control, fac) == pytest.approx(output, abs=FIRMWARE_FLOAT32)
    assert px4.px4_rel_thrust(output, fac) == pytest.approx(control, abs=FIRMWARE_FLOAT32)


@pytest.mark.parametrize("fac", [0.2, 0.35, 0.6])
def test_px4_thr_mdl_fac_recovered_from_the_firmware_outputs(fac: float) -> None:
    rows = [(c, x) for f, c, x in PX4_OUTPUT if f == fac]
    control, output = (np.array(v) for v in zip(*rows, strict=True))
    fit = px4.fit_px4(18.0 * control, output)  # a motor whose thrust is what PX4 assumes
    assert fit.thr_mdl_fac == pytest.approx(fac, abs=1e-5)
    assert fit.thrust_max_n == pytest.approx(18.0, rel=1e-5)
    held = px4.fit_px4(18.0 * control, output, thrust_max_n=18.0)  # full thrust known
    assert held.thr_mdl_fac == pytest.approx(fac, abs=1e-5)


def test_px4_export_through_a_map() -> None:
    # a motor that behaves as PX4's model with THR_MDL_FAC 0.35, measured up to full output
    # (rel_thrust = a·x² + b·x, FunctionMotors.hpp:85, the model PX4 inverts; anchored by the
    # firmware outputs above)
    s = np.linspace(0.03, 1.0, 60)
    control = 0.35 * s * s + 0.65 * s
    t = 20.0 * control
    b = np.full_like(s, 24.0)
    box = ValidityBox(Box(t.min(), t.max()), Box(24, 24), Box(100 * s.min(), 100))
    tmap = _map_from(t, b, 100 * s, "poly4", box)
    res = export_map(tmap, "px4", ExportOptions(mass_kg=2.0, rotors=4))
    assert res.values["THR_MDL_FAC"] == pytest.approx(0.35, abs=0.01)
    line = re.search(r"^1\t1\tTHR_MDL_FAC\t([0-9.]+)\t9$", res.text, re.M)
    assert line is not None and float(line.group(1)) == res.values["THR_MDL_FAC"]
    # hover: 2 kg / 4 rotors = 4.903 N per rotor, a fraction of the 20 N at full output
    assert res.values["MPC_THR_HOVER"] == pytest.approx(2.0 * 9.80665 / 4 / 20.0, abs=0.003)
    assert res.values["full_throttle_thrust_n"] == pytest.approx(20.0, rel=0.005)
    assert "map has no voltage dependence" in res.text  # fitted at a single voltage


def test_px4_reports_battery_effect_and_bat_scale() -> None:
    res = export_map(synthetic_map("motor"), "px4")
    assert res.residual["box_rms_pct"] > res.residual["rms_pct"]
    assert res.residual["bat_rms_pct"] < res.residual["box_rms_pct"]
    assert res.values["MC_BAT_SCALE_EN"] == 1
    assert "with MC_BAT_SCALE_EN=1" in res.text


# -- ArduPilot: Thrust_Linearization -------------------------------------------------------------
#: (thrust_in, MOT_THST_EXPO, SPIN_MIN, SPIN_MAX, BAT_VOLT_MAX, BAT_VOLT_MIN, battery V)
#: -> (actuator, lift_max), MOT_OPTIONS bit 0 (raw voltage, no filter)
ARDUPILOT_ACTUATOR = [
    ((0.5, 0.65, 0.15, 0.95, 25.2, 19.8, 25.2), (0.6685760021209717, 1.0)),
    ((0.5, 0.65, 0.15, 0.95, 25.2, 19.8, 22.0), (0.6637064218521118, 0.8009573221206665)),
    ((0.3, 0.4, 0.12, 0.95, 25.2, 19.8, 20.5), (0.4379749298095703, 0.7528029680252075)),
    # below MOT_BAT_VOLT_MIN: the ratio is held at MIN's
    ((0.8, 0.55, 0.13, 0.95, 25.2, 19.8, 18.0), (0.8345822691917419, 0.6931121349334717)),
    # below a quarter of MIN the firmware switches compensation off (lift_max 1)
    ((0.4, 0.65, 0.15, 0.95, 25.2, 19.8, 4.0), (0.5981187224388123, 1.0)),
    # MIN below 0.6 x MAX is raised to it (4S: 13.2 -> 10.08 is not binding; 16.8 x 0.6)
    ((0.6, 0.7, 0.1, 0.9, 16.8, 13.2, 15.1), (0.6861091256141663, 0.8351439833641052)),
]


@pytest.mark.parametrize(("args", "expected"), ARDUPILOT_ACTUATOR)
def test_ardupilot_actuator_is_the_firmware_output(
    args: tuple[float, ...], expected: tuple[float, float]
) -> None:
    thrust_in, expo, spin_min, spin_max, v_max, v_min, volts = args
    actuator, lift_max = expected
    p = ardupilot.ArduPilotParams(expo, spin_min, spin_max, v_max, v_min, 1.0)
    r = float(ardupilot.ardupilot_voltage_ratio(volts, p))
    assert r * (1 - expo) + expo * r * r == pytest.approx(lift_max, abs=FIRMWARE_FLOAT32)
    thrust = thrust_in * lift_max  # T = thrust_in · K · lift_max, K = 1
    assert float(ardupilot.ardupilot_actuator(thrust, volts, p)) == pytest.approx(
        actuator, abs=2e-6
    )
    assert float(ardupilot.ardupilot_thrust(actuator, volts, p)) == pytest.approx(thrust, abs=1e-5)


def test_ardupilot_expo_recovered_from_the_firmware_outputs() -> None:
    # the firmware's outputs for MOT_THST_EXPO 0.65 at full voltage (ratio 1): computed by hand
    # from apply_thrust_curve_and_volt_scaling for thrust_in 0.1..0.9
    thrust_in = np.array([0.1, 0.3, 0.5, 0.7, 0.9])
    actuator = np.array([0.3152097463607788, 0.5192307233810425, 0.6685760021209717,
                         0.7922990322113037, 0.9002987146377563])  # fmt: skip
    p = ardupilot.ArduPilotParams(0.65, 0.15, 0.95, 25.2, 19.8, 1.0)
    np.testing.assert_allclose(
        ardupilot.ardupilot_actuator(thrust_in, 25.2, p), actuator, atol=2e-6
    )
    fit = ardupilot.fit_ardupilot(
        10.0 * thrust_in, np.full(5, 25.2), actuator, spin_max=0.95, bat_volt_max=25.2,
        bat_volt_min=19.8, spin_min=0.15,
    )  # fmt: skip
    assert fit.thst_expo == pytest.approx(0.65, abs=1e-4)
    assert fit.thrust_max_n == pytest.approx(10.0, rel=1e-4)


def test_ardupilot_rules_hold_the_firmware_defaults_and_ranges() -> None:
    assert ARDUCOPTER_4.param("MOT_THST_EXPO").default == 0.65
    assert ARDUCOPTER_4.param("MOT_SPIN_MIN").default == 0.15
    assert ARDUCOPTER_4.param("MOT_SPIN_MAX").default == 0.95
    assert (
        ARDUCOPTER_4.param("MOT_BAT_VOLT_MAX").lo,
        ARDUCOPTER_4.param("MOT_BAT_VOLT_MAX").hi,
    ) == (6, 53)
    assert (
        ARDUCOPTER_4.param("MOT_BAT_VOLT_MIN").lo,
        ARDUCOPTER_4.param("MOT_BAT_VOLT_MIN").hi,
    ) == (6, 42)
    assert ARDUPILOT_CELL_V == (3.3, 4.2)


def _ardupilot_firmware_thrust(
    act: np.ndarray,
    volts: np.ndarray,
    *,
    expo: float,
    spins: tuple[float, float],
    bat: tuple[float, float],
    k: float,
) -> np.ndarray:
    """The thrust ArduPilot assumes for an actuator value: remove_thrust_curve_and_volt_scaling
    (AP_Motors_Thrust_Linearization.cpp:137-153) gives thrust_in, the demand after the
    compensation gain 1/lift_max, so the thrust is thrust_in·K·lift_max. Transcribed here so
    the map is built from the firmware, not from our module."""
    v_max, v_min = bat
    v_min = max(v_min, 0.6 * v_max)  # line 169
    ratio = np.clip(volts, v_min, v_max) / v_max  # lines 172-179
    lift_max = ratio * (1 - expo) + expo * ratio * ratio  # line 184
    throttle = (act - spins[0]) / (spins[1] - spins[0])  # actuator_to_thrust, line 114
    battery_scale = 1.0 / ratio  # lines 139-142
    thrust = (throttle / battery_scale) * (2.0 * expo) - (expo - 1.0)  # line 149
    thrust = thrust * thrust - (1.0 - expo) * (1.0 - expo)  # line 150
    thrust_in = thrust / (4.0 * expo * lift_max)  # line 151
    return np.asarray(thrust_in * k * lift_max)


def test_ardupilot_export_through_a_map() -> None:
    # MOT_SPIN_MIN comes from the measured spin-up (here 0.16), MOT_THST_EXPO is fitted above it;
    # a poly4 map carries no voltage physics, so the battery range stays the stand's band
    a, v = np.meshgrid(np.linspace(0.16, 1.0, 40), np.linspace(21.0, 25.2, 7))
    a, v = a.ravel(), v.ravel()
    t = _ardupilot_firmware_thrust(a, v, expo=0.55, spins=(0.16, 0.95), bat=(25.2, 21.0), k=18.0)
    t_hi, t_lo = float(t.max()), float(t.min())
    box = ValidityBox(Box(t_lo, t_hi), Box(21.0, 25.2), Box(16, 100))
    tmap = replace(_map_from(t, v, 100 * a, "poly4", box), spin_up={"throttle_pct": 16.0})
    res = export_map(tmap, "ardupilot", ExportOptions(voltage_v=25.2))
    assert res.values["MOT_THST_EXPO"] == pytest.approx(0.55, abs=0.01)
    assert res.values["MOT_SPIN_MIN"] == 0.16
    params = dict(line.split(",") for line in res.text.splitlines() if not line.startswith("#"))
    assert set(params) >= {
        "MOT_THST_EXPO", "MOT_SPIN_MIN", "MOT_SPIN_MAX", "MOT_PWM_MIN", "MOT_PWM_MAX",
        "MOT_BAT_VOLT_MAX", "MOT_BAT_VOLT_MIN",
    }  # fmt: skip
    assert float(params["MOT_BAT_VOLT_MAX"]) == 25.2 and float(params["MOT_PWM_MIN"]) == 1000
    assert float(params["MOT_BAT_VOLT_MIN"]) == 21.0
    assert "a poly4 map's voltage term is a polynomial" in res.text
    # full lift is held at the map's own thrust at MOT_SPIN_MAX (17.91 N here: the poly4 map is
    # itself off by up to 0.68 % of the range), so the curve cannot absorb the map's error
    assert res.values["thrust_max_n"] == pytest.approx(18.0, rel=0.01)
    assert res.residual["rms_pct"] < 1.0
    assert res.residual["nocomp_rms_pct"] > 5 * res.residual["rms_pct"]


# -- Betaflight: pidApplyThrustLinearization -------------------------------------------------------
#: (thrust_linear, x) -> (4.5/4.6 output, 2026.6 output)
BETAFLIGHT_OUTPUT = [
    (25, 0.1, 0.12025000154972076, 0.12700000405311584),
    (25, 0.3, 0.33675000071525574, 0.3577499985694885),
    (25, 0.5, 0.53125, 0.5625), (25, 0.8, 0.8080000281333923, 0.8340000510215759),
    (55, 0.1, 0.14455001056194305, 0.17128001153469086),
    (55, 0.3, 0.38085001707077026, 0.4409100115299225),
    (55, 0.5, 0.5687500238418579, 0.637499988079071),
    (55, 0.8, 0.8175999522209167, 0.858959972858429),
    (100, 0.1, 0.1809999942779541, 0.2619999945163727),
    (100, 0.3, 0.44700002670288086, 0.5940000414848328), (100, 0.5, 0.625, 0.75),
    (100, 0.8, 0.8319999575614929, 0.8640000224113464),
    (125, 0.1, 0.20124998688697815, 0.32500001788139343),
    (125, 0.3, 0.48375001549720764, 0.6937500238418579), (125, 0.5, 0.65625, 0.8125),
    (125, 0.8, 0.8399999737739563, 0.8500000238418579),
]  # fmt: skip


@pytest.mark.parametrize(("value", "x", "legacy", "new"), BETAFLIGHT_OUTPUT)
def test_betaflight_out_is_the_firmware_output(
    value: int, x: float, legacy: float, new: float
) -> None:
    assert betaflight.betaflight_out(x, value / 100, "legacy") == pytest.approx(
        legacy, abs=FIRMWARE_FLOAT32
    )
    assert betaflight.betaflight_out(x, value / 100, "2026.6") == pytest.approx(
        new, abs=FIRMWARE_FLOAT32
    )
    assert betaflight.betaflight_m(legacy, value / 100, "legacy") == pytest.approx(x, abs=1e-5)
    assert betaflight.betaflight_m(new, value / 100, "2026.6") == pytest.approx(x, abs=1e-5)


@pytest.mark.parametrize("generation", ["legacy", "2026.6"])
@pytest.mark.parametrize("value", [25, 55, 100, 125])
def test_betaflight_thrust_linear_recovered_from_the_firmware_outputs(
    generation: str, value: int
) -> None:
    rows = [(x, lg if generation == "legacy" else nw) for v, x, lg, nw in BETAFLIGHT_OUTPUT
            if v == value]  # fmt: skip
    m, out = (np.array(c) for c in zip(*rows, strict=True))
    fit = betaflight.fit_betaflight(12.0 * m, out, generation)
    assert fit.thrust_linear == value
    held = betaflight.fit_betaflight(12.0 * m, out, generation, thrust_max_n=12.0)
    assert held.thrust_linear == value and held.thrust_max_n == 12.0


def test_betaflight_rules_hold_the_firmware_range() -> None:
    p = BETAFLIGHT_46.param("thrust_linear")
    assert (p.lo, p.hi, p.default) == (0, 150, 0)


def test_betaflight_2026_curve_is_capped_where_it_stops_rising() -> None:
    m = np.linspace(0, 1, 20001)
    e_max = betaflight.betaflight_max_expo("2026.6")
    assert np.all(np.diff(betaflight.betaflight_out(m, e_max, "2026.6")) > 0)
    assert np.any(np.diff(betaflight.betaflight_out(m, e_max + 0.02, "2026.6")) < 0)
    assert betaflight.betaflight_max_expo("legacy") == 1.5


def test_betaflight_generations_differ_and_version_parsing() -> None:
    assert betaflight.betaflight_generation("4.5") == "legacy"
    assert betaflight.betaflight_generation("2025.12") == "legacy"
    assert betaflight.betaflight_generation("2026.6") == "2026.6"
    assert betaflight.betaflight_generation("2026.12.1") == "2026.6"
    m = np.array([0.25])
    assert betaflight.betaflight_out(m, 0.4, "legacy")[0] == pytest.approx(
        0.25 * (1 + 0.4 * 0.75**2)
    )
    assert betaflight.betaflight_out(m, 0.4, "2026.6")[0] == pytest.approx(
        0.25 * (1 + 0.4 * 0.75 * 1.2)
    )


@pytest.mark.parametrize("firmware", ["4.5", "2026.6"])
def test_betaflight_export_through_a_map(firmware: str) -> None:
    idle_lo = 48 + 0.055 * 1999
    m = np.linspace(0.03, 1.0, 60)  # measured up to full output
    out = _betaflight_firmware(m, 45, firmware)
    dshot = idle_lo + out * (2047 - idle_lo)
    pct = SCALES["dshot"].to_pct(dshot)
    t = 15.0 * m
    b = np.full_like(t, 24.0)
    box = ValidityBox(
        Box(t.min(), t.max()), Box(24.0, 24.0), Box(float(pct.min()), float(pct.max()))
    )
    coef = MODELS["poly4"].fit(t, b, pct, "l2")
    tmap = ThrustMap("poly4", tuple(float(c) for c in coef), SCALES["dshot"], box)
    res = export_map(tmap, "betaflight", ExportOptions(firmware=firmware))
    assert "set thrust_linear = 45\n" in res.text
    idle = "dshot_idle_value" if firmware == "4.5" else "motor_idle"  # renamed in 4.6
    assert f"set {idle} = 550\n" in res.text and "set motor_output_limit = 100\n" in res.text
    assert res.residual["rms_pct"] < 0.1


def _betaflight_firmware(x: np.ndarray, thrust_linear: int, firmware: str) -> np.ndarray:
    """pidApplyThrustLinearization as the firmware writes it (module docstring for the lines),
    transcribed here so the map below is built from the firmware, not from our module."""
    e = thrust_linear / 100.0
    if firmware in ("4.5", "4.6", "2025.12"):
        return np.asarray(x * (1.0 + e * (1.0 - x) * (1.0 - x)))
    inv = 1.0 - x
    return np.asarray(x * (1.0 + e * inv * (1.0 + e * (inv - x))))


# -- Crazyflie (seed 2) --------------------------------------------------------------------------
SEED2 = (6.40308e-9, 0.000742171, -0.9899922188)  # seed 2's published a, b, c (grams)


def test_crazyflie_quadratic_recovered_from_seed2_coefficients() -> None:
    u = np.linspace(1000, 60000, 60)
    a, b, c = SEED2
    fa, fb, fc = plat.fit_quadratic(u, a * u * u + b * u + c)
    assert (fa, fb, fc) == pytest.approx(SEED2, rel=1e-6)


def test_crazyflie_export_through_a_map() -> None:
    a, b, c = SEED2
    u = np.linspace(8000, 65535, 80)  # measured up to full command
    thrust_n = (a * u * u + b * u + c) / 1000 * 9.80665 / 4  # per rotor
    pct = SCALES["crazyflie"].to_pct(u)
    volts = np.full_like(u, 4.0)
    box = ValidityBox(Box(thrust_n.min(), thrust_n.max()), Box(4.0, 4.0), Box(pct.min(), pct.max()))
    coef = MODELS["poly4"].fit(thrust_n, volts, pct, "l2")
    tmap = ThrustMap("poly4", tuple(float(x) for x in coef), SCALES["crazyflie"], box)
    res = export_map(tmap, "crazyflie", ExportOptions(rotors=4))
    cf = res.values["seed2"]
    # through the map's full-throttle thrust at u = 65535: a and b within 1 %, the small constant
    # c (-0.99 g) within 0.1 g
    assert (cf.a, cf.b) == pytest.approx(SEED2[:2], rel=0.01)
    assert cf.c == pytest.approx(c, abs=0.1)
    assert cf.f_max_g == pytest.approx(a * 65535**2 + b * 65535 + c, rel=0.005)
    full_g = res.values["full_throttle_thrust_n"] * 4 * 1000 / 9.80665
    assert cf.f_max_g == pytest.approx(full_g, rel=1e-9)  # the one number, in grams
    # seed 2's linearisation: u' = û / f_max · 65536, û the thrust the polynomial predicts at u
    up = plat.crazyflie_linearise(np.array([30000.0]), cf)
    assert up[0] == pytest.approx((a * 3e4**2 + b * 3e4 + c) / cf.f_max_g * 65536, rel=0.01)


# -- Aerostack2 ----------------------------------------------------------------------------------
def _as2_params(text: str) -> dict[str, float]:
    out: dict[str, float] = {}
    for key in (
        "a",
        "b",
        "c",
        "d",
        "e",
        "f",
        "gamma2",
        "gamma1",
        "gamma0",
        "min_throttle",
        "max_throttle",
    ):
        mt = re.search(rf"^\s+{key}: (\S+)$", text, re.M)
        assert mt is not None, key
        out[key] = float(mt.group(1))
    return out


def test_aerostack2_poly2_map_is_exact_and_uses_as2_names() -> None:
    tmap = synthetic_map("poly2", gamma=True)
    res = export_map(tmap, "aerostack2", ExportOptions(rotors=4))
    assert "/**:\n  ros__parameters:\n    use_thrust_map: true\n" in res.text
    assert "    polynomial_thrust_map:\n" in res.text and "use_correction_factor: true" in res.text
    p = _as2_params(res.text)
    t, v = np.meshgrid(np.linspace(0.3, 10, 9), np.linspace(21.6, 24.9, 5))  # inside the γ range
    t, v = t.ravel(), v.ravel()
    collective = 4 * t
    # as2_core: thrust per motor, times gamma(V), into the surface (in µs)
    tm = collective / 4 * (p["gamma2"] * v * v + p["gamma1"] * v + p["gamma0"])
    thr = p["a"] + p["b"] * tm + p["c"] * v + p["d"] * tm**2 + p["e"] * tm * v + p["f"] * v**2
    np.testing.assert_allclose(thr, SCALES["pwm"].from_pct(tmap.throttle_pct(t, v)), rtol=1e-12)
    assert (p["min_throttle"], p["max_throttle"]) == (1000.0, 2000.0)


def test_aerostack2_motor_map_is_refitted_with_small_residual() -> None:
    res = export_map(synthetic_map("motor"), "aerostack2")
    assert "refitted to the motor map" in res.text
    assert res.residual["rms_pct"] < 1.0


# -- every export: comment header with hash, box and residual; CLI --------------------------------
ALL = [
    ("pwm", []),
    ("c-header", ["--encoding", "pwm"]),
    ("aerostack2", []),
    ("px4", ["--mass-kg", "1.4"]),
    ("ardupilot", ["--mass-kg", "1.4"]),
    ("betaflight", ["--firmware", "4.5"]),
]


@pytest.mark.parametrize(("target", "extra"), ALL)
def test_every_export_names_map_hash_box_and_residual(
    tmp_path: pytest.TempPathFactory, target: str, extra: list[str]
) -> None:
    from pathlib import Path

    from click.testing import CliRunner

    from thrustmap.cli import cli

    base = Path(str(tmp_path))
    path = base / "map.json"
    synthetic_map("motor", gamma=True).save(path)
    digest = ThrustMap.load(path).file_sha256
    out = base / "out.txt"
    res = CliRunner().invoke(cli, ["export", str(path), "--to", target, *extra, "-o", str(out)])
    assert res.exit_code == 0, res.output
    head = [ln for ln in out.read_text().splitlines() if ln.lstrip().startswith(("#", "*"))]
    text = "\n".join(head)
    assert f"map file sha256: {digest}" in text
    assert "validity box: thrust 0.3..10 N per rotor, voltage 21..25.2 V" in text
    assert "residual: " in text
    assert "gamma correction: gamma(B) =" in text


def test_px4_clamped_factor_refits_thrust_scale_and_warns() -> None:
    # a dead band: thrust starts at s = 0.2, which PX4's form (no offset) cannot follow
    s = np.linspace(0.25, 0.95, 30)
    t = 20.0 * ((s - 0.2) / 0.8) ** 2
    fit = px4.fit_px4(t, s)
    assert fit.thr_mdl_fac == 1.0
    assert fit.thrust_max_n == pytest.approx(float(np.dot(s * s, t) / np.dot(s * s, s * s)))
