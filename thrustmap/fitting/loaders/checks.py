"""The unit checks: every value a loader returns is questioned against physics (a battery's
voltage, an ESC pulse, the thrust a rotor can make per volt and per watt, a pulling
propeller's sign, a thrust that leaves the load cell's noise), and the step-summary shape."""

from __future__ import annotations

import logging
import re
from typing import Any

import numpy as np

from thrustmap.core.errors import DataFormatError
from thrustmap.core.physical import (  # the physical ranges live in one place
    BATTERY_V,
    G0,
    MAX_ROTOR_THRUST_N,
    MAX_THRUST_PER_VOLT_N,
    THRUST_PER_WATT_GF,
    TYPICAL_THRUST_PER_WATT_GF,
    one_cell_voltage,
    thrust_too_small_for_pack,
    thrust_unit_by_power,
)
from thrustmap.core.units import ThrottleScale
from thrustmap.fitting.dataset import Dataset, FloatArray
from thrustmap.fitting.loaders.table import Table

log = logging.getLogger(__name__)


#: Shape of a step summary: every row a new command at least this far (% of the throttle span)
#: from the previous one, and (where time is logged) rows this far apart: a stand's own log
#: samples at several Hz and repeats a held command, a step export holds each step for seconds.
STEP_SUMMARY_MIN_STEP_PCT = 1.0
STEP_SUMMARY_MIN_DT_S = 0.75


def is_step_summary(throttle: FloatArray, time_s: FloatArray | None, scale: ThrottleScale) -> bool:
    """True when the rows look like one averaged row per throttle step (the RCbenchmark app's
    "steps" export): at least three rows, every row at a command distinct from the previous one
    by ``STEP_SUMMARY_MIN_STEP_PCT`` of the span, and rows ``STEP_SUMMARY_MIN_DT_S`` apart in
    the median where the file has a time column. A continuous log repeats each held command; a
    ramp moves in small increments at the logging rate."""
    if len(throttle) < 3 or not np.all(np.isfinite(throttle)):
        return False
    step = np.abs(np.diff(throttle)) / scale.span * 100.0
    if float(step.min()) < STEP_SUMMARY_MIN_STEP_PCT:
        return False
    if time_s is not None:
        dt = np.diff(time_s)
        if not np.all(np.isfinite(dt)) or float(np.median(dt)) < STEP_SUMMARY_MIN_DT_S:
            return False
    return True


def check_voltage(table: Table, voltage_v: FloatArray, meta: dict[str, Any]) -> FloatArray:
    """Battery voltage must be a battery's (1S..14S); millivolts are converted and said."""
    lo, hi = BATTERY_V
    if voltage_v.size == 0:
        return voltage_v
    med = float(np.median(voltage_v))
    if lo * 1000 <= med <= hi * 1000:
        note = f"voltage reads {med:.0f} (median): taken as mV and divided by 1000"
        meta["voltage_note"] = note
        log.warning("%s: %s", table.path, note)
        voltage_v = voltage_v / 1000.0
    bad = np.flatnonzero((voltage_v < lo) | (voltage_v > hi))
    if bad.size:
        k = int(bad[0])
        raise DataFormatError(
            f"voltage {voltage_v[k]:g} V is not a battery voltage; expected {lo:g}..{hi:g} V "
            "(1S..14S) in volts or millivolts",
            file=table.path,
            line=table.lines[k],
        )
    return voltage_v


def check_thrust(
    table: Table,
    thrust_n: FloatArray,
    voltage_v: FloatArray,
    current_a: FloatArray | None,
    rotors_on_esc: int | None = None,
) -> None:
    """Thrust against what a rotor can make: absolute size, per volt of battery, and per
    electrical watt."""
    big = np.flatnonzero(np.abs(thrust_n) > MAX_ROTOR_THRUST_N)
    if big.size:
        k = int(big[0])
        raise DataFormatError(
            f"thrust {thrust_n[k]:g} N per rotor is beyond any multirotor stand "
            f"(> {MAX_ROTOR_THRUST_N:g} N); is the thrust unit right?",
            file=table.path,
            line=table.lines[k],
        )
    if current_a is not None:
        check_thrust_per_watt(table, thrust_n, voltage_v, current_a)
    rotors = max(rotors_on_esc or 1, 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        per_volt = np.abs(thrust_n) / rotors / voltage_v
    over = np.flatnonzero(np.isfinite(per_volt) & (per_volt > MAX_THRUST_PER_VOLT_N))
    if over.size >= max(3, 0.01 * len(thrust_n)):  # a stray spike alone is not a wrong unit
        k = int(over[0])
        raise DataFormatError(
            f"thrust {thrust_n[k] / rotors:g} N per rotor at {voltage_v[k]:.2f} V is "
            f"{per_volt[k]:.1f} N per volt of battery; no motor makes more than "
            f"{MAX_THRUST_PER_VOLT_N:g} N/V (~{MAX_THRUST_PER_VOLT_N * 3.7:.0f} N per cell): "
            "is the thrust unit right (grams read as newtons?)",
            file=table.path,
            line=table.lines[k],
        )


def thrust_per_watt_gf(
    thrust_n: FloatArray, voltage_v: FloatArray, current_a: FloatArray, rotors: int = 1
) -> float | None:
    """Median thrust per electrical watt at load, gf/W per rotor (None: too few rows at load):
    the rows above 1 W (a resting rotor's ESC draws a fraction of a watt) and a fifth of the
    top power, so a 2S motor's first steps count too."""
    power_w = np.abs(voltage_v * current_a) / max(rotors, 1)  # some stands log it negative
    ok = np.isfinite(power_w) & (power_w > max(1.0, 0.2 * float(np.nanmax(power_w, initial=0.0))))
    if ok.sum() < 3:
        return None
    return float(np.median(np.abs(thrust_n[ok]) / G0 * 1000.0 / power_w[ok]))


def check_thrust_per_watt(
    table: Table, thrust_n: FloatArray, voltage_v: FloatArray, current_a: FloatArray
) -> None:
    gf_per_w = thrust_per_watt_gf(thrust_n, voltage_v, current_a)
    if gf_per_w is None:
        return
    lo, hi = THRUST_PER_WATT_GF
    if not lo <= gf_per_w <= hi:
        raise DataFormatError(
            f"thrust per electrical watt is {gf_per_w:.3g} gf/W (median at load); propellers "
            f"make {lo:g}..{hi:g} gf/W: is the thrust (or current) unit right?",
            file=table.path,
        )


def check_one_cell(table: Table, ds_thrust_n: FloatArray, voltage_v: FloatArray,
                   current_a: FloatArray | None, meta: dict[str, Any]) -> None:  # fmt: skip
    """A voltage column reading one lithium cell (``physical.one_cell_voltage``): a per-cell
    column of a bigger pack is refused; a 1S pack is said (``meta["voltage_note"]``)."""
    if not voltage_v.size:
        return
    gf_per_w = None if current_a is None else thrust_per_watt_gf(ds_thrust_n, voltage_v,
                                                                  current_a)  # fmt: skip
    top = float(np.nanmax(np.abs(ds_thrust_n), initial=0.0))
    refused, why = one_cell_voltage(float(np.median(voltage_v)), gf_per_w, top)
    if refused:
        raise DataFormatError(why, file=table.path)
    if why:
        meta["voltage_note"] = why
        log.warning("%s: %s", table.path, why)


def check_unnamed_thrust_unit(ds: Dataset, given: str) -> None:
    """A thrust column whose header names no unit, read in the ``given`` unit: beside a current
    column its thrust per watt names the unit (``physical.thrust_unit_by_power``); without
    one, a thrust too small for the pack and the throttle is questioned."""
    rotors = ds.rotors_on_esc or 1
    if ds.current_a is not None:
        gf_per_w = thrust_per_watt_gf(ds.thrust_n, ds.voltage_v, ds.current_a, rotors)
        unit = None if gf_per_w is None else thrust_unit_by_power(gf_per_w, given)
        if gf_per_w is not None and unit is not None and unit.lower() != given.lower():
            raise DataFormatError(
                f"thrust column (no unit in its header) read in {given} gives {gf_per_w:.3g} "
                f"gf/W at load; propellers make {TYPICAL_THRUST_PER_WATT_GF[0]:g}.."
                f"{TYPICAL_THRUST_PER_WATT_GF[1]:g} gf/W, which it gives in {unit}: "
                f"--thrust-unit {unit}? (a column truly in {given}, or a current that feeds "
                f"several motors of which one is on the load cell: name its unit in the header, "
                f"'Thrust ({given})')",
                file=ds.path,
            )
        return
    pct = ds.throttle_pct
    if not pct.size:
        return
    top = pct >= np.quantile(pct, 0.9)
    why = thrust_too_small_for_pack(
        float(np.median(np.abs(ds.thrust_n[top]))) / rotors,
        float(np.median(ds.voltage_v[top])),
        float(np.median(pct[top])),
        given,
    )
    if why is not None:
        raise DataFormatError(why, file=ds.path)


def normalise_sign(
    thrust_n: FloatArray, throttle: FloatArray, meta: dict[str, Any], path: str
) -> FloatArray:
    """A pulling propeller is positive: flip when thrust at the highest throttles is negative."""
    top = throttle >= np.quantile(throttle, 0.75)
    if np.median(thrust_n[top]) < 0:
        meta["thrust_sign_flipped"] = True
        log.info("%s: thrust reads negative for a pulling propeller; sign flipped", path)
        return -thrust_n
    return thrust_n


_THOUSANDS = re.compile(r"\d{1,2}\.\d{3}")


def check_pulse_us(table: Table, index: int, us: FloatArray) -> FloatArray:
    """An ESC pulse is 500..2600 µs. Cells like ``1.500`` below that are a spreadsheet's
    thousands separator (1500 µs): converted and said; anything else is refused."""
    lo, hi = 500.0, 2600.0
    bad = np.flatnonzero(np.isfinite(us) & ((us < lo) | (us > hi)))
    if not bad.size:
        return us
    cells = [table.rows[i][index].strip() for i in bad]
    if all(_THOUSANDS.fullmatch(c) for c in cells) and np.all(us[bad] * 1000 >= lo):
        us = us.copy()
        us[bad] *= 1000.0
        note = (
            f"'{table.header[index]}': {len(bad)} cells like '{cells[0]}' read as "
            f"{us[bad[0]]:g} µs ('.' taken as a thousands separator)"
        )
        table.notes.append(note)
        log.warning("%s: %s", table.path, note)
        return us
    k = int(bad[0])
    raise DataFormatError(
        f"'{table.rows[k][index].strip()[:30]}' is not an ESC pulse; expected {lo:g}..{hi:g} µs",
        file=table.path,
        line=table.lines[k],
        column=table.header[index],
    )


#: a Ds log's thrust "leaves the noise" when at least this share of its samples lies beyond
#: ``THRUST_NOISE_SIGMAS`` noise deviations (never less than ``THRUST_NOISE_FLOOR_N``) from zero
THRUST_LEAVES_SHARE = 0.01
THRUST_NOISE_SIGMAS = 6.0
THRUST_NOISE_FLOOR_N = 0.005


def check_thrust_leaves_noise(ds: Dataset) -> None:
    """Refuse a thrustmap Ds log whose thrust never leaves the load cell's noise.

    Such a log (a thrown propeller, an unplugged load cell, a stand measuring a motor nobody
    drove) fits a map that is pure noise. The noise is measured on the log itself, from the
    sample-to-sample differences (median |diff| / 0.954 is the deviation of Gaussian noise,
    and the few steps of a sweep do not move a median); the runner tares the stand, so zero
    thrust is 0. A load cell that holds its value between updates (most differences 0) cannot
    be judged this way and is never refused."""
    if ds.format != "thrustmap":
        return
    thrust = ds.thrust_n[np.isfinite(ds.thrust_n)]
    diffs = np.abs(np.diff(thrust))
    diffs = diffs[diffs > 0]
    if thrust.size < 20 or diffs.size < thrust.size // 2:
        return
    band = max(THRUST_NOISE_SIGMAS * float(np.median(diffs)) / 0.954, THRUST_NOISE_FLOOR_N)
    if np.count_nonzero(np.abs(thrust) > band) >= THRUST_LEAVES_SHARE * thrust.size:
        return
    pct = ds.throttle_scale.to_pct(ds.throttle_native[np.isfinite(ds.throttle_native)])
    top = float(np.max(pct)) if pct.size else 0.0
    raise DataFormatError(
        f"thrust never leaves the load cell's noise (|T| <= {band:.3f} N) with the throttle up "
        f"to {top:.0f} %: expected a thrust that follows the command (a thrown propeller, an "
        "unplugged load cell, or the stand measuring another motor?)",
        file=ds.path,
    )
