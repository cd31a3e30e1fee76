"""PX4: rel_thrust = f·s² + (1 − f)·s, THR_MDL_FAC fitted to the map, and the battery
scaling's per-cell BAT1_V_CHARGED."""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from thrustmap.core.errors import FitError
from thrustmap.fitting.export.encodings import (
    G0_MPS2,
    ExportOptions,
    ExportResult,
    Samples,
    comment,
    header_lines,
    reference_voltage,
    rms_max,
)
from thrustmap.fitting.export.firmware.common import (
    FloatArray,
    change_lines,
    idle_low_end,
    pwm_scale,
    supported_samples,
    throttle_fraction,
)
from thrustmap.fitting.export.rules import px4_rules
from thrustmap.fitting.mapfile import ThrustMap

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


def fit_px4(thrust_n: npt.ArrayLike, throttle_frac: npt.ArrayLike) -> Px4Fit:
    """THR_MDL_FAC as PX4's docs fit it: T = Tmax·(f·s² + (1 − f)·s), least squares in thrust.

    Linear in (A, C) = (Tmax·f, Tmax·(1 − f)), so Tmax need not be measured at full throttle.
    """
    t = np.asarray(thrust_n, float)
    s = np.asarray(throttle_frac, float)
    if t.size < 2:
        raise FitError("THR_MDL_FAC needs at least two (thrust, throttle) points")
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


#: a LiPo/LiHV cell on the stand, under load to full charge (V per cell): reads a cell count
CELL_V_RANGE = (3.0, 4.35)


def cells_from_voltage(lo_v: float, hi_v: float) -> int | None:
    """The fewest cells whose per-cell voltage holds ``lo_v..hi_v`` within :data:`CELL_V_RANGE`
    (a stand's pack is near charged, so the fewest cells is the likely count); None if none."""
    for cells in range(1, 15):
        if hi_v / cells <= CELL_V_RANGE[1] and lo_v / cells >= CELL_V_RANGE[0]:
            return cells
    return None


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
    idle_note = ""
    if scale.name == "pwm":
        scale, idle_note = idle_low_end(tmap, scale, opts.range_ is not None, "PWM minimum")
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
    ref = supported_samples(tmap, voltage_v=b_ref, n_thrust=81)
    s_ref = throttle_fraction(ref.throttle_pct, scale)
    keep = s_ref >= 0.0  # the curve is fitted above the output range's low end (the idle)
    ref = Samples(ref.thrust_n[keep], ref.voltage_v[keep], ref.throttle_pct[keep])
    s_ref = s_ref[keep]
    fit = fit_px4(ref.thrust_n, s_ref)
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
    values: dict[str, float] = {"THR_MDL_FAC": f, "thrust_max_n": fit.thrust_max_n}
    params: list[tuple[str, float, int]] = [("THR_MDL_FAC", f, 9)]
    notes = [
        f"fitted at {b_ref:g} V over thrust {tmap.validity.thrust_n.lo:g}.."
        f"{tmap.validity.thrust_n.hi:g} N; full-throttle thrust of the fitted curve "
        f"{fit.thrust_max_n:.4g} N per rotor",
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
    if opts.mass_kg is not None:
        rotors = opts.rotors or 4
        hover_n = opts.mass_kg * G0_MPS2 / rotors
        s_h = float(
            throttle_fraction(tmap.throttle_pct(np.array([hover_n]), np.array([b_ref])), scale)[0]
        )
        hover = float(px4_rel_thrust(s_h, f))
        notes.append(
            f"hover: {opts.mass_kg:g} kg on {rotors} rotors = {hover_n:.4g} N per rotor, throttle "
            f"{100 * s_h:.2f} % at {b_ref:g} V -> MPC_THR_HOVER {hover:.3f}"
        )
        if not tmap.validity.thrust_n.lo <= hover_n <= tmap.validity.thrust_n.hi:
            notes.append("WARNING: hover thrust is outside the map's thrust box (extrapolated)")
        params.append(("MPC_THR_HOVER", round(hover, 3), 9))
        values["MPC_THR_HOVER"] = round(hover, 3)
    if idle_note:
        notes.append(idle_note)
    if pwm_params and len(pwm_params) > 2:
        notes.append(
            f"PWM_MAIN_MINn/MAXn written for outputs 1..{rotors_out} (--rotors); if your motors "
            "sit on other outputs, apply the same values there"
        )
    params += pwm_params
    written = {n: float(v) for n, v, _ in params}
    rules.require(written)
    values.update(written)
    lines = (
        header_lines(tmap, "PX4 parameters (QGroundControl .params)", residual)
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
    return ExportResult("px4", text, dict(values), resid, ".params")
