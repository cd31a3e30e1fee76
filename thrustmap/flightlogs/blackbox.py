"""Betaflight blackbox logs (.bbl/.bfl, decoded by our own decoder) -> :class:`FlightLog`.

The unit and sign normalisation here is shared with the blackbox_decode CSV reader
(:mod:`blackbox_csv`), which builds the same :class:`BlackboxTable`:

- ``accel_up_mps2`` = +accSmooth[2] / acc_1G · 9.80665 (acc_1G from the headers, an option, or
  inferred from the median magnitude of the accelerometer, snapped to a power of two).
- ``voltage_v`` from vbatLatest with its scale decided from the data and ``vbatref``: Betaflight
  4.0–4.2 logs hold 0.01 V units (the official decoder divides by 10 below 4.3 regardless),
  3.x logs 0.1 V. The candidate scale that gives a plausible pack voltage wins.
- ``motor_outputs`` in the firmware's motor units (DShot values for DShot/ProShot, µs-equivalent
  otherwise) with ``motor_output_scale`` spanning the ``motorOutput`` header range.
- ``armed`` from slow-frame flightModeFlags bit 0 (the ARM box in Betaflight >= 3.2, whose
  slow frames log the mode-activation mask) and the disarm event; otherwise from the motors.
- ``thrust_cmd_norm`` = (rcCommand[3] − 1000) / 1000: the pilot's stick throttle, not the mixer.
"""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

import thrustmap.flightlogs.blackbox_format as blackbox_format
from thrustmap.core.errors import DataFormatError
from thrustmap.core.units import ThrottleScale
from thrustmap.flightlogs import blackbox_decode as bd
from thrustmap.flightlogs.series import FlightLog, Signal

log = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]
G0 = 9.80665
#: Betaflight motor protocols at or above this index are digital (DShot150.., ProShot).
FIRST_DIGITAL_PROTOCOL = 5
DSHOT_RANGE = (48.0, 2047.0)
#: why a log with no data frames is skipped (df.extraction groups these in one line)
EMPTY_LOG = "empty (no data frames)"


@dataclass
class BlackboxTable:
    """Main-frame columns of one log plus what is needed to normalise them."""

    headers: dict[str, str]
    time_us: FloatArray
    fields: dict[str, FloatArray]  # by field name without unit, e.g. "accSmooth[2]"
    units: dict[str, str] = field(default_factory=dict)  # "raw" unless a CSV says otherwise
    mode_time_us: FloatArray | None = None  # when flightModeFlags took each value
    mode_flags: npt.NDArray[np.int64] | None = None
    disarm_time_us: float | None = None
    warnings: list[str] = field(default_factory=list)
    metadata: dict[str, Any] = field(default_factory=dict)


def median(x: FloatArray) -> float:
    """The median of the finite values (NaN when none): :func:`series.nanmedian`'s value, found
    by partitioning rather than sorting (a log's columns hold 10^4..10^5 values)."""
    v = x[np.isfinite(x)]
    if not len(v):
        return float("nan")
    lo, hi = (len(v) - 1) // 2, len(v) // 2
    part = np.partition(v, (lo, hi))
    return float(0.5 * (part[lo] + part[hi]))


# --- sniff / read ----------------------------------------------------------------------------


def sniff(path: Path, head: bytes) -> bool:
    return blackbox_format.LOG_START_MARKER[:30] in head


def read(
    path: Path | str,
    *,
    acc_1g: float | None = None,
    vbat_scale_v: float | None = None,
    **_options: Any,
) -> list[FlightLog]:
    """Every flight (log) in a .bbl/.bfl file, one :class:`FlightLog` each."""
    p = Path(path)
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise DataFormatError(f"cannot read blackbox log: {exc.strerror}", file=str(p)) from None
    ranges = blackbox_format.split_logs(data)
    if not ranges:
        raise DataFormatError(
            "not a blackbox log: no 'H Product:Blackbox flight data recorder' header found",
            file=str(p),
        )
    flights: list[FlightLog] = []
    notes: list[str] = []
    if ranges[0][0] > 0:
        notes.append(f"{ranges[0][0]} bytes before the first log header ignored")
    refused: list[dict[str, Any]] = []  # logs of a multi-log file that could not be read
    for i, (a, b) in enumerate(ranges):
        try:
            decoded = bd.decode_log(data[a:b], index=i, offset=a, keep_field=used_field)
        except blackbox_format.CorruptFrame as exc:
            notes.append(f"log {i + 1} of {len(ranges)} skipped: {exc}")
            refused.append(refusal(i, len(ranges), f"corrupt: {exc}"))
            continue
        if len(decoded.main) == 0:
            notes.append(f"log {i + 1} of {len(ranges)} holds no data frames (empty log), skipped")
            refused.append(refusal(i, len(ranges), EMPTY_LOG))
            continue
        table = table_from_decoded(decoded)
        try:
            flights.append(to_flightlog(table, str(p), "blackbox", i, acc_1g, vbat_scale_v))
        except DataFormatError as exc:
            if len(ranges) == 1:
                raise
            # one log of a flash dump that cannot be normalised: the others are still read
            why = (f"column '{exc.column}': " if exc.column else "") + exc.message
            notes.append(f"log {i + 1} of {len(ranges)} skipped: {why}")
            refused.append(refusal(i, len(ranges), why))
    if not flights:
        detail = "; ".join(notes) or "no frames"
        raise DataFormatError(
            f"blackbox file holds {len(ranges)} log(s) but none with usable data ({detail})",
            file=str(p),
        )
    # the logs skipped are listed once (metadata, reported by whoever extracts: one line each),
    # not repeated in the warnings of every flight of a 44-log flash dump
    skipped = {f"log {r['log']} of {len(ranges)} " for r in refused}
    general = [n for n in notes if not any(n.startswith(k) for k in skipped)]
    for fl in flights:
        fl.warnings[:0] = general
        fl.metadata["logs_in_file"] = len(ranges)
        fl.metadata["logs_refused_by_reader"] = refused
    for note in notes:
        log.debug("%s: %s", p, note)
    return flights


def refusal(index: int, logs: int, why: str) -> dict[str, Any]:
    """One unusable log of a multi-log file: its number as Betaflight's viewer and
    blackbox_decode count them (1-based over every log start in the file), and why."""
    return {"log": index + 1, "logs_in_file": logs, "reason": why}


#: the main-frame fields a flight log is built from (to_flightlog); the decoder skips the rest.
#: INAV names the battery fields ``vbat`` and ``amperage`` (its blackbox.c blackboxMainFields).
USED_FIELDS = re.compile(
    r"vbatLatest|amperageLatest|vbat|amperage|accSmooth\[[012]\]|motor\[\d+\]|rcCommand\[3\]"
)


def used_field(name: str) -> bool:
    return USED_FIELDS.fullmatch(name) is not None


def table_from_decoded(d: blackbox_format.DecodedLog) -> BlackboxTable:
    cols = {name: d.main[:, k].astype(float) for k, name in enumerate(d.main_fields)}
    time_us = cols.pop("time")
    # slow frames and events sit between main frames: time them at the next main frame (one
    # frame interval after the last one when they follow it)
    step = median(np.diff(time_us)) if len(time_us) > 1 else 0.0
    frame_time = np.append(time_us, time_us[-1] + step)
    n = len(time_us)
    mode_t: FloatArray | None = None
    mode_f: npt.NDArray[np.int64] | None = None
    if "flightModeFlags" in d.slow_fields and len(d.slow):
        k = d.slow_fields.index("flightModeFlags")
        mode_t = frame_time[np.clip(d.slow_frame_index, 0, n)]
        mode_f = d.slow[:, k].astype(np.int64)
    disarm = [e.frame_index for e in d.events if e.kind == blackbox_format.EVENT_DISARM]
    disarm_t = float(frame_time[min(disarm[0], n)]) if disarm else None
    meta: dict[str, Any] = {
        "frames": dict(d.stats),
        "ended_cleanly": d.ended_cleanly,
        "byte_range": list(d.byte_range),
        "events": [
            {"frame": e.frame_index, "type": e.kind, "data": list(e.data)} for e in d.events
        ],
    }
    if "loopIteration" in cols:
        meta["loop_iterations"] = [int(cols["loopIteration"][0]), int(cols["loopIteration"][-1])]
    warnings = list(d.warnings)
    if not d.ended_cleanly:
        warnings.append(f"log {d.index + 1} has no log-end event (recording cut off?)")
    return BlackboxTable(
        headers=d.headers,
        time_us=time_us,
        fields=cols,
        units={k: "raw" for k in cols},
        mode_time_us=mode_t,
        mode_flags=mode_f,
        disarm_time_us=disarm_t,
        warnings=warnings,
        metadata=meta,
    )


# --- normalisation ---------------------------------------------------------------------------


def plausible_pack_voltage(v: float) -> bool:
    """A 1–14 cell lithium pack (2.8–4.45 V per cell)."""
    return any(2.8 * n <= v <= 4.45 * n for n in range(1, 15))


def firmware_version(headers: dict[str, str]) -> tuple[str, tuple[int, ...]]:
    rev = headers.get("Firmware revision", "")
    m = re.match(r"\s*(\w+)\s+(\d+)\.(\d+)(?:\.(\d+))?", rev)
    if not m:
        return rev.split(" ")[0] if rev else "", ()
    return m.group(1), tuple(int(x) for x in m.groups()[1:] if x is not None)


def decide_vbat_scale(
    raw: FloatArray, unit: str, headers: dict[str, str]
) -> tuple[float | None, str]:
    """Volts per logged unit of vbatLatest (None when no battery is sensed) and why."""
    good = raw[np.isfinite(raw) & (raw > 0)]
    if unit == "raw":
        candidates = [0.01, 0.1]
    elif unit.lower() == "v":  # decoder printed raw/10 (< 4.3) or raw/100 (>= 4.3)
        candidates = [1.0, 0.1]
    elif unit.lower() == "mv":
        candidates = [1e-3, 1e-4]
    else:
        raise DataFormatError(f"vbatLatest in unknown unit '{unit}'", column="vbatLatest")
    med = median(good)
    if len(good) == 0 or med * max(candidates) < 1.0:
        return None, "no battery voltage sensed (vbatLatest ~ 0)"
    plausible = [c for c in candidates if plausible_pack_voltage(med * c)]
    vbatref = blackbox_format.header_int(headers, "vbatref", 0)
    ref_v = None
    if vbatref > 0:
        ref_v = next(
            (vbatref * s for s in (0.01, 0.1) if plausible_pack_voltage(vbatref * s)), None
        )
    if len(plausible) == 1 and (ref_v is None or 0.5 <= med * plausible[0] / ref_v <= 1.2):
        return plausible[0], f"median {med * plausible[0]:.2f} V is the only plausible pack voltage"
    if ref_v is not None:
        best = min(candidates, key=lambda c: abs(np.log(med * c / ref_v)))
        return best, f"closest to vbatref {ref_v:.2f} V (median {med * best:.2f} V)"
    if plausible:
        return plausible[
            0
        ], f"ambiguous; assumed {plausible[0]} V/unit (median {med * plausible[0]:.2f} V)"
    return candidates[
        0
    ], f"no plausible pack voltage (median {med:g} units); assumed {candidates[0]} V/unit"


def infer_acc_1g(ax: FloatArray, ay: FloatArray, az: FloatArray) -> float:
    """acc_1G from the median accelerometer magnitude, snapped to a power of two within 10 %."""
    mag = median(np.sqrt(ax * ax + ay * ay + az * az))
    if not mag > 0:
        raise DataFormatError(
            "cannot infer acc_1G: the accelerometer reads zero", column="accSmooth"
        )
    pow2 = 2.0 ** round(np.log2(mag))
    return pow2 if abs(mag / pow2 - 1.0) < 0.1 else mag


def _accel_mps2(
    table: BlackboxTable, axis: int, acc_1g: float | None
) -> tuple[FloatArray, str, float | None]:
    name = f"accSmooth[{axis}]"
    raw = table.fields[name]
    unit = table.units.get(name, "raw").lower()
    if unit in ("m/s/s", "m/s2", "m/s²"):
        return raw, name, None
    if unit == "g":
        return raw * G0, f"{name} (g)", None
    if acc_1g is None:
        raise DataFormatError("acc_1G unknown", column=name)
    return raw / acc_1g * G0, f"{name} / acc_1G {acc_1g:g}", acc_1g


def motor_scale(
    headers: dict[str, str], motors: FloatArray, warnings: list[str]
) -> tuple[ThrottleScale, float, str]:
    """The ESC's 0..100 % range for the motor values, the idle value and where both came from.

    DShot: the ESC's range is 48..2047 whatever the headers say; the low end of the
    ``motorOutput`` header is the idle Betaflight spins at when armed (``dshot_idle_value``,
    e.g. 158 = 5.5 %), not 0 %. PWM-family protocols: 0 % is ``mincommand`` (1000 when the
    headers lack it), 100 % the high end of ``motorOutput`` (maxthrottle); the low end
    (minthrottle) is idle."""
    protocol = blackbox_format.header_int(headers, "motor_pwm_protocol", -1)
    lo = blackbox_format.header_int(headers, "motorOutput", -1, 0)
    hi = blackbox_format.header_int(headers, "motorOutput", -1, 1)
    if lo < 0 or hi <= lo:
        lo = blackbox_format.header_int(headers, "minthrottle", -1)
        hi = blackbox_format.header_int(headers, "maxthrottle", -1)
    if firmware_version(headers)[0] == "INAV":
        return inav_motor_scale(headers, lo, hi, protocol, warnings)
    digital = protocol >= FIRST_DIGITAL_PROTOCOL
    if protocol < 0:  # no headers: guess from the values
        digital = bool(len(motors)) and float(np.nanmin(motors)) < 900.0
        warnings.append(
            "motor protocol unknown (no headers); assumed "
            + ("DShot" if digital else "PWM-equivalent µs")
        )
    if digital:
        scale = ThrottleScale("dshot", DSHOT_RANGE[0], DSHOT_RANGE[1], "dshot")
        idle = float(lo) if 0 <= lo < hi else DSHOT_RANGE[0]
        idle_pct = float(scale.to_pct(idle))
        src = (
            f"DShot {DSHOT_RANGE[0]:g}..{DSHOT_RANGE[1]:g} (the ESC's 0..100 %); motorOutput low "
            f"end {idle:g} is the armed idle ({idle_pct:.1f} %)"
        )
        if "dshot_idle_value" in headers:
            src += f", dshot_idle_value {blackbox_format.header_int(headers, 'dshot_idle_value', 0) / 100:g} %"
        return scale, idle, src
    zero = blackbox_format.header_int(headers, "mincommand", -1)
    if lo < 0 or hi <= lo:
        lo, hi = 1000, 2000
        warnings.append(f"motorOutput range unknown; assumed {lo}..{hi}")
    src_zero = "mincommand" if zero > 0 else "assumed 1000 (no mincommand header)"
    if not 0 < zero < hi:
        zero = 1000 if hi > 1000 else lo
    scale = ThrottleScale("pwm", float(zero), float(hi), "us")
    src = (
        f"PWM {zero}..{hi} us ({src_zero} .. motorOutput high end); motorOutput low end {lo} "
        "is the armed idle (minthrottle)"
    )
    return scale, float(lo), src


#: INAV's default ``min_command`` (µs), the motor value it sends when stopped: used when the
#: log's headers do not carry ``mincommand`` (INAV 8 writes no such header).
INAV_MINCOMMAND_DEFAULT = 1000


def inav_motor_scale(
    headers: dict[str, str], lo: int, hi: int, protocol: int, warnings: list[str]
) -> tuple[ThrottleScale, float, str]:
    """INAV logs motor[] as its mixer computes them (blackbox.c loadMainState: motor[i]), in
    µs-equivalent mincommand..maxthrottle whatever the protocol; for DShot, flight/mixer.c
    writeMotors scales mincommand..maxthrottle onto DShot 48..2047 when it sends them. So 0 %
    is mincommand and 100 % maxthrottle; the ``motorOutput`` low end is the armed idle (the
    mixer's throttleIdleValue). Betaflight's DShot range never applies to these values."""
    zero = blackbox_format.header_int(headers, "mincommand", -1)
    zero_src = "mincommand"
    if not 0 < zero < hi:
        zero, zero_src = INAV_MINCOMMAND_DEFAULT, "INAV's default min_command (not in the headers)"
    if lo < 0 or hi <= lo:
        lo, hi = 1100, 2000
        warnings.append(f"motorOutput range unknown; assumed INAV's {lo}..{hi}")
    scale = ThrottleScale("pwm", float(zero), float(hi), "us")
    proto = f"motor_pwm_protocol {protocol}" if protocol >= 0 else "protocol not in the headers"
    src = (
        f"INAV: motor[] in µs-equivalent {zero}..{hi} ({zero_src} .. motorOutput high end, "
        f"maxthrottle) whatever the protocol ({proto}: INAV's mixer scales these onto DShot "
        f"48..2047 itself); motorOutput low end {lo} is the armed idle"
    )
    return scale, float(lo), src


def inav_vbat_scale(raw: FloatArray) -> tuple[float | None, str]:
    """INAV's ``vbat`` field is getBatteryRawVoltage(), in 0.01 V (sensors/battery.c); the
    ``vbatref`` header is the same value at log start."""
    good = raw[np.isfinite(raw) & (raw > 0)]
    med = median(good)
    if len(good) == 0 or med * 0.01 < 1.0:
        return None, "no battery voltage sensed (INAV vbat ~ 0)"
    v = med * 0.01
    why = "INAV logs vbat in 0.01 V (blackbox.c loadMainState: getBatteryRawVoltage())"
    if not plausible_pack_voltage(v):
        return None, f"{why}, but the median {v:.2f} V is no lithium pack's voltage"
    return 0.01, why


def accelerometer_off_reason(headers: dict[str, str]) -> str:
    """Why a log's accelerometer reads exactly zero, naming what the headers say."""
    said = []
    fw = firmware_version(headers)[0]
    if "acc_hardware" in headers:
        hw = blackbox_format.header_int(headers, "acc_hardware", -1)
        # Betaflight/Cleanflight accelerationSensor_e: 0 default (auto), 1 NONE
        none = hw == 1 and fw != "INAV"
        said.append(f"header acc_hardware:{headers['acc_hardware']}" + (" is NONE" if none else ""))
    if "acc_1G" in headers and blackbox_format.header_int(headers, "acc_1G", -1) == 0:
        said.append("acc_1G:0")
    return "all zero: accelerometer disabled?" + (f" {', '.join(said)}" if said else "")


def _armed(
    table: BlackboxTable, time_s: FloatArray, motors: FloatArray | None, idle: float | None
) -> Signal | None:
    fw, version = firmware_version(table.headers)
    flags_are_boxes = fw in ("", "Betaflight") and (not version or version >= (3, 2))
    if table.mode_flags is not None and table.mode_time_us is not None and flags_are_boxes:
        t = table.mode_time_us * 1e-6
        v = (table.mode_flags & 1).astype(float)
        origin = "flightModeFlags bit 0 (ARM box)"
        if table.disarm_time_us is not None:
            t = np.append(t, table.disarm_time_us * 1e-6)
            v = np.append(v, 0.0)
            origin += " + disarm event"
        order = np.argsort(t, kind="stable")
        t, v = t[order], v[order]
        if len(t) and t[0] > time_s[0]:
            t = np.insert(t, 0, time_s[0])
            v = np.insert(v, 0, v[0])
        keep = np.append(t[1:] > t[:-1], True)  # last value wins at equal times
        return Signal(t[keep], v[keep], "bool", origin)
    if motors is not None and idle is not None:
        armed = (np.nanmin(motors, axis=1) >= idle - 1.0).astype(float)
        return Signal(time_s, armed, "bool", f"all motors >= motorOutput low (idle) {idle:g}")
    return None


def to_flightlog(
    table: BlackboxTable,
    path: str,
    fmt: str,
    index: int,
    acc_1g: float | None = None,
    vbat_scale_v: float | None = None,
) -> FlightLog:
    """Normalise one blackbox table into the common shape."""
    warnings = list(table.warnings)
    t_us = table.time_us
    ok = np.isfinite(t_us)
    keep = ok & np.append(True, t_us[1:] > np.maximum.accumulate(np.where(ok, t_us, -np.inf))[:-1])
    if int((~keep).sum()):
        warnings.append(
            f"{int((~keep).sum())} frame(s) with missing or non-increasing time dropped"
        )
    time_s = t_us[keep] * 1e-6
    if len(time_s) == 0:
        raise DataFormatError("blackbox log has no frames with a valid time", file=path)
    cols = {k: v[keep] for k, v in table.fields.items()}
    headers = table.headers
    fl = FlightLog(path=path, format=fmt, index=index, warnings=warnings)
    meta = fl.metadata
    fw, version = firmware_version(headers)
    meta.update(
        firmware=fw,
        firmware_version=".".join(str(x) for x in version),
        firmware_revision=headers.get("Firmware revision", ""),
        craft_name=headers.get("Craft name", ""),
        board=headers.get("Board information", ""),
        time_origin="flight controller boot",
        duration_s=float(time_s[-1] - time_s[0]),
        sample_rate_hz=float((len(time_s) - 1) / (time_s[-1] - time_s[0]))
        if len(time_s) > 1
        else 0.0,
        headers=dict(headers),
    )
    meta.update(table.metadata)

    inav = fw == "INAV"
    vbat_name = "vbatLatest" if "vbatLatest" in cols or not inav else "vbat"
    if vbat_name in cols:
        unit = table.units.get(vbat_name, "raw")
        if vbat_scale_v is not None:
            scale_v: float | None = vbat_scale_v
            reason = "given"
        elif inav and unit == "raw":
            scale_v, reason = inav_vbat_scale(cols[vbat_name])
        else:
            scale_v, reason = decide_vbat_scale(cols[vbat_name], unit, headers)
        meta["vbat_scale_v_per_unit"] = scale_v
        meta["vbat_scale_reason"] = reason
        if scale_v is None:
            warnings.append(f"battery voltage not used: {reason}")
        else:
            fl.voltage_v = Signal(
                time_s, cols[vbat_name] * scale_v, "V", f"{vbat_name} ({unit}) × {scale_v:g}"
            )
    amp_name = "amperageLatest" if "amperageLatest" in cols or not inav else "amperage"
    if amp_name in cols:  # 0.01 A: Betaflight's amperageLatest, INAV's getAmperage()
        unit = table.units.get(amp_name, "raw")
        factor = 0.01 if unit == "raw" else (1e-3 if unit.lower() == "ma" else 1.0)
        fl.extras["current_a"] = Signal(
            time_s, cols[amp_name] * factor, "A", f"{amp_name} ({unit})"
        )

    acc_names = [f"accSmooth[{k}]" for k in range(3)]
    acc_zero = all(n in cols for n in acc_names) and not any(
        np.any(np.nan_to_num(cols[n]) != 0.0) for n in acc_names
    )
    if acc_zero:  # the craft logs accSmooth but has no accelerometer running
        warnings.append(f"no accelerometer data in this log ({accelerometer_off_reason(headers)})")
    if all(n in cols for n in acc_names) and not acc_zero:
        if acc_1g is not None:
            source = "option"
        elif "acc_1G" in headers:
            acc_1g, source = float(blackbox_format.header_int(headers, "acc_1G", 0)), "header"
        else:
            acc_1g, source = None, ""
        if (acc_1g is None or acc_1g <= 0) and all(
            table.units.get(n, "raw") == "raw" for n in acc_names
        ):
            acc_1g = infer_acc_1g(*(cols[n] for n in acc_names))
            source = "inferred from the median accelerometer magnitude"
            warnings.append(f"acc_1G not in the log; {source}: {acc_1g:g}")
        up, origin, used = _accel_mps2(BlackboxTable(headers, t_us, cols, table.units), 2, acc_1g)
        fl.accel_up_mps2 = Signal(time_s, up, "m/s^2", "+" + origin)
        for k, name in ((0, "accel_x_mps2"), (1, "accel_y_mps2")):
            a, o, _ = _accel_mps2(BlackboxTable(headers, t_us, cols, table.units), k, acc_1g)
            fl.extras[name] = Signal(time_s, a, "m/s^2", o)
        if used is not None:
            meta["acc_1g"] = used
            meta["acc_1g_source"] = source

    motor_names = sorted(
        (n for n in cols if re.fullmatch(r"motor\[\d+\]", n)), key=lambda n: int(n[6:-1])
    )
    motors: FloatArray | None = None
    if motor_names:
        motors = np.stack([cols[n] for n in motor_names], axis=1)
        fl.motor_output_scale, idle, scale_src = motor_scale(headers, motors, warnings)
        meta["motor_idle"] = idle
        meta["motor_output_scale_source"] = scale_src
        meta["motor_channels"] = f"{len(motor_names)} motor fields in the log header"
        fl.motor_outputs = Signal(
            time_s, motors, fl.motor_output_scale.unit, f"{motor_names[0]}..{motor_names[-1]}"
        )
        meta["motor_count"] = len(motor_names)
    if "rcCommand[3]" in cols:
        fl.thrust_cmd_norm = Signal(
            time_s,
            (cols["rcCommand[3]"] - 1000.0) / 1000.0,
            "1",
            "rcCommand[3] (pilot stick throttle 1000..2000, not the mixer output)",
        )
    fl.armed = _armed(table, time_s, motors, meta.get("motor_idle"))
    return fl
