"""Betaflight: thrust_linear in both of its forms (before 2026.6 and from it), fitted to the
map."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
import scipy.optimize as opt

from thrustmap.core.errors import ConfigError, FitError
from thrustmap.fitting.export.encodings import (
    ExportOptions,
    ExportResult,
    Samples,
    comment,
    export_values,
    header_lines,
    reference_voltage,
    rms_max,
    target_scale,
)
from thrustmap.fitting.export.firmware.common import (
    FloatArray,
    change_lines,
    pack_line,
    spin_up_fraction,
    spin_up_native,
    supported_samples,
    throttle_fraction,
)
from thrustmap.fitting.export.rules import betaflight_rules
from thrustmap.fitting.mapfile import ThrustMap


def betaflight_generation(firmware: str | None) -> str:
    """'legacy' (before 2026.6) or '2026.6' from a version string like 4.5, 2025.12, 2026.6."""
    if not firmware:
        raise ConfigError(
            "betaflight export needs --firmware VERSION (e.g. 4.5, 2025.12, 2026.6): "
            "thrust_linear changed formula in 2026.6"
        )
    try:
        parts = tuple(int(p) for p in firmware.strip().split(".")[:2])
    except ValueError:
        raise ConfigError(
            f"--firmware: expected a version like 4.5 or 2026.6, got '{firmware}'"
        ) from None
    return "2026.6" if parts >= (2026, 6) else "legacy"


def betaflight_out(m: npt.ArrayLike, e: float, generation: str) -> FloatArray:
    x = np.asarray(m, float)
    if generation == "legacy":
        return np.asarray(x * (1.0 + e * (1.0 - x) ** 2), dtype=float)
    return np.asarray(x * (1.0 + e * (1.0 - x) * (1.0 + e * (1.0 - 2.0 * x))), dtype=float)


def betaflight_m(out: npt.ArrayLike, e: float, generation: str) -> FloatArray:
    """Inverse of ``betaflight_out`` on 0..1 (bisection; the curve is monotone there)."""
    y = np.clip(np.asarray(out, float), 0.0, 1.0)
    lo, hi = np.zeros_like(y), np.ones_like(y)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        below = betaflight_out(mid, e, generation) < y
        lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
    return np.asarray(0.5 * (lo + hi), dtype=float)


def betaflight_max_expo(generation: str) -> float:
    """Largest e the fit may use: Betaflight's 150 limit, or where the 2026.6 curve stops rising.

    d(out)/dm for 2026.6 is 1 + e·x + e²·(1.5x² − 0.5) with x = 1 − 2m, whose minimum
    5/6 − e²/2 is negative above e = √(5/3) ≈ 1.29: such a curve would not be invertible.
    """
    return 1.5 if generation == "legacy" else math.floor(100 * math.sqrt(5 / 3)) / 100


@dataclass(frozen=True)
class BetaflightFit:
    thrust_linear: int
    expo: float
    thrust_max_n: float


def fit_betaflight(
    thrust_n: npt.ArrayLike, out: npt.ArrayLike, generation: str, thrust_max_n: float | None = None
) -> BetaflightFit:
    """thrust_linear minimising output error; the thrust scale T_max is fitted with it, or held
    at ``thrust_max_n`` (the map's full-throttle thrust, ``fitting.mapvalues``): m = 1 is then
    where the map says full output is."""
    t = np.asarray(thrust_n, float)
    y = np.asarray(out, float)
    if t.size < 3:
        raise FitError("thrust_linear fit needs at least three points")
    if thrust_max_n is not None:
        return _fit_betaflight_expo(t, y, generation, thrust_max_n)

    def resid(x: FloatArray) -> FloatArray:
        pred = betaflight_out(np.clip(t / x[1], 0.0, 1.0), float(x[0]), generation)
        return np.asarray(pred - y, dtype=float)

    e_max = betaflight_max_expo(generation)
    best: tuple[float, FloatArray] | None = None
    for e0 in np.arange(0.0, e_max + 1e-9, 0.1):
        m = betaflight_m(y, float(e0), generation)
        tmax = float(np.dot(t, m) / max(np.dot(m, m), 1e-300))
        if tmax > 0:
            x0 = np.array([e0, tmax])
            cost = float(np.sum(resid(x0) ** 2))
            if best is None or cost < best[0]:
                best = (cost, x0)
    if best is None:
        raise FitError("thrust_linear fit: thrust does not increase with throttle")
    sol = opt.least_squares(
        resid,
        np.array([min(best[1][0], e_max), best[1][1]]),
        bounds=([0.0, 1e-9], [e_max, np.inf]),
        xtol=1e-12,
        ftol=1e-12,
    )
    e = float(sol.x[0])
    return BetaflightFit(int(round(100 * e)), e, float(sol.x[1]))


def _fit_betaflight_expo(
    t: FloatArray, y: FloatArray, generation: str, thrust_max_n: float
) -> BetaflightFit:
    """e alone (T_max held), least squares in output: a scan, then refined."""
    m = np.clip(t / thrust_max_n, 0.0, 1.0)

    def resid(x: FloatArray) -> FloatArray:
        return np.asarray(betaflight_out(m, float(x[0]), generation) - y, dtype=float)

    e_max = betaflight_max_expo(generation)
    grid = np.linspace(0.0, e_max, 31)
    e0 = grid[int(np.argmin([np.sum(resid(np.array([e])) ** 2) for e in grid]))]
    sol = opt.least_squares(resid, np.array([e0]), bounds=([0.0], [e_max]), xtol=1e-12, ftol=1e-12)
    e = float(sol.x[0])
    return BetaflightFit(int(round(100 * e)), e, float(thrust_max_n))


def export_betaflight(tmap: ThrustMap, opts: ExportOptions) -> ExportResult:
    generation = betaflight_generation(opts.firmware)
    assert opts.firmware is not None  # betaflight_generation refuses None
    rules = betaflight_rules(opts.firmware)
    idle_name = "dshot_idle_value" if rules.title == "Betaflight 4.5" else "motor_idle"
    enc = opts.encoding or "dshot"
    if enc not in ("dshot", "pwm"):
        raise ConfigError(f"betaflight export takes --encoding dshot or pwm, not '{enc}'")
    spin = spin_up_native(tmap, enc)
    default_idle = int(rules.param(idle_name).default or 0)
    if enc == "dshot":
        if opts.range_ is None:
            idle = default_idle
            if spin is not None:
                idle = max(idle, math.ceil((spin - 48.0) / 1999.0 * 10000 - 1e-6))
            limit = 100
        else:
            lo, hi = opts.range_
            idle = round((lo - 48.0) / 1999.0 * 10000)
            limit = round((hi - 48.0) / 1999.0 * 100)
        settings = [(idle_name, idle), ("motor_output_limit", limit)]
        rules.require(dict(settings))
        lo, hi = 48.0 + idle / 10000 * 1999.0, 2047.0 - 1999.0 * (1 - limit / 100)
    else:
        base_lo = 1070.0 if idle_name == "dshot_idle_value" else 1000.0 + default_idle / 10
        lo, hi = opts.range_ or (max(base_lo, math.ceil(spin - 1e-6)) if spin else base_lo, 2000.0)
        lo, hi = float(round(lo)), float(round(hi))
        if idle_name == "dshot_idle_value":
            settings = [("min_throttle", int(lo)), ("max_throttle", int(hi))]
        else:  # 4.6+: the PWM low end is min_command (default 1000) + motor_idle / 10 µs
            settings = [(idle_name, int(round((lo - 1000.0) * 10))), ("max_throttle", int(hi))]
        rules.require(dict(settings))
    if spin is None:
        _, why = spin_up_fraction(tmap, target_scale(enc))
        idle_note = f"idle {lo:.6g} {enc}: {why}; check every motor spins at idle"
    elif lo < spin - 1e-6:
        raise ConfigError(
            f"--range low end {lo:.6g} ({idle_name}) is below {spin:.6g}, the lowest command "
            "the stand saw spinning reliably: a motor can stall or desync at idle"
        )
    else:
        idle_note = (
            f"idle {lo:.6g} {enc} at or above the stand spin-up {spin:.6g} (firmware default "
            f"{idle_name} {default_idle}); thrust_linear is fitted above it"
        )
    scale = target_scale(enc, (lo, hi))
    b_ref = reference_voltage(tmap, opts.voltage_v)
    mv = export_values(tmap, scale, opts, b_ref)
    ref = supported_samples(tmap, voltage_v=b_ref, n_thrust=81)
    out = throttle_fraction(ref.throttle_pct, scale)
    keep = out >= 0.0  # above idle
    ref = Samples(ref.thrust_n[keep], ref.voltage_v[keep], ref.throttle_pct[keep])
    out = out[keep]
    full = mv.full_throttle
    fit = fit_betaflight(ref.thrust_n, out, generation, None if full is None else full.value)
    e = fit.thrust_linear / 100.0
    pred = betaflight_out(np.clip(ref.thrust_n / fit.thrust_max_n, 0, 1), e, generation)
    r_ref = rms_max(100 * (pred - out))
    box = supported_samples(tmap)
    out_box = throttle_fraction(box.throttle_pct, scale)
    keep = out_box >= 0.0
    box = Samples(box.thrust_n[keep], box.voltage_v[keep], box.throttle_pct[keep])
    out_box = out_box[keep]
    pred_box = betaflight_out(np.clip(box.thrust_n / fit.thrust_max_n, 0, 1), e, generation)
    r_box = rms_max(100 * (pred_box - out_box))
    lin = betaflight_out(np.clip(ref.thrust_n / fit.thrust_max_n, 0, 1), 0.0, generation)
    r_lin = rms_max(100 * (lin - out))
    residual = [
        f"thrust_linear={fit.thrust_linear} curve vs map at {b_ref:g} V: RMS {r_ref[0]:.3f} %, "
        f"max {r_ref[1]:.3f} % of the motor output range (thrust_linear=0 would leave RMS "
        f"{r_lin[0]:.3f} %)",
        f"over the supported region of the voltage box (Betaflight's curve has no voltage term): RMS {r_box[0]:.3f} %, "
        f"max {r_box[1]:.3f} %; vbat_sag_compensation addresses part of this",
    ]
    formula = (
        "out = m*(1 + e*(1-m)^2)" if generation == "legacy"
        else "out = m*(1 + e*(1-m)*(1 + e*(1-2m)))"
    )  # fmt: skip
    notes = [
        f"firmware {opts.firmware} -> {formula}, e = thrust_linear/100, m = T/T_max; fitted "
        f"e = {fit.expo:.4f}, "
        + (
            f"T_max held at the map's full-throttle thrust {fit.thrust_max_n:.4g} N per rotor "
            f"at {b_ref:g} V ({full.interval_text()})"
            if full is not None
            else f"T_max {fit.thrust_max_n:.4g} N fitted (the map cannot say its full-throttle "
            "thrust)"
        ),
        f"motor output range {lo:.6g}..{hi:.6g} ({enc}) set by the lines below"
        + (
            " (the PWM low end is min_command + motor_idle/10 us: min_command must stay at "
            "its default 1000)"
            if enc == "pwm" and idle_name == "motor_idle"
            else ""
        ),
    ]
    if fit.expo > betaflight_max_expo(generation) - 0.005:
        notes.append(
            f"WARNING: fit hit the limit {round(100 * betaflight_max_expo(generation))}; "
            "the map is more curved than this firmware's curve can follow"
        )
    notes.append(idle_note)
    notes.append(pack_line(tmap))
    written = {"thrust_linear": float(fit.thrust_linear), **{k: float(v) for k, v in settings}}
    rules.require(written)
    lines = (
        header_lines(tmap, f"Betaflight CLI ({generation} thrust_linear)", residual, mv)
        + change_lines(rules, written)
        + notes
    )
    text = comment(lines, "#")
    text += f"set thrust_linear = {fit.thrust_linear}\n"
    text += "".join(f"set {k} = {v}\n" for k, v in settings) + "save\n"
    values: dict[str, Any] = {"thrust_linear": fit.thrust_linear, "expo": fit.expo}
    values["full_throttle_thrust_n"] = fit.thrust_max_n
    values["thrust_max_n"] = fit.thrust_max_n
    values["map_values"] = mv
    values.update({k: float(v) for k, v in settings})
    resid = {"rms_pct": r_ref[0], "max_pct": r_ref[1], "box_rms_pct": r_box[0]}
    return ExportResult("betaflight", text, values, resid, ".txt")
