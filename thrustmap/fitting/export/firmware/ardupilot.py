"""ArduPilot: MOT_THST_EXPO, MOT_SPIN_MIN/MAX and the battery voltage compensation
(MOT_BAT_VOLT_MAX/MIN) fitted to the map through ArduPilot's own path from thrust to
actuator."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import scipy.optimize as opt

from thrustmap.core.errors import FitError
from thrustmap.core.units import SCALES
from thrustmap.fitting.export.encodings import (
    G0_MPS2,
    ExportOptions,
    ExportResult,
    comment,
    header_lines,
    reference_voltage,
    require_voltage,
    rms_max,
)
from thrustmap.fitting.export.firmware.common import (
    FloatArray,
    change_lines,
    pwm_scale,
    spin_up_fraction,
    supported_samples,
    throttle_fraction,
)
from thrustmap.fitting.export.rules import ARDUPILOT_SPIN_MARGIN, Firmware, ardupilot_rules
from thrustmap.fitting.mapfile import ThrustMap


@dataclass(frozen=True)
class ArduPilotParams:
    thst_expo: float
    spin_min: float
    spin_max: float
    bat_volt_max: float
    bat_volt_min: float
    thrust_max_n: float  # K: thrust at u = 1 and full voltage (what hover learning absorbs)


def ardupilot_voltage_ratio(voltage_v: npt.ArrayLike, p: ArduPilotParams) -> FloatArray:
    if not (p.bat_volt_max > 0 and p.bat_volt_min > 0):
        return np.ones_like(np.asarray(voltage_v, float))
    lo = max(p.bat_volt_min, 0.6 * p.bat_volt_max)
    v = np.clip(np.asarray(voltage_v, float), lo, p.bat_volt_max) / p.bat_volt_max
    return np.asarray(v, dtype=float)


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
) -> ArduPilotParams:
    """Fit MOT_THST_EXPO and MOT_SPIN_MIN (and the thrust scale) minimising actuator error.

    With ``spin_min`` given (the measured spin-up and the firmware's margin), MOT_SPIN_MIN is
    held there and only MOT_THST_EXPO and the thrust scale are fitted, on the points above it.
    """
    t = np.asarray(thrust_n, float)
    b = np.asarray(voltage_v, float)
    a = np.asarray(actuator, float)
    if spin_min is not None:
        return _fit_ardupilot_expo(t, b, a, spin_min, spin_max, bat_volt_max, bat_volt_min)
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
    spin_min: float,
    spin_max: float,
    bat_volt_max: float,
    bat_volt_min: float,
) -> ArduPilotParams:
    keep = a >= spin_min
    t, b, a = t[keep], b[keep], a[keep]
    if t.size < 3:
        raise FitError(
            f"ArduPilot fit: fewer than three map points above MOT_SPIN_MIN {spin_min:g}; the map "
            "does not cover the range where the motor spins"
        )

    def params(x: FloatArray) -> ArduPilotParams:
        return ArduPilotParams(
            float(x[0]), spin_min, spin_max, bat_volt_max, bat_volt_min, float(np.exp(x[1]))
        )

    def resid(x: FloatArray) -> FloatArray:
        return np.asarray(ardupilot_actuator(t, b, params(x)) - a, dtype=float)

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


def export_ardupilot(tmap: ThrustMap, opts: ExportOptions) -> ExportResult:
    rules = ardupilot_rules(opts.firmware)
    require_voltage(tmap, "ardupilot")
    scale = pwm_scale(opts)
    vbox = tmap.validity.voltage_v
    v_max = reference_voltage(tmap, opts.voltage_v)
    v_min = vbox.lo
    spin_frac, spin_why = spin_up_fraction(tmap, scale)
    spin_min = ardupilot_spin_min(spin_frac, rules)
    arm = rules.param("MOT_SPIN_ARM").default or 0.0
    # check what can be checked before fitting: a refusal names the rule, not a fit failure
    rules.require(
        {"MOT_SPIN_MIN": spin_min, "MOT_SPIN_MAX": opts.spin_max,
         "MOT_PWM_MIN": scale.lo, "MOT_PWM_MAX": scale.hi,
         "MOT_BAT_VOLT_MAX": round(v_max, 2), "MOT_BAT_VOLT_MIN": round(v_min, 2)}
    )  # fmt: skip
    box = supported_samples(tmap)
    act = throttle_fraction(box.throttle_pct, scale)
    fit = fit_ardupilot(
        box.thrust_n,
        box.voltage_v,
        act,
        spin_max=opts.spin_max,
        bat_volt_max=v_max,
        bat_volt_min=v_min,
        spin_min=spin_min,
    )
    shown = ArduPilotParams(
        round(fit.thst_expo, 4), spin_min, opts.spin_max,
        round(v_max, 2), round(v_min, 2), fit.thrust_max_n,
    )  # fmt: skip
    above = act >= spin_min  # the region the firmware's curve covers
    err_box = 100 * (ardupilot_actuator(box.thrust_n, box.voltage_v, shown) - act)[above]
    at_ref = (box.voltage_v == np.max(box.voltage_v))[above]
    no_comp = ArduPilotParams(
        shown.thst_expo, shown.spin_min, shown.spin_max, 0.0, 0.0, shown.thrust_max_n
    )
    err_nocomp = 100 * (ardupilot_actuator(box.thrust_n, box.voltage_v, no_comp) - act)[above]
    r_box, r_ref, r_nc = rms_max(err_box), rms_max(err_box[at_ref]), rms_max(err_nocomp)
    t_at_min = float(
        tmap.thrust_n(
            np.array([float(SCALES[scale.name].to_pct(scale.lo + spin_min * scale.span))]),
            np.array([v_max]),
        )[0]
    )
    residual = [
        f"ArduPilot curve vs map over the supported region above MOT_SPIN_MIN (with its "
        "voltage scaling): "
        f"RMS {r_box[0]:.3f} %, max {r_box[1]:.3f} % of the {scale.lo:g}..{scale.hi:g} "
        f"{scale.unit} range ({int(above.sum())} points)",
        f"at {vbox.hi:g} V only: RMS {r_ref[0]:.3f} %, max {r_ref[1]:.3f} %; without voltage "
        f"scaling (MOT_BAT_VOLT_MAX=0): RMS {r_nc[0]:.3f} %, max {r_nc[1]:.3f} %",
    ]
    if spin_frac is None:
        spin_note = (
            f"MOT_SPIN_MIN kept at the firmware default {spin_min:g}: {spin_why}; check on the "
            "vehicle that every motor spins reliably at MOT_SPIN_MIN"
        )
    else:
        spin_note = (
            f"MOT_SPIN_MIN {spin_min:g} = max(measured spin-up {spin_frac:.4f}, default "
            f"MOT_SPIN_ARM {arm:g} + {ARDUPILOT_SPIN_MARGIN:g}); {spin_why}"
        )
    notes = [
        spin_note,
        f"the map gives {t_at_min:.4g} N per rotor at MOT_SPIN_MIN and {v_max:g} V; ArduPilot's "
        "curve starts from zero there (the residual above covers this)",
        f"MOT_SPIN_ARM is not written: this file assumes its default {arm:g}; keep MOT_SPIN_ARM "
        f"at least {ARDUPILOT_SPIN_MARGIN:g} below MOT_SPIN_MIN (pre-arm refuses ARM > MIN)",
        f"MOT_SPIN_MAX {opts.spin_max:g} is a convention (headroom) and fixes the scale of "
        "MOT_THST_EXPO, fitted above MOT_SPIN_MIN",
        f"MOT_BAT_VOLT_MAX/MIN: the pack under load on the stand ({vbox.lo:g}..{vbox.hi:g} V); "
        "ArduPilot compensates on its resting-voltage estimate (sag removed) unless "
        "MOT_OPTIONS bit 0 (raw voltage) is set, which matches these loaded voltages",
        f"thrust at u=1 and {v_max:g} V: {fit.thrust_max_n:.4g} N per rotor",
        "MOT_PWM_TYPE must match the ESC protocol",
    ]
    if spin_frac is not None and spin_frac > arm:
        notes.append(
            f"the stand saw no reliable spin below {spin_frac:.4f}: at MOT_SPIN_ARM {arm:g} the "
            "motors may not turn when armed on the ground; raise MOT_SPIN_ARM to where they do, "
            f"still {ARDUPILOT_SPIN_MARGIN:g} below MOT_SPIN_MIN"
        )
    if 0.6 * v_max > v_min:
        notes.append(
            f"ArduPilot raises MOT_BAT_VOLT_MIN to 0.6 x MOT_BAT_VOLT_MAX = {0.6 * v_max:.2f} V"
        )
    params: list[tuple[str, float, str]] = [
        ("MOT_THST_EXPO", shown.thst_expo, ".4f"),
        ("MOT_SPIN_MIN", shown.spin_min, ".4f"),
        ("MOT_SPIN_MAX", shown.spin_max, ".4f"),
        ("MOT_PWM_MIN", scale.lo, ".0f"),
        ("MOT_PWM_MAX", scale.hi, ".0f"),
        ("MOT_BAT_VOLT_MAX", shown.bat_volt_max, ".2f"),
        ("MOT_BAT_VOLT_MIN", shown.bat_volt_min, ".2f"),
    ]
    if scale.name != "pwm":
        notes.append(f"MOT_PWM_MIN/MAX are in {scale.name} units here ({scale.unit})")
    if opts.mass_kg is not None:
        rotors = opts.rotors or 4
        hover_n = opts.mass_kg * G0_MPS2 / rotors
        hover = hover_n / fit.thrust_max_n
        notes.append(
            f"hover: {opts.mass_kg:g} kg on {rotors} rotors = {hover_n:.4g} N per rotor -> "
            f"MOT_THST_HOVER {hover:.4f} (ArduPilot learns it with MOT_HOVER_LEARN)"
        )
        params.append(("MOT_THST_HOVER", round(hover, 4), ".4f"))
    written = {n: float(format(v, fmt)) for n, v, fmt in params}
    rules.require(written)
    lines = (
        header_lines(tmap, "ArduPilot parameters (.param)", residual)
        + change_lines(rules, written)
        + notes
    )
    text = comment(lines, "#") + "".join(f"{n},{format(v, fmt)}\n" for n, v, fmt in params)
    values: dict[str, float] = dict(written)
    values["thrust_max_n"] = fit.thrust_max_n
    if spin_frac is not None:
        values["spin_up_fraction"] = spin_frac
    resid = {
        "rms_pct": r_box[0],
        "max_pct": r_box[1],
        "ref_rms_pct": r_ref[0],
        "nocomp_rms_pct": r_nc[0],
    }
    return ExportResult("ardupilot", text, values, resid, ".param")
