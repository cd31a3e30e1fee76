"""PX4: rel_thrust = f·s² + (1 − f)·s, THR_MDL_FAC fitted to the map, and the battery
scaling's per-cell BAT1_V_CHARGED."""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from thrustmap.core.errors import FitError
from thrustmap.core.physical import CELL_V_RANGE, cells_from_voltage
from thrustmap.core.units import ThrottleScale
from thrustmap.fitting.export.encodings import (
    ExportOptions,
    ExportResult,
    Samples,
    comment,
    export_values,
    header_lines,
    reference_voltage,
    rms_max,
)
from thrustmap.fitting.export.firmware.common import (
    FloatArray,
    change_lines,
    idle_low_end,
    pwm_scale,
    saturation_high_end,
    supported_samples,
    throttle_fraction,
    voltage_outside_line,
)
from thrustmap.fitting.export.rules import PX4_BATTERY_SCALE_MAX, px4_rules
from thrustmap.fitting.mapfile import ThrustMap
from thrustmap.fitting.mapvalues import MapValue

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Px4Fit:
    thr_mdl_fac: float
    thrust_max_n: float


def px4_rel_thrust(s: npt.ArrayLike, f: float) -> FloatArray:
    x = np.asarray(s, float)
    return np.asarray(f * x * x + (1.0 - f) * x, dtype=float)


def px4_throttle(rel_thrust: npt.ArrayLike, f: float) -> FloatArray:
    """PX4's inverse: the normalised throttle s for a relative thrust (clamped to 0..1)."""
    r = np.clip(np.asarray(rel_thrust, float), 0.0, 1.0)
    if f < 1e-9:
        return np.asarray(r, dtype=float)
    s = (-(1.0 - f) + np.sqrt((1.0 - f) ** 2 + 4.0 * f * r)) / (2.0 * f)
    return np.asarray(s, dtype=float)


def fit_px4(
    thrust_n: npt.ArrayLike, throttle_frac: npt.ArrayLike, thrust_max_n: float | None = None
) -> Px4Fit:
    """THR_MDL_FAC as PX4's docs fit it: T = Tmax·(f·s² + (1 − f)·s), least squares in thrust.

    Linear in (A, C) = (Tmax·f, Tmax·(1 − f)), so Tmax need not be measured at full throttle.
    With ``thrust_max_n`` given (the map's full-throttle thrust, ``fitting.mapvalues``) Tmax is
    held there and only f is fitted: the curve then ends where the map says full throttle is.
    """
    t = np.asarray(thrust_n, float)
    s = np.asarray(throttle_frac, float)
    if t.size < 2:
        raise FitError("THR_MDL_FAC needs at least two (thrust, throttle) points")
    if thrust_max_n is not None:
        return _fit_px4_fixed(t, s, thrust_max_n)
    (a, c), *_ = np.linalg.lstsq(np.stack([s * s, s], axis=1), t, rcond=None)
    tmax = float(a + c)
    if not tmax > 0:
        raise FitError("THR_MDL_FAC fit: thrust does not increase with throttle in this range")
    f = float(a) / tmax
    if not 0.0 <= f <= 1.0:
        log.warning("THR_MDL_FAC %.3f outside PX4's 0..1; clamped", f)
        f = min(max(f, 0.0), 1.0)
        g = px4_rel_thrust(s, f)
        tmax = float(np.dot(g, t) / np.dot(g, g))  # best full-throttle thrust for that f
    return Px4Fit(f, tmax)


def _fit_px4_fixed(t: FloatArray, s: FloatArray, thrust_max_n: float) -> Px4Fit:
    """f minimising Σ (T − Tmax·(f·s² + (1 − f)·s))² with Tmax held: linear in f."""
    x = s * s - s
    den = float(np.dot(x, x))
    f = float(np.dot(t / thrust_max_n - s, x) / den) if den > 0 else 0.0
    if not 0.0 <= f <= 1.0:
        log.warning("THR_MDL_FAC %.3f outside PX4's 0..1; clamped", f)
        f = min(max(f, 0.0), 1.0)
    return Px4Fit(f, float(thrust_max_n))


def _px4_hover(
    hover: MapValue, scale: ThrottleScale, f: float, opts: ExportOptions
) -> tuple[float, str]:
    """MPC_THR_HOVER: the map's hover throttle in PX4's units, the thrust setpoint whose output
    through THR_MDL_FAC is that throttle (and its interval the same way), and its line."""

    def rel(pct: float) -> float:
        s_h = float(throttle_fraction(np.array([pct]), scale)[0])
        return float(px4_rel_thrust(min(max(s_h, 0.0), 1.0), f))

    frac = rel(hover.value)
    iv = (
        "" if hover.lo is None or hover.hi is None
        else f" (95 % interval {rel(hover.lo):.3f}..{rel(hover.hi):.3f})"
    )  # fmt: skip
    return round(frac, 3), (
        f"hover: {opts.mass_kg:g} kg on {opts.rotors or 4} rotors = {hover.thrust_n:.4g} N per "
        f"rotor, throttle {hover.value:.2f} % at {hover.voltage_v:g} V; MPC_THR_HOVER "
        f"{frac:.3f}{iv}: the setpoint PX4's curve (THR_MDL_FAC {f:g}) turns into that throttle"
    )


def _px4_outside(tmap: ThrustMap, b_ref: float) -> list[str]:
    """The header's written values outside the supported region beyond the map's own values:
    the battery scaling's low end."""
    return [x for x in [_bat_outside(tmap, b_ref)] if x]


def _bat_outside(tmap: ThrustMap, b_ref: float) -> str | None:
    """PX4 scales thrust by BAT1_V_CHARGED / V_cell up to 1.3 (``rules.PX4_BATTERY_SCALE_MAX``):
    it compensates down to V_charged / 1.3, below the stand's voltages when they are narrower."""
    low = b_ref / PX4_BATTERY_SCALE_MAX
    line = voltage_outside_line(tmap, "MC_BAT_SCALE_EN compensates down to V_charged/1.3", low)
    if line is None or not tmap.model_def.uses_voltage:
        return line
    return line + (
        " (the map's voltage term is motor physics, checked across 2S/3S: docs/howto/export.md)"
        if tmap.model == "motor"
        else " (the map's voltage term is a polynomial: no evidence it holds there)"
    )


def _bat_v_charged_note(tmap: ThrustMap, b_ref: float) -> str:
    """The header line on BAT1_V_CHARGED, which PX4 reads PER CELL (V_charged = it x cells)."""
    head = "MC_BAT_SCALE_EN scales the thrust setpoint by V_charged/V_now (1..1.3); "
    box = tmap.validity.voltage_v
    cells = cells_from_voltage(box.lo, box.hi)
    if cells is None:
        return head + (
            f"set BAT1_V_CHARGED (per cell) to {b_ref:g} V / BAT1_N_CELLS: the map's "
            f"{box.lo:g}..{box.hi:g} V does not tell the cell count"
        )
    return head + (
        f"set BAT1_V_CHARGED = {b_ref / cells:.3f} V (per cell: {b_ref:g} V on {cells} cells, the "
        f"count read from the map's {box.lo:.2f}..{box.hi:.2f} V at "
        f"{CELL_V_RANGE[0]:g}-{CELL_V_RANGE[1]:g} V a cell; on N cells use {b_ref:g} V / N)"
    )


def export_px4(tmap: ThrustMap, opts: ExportOptions) -> ExportResult:
    rules = px4_rules(opts.firmware)
    scale = pwm_scale(opts)
    idle_note = top_note = ""
    if scale.name == "pwm":
        scale, idle_note = idle_low_end(tmap, scale, opts.range_ is not None, "PWM minimum")
        scale, top_note = saturation_high_end(tmap, scale, opts.range_ is not None, "PWM maximum")
    rotors_out = opts.rotors or 4
    pwm_params: list[tuple[str, float, int]] = []
    if scale.name == "pwm":
        if rules.title.startswith("PX4 v1.13"):
            pwm_params = [("PWM_MAIN_MIN", scale.lo, 6), ("PWM_MAIN_MAX", scale.hi, 6)]
        else:
            for n in range(1, rotors_out + 1):
                pwm_params += [(f"PWM_MAIN_MIN{n}", scale.lo, 6), (f"PWM_MAIN_MAX{n}", scale.hi, 6)]
        rules.require({k: v for k, v, _ in pwm_params})
    b_ref = reference_voltage(tmap, opts.voltage_v)
    mv = export_values(tmap, scale, opts, b_ref)
    full = mv.full_throttle
    ref = supported_samples(tmap, voltage_v=b_ref, n_thrust=81)
    s_ref = throttle_fraction(ref.throttle_pct, scale)
    keep = s_ref >= 0.0  # the curve is fitted above the output range's low end (the idle)
    ref = Samples(ref.thrust_n[keep], ref.voltage_v[keep], ref.throttle_pct[keep])
    s_ref = s_ref[keep]
    fit = fit_px4(ref.thrust_n, s_ref, thrust_max_n=None if full is None else full.value)
    f = round(fit.thr_mdl_fac, 3)
    err_ref = 100 * (px4_throttle(ref.thrust_n / fit.thrust_max_n, f) - s_ref)
    box = supported_samples(tmap)
    s_box = throttle_fraction(box.throttle_pct, scale)
    keep = s_box >= 0.0
    box = Samples(box.thrust_n[keep], box.voltage_v[keep], box.throttle_pct[keep])
    s_box = s_box[keep]
    err_box = 100 * (px4_throttle(box.thrust_n / fit.thrust_max_n, f) - s_box)
    bat_scale = np.clip(b_ref / box.voltage_v, 1.0, 1.3)
    err_bat = 100 * (px4_throttle(box.thrust_n / fit.thrust_max_n * bat_scale, f) - s_box)
    r_ref, r_box, r_bat = rms_max(err_ref), rms_max(err_box), rms_max(err_bat)
    varies = tmap.model_def.uses_voltage and tmap.validity.voltage_v.hi > tmap.validity.voltage_v.lo
    bat_en = int(varies and r_bat[0] < r_box[0])
    residual = [
        f"PX4 curve vs map at {b_ref:g} V: RMS {r_ref[0]:.3f} %, max {r_ref[1]:.3f} % of the "
        f"{scale.lo:g}..{scale.hi:g} {scale.unit} range (single-factor form)",
    ]
    if varies:
        residual += [
            f"over the supported region of the voltage box without battery scaling: RMS {r_box[0]:.3f} %, max "
            f"{r_box[1]:.3f} % (battery variation adds this on top of the form error)",
            f"with MC_BAT_SCALE_EN=1 (thrust x {b_ref:g} V / V_now, clamped 1..1.3): RMS "
            f"{r_bat[0]:.3f} %, max {r_bat[1]:.3f} %",
        ]
    else:
        residual.append("map has no voltage dependence: battery effect not assessed")
    values: dict[str, float] = {
        "THR_MDL_FAC": f,
        "thrust_max_n": fit.thrust_max_n,
        "full_throttle_thrust_n": fit.thrust_max_n,
    }
    params: list[tuple[str, float, int]] = [("THR_MDL_FAC", f, 9)]
    notes = [
        f"fitted at {b_ref:g} V over thrust {tmap.validity.thrust_n.lo:g}.."
        f"{tmap.validity.thrust_n.hi:g} N, "
        + (
            f"its full-throttle end held at the map's full-throttle thrust {full.value:.4g} N "
            f"per rotor ({full.interval_text()})"
            if full is not None
            else f"the map cannot say its full-throttle thrust: the curve's own {fit.thrust_max_n:.4g} N"
        ),
        f"ESC output range {scale.lo:g}..{scale.hi:g} {scale.unit}: THR_MDL_FAC is normalised "
        "over it"
        + (
            " (written below as the PWM output limits)"
            if pwm_params
            else f"; set it on the {scale.name} outputs yourself"
        ),
        _bat_v_charged_note(tmap, b_ref),
    ]
    if f in (0.0, 1.0):
        notes.append(
            f"WARNING: THR_MDL_FAC is at its limit {f:g}: the measured curve does not fit PX4's "
            "form over this range (often a dead band: move the PWM minimum, --range, up to "
            "where thrust starts)"
        )
    params.append(("MC_BAT_SCALE_EN", bat_en, 6))
    values["MC_BAT_SCALE_EN"] = bat_en
    hover_line = ""
    if mv.hover is not None:
        hover, hover_line = _px4_hover(mv.hover, scale, f, opts)
        notes.append(hover_line)
        params.append(("MPC_THR_HOVER", hover, 9))
        values["MPC_THR_HOVER"] = hover
    notes += [n for n in (idle_note, top_note) if n]
    if pwm_params and len(pwm_params) > 2:
        notes.append(
            f"PWM_MAIN_MINn/MAXn written for outputs 1..{rotors_out} (--rotors); if your motors "
            "sit on other outputs, apply the same values there"
        )
    params += pwm_params
    written = {n: float(v) for n, v, _ in params}
    rules.require(written)
    values.update(written)
    outside = _px4_outside(tmap, b_ref)
    lines = (
        header_lines(tmap, "PX4 parameters (QGroundControl .params)", residual, mv, outside)
        + change_lines(rules, written)
        + notes
    )
    text = comment(lines, "#")
    text += "#\n# Vehicle-Id\tComponent-Id\tName\tValue\tType\n"
    for name, value, typ in params:
        shown = f"{value:.6g}" if typ == 9 else str(int(value))
        text += f"1\t1\t{name}\t{shown}\t{typ}\n"
    resid = {
        "rms_pct": r_ref[0], "max_pct": r_ref[1],
        "box_rms_pct": r_box[0], "box_max_pct": r_box[1],
        "bat_rms_pct": r_bat[0], "bat_max_pct": r_bat[1],
    }  # fmt: skip
    out: dict[str, Any] = dict(values)
    out["map_values"] = mv
    return ExportResult("px4", text, out, resid, ".params")
