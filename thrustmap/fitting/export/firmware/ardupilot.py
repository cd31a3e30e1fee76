"""ArduPilot: MOT_THST_EXPO, MOT_SPIN_MIN/MAX and the battery voltage compensation
(MOT_BAT_VOLT_MAX/MIN) fitted to the map through ArduPilot's own path from thrust to
actuator."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
import scipy.optimize as opt

from thrustmap.core.errors import FitError
from thrustmap.core.physical import cells_from_voltage
from thrustmap.core.units import SCALES, ThrottleScale
from thrustmap.fitting.export.encodings import (
    ExportOptions,
    ExportResult,
    comment,
    export_values,
    header_lines,
    reference_voltage,
    require_voltage,
    rms_max,
)
from thrustmap.fitting.export.firmware.common import (
    FloatArray,
    change_lines,
    pack_line,
    pwm_scale,
    saturation_high_end,
    spin_up_fraction,
    supported_samples,
    throttle_fraction,
    voltage_outside_line,
)
from thrustmap.fitting.export.rules import (
    ARDUPILOT_CELL_V,
    ARDUPILOT_SPIN_MARGIN,
    Firmware,
    ardupilot_rules,
)
from thrustmap.fitting.mapfile import ThrustMap
from thrustmap.fitting.mapvalues import MapValue, MapValues, thrust_at, thrust_at_command


@dataclass(frozen=True)
class ArduPilotParams:
    thst_expo: float
    spin_min: float
    spin_max: float
    bat_volt_max: float
    bat_volt_min: float
    thrust_max_n: float  # K: thrust at u = 1 and full voltage (what hover learning absorbs)


def ardupilot_voltage_ratio(voltage_v: npt.ArrayLike, p: ArduPilotParams) -> FloatArray:
    """ArduPilot's battery ratio (Thrust_Linearization::update_lift_max_from_batt_voltage):
    off (1) when MOT_BAT_VOLT_MAX <= 0, MIN >= MAX or the voltage reads below a quarter of MIN;
    MIN raised to 0.6 x MAX; the voltage clamped to MIN..MAX, over MAX."""
    b = np.asarray(voltage_v, float)
    if not (p.bat_volt_max > 0 and p.bat_volt_min > 0) or p.bat_volt_min >= p.bat_volt_max:
        return np.ones_like(b)
    lo = max(p.bat_volt_min, 0.6 * p.bat_volt_max)
    v = np.clip(b, lo, p.bat_volt_max) / p.bat_volt_max
    return np.asarray(np.where(b < 0.25 * lo, 1.0, v), dtype=float)


def ardupilot_actuator(
    thrust_n: npt.ArrayLike, voltage_v: npt.ArrayLike, p: ArduPilotParams
) -> FloatArray:
    """ArduPilot's path from thrust to actuator (0..1 of MOT_PWM_MIN..MAX)."""
    e = min(max(p.thst_expo, -1.0), 1.0)
    v = ardupilot_voltage_ratio(voltage_v, p)
    lift_max = v * (1.0 - e) + e * v * v
    demand = np.asarray(thrust_n, float) / (p.thrust_max_n * lift_max)  # T_d, 0..1
    x = lift_max * demand
    if abs(e) < 1e-9:
        u0 = x
    else:
        u0 = ((e - 1.0) + np.sqrt(np.clip((1.0 - e) ** 2 + 4.0 * e * x, 0.0, None))) / (2.0 * e)
    u = np.clip(u0 / v, 0.0, 1.0)
    return np.asarray(p.spin_min + (p.spin_max - p.spin_min) * u, dtype=float)


def ardupilot_thrust(
    actuator: npt.ArrayLike, voltage_v: npt.ArrayLike, p: ArduPilotParams
) -> FloatArray:
    """Forward of the same model: thrust ArduPilot assumes for an actuator value."""
    e = p.thst_expo
    u = (np.asarray(actuator, float) - p.spin_min) / (p.spin_max - p.spin_min)
    w = np.clip(u, 0.0, None) * ardupilot_voltage_ratio(voltage_v, p)
    return np.asarray(p.thrust_max_n * ((1.0 - e) * w + e * w * w), dtype=float)


def fit_ardupilot(
    thrust_n: npt.ArrayLike,
    voltage_v: npt.ArrayLike,
    actuator: npt.ArrayLike,
    *,
    spin_max: float = 0.95,
    bat_volt_max: float,
    bat_volt_min: float,
    spin_min: float | None = None,
    thrust_max_n: float | None = None,
) -> ArduPilotParams:
    """Fit MOT_THST_EXPO and MOT_SPIN_MIN (and the thrust scale) minimising actuator error.

    With ``spin_min`` given (the measured spin-up and the firmware's margin), MOT_SPIN_MIN is
    held there and only MOT_THST_EXPO and the thrust scale are fitted, on the points above it;
    with ``thrust_max_n`` too (the map's thrust at MOT_SPIN_MAX, ``fitting.mapvalues``) the scale
    is held as well and MOT_THST_EXPO alone is fitted.
    """
    t = np.asarray(thrust_n, float)
    b = np.asarray(voltage_v, float)
    a = np.asarray(actuator, float)
    if spin_min is not None:
        volts = (bat_volt_max, bat_volt_min)
        return _fit_ardupilot_expo(t, b, a, (spin_min, spin_max), volts, thrust_max_n)
    if t.size < 3:
        raise FitError("ArduPilot fit needs at least three points")

    def params(x: FloatArray) -> ArduPilotParams:
        return ArduPilotParams(
            float(x[0]), float(x[1]), spin_max, bat_volt_max, bat_volt_min, float(np.exp(x[2]))
        )

    def resid(x: FloatArray) -> FloatArray:
        return np.asarray(ardupilot_actuator(t, b, params(x)) - a, dtype=float)

    best: tuple[float, FloatArray] | None = None
    for e0 in (-0.5, 0.0, 0.3, 0.65, 0.9):
        for s0 in (0.0, 0.05, 0.1, 0.15, 0.2):
            p = ArduPilotParams(e0, s0, spin_max, bat_volt_max, bat_volt_min, 1.0)
            g = ardupilot_thrust(a, b, p)  # thrust per unit K
            k = float(np.dot(g, t) / max(np.dot(g, g), 1e-300))
            if not k > 0:
                continue
            x0 = np.array([e0, s0, math.log(k)])
            cost = float(np.sum(resid(x0) ** 2))
            if best is None or cost < best[0]:
                best = (cost, x0)
    if best is None:
        raise FitError("ArduPilot fit: thrust does not increase with throttle")
    sol = opt.least_squares(
        resid,
        best[1],
        bounds=([-1.0, 0.0, -np.inf], [1.0, spin_max - 0.05, np.inf]),
        x_scale=[0.1, 0.01, 0.1],
        xtol=1e-12,
        ftol=1e-12,
    )
    return params(sol.x)


def _fit_ardupilot_expo(
    t: FloatArray,
    b: FloatArray,
    a: FloatArray,
    spins: tuple[float, float],
    volts: tuple[float, float],
    thrust_max_n: float | None,
) -> ArduPilotParams:
    spin_min, spin_max = spins
    bat_volt_max, bat_volt_min = volts
    keep = a >= spin_min
    t, b, a = t[keep], b[keep], a[keep]
    if t.size < 3:
        raise FitError(
            f"ArduPilot fit: fewer than three map points above MOT_SPIN_MIN {spin_min:g}; the map "
            "does not cover the range where the motor spins"
        )

    def params(x: FloatArray) -> ArduPilotParams:
        k = thrust_max_n if thrust_max_n is not None else float(np.exp(x[1]))
        return ArduPilotParams(float(x[0]), spin_min, spin_max, bat_volt_max, bat_volt_min, k)

    def resid(x: FloatArray) -> FloatArray:
        return np.asarray(ardupilot_actuator(t, b, params(x)) - a, dtype=float)

    if thrust_max_n is not None:
        grid = np.linspace(-1.0, 1.0, 41)
        e0 = grid[int(np.argmin([np.sum(resid(np.array([e])) ** 2) for e in grid]))]
        sol1 = opt.least_squares(
            resid, np.array([e0]), bounds=([-1.0], [1.0]), x_scale=[0.1], xtol=1e-12, ftol=1e-12
        )
        return params(sol1.x)
    best: tuple[float, FloatArray] | None = None
    for e0 in (-0.5, 0.0, 0.3, 0.65, 0.9):
        g = ardupilot_thrust(
            a, b, ArduPilotParams(e0, spin_min, spin_max, bat_volt_max, bat_volt_min, 1.0)
        )
        k = float(np.dot(g, t) / max(np.dot(g, g), 1e-300))
        if not k > 0:
            continue
        x0 = np.array([e0, math.log(k)])
        cost = float(np.sum(resid(x0) ** 2))
        if best is None or cost < best[0]:
            best = (cost, x0)
    if best is None:
        raise FitError("ArduPilot fit: thrust does not increase with throttle")
    sol = opt.least_squares(
        resid, best[1], bounds=([-1.0, -np.inf], [1.0, np.inf]), x_scale=[0.1, 0.1],
        xtol=1e-12, ftol=1e-12,
    )  # fmt: skip
    return params(sol.x)


def ardupilot_spin_min(spin_frac: float | None, rules: Firmware) -> float:
    """MOT_SPIN_MIN: the measured spin-up, but never less than the default MOT_SPIN_ARM plus the
    firmware's usual margin; the firmware default when the data cannot tell. Rounded up."""
    arm = rules.param("MOT_SPIN_ARM").default or 0.0
    if spin_frac is None:
        return rules.param("MOT_SPIN_MIN").default or 0.0
    return math.ceil(max(spin_frac, arm + ARDUPILOT_SPIN_MARGIN) * 1e4 - 1e-6) / 1e4


def ardupilot_battery_range(tmap: ThrustMap, given_max_v: float | None) -> tuple[float, float, str]:
    """MOT_BAT_VOLT_MAX/MIN by the rule in docs/howto/export.md, and the sentence saying why.

    A ``motor`` map's voltage term is physics (throttle for a thrust ∝ 1/B, checked carrying
    maps from 2S to 3S on other rigs, a wider ratio than a discharge from 4.2 to 3.3 V a cell):
    it is trusted over the whole discharge, so the range is ArduPilot's documented one
    (``ARDUPILOT_CELL_V`` x the cell count read from the map's voltages). A polynomial map's
    voltage term is not (it diverges across voltage), and a map whose cell count cannot be read
    gives no pack: then the stand's band is kept and the header says what ArduPilot does below
    it. ``given_max_v`` (--voltage-v) sets MOT_BAT_VOLT_MAX in every case."""
    box = tmap.validity.voltage_v
    cells = cells_from_voltage(box.lo, box.hi)
    if tmap.model == "motor" and cells is not None:
        lo_c, hi_c = ARDUPILOT_CELL_V
        v_max = given_max_v if given_max_v is not None else round(hi_c * cells, 2)
        return (
            v_max,
            round(lo_c * cells, 2),
            (
                f"MOT_BAT_VOLT_MAX/MIN: ArduPilot's documented {hi_c:g}/{lo_c:g} V a cell x {cells} "
                f"cells (a {cells}S pack, read from the map's {box.lo:.2f}..{box.hi:.2f} V): the "
                "map's voltage term is motor physics, checked from 2S to 3S on other rigs "
                "(docs/howto/export.md), so compensation runs over the whole discharge"
            ),
        )
    v_max = reference_voltage(tmap, given_max_v)
    why = (
        f"a {tmap.model} map's voltage term is a polynomial with no evidence outside the "
        "voltages measured"
        if cells is not None
        else "the map's voltages do not tell the cell count"
    )
    return (
        v_max,
        box.lo,
        (
            f"MOT_BAT_VOLT_MAX/MIN: the stand's band {box.lo:g}..{v_max:g} V ({why}); below "
            "MOT_BAT_VOLT_MIN ArduPilot holds the compensation of MOT_BAT_VOLT_MIN, so a pack "
            "sagging further gets less thrust than demanded (the altitude loop makes it up)"
        ),
    )


def _k_value(
    tmap: ThrustMap, scale: ThrottleScale, spin_max: float, v_max: float
) -> MapValue | None:
    """The map's thrust at MOT_SPIN_MAX and MOT_BAT_VOLT_MAX: ArduPilot's full lift (u = 1);
    None when the map cannot say (then the fit finds it)."""
    pct = float(SCALES[scale.name].to_pct(scale.lo + spin_max * scale.span))
    try:
        return thrust_at_command(
            tmap, pct, v_max, key="thrust_at_spin_max_n", name="thrust at MOT_SPIN_MAX (u = 1)"
        )
    except FitError:
        return None


def export_ardupilot(tmap: ThrustMap, opts: ExportOptions) -> ExportResult:
    rules = ardupilot_rules(opts.firmware)
    require_voltage(tmap, "ardupilot")
    scale, top_note = saturation_high_end(
        tmap, pwm_scale(opts), opts.range_ is not None, "MOT_PWM_MAX"
    )
    v_max, v_min, bat_why = ardupilot_battery_range(tmap, opts.voltage_v)
    spin_frac, spin_why = spin_up_fraction(tmap, scale)
    spin_min = ardupilot_spin_min(spin_frac, rules)
    arm = rules.param("MOT_SPIN_ARM").default or 0.0
    # check what can be checked before fitting: a refusal names the rule, not a fit failure
    rules.require(
        {"MOT_SPIN_MIN": spin_min, "MOT_SPIN_MAX": opts.spin_max,
         "MOT_PWM_MIN": scale.lo, "MOT_PWM_MAX": scale.hi,
         "MOT_BAT_VOLT_MAX": round(v_max, 2), "MOT_BAT_VOLT_MIN": round(v_min, 2)}
    )  # fmt: skip
    k = _k_value(tmap, scale, opts.spin_max, v_max)
    mv = export_values(tmap, scale, opts, reference_voltage(tmap, opts.voltage_v))
    mv = MapValues(
        mv.voltage_v, mv.full_throttle, mv.hover, mv.spin_up, () if k is None else (k,), mv.unknown
    )
    box = supported_samples(tmap)
    act = throttle_fraction(box.throttle_pct, scale)
    fit = fit_ardupilot(
        box.thrust_n, box.voltage_v, act, spin_max=opts.spin_max, bat_volt_max=v_max,
        bat_volt_min=v_min, spin_min=spin_min, thrust_max_n=None if k is None else k.value,
    )  # fmt: skip
    shown = ArduPilotParams(
        round(fit.thst_expo, 4), spin_min, opts.spin_max,
        round(v_max, 2), round(v_min, 2), fit.thrust_max_n,
    )  # fmt: skip
    residual, resid = _ardupilot_residual(box.thrust_n, box.voltage_v, act, shown, scale)
    params: list[tuple[str, float, str]] = [
        ("MOT_THST_EXPO", shown.thst_expo, ".4f"),
        ("MOT_SPIN_MIN", shown.spin_min, ".4f"),
        ("MOT_SPIN_MAX", shown.spin_max, ".4f"),
        ("MOT_PWM_MIN", scale.lo, ".0f"),
        ("MOT_PWM_MAX", scale.hi, ".0f"),
        ("MOT_BAT_VOLT_MAX", shown.bat_volt_max, ".2f"),
        ("MOT_BAT_VOLT_MIN", shown.bat_volt_min, ".2f"),
    ]
    notes = _ardupilot_notes(tmap, shown, (spin_frac, spin_why, arm), scale, bat_why)
    notes += [top_note] if top_note else []
    outside = [
        line
        for name, v in (("MOT_BAT_VOLT_MAX", shown.bat_volt_max),
                        ("MOT_BAT_VOLT_MIN", shown.bat_volt_min))
        if (line := voltage_outside_line(tmap, name, v)) is not None
    ]  # fmt: skip
    if mv.hover is not None:
        hover, hover_line = _ardupilot_hover(mv.hover, scale, shown, opts)
        notes.append(hover_line)
        params.append(("MOT_THST_HOVER", hover, ".4f"))
    written = {n: float(format(v, fmt)) for n, v, fmt in params}
    rules.require(written)
    lines = (
        header_lines(tmap, "ArduPilot parameters (.param)", residual, mv, outside)
        + change_lines(rules, written)
        + notes
    )
    text = comment(lines, "#") + "".join(f"{n},{format(v, fmt)}\n" for n, v, fmt in params)
    values: dict[str, Any] = dict(written)
    values["thrust_max_n"] = fit.thrust_max_n
    if mv.full_throttle is not None:
        values["full_throttle_thrust_n"] = mv.full_throttle.value
    values["map_values"] = mv
    if spin_frac is not None:
        values["spin_up_fraction"] = spin_frac
    return ExportResult("ardupilot", text, values, resid, ".param")


def _ardupilot_hover(
    hover: MapValue, scale: ThrottleScale, p: ArduPilotParams, opts: ExportOptions
) -> tuple[float, str]:
    """MOT_THST_HOVER: the map's hover throttle in ArduPilot's units, the throttle demand
    ArduPilot's curve (with its voltage scaling at the hover's voltage) turns into that output:
    demand = thrust / full lift at that output (and its interval the same way)."""

    def demand(pct: float) -> float:
        act = float(throttle_fraction(np.array([pct]), scale)[0])
        return float(ardupilot_thrust(act, hover.voltage_v, p)[()]) / p.thrust_max_n

    frac = demand(hover.value)
    iv = (
        "" if hover.lo is None or hover.hi is None
        else f" (95 % interval {demand(hover.lo):.4f}..{demand(hover.hi):.4f})"
    )  # fmt: skip
    return round(frac, 4), (
        f"hover: {opts.mass_kg:g} kg on {opts.rotors or 4} rotors = {hover.thrust_n:.4g} N per "
        f"rotor, throttle {hover.value:.2f} % at {hover.voltage_v:g} V -> MOT_THST_HOVER "
        f"{frac:.4f}{iv}, the demand ArduPilot's curve turns into that output (ArduPilot learns "
        "it with MOT_HOVER_LEARN)"
    )


def _ardupilot_residual(
    t: FloatArray, b: FloatArray, act: FloatArray, shown: ArduPilotParams, scale: ThrottleScale
) -> tuple[list[str], dict[str, float]]:
    """The residual lines of ArduPilot's curve against the map above MOT_SPIN_MIN, with and
    without its voltage scaling, and the figures."""
    above = act >= shown.spin_min  # the region the firmware's curve covers
    err_box = 100 * (ardupilot_actuator(t, b, shown) - act)[above]
    at_ref = (b == np.max(b))[above]
    no_comp = ArduPilotParams(
        shown.thst_expo, shown.spin_min, shown.spin_max, 0.0, 0.0, shown.thrust_max_n
    )
    err_nocomp = 100 * (ardupilot_actuator(t, b, no_comp) - act)[above]
    r_box, r_ref, r_nc = rms_max(err_box), rms_max(err_box[at_ref]), rms_max(err_nocomp)
    lines = [
        "ArduPilot curve vs map over the supported region above MOT_SPIN_MIN (with its "
        f"voltage scaling): RMS {r_box[0]:.3f} %, max {r_box[1]:.3f} % of the "
        f"{scale.lo:g}..{scale.hi:g} {scale.unit} range ({int(above.sum())} points)",
        f"at {float(np.max(b)):g} V only: RMS {r_ref[0]:.3f} %, max {r_ref[1]:.3f} %; without "
        f"voltage scaling (MOT_BAT_VOLT_MAX=0): RMS {r_nc[0]:.3f} %, max {r_nc[1]:.3f} %",
    ]
    figures = {
        "rms_pct": r_box[0], "max_pct": r_box[1], "ref_rms_pct": r_ref[0],
        "nocomp_rms_pct": r_nc[0],
    }  # fmt: skip
    return lines, figures


def _ardupilot_notes(
    tmap: ThrustMap,
    shown: ArduPilotParams,
    spin: tuple[float | None, str, float],
    scale: ThrottleScale,
    bat_why: str,
) -> list[str]:
    """The header's notes: where MOT_SPIN_MIN, MOT_SPIN_MAX and the battery range come from."""
    spin_frac, spin_why, arm = spin
    v_max = shown.bat_volt_max
    if spin_frac is None:
        spin_note = (
            f"MOT_SPIN_MIN kept at the firmware default {shown.spin_min:g}: {spin_why}; check on "
            "the vehicle that every motor spins reliably at MOT_SPIN_MIN"
        )
    else:
        spin_note = (
            f"MOT_SPIN_MIN {shown.spin_min:g} = max(measured spin-up {spin_frac:.4f}, default "
            f"MOT_SPIN_ARM {arm:g} + {ARDUPILOT_SPIN_MARGIN:g}); {spin_why}"
        )
    pct_min = float(SCALES[scale.name].to_pct(scale.lo + shown.spin_min * scale.span))
    t_at_min = thrust_at(tmap, pct_min, min(v_max, tmap.validity.voltage_v.hi))
    notes = [
        pack_line(tmap),
        spin_note,
        f"the map gives {t_at_min:.4g} N per rotor at MOT_SPIN_MIN; ArduPilot's curve starts "
        "from zero there (the residual above covers this)",
        f"MOT_SPIN_ARM is not written: this file assumes its default {arm:g}; keep MOT_SPIN_ARM "
        f"at least {ARDUPILOT_SPIN_MARGIN:g} below MOT_SPIN_MIN (pre-arm refuses ARM > MIN)",
        f"MOT_SPIN_MAX {shown.spin_max:g} is a convention (headroom) and fixes the scale of "
        "MOT_THST_EXPO, fitted above MOT_SPIN_MIN with ArduPilot's full lift (u = 1, "
        f"MOT_SPIN_MAX at {v_max:g} V) held at the map's {shown.thrust_max_n:.4g} N",
        bat_why,
        "ArduPilot compensates on its resting-voltage estimate (sag removed) unless MOT_OPTIONS "
        "bit 0 (raw voltage) is set, which matches the stand's loaded voltages",
        "MOT_PWM_TYPE must match the ESC protocol",
    ]
    if spin_frac is not None and spin_frac > arm:
        notes.append(
            f"the stand saw no reliable spin below {spin_frac:.4f}: at MOT_SPIN_ARM {arm:g} the "
            "motors may not turn when armed on the ground; raise MOT_SPIN_ARM to where they do, "
            f"still {ARDUPILOT_SPIN_MARGIN:g} below MOT_SPIN_MIN"
        )
    if 0.6 * v_max > shown.bat_volt_min:
        notes.append(
            f"ArduPilot raises MOT_BAT_VOLT_MIN to 0.6 x MOT_BAT_VOLT_MAX = {0.6 * v_max:.2f} V"
        )
    if scale.name != "pwm":
        notes.append(f"MOT_PWM_MIN/MAX are in {scale.name} units here ({scale.unit})")
    return notes
