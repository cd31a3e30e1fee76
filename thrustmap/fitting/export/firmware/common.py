"""What the three firmware exports share: the map's supported samples, throttle as a
fraction of the output range, the measured spin-up in it, and the output's low end."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from thrustmap.core.errors import ConfigError, FitError
from thrustmap.core.physical import cells_from_voltage
from thrustmap.core.units import SCALES, ThrottleScale
from thrustmap.fitting.export.encodings import ExportOptions, Samples, map_samples, target_scale
from thrustmap.fitting.export.rules import Firmware
from thrustmap.fitting.mapfile import ThrustMap
from thrustmap.fitting.mapvalues import saturation_pct
from thrustmap.fitting.spinup import SpinUp

FloatArray = npt.NDArray[np.float64]


def throttle_fraction(tmap_pct: FloatArray, scale: ThrottleScale) -> FloatArray:
    """Throttle as a fraction of ``scale``'s range (percent of the map -> encoding -> 0..1)."""
    native = SCALES[scale.name].from_pct(tmap_pct)
    return np.asarray((native - scale.lo) / scale.span, dtype=float)


def supported_samples(
    tmap: ThrustMap, *, n_thrust: int = 41, n_voltage: int = 9, voltage_v: float | None = None
) -> Samples:
    """Map samples over the validity box, kept where the map's throttle lies inside the
    throttle range measured on the stand (the supported region): the corner of the box at high
    thrust and low voltage asks for more than the motor gave, and is not fitted nor scored."""
    s = map_samples(tmap, n_thrust=n_thrust, n_voltage=n_voltage, voltage_v=voltage_v)
    th = tmap.validity.throttle_pct
    keep = (s.throttle_pct >= th.lo - 1e-9) & (s.throttle_pct <= th.hi + 1e-9)
    if int(keep.sum()) < 3:
        raise FitError("fewer than three map points inside the measured throttle range")
    return Samples(s.thrust_n[keep], s.voltage_v[keep], s.throttle_pct[keep])


def pwm_scale(opts: ExportOptions) -> ThrottleScale:
    name = opts.encoding or "pwm"
    if name not in ("pwm", "oneshot125", "oneshot42", "multishot"):
        raise ConfigError(f"this export takes a PWM-style --encoding, not '{name}'")
    return target_scale(name, opts.range_)


def spin_up_native(tmap: ThrustMap, encoding: str) -> float | None:
    """The measured spin-up in ``encoding``'s units (its default range), None when unknown."""
    block = SpinUp.from_dict(tmap.spin_up) if tmap.spin_up else None
    if block is None or block.throttle_pct is None:
        return None
    return float(SCALES[encoding].from_pct(block.throttle_pct))


def idle_low_end(
    tmap: ThrustMap, scale: ThrottleScale, given: bool, what: str
) -> tuple[ThrottleScale, str]:
    """The output range's low end (the armed idle) at or above the measured spin-up: raised to
    it when the user gave no --range, refused when the given one is below it."""
    spin = spin_up_native(tmap, scale.name)
    if spin is None:
        _, why = spin_up_fraction(tmap, scale)
        return scale, f"{what} kept at {scale.lo:g} {scale.unit}: {why}"
    if given:
        if scale.lo < spin - 1e-9:
            raise ConfigError(
                f"--range low end {scale.lo:g} {scale.unit} ({what}) is below {spin:.6g}, the "
                "lowest command the stand saw spinning reliably: a motor can stall there"
            )
        return scale, f"{what} {scale.lo:g} {scale.unit} as given (stand spin-up {spin:.6g})"
    if spin <= scale.lo:
        return scale, f"{what} {scale.lo:g} {scale.unit} is above the stand spin-up {spin:.6g}"
    lo = float(math.ceil(spin - 1e-9))
    if not lo < scale.hi:
        raise ConfigError(f"stand spin-up {spin:.6g} is at or above the range top {scale.hi:g}")
    return scale.with_range(lo, scale.hi), (
        f"{what} raised from {scale.lo:g} to {lo:g} {scale.unit}: the stand saw reliable "
        "spin and thrust only from there (the curve is fitted above it)"
    )


def saturation_high_end(
    tmap: ThrustMap, scale: ThrottleScale, given: bool, what: str
) -> tuple[ThrottleScale, str]:
    """The output range's top at the command where the stand saw the ESC's output saturate
    (the map's ``saturation``): lowered to it when the user gave no --range (every command
    above it adds no thrust, so the mixer's full output belongs there), kept and named when
    the given range reaches above it. ("", unchanged) when the map saw no saturation."""
    sat = saturation_pct(tmap)
    if sat is None:
        return scale, ""
    top = float(math.floor(float(SCALES[scale.name].from_pct(sat)) + 1e-9))
    if top >= scale.hi:
        return scale, ""
    if given:
        return scale, (
            f"{what} {scale.hi:g} {scale.unit} as given, above {top:g} {scale.unit} where the "
            "stand saw the ESC's output saturate: commands above it add no thrust"
        )
    if not top > scale.lo:
        raise ConfigError(
            f"the ESC's output saturated at {top:g} {scale.unit}, at or below the range's low "
            f"end {scale.lo:g}: recalibrate the ESC's end points and measure again"
        )
    return scale.with_range(scale.lo, top), (
        f"{what} lowered from {scale.hi:g} to {top:g} {scale.unit}: the stand saw the ESC's "
        "output saturate there (thrust stopped rising), so the mixer's full output is put "
        "where thrust ends; recalibrating the ESC's end points would give the range back "
        "(--range keeps yours)"
    )


def spin_up_fraction(tmap: ThrustMap, scale: ThrottleScale) -> tuple[float | None, str]:
    """The measured spin-up as a fraction of ``scale`` (None when the data cannot tell), and
    one sentence saying where it comes from."""
    block = SpinUp.from_dict(tmap.spin_up) if tmap.spin_up else None
    if block is None:
        return None, (
            "the map records no measured spin-up (fitted before this tool measured it): the "
            "stand data cannot tell"
        )
    if block.throttle_pct is None:
        return None, block.reason
    frac = float(throttle_fraction(np.array([block.throttle_pct]), scale)[0])
    native = float(SCALES[scale.name].from_pct(block.throttle_pct))
    return frac, (
        f"the stand saw the motor spin and make thrust from {native:.6g} {scale.unit} "
        f"({frac:.4f} of {scale.lo:g}..{scale.hi:g}) in every sweep ({block.signal})"
    )


def change_lines(rules: Firmware, written: dict[str, float]) -> list[str]:
    return [f"firmware: {rules.header()}", "written vs the firmware defaults:"] + [
        f"  {line}" for line in rules.changes(written)
    ]


def voltage_outside_line(tmap: ThrustMap, what: str, voltage_v: float) -> str | None:
    """The header line for a written voltage outside the voltages the map was measured at (None
    inside them): how far, and the map's interval there against inside (its κ term)."""
    region = tmap.supported_region()
    lo_v, hi_v = region.voltage_lo_v, region.voltage_hi_v
    if lo_v <= voltage_v <= hi_v:
        return None
    edge = min(max(voltage_v, lo_v), hi_v)
    t_lo, t_hi = (float(x) for x in region.thrust_range(edge))
    t_mid = 0.5 * (t_lo + t_hi)
    inside = tmap.interval_pct(t_mid, edge)
    there = tmap.interval_pct(t_mid, voltage_v)
    side = "below" if voltage_v < lo_v else "above"
    iv = (
        ""
        if inside is None or there is None
        else f"; the map's 95 % interval at {t_mid:.3g} N grows from ±{float(inside):.2f} % "
        f"throttle at {edge:.2f} V to ±{float(there):.2f} % there"
    )
    return (
        f"{what} = {voltage_v:.4g} V: {side} the voltages measured ({lo_v:.2f}..{hi_v:.2f} V), "
        f"|ln(B/B_edge)| = {abs(math.log(voltage_v / edge)):.3f}{iv}"
    )


def pack_line(tmap: ThrustMap) -> str:
    """The header line naming the pack the map was measured on (its cell count, read from its
    voltages): the vehicle this export is loaded on must fly the same pack."""
    box = tmap.validity.voltage_v
    cells = cells_from_voltage(box.lo, box.hi)
    if cells is None:
        return (
            f"pack: the map's voltages {box.lo:.2f}..{box.hi:.2f} V do not tell the cell count; "
            "load this only on a vehicle flying the pack the stand used"
        )
    return (
        f"pack: {cells}S, read from the map's {box.lo:.2f}..{box.hi:.2f} V "
        f"({box.lo / cells:.2f}..{box.hi / cells:.2f} V a cell): load this only on a {cells}S "
        "vehicle"
    )
