"""Load Ds (bench data) from stand logs, auto-detected by header.

Formats: RCbenchmark (Tyto app) logs and their spreadsheet re-saves, Flight Stand exports,
Crazyflie system-id logs, the project's own Ds log (:mod:`thrustmap.core.dslog`), and any CSV through an
explicit ``ColumnMap``. Every error names the file, the line or column, and what was expected.

What a loader assumes, it says (``Dataset.meta`` and a logged warning):

- the shape of the rows: a step-summary export (one averaged row per throttle step) is marked
  ``meta["layout"]``; a sparse log (each sensor written when it updates) keeps the rows with a
  thrust reading and carries the last command and voltage forward only within a bounded age;
- a last row without a line end that is cut short (a partial write) is dropped;
- units checked against physics: a battery voltage (1S..14S; millivolts are converted), an ESC
  pulse of 500..2600 µs (a spreadsheet's ``1.500`` is 1500 µs), per-rotor thrust a stand can
  measure, and thrust per electrical watt a propeller can make; anything else is refused with
  the file, line and column. A written ``nan`` or ``inf`` is never a measurement.
"""

from __future__ import annotations

import csv
import hashlib
import logging
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from thrustmap.core import dslog
from thrustmap.core.errors import DataFormatError
from thrustmap.core.physical import (  # the physical ranges live in one place
    BATTERY_V,
    G0,
    MAX_ROTOR_THRUST_N,
    MAX_THRUST_PER_VOLT_N,
    THRUST_PER_WATT_GF,
    check_header_unit,
)
from thrustmap.core.units import SCALES, ThrottleScale
from thrustmap.fitting.dataset import (
    SAMPLE_AND_HOLD,
    STEP_SUMMARY,
    BoolArray,
    Dataset,
    FloatArray,
    IntArray,
)

log = logging.getLogger(__name__)

THRUST_UNITS: dict[str, float] = {
    "n": 1.0,
    "kgf": G0,
    "kg": G0,
    "gf": G0 / 1000.0,
    "g": G0 / 1000.0,
    "lbf": 4.4482216152605,
    "ozf": 0.27801385095378,
}


@dataclass(frozen=True)
class ColumnMap:
    """How to read a CSV no built-in format recognises (``--col-*`` options on the CLI)."""

    throttle: str
    thrust: str
    voltage: str
    time: str | None = None
    current: str | None = None
    rpm: str | None = None
    thrust_unit: str = "N"
    throttle_scale: ThrottleScale = SCALES["pwm"]
    rotors_on_esc: int | None = None


@dataclass
class _Table:
    path: str
    header: list[str]  # as written in the file
    keys: list[str]  # normalised for matching
    rows: list[list[str]]
    lines: list[int]  # 1-based line number of each row
    delimiter: str
    notes: list[str] = field(default_factory=list)  # conversions made while reading, for meta
    decimal_comma: bool | None = None  # decided on first use


def normalise_header(name: str) -> str:
    """Fold the variants stand software writes: Greek/micro µ, dot operators, spacing, case."""
    s = name.replace("\u03bc", "\u00b5").replace("\u22c5", "\u00b7").replace("\ufeff", "")
    return re.sub(r"\s+", " ", s).strip().lower()


def read_table(path: str | Path) -> _Table:
    """Read a delimited text file with line numbers kept; detect delimiter; refuse binaries."""
    p = Path(path)
    name = str(path)
    try:
        raw = p.read_bytes()
    except IsADirectoryError:
        raise DataFormatError("is a directory; expected a CSV file", file=name) from None
    except OSError as exc:
        raise DataFormatError(f"cannot read: {exc.strerror}", file=name) from None
    if not raw.strip():
        raise DataFormatError("file is empty; expected a CSV header and data rows", file=name)
    nul = raw.find(b"\x00")
    if nul >= 0:
        raise DataFormatError(
            f"binary data (NUL byte at offset {nul}); expected a text CSV file", file=name
        )
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        text = raw.decode("cp1252", errors="replace")  # Windows-saved logs: µ is 0xB5
    lines = text.splitlines()
    first = next((i for i, ln in enumerate(lines) if ln.strip() and not ln.startswith("#")), None)
    if first is None:
        raise DataFormatError("no header line found; expected a CSV header", file=name)
    head = lines[first]
    delimiter = max((",", ";", "\t"), key=head.count)
    if head.count(delimiter) == 0:
        raise DataFormatError(
            "header has a single column; expected fields separated by ',', ';' or tab",
            file=name,
            line=first + 1,
        )
    parsed = _parse_rows(lines[first:], delimiter, name, first)
    header = [h.strip() for h in parsed[0]]
    while header and header[-1] == "":  # RCbenchmark's trailing comma
        header.pop()
    rows: list[list[str]] = []
    numbers: list[int] = []
    for offset, row in enumerate(parsed[1:], start=first + 2):
        if not row or all(not c.strip() for c in row):
            continue
        rows.append(row)
        numbers.append(offset)
    keys = [normalise_header(h) for h in header]
    notes: list[str] = []
    if rows and not text.endswith(("\n", "\r")) and _torn(rows, dslog.is_ds_header(keys)):
        note = f"last row (line {numbers[-1]}) has no line end and is cut short: dropped"
        notes.append(note + " (a partial write?)")
        log.warning("%s: %s (a partial write?)", name, note)
        rows.pop()
        numbers.pop()
    if not rows:
        raise DataFormatError("header only, no data rows", file=name, line=first + 1)
    return _Table(name, header, keys, rows, numbers, delimiter, notes)


#: a stand log's field is a number or a short label: a longer one is not a stand CSV
MAX_FIELD_CHARS = 10_000


def _parse_rows(lines: list[str], delimiter: str, name: str, first: int) -> list[list[str]]:
    """CSV rows; a field too long to be a number or a label is refused with its line."""
    for k, ln in enumerate(lines):
        if len(ln) > MAX_FIELD_CHARS and any(len(f) > MAX_FIELD_CHARS for f in ln.split(delimiter)):
            raise DataFormatError(
                f"a field of {max(len(f) for f in ln.split(delimiter))} characters; expected "
                f"numbers or short labels (at most {MAX_FIELD_CHARS})",
                file=name,
                line=first + k + 1,
            )
    reader = csv.reader(lines, delimiter=delimiter)
    try:
        return list(reader)
    except csv.Error as exc:
        raise DataFormatError(
            f"not a CSV row: {exc}", file=name, line=first + reader.line_num
        ) from None


def _torn(rows: list[list[str]], always: bool) -> bool:
    """Is the last row (written without a line end) cut short? Yes when ``always`` (a writer that
    ends every row, as thrustmap's own), when it has fewer fields than the rows before it, or
    when its last cell is shorter than that column's cell in every earlier row (a number cut
    in the middle still parses: ``23.9`` of ``23.912``)."""
    if always or len(rows) < 2:
        return always
    last = rows[-1]
    counts = sorted(len(r) for r in rows[:-1])
    if len(last) < counts[len(counts) // 2]:
        return True
    k = max((i for i, c in enumerate(last) if c.strip()), default=-1)
    if k < 0:
        return False
    earlier = [len(r[k].strip()) for r in rows[:-1] if k < len(r) and r[k].strip()]
    return bool(earlier) and len(last[k].strip()) < min(earlier)


def _find(table: _Table, pattern: str) -> tuple[int, re.Match[str]] | None:
    rx = re.compile(pattern)
    hits = [(i, m) for i, k in enumerate(table.keys) if (m := rx.fullmatch(k))]
    if len(hits) > 1:
        cols = ", ".join(f"{table.header[i]!r} (column {i + 1})" for i, _ in hits)
        raise DataFormatError(
            f"duplicated header: {cols}; expected one such column", file=table.path
        )
    return hits[0] if hits else None


_DECIMAL_COMMA = re.compile(r"-?\d*,\d+")
_GROUPED = re.compile(r"-?\d{1,3}(?:\.\d{3})+(?:,\d*)?")


def _uses_decimal_comma(table: _Table) -> bool:
    """A ';'-separated re-save from a locale that writes 1.234,5: some cell has a decimal comma."""
    if table.decimal_comma is None:
        table.decimal_comma = table.delimiter == ";" and any(
            _DECIMAL_COMMA.fullmatch(c.strip()) for row in table.rows for c in row
        )
    return table.decimal_comma


def _column(table: _Table, index: int, *, allow_empty: bool = False) -> FloatArray:
    """Convert column ``index`` to floats; name the line and column of the first bad cell.

    Empty cells are NaN with ``allow_empty`` and an error otherwise; a written ``nan`` or
    ``inf`` is always an error (a measurement that cannot be). In a file with decimal commas,
    dots are thousands separators (``1.500`` is 1500, said in the dataset's notes)."""
    cells: list[str] = []
    for row, line in zip(table.rows, table.lines, strict=True):
        if index >= len(row):
            raise DataFormatError(
                f"row has {len(row)} fields; expected at least {index + 1}",
                file=table.path,
                line=line,
            )
        cells.append(row[index].strip())
    col = table.header[index]
    decimal_comma = _uses_decimal_comma(table)
    if not decimal_comma:  # fast path; the slow one below names the first bad cell
        empty = np.array([not c for c in cells], dtype=bool)
        try:
            fast = np.asarray([c or "nan" for c in cells], dtype=float)
        except ValueError:
            fast = None
        clean = fast is not None and not (~np.isfinite(fast) & ~empty).any()
        if fast is not None and clean and (allow_empty or not empty.any()):
            return fast
    grouped = 0
    values = np.empty(len(cells))
    for k, cell in enumerate(cells):
        text = cell
        if decimal_comma:
            if "." in text:
                if not _GROUPED.fullmatch(text):
                    raise DataFormatError(
                        f"'{cell[:30]}' mixes '.' into a decimal-comma file; expected a number "
                        "like 1.234,5 or 1234,5",
                        file=table.path,
                        line=table.lines[k],
                        column=col,
                    )
                text = text.replace(".", "")
                grouped += 1
            text = text.replace(",", ".")
        if not text:
            if not allow_empty:
                raise DataFormatError(
                    "empty cell; expected a number",
                    file=table.path,
                    line=table.lines[k],
                    column=col,
                )
            values[k] = np.nan
            continue
        try:
            v = float(text)
        except ValueError:
            raise DataFormatError(
                f"'{cell[:30]}' is not a number; expected a number",
                file=table.path,
                line=table.lines[k],
                column=col,
            ) from None
        if not np.isfinite(v):
            raise DataFormatError(
                f"'{cell[:30]}' is not a finite number; expected a measured value",
                file=table.path,
                line=table.lines[k],
                column=col,
            )
        values[k] = v
    if grouped:
        note = f"'{col}': '.' read as a thousands separator in {grouped} cells (decimal commas)"
        if note not in table.notes:
            table.notes.append(note)
            log.warning("%s: %s", table.path, note)
    return values


def _thrust_factor(table: _Table, index: int, unit: str) -> float:
    factor = THRUST_UNITS.get(unit.lower())
    if factor is None:
        raise DataFormatError(
            f"unknown thrust unit '{unit}'; expected one of: N, kgf, gf, g, lbf, ozf",
            file=table.path,
            column=table.header[index],
        )
    return factor


def _need(table: _Table, pattern: str, what: str, fmt: str) -> tuple[int, re.Match[str]]:
    hit = _find(table, pattern)
    if hit is None:
        raise DataFormatError(f"{fmt} log has no {what} column", file=table.path)
    return hit


def _sha256(path: str) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _finish(
    table: _Table,
    fmt: str,
    scale: ThrottleScale,
    throttle: FloatArray,
    thrust_n: FloatArray,
    voltage_v: FloatArray,
    *,
    time_s: FloatArray | None = None,
    current_a: FloatArray | None = None,
    rpm: FloatArray | None = None,
    rotors_on_esc: int | None = None,
    meta: dict[str, Any] | None = None,
    step: IntArray | None = None,
    settled: BoolArray | None = None,
) -> Dataset:
    meta = dict(meta or {})
    voltage_v = _check_voltage(table, voltage_v, meta)
    if table.notes:
        meta["read_notes"] = list(table.notes)
    thrust_n = _normalise_sign(thrust_n, throttle, meta, table.path)
    _check_thrust(table, thrust_n, voltage_v, current_a, rotors_on_esc)
    if step is None and "layout" not in meta and is_step_summary(throttle, time_s, scale):
        meta["layout"] = STEP_SUMMARY
        log.info(
            "%s: step-summary export (one averaged row per throttle step, %d steps): "
            "every row is taken as a steady-state point",
            table.path,
            len(throttle),
        )
    return Dataset(
        path=table.path,
        format=fmt,
        throttle_scale=scale,
        throttle_native=throttle,
        thrust_n=thrust_n,
        voltage_v=voltage_v,
        line=np.asarray(table.lines, dtype=np.int64),
        time_s=time_s,
        current_a=current_a,
        rpm=rpm,
        rotors_on_esc=rotors_on_esc,
        step=step,
        settled=settled,
        sha256=_sha256(table.path),
        meta=meta,
    )


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


# BATTERY_V, THRUST_PER_WATT_GF, MAX_ROTOR_THRUST_N, MAX_THRUST_PER_VOLT_N: core.physical


def _check_voltage(table: _Table, voltage_v: FloatArray, meta: dict[str, Any]) -> FloatArray:
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


def _check_thrust(
    table: _Table,
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
        _check_thrust_per_watt(table, thrust_n, voltage_v, current_a)
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


def _check_thrust_per_watt(
    table: _Table, thrust_n: FloatArray, voltage_v: FloatArray, current_a: FloatArray
) -> None:
    power_w = np.abs(voltage_v * current_a)  # some stands log the current negative
    # rows at load: above 1 W (a resting rotor's ESC draws a fraction of a watt) and a fifth of
    # the top power, so a 2S motor's first steps count too (grams read as newtons at any throttle)
    ok = np.isfinite(power_w) & (power_w > max(1.0, 0.2 * float(np.nanmax(power_w, initial=0.0))))
    if ok.sum() < 3:
        return
    gf_per_w = float(np.median(np.abs(thrust_n[ok]) / G0 * 1000.0 / power_w[ok]))
    lo, hi = THRUST_PER_WATT_GF
    if not lo <= gf_per_w <= hi:
        raise DataFormatError(
            f"thrust per electrical watt is {gf_per_w:.3g} gf/W (median at load); propellers "
            f"make {lo:g}..{hi:g} gf/W: is the thrust (or current) unit right?",
            file=table.path,
        )


def _normalise_sign(
    thrust_n: FloatArray, throttle: FloatArray, meta: dict[str, Any], path: str
) -> FloatArray:
    """A pulling propeller is positive: flip when thrust at the highest throttles is negative."""
    top = throttle >= np.quantile(throttle, 0.75)
    if np.median(thrust_n[top]) < 0:
        meta["thrust_sign_flipped"] = True
        log.info("%s: thrust reads negative for a pulling propeller; sign flipped", path)
        return -thrust_n
    return thrust_n


# -- the formats -----------------------------------------------------------------------------

MU = "\u00b5"


#: Sparse logs (each sensor written when it updates): how old a carried-forward command or
#: voltage may be, in seconds where the log has a time column, else in rows.
CARRY_THROTTLE_S = 0.5
CARRY_VOLTAGE_S = 2.0
CARRY_THROTTLE_ROWS = 5
CARRY_VOLTAGE_ROWS = 20
#: A log is sparse (not a dense log with a hole) when this share of rows lacks a required cell.
SPARSE_MIN_FRACTION = 0.1


_THOUSANDS = re.compile(r"\d{1,2}\.\d{3}")


def _check_pulse_us(table: _Table, index: int, us: FloatArray) -> FloatArray:
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


def _carry(values: FloatArray, age_axis: FloatArray, max_age: float) -> tuple[FloatArray, int]:
    """Forward-fill NaN cells with the last value at most ``max_age`` old on ``age_axis``
    (time or row index); returns the filled column and how many cells were filled."""
    have = np.isfinite(values)
    idx = np.where(have, np.arange(len(values)), -1)
    np.maximum.accumulate(idx, out=idx)
    src = np.maximum(idx, 0)
    fresh = (idx >= 0) & (age_axis - age_axis[src] <= max_age)
    out = np.where(fresh, values[src], np.nan)
    return np.asarray(out, dtype=float), int((fresh & ~have).sum())


def _assemble(
    table: _Table,
    fmt: str,
    scale: ThrottleScale,
    cols: dict[str, int | None],
    thrust_factor: float,
    *,
    meta: dict[str, Any] | None = None,
    rotors_on_esc: int | None = None,
    current_factor: float = 1.0,
) -> Dataset:
    """Columns ``throttle``, ``thrust``, ``voltage`` (required) and ``time``, ``current``, ``rpm``
    (optional) into a Dataset. A dense log must have every required cell; a sparse one (empty
    cells in the required columns: each sensor logged when it updates) keeps the rows with a
    thrust reading and carries the last command and voltage forward within a bounded age."""
    meta = dict(meta or {})
    raw = {k: _column(table, i, allow_empty=True) for k, i in cols.items() if i is not None}
    if scale.unit == "us":
        raw["throttle"] = _check_pulse_us(table, cols["throttle"] or 0, raw["throttle"])
    required = ("throttle", "thrust", "voltage")
    gaps = ~np.all([np.isfinite(raw[k]) for k in required], axis=0)
    if float(gaps.mean()) < SPARSE_MIN_FRACTION:
        for k in (*required, "time"):  # a dense log with a few holes: the first one is an error
            if cols.get(k) is not None:
                _column(table, cols[k] or 0)
        keep = np.ones(len(table.rows), dtype=bool)
    else:
        t = raw.get("time")
        if t is not None and not np.all(np.isfinite(t)):
            bad = int(np.flatnonzero(~np.isfinite(t))[0])
            raise DataFormatError(
                "empty cell; expected a time on every row of a sparse log",
                file=table.path,
                line=table.lines[bad],
                column=table.header[cols["time"] or 0],
            )
        if t is not None and np.any(np.diff(t) < 0):
            bad = int(np.flatnonzero(np.diff(t) < 0)[0]) + 1
            raise DataFormatError(
                "time goes backwards; expected increasing times in a sparse log",
                file=table.path,
                line=table.lines[bad],
                column=table.header[cols["time"] or 0],
            )
        axis = t if t is not None else np.arange(len(table.rows), dtype=float)
        unit = "s" if t is not None else " rows"
        ages = {
            "throttle": CARRY_THROTTLE_S if t is not None else CARRY_THROTTLE_ROWS,
            "voltage": CARRY_VOLTAGE_S if t is not None else CARRY_VOLTAGE_ROWS,
        }
        have_thrust = np.isfinite(raw["thrust"])
        filled: dict[str, int] = {}
        for k in ("throttle", "voltage", "current", "rpm"):
            if k in raw:
                age = ages.get(k, ages["throttle"])
                raw[k], filled[k] = _carry(raw[k], axis, age)
        keep = have_thrust & np.isfinite(raw["throttle"]) & np.isfinite(raw["voltage"])
        if not keep.any():
            raise DataFormatError(
                "sparse log: no row has a thrust reading with a throttle command and a voltage "
                f"at most {ages['throttle']:g}{unit} / {ages['voltage']:g}{unit} old",
                file=table.path,
            )
        stale = int((have_thrust & ~keep).sum())
        meta["sparse"] = (
            f"sensors logged as they update: kept the {int(keep.sum())} rows with a thrust "
            f"reading of {len(keep)}; throttle carried forward on {filled['throttle']} rows "
            f"(at most {ages['throttle']:g}{unit} old), voltage on {filled['voltage']} rows "
            f"(at most {ages['voltage']:g}{unit} old)"
            + (f"; {stale} thrust rows dropped: no command or voltage that recent" if stale else "")
        )
        log.warning("%s: %s", table.path, meta["sparse"])
        table = replace(
            table,
            rows=[r for r, k in zip(table.rows, keep, strict=True) if k],
            lines=[n for n, k in zip(table.lines, keep, strict=True) if k],
        )

    def opt(k: str, factor: float = 1.0) -> FloatArray | None:
        return None if k not in raw else raw[k][keep] * factor

    return _finish(
        table,
        fmt,
        scale,
        raw["throttle"][keep],
        raw["thrust"][keep] * thrust_factor,
        raw["voltage"][keep],
        time_s=opt("time"),
        current_a=opt("current", current_factor),
        rpm=opt("rpm"),
        rotors_on_esc=rotors_on_esc,
        meta=meta,
    )


def _rcbenchmark(table: _Table) -> Dataset | None:
    th = _find(table, rf"esc(?: signal)? \({MU}s\)")
    thrust = _find(table, r"thrust \(([^)]*)\)")
    if th is None or thrust is None:
        return None
    volt = _need(table, r"voltage \(v\)", "'Voltage (V)'", "RCbenchmark")
    factor = _thrust_factor(table, thrust[0], thrust[1].group(1))
    t = _find(table, r"time \(s\)")
    cur = _find(table, r"current \(a\)")
    rpm = _find(table, r"motor electrical speed \(rpm\)") or _find(
        table, r"motor optical speed \(rpm\)"
    )
    return _assemble(
        table,
        "rcbenchmark" if t is not None else "rcbenchmark-resaved",
        SCALES["pwm"],
        {
            "throttle": th[0],
            "thrust": thrust[0],
            "voltage": volt[0],
            "time": None if t is None else t[0],
            "current": None if cur is None else cur[0],
            "rpm": None if rpm is None else rpm[0],
        },
        factor,
    )


def _flight_stand(table: _Table) -> Dataset | None:
    rx = re.compile(rf"(.+) - esc throttle \({MU}s\)")
    trains = [(i, m) for i, k in enumerate(table.keys) if (m := rx.fullmatch(k))]
    if not trains:
        return None
    th = trains[0]
    name = th[1].group(1)
    meta: dict[str, Any] = {"powertrain": name}
    if len({m.group(1) for _, m in trains}) > 1:
        others = ", ".join(repr(table.header[i]) for i, _ in trains[1:])
        meta["powertrain_note"] = f"several powertrains: loaded '{name}' only; ignored {others}"
        log.warning("%s: %s", table.path, meta["powertrain_note"])
    elif len(trains) > 1:
        _find(table, rx.pattern)  # the same powertrain twice: the duplicated-header error
    prefix = re.escape(name)
    thrust = _need(
        table, rf"{prefix} - force fz \(thrust\) \(([^)]*)\)", "'force Fz (thrust)'", "Flight Stand"
    )
    volt = _need(table, rf"{prefix} - voltage \(v\)", "'voltage (V)'", "Flight Stand")
    factor = _thrust_factor(table, thrust[0], thrust[1].group(1))
    t = _find(table, r"time \(s\)")
    cur = _find(table, rf"{prefix} - current \(a\)")
    rpm = _find(table, rf"{prefix} - rotation speed \(rpm\)")
    return _assemble(
        table,
        "flight-stand",
        SCALES["pwm"],
        {
            "throttle": th[0],
            "thrust": thrust[0],
            "voltage": volt[0],
            "time": None if t is None else t[0],
            "current": None if cur is None else cur[0],
            "rpm": None if rpm is None else rpm[0],
        },
        factor,
        meta=meta,
    )


#: The Crazyflie system-id logger writes one row every 10 ms and no time column.
CRAZYFLIE_PERIOD_S = 0.01


def _crazyflie(table: _Table) -> Dataset | None:
    w = _find(table, r"weight\[g\]")
    pwm = _find(table, r"pwm")
    vbat = _find(table, r"vbat\[v\]")
    if w is None or pwm is None or vbat is None:
        return None
    cur = _find(table, r"i\[a\]")
    rpms = [hit[0] for k in range(1, 5) if (hit := _find(table, rf"rpm{k}")) is not None]
    ds = _assemble(
        table,
        "crazyflie",
        SCALES["crazyflie"],
        {"throttle": pwm[0], "thrust": w[0], "voltage": vbat[0], "current": cur and cur[0]},
        # weight[g] is the TOTAL of four motors; the map is per rotor (current likewise).
        G0 / 1000.0 / 4.0,
        rotors_on_esc=4,
        current_factor=0.25,
        meta={
            "thrust_note": "weight[g] of 4 motors divided by 4; i[A] likewise",
            "time_note": f"no time column: one row every {CRAZYFLIE_PERIOD_S * 1000:g} ms",
            "thrust_sensor": SAMPLE_AND_HOLD,  # its load cell updates every ~10 rows and holds
        },
    )
    n_rows = len(ds)
    time_s = (ds.line - ds.line[0]).astype(float) * CRAZYFLIE_PERIOD_S
    rpm = None
    if rpms:
        by_row = dict(zip(table.lines, range(len(table.lines)), strict=True))
        rows = [by_row[int(n)] for n in ds.line]
        each = np.vstack([_column(table, i, allow_empty=True)[rows] for i in rpms])
        count = np.isfinite(each).sum(axis=0)
        total = np.where(np.isfinite(each), each, 0.0).sum(axis=0)
        rpm = np.where(count > 0, total / np.maximum(count, 1), np.nan) if n_rows else None
        ds.meta["rpm_note"] = f"mean of {len(rpms)} motors' rpm"
    return replace(ds, time_s=time_s, rpm=rpm)


def _thrustmap_ds(table: _Table) -> Dataset | None:
    """thrustmap's own Ds log: decoded by :mod:`thrustmap.core.dslog`, checked against its sidecar."""
    if not dslog.is_ds_header(table.keys):
        return None
    cols = dslog.parse(table.header, table.rows, table.lines, table.path)
    side = dslog.read_sidecar(table.path)
    side_name = dslog.sidecar_path(table.path).name
    column = f"throttle_{cols.throttle_unit}"
    info: dict[str, Any] = {}
    if side is not None:
        scale = side.throttle_scale
        if dslog.throttle_column(scale) != column:
            raise DataFormatError(
                f"sidecar {side_name} gives throttle scale '{scale.name}' in {scale.unit}, "
                f"but the log's column is '{column}'; expected them to agree",
                file=table.path,
            )
        info["outcome"] = {"status": side.status, "reason": side.reason}
        info["strategy"] = side.strategy
        if side.status == "running":
            info["partial"] = "the run never finished (process died?): log kept as recorded"
        elif side.status == "aborted":
            info["partial"] = f"run aborted: {side.reason}"
        if side.samples is not None and side.samples != len(table.rows):
            if len(table.rows) > side.samples:
                raise DataFormatError(
                    f"the log has {len(table.rows)} rows but its sidecar {side_name} recorded "
                    f"{side.samples} samples; expected the sidecar of this log",
                    file=table.path,
                )
            info["partial"] = (
                f"sidecar {side_name} recorded {side.samples} samples but the log has "
                f"{len(table.rows)} rows: the log was cut short; loaded what is left"
            )
        rotors = side.rotors_on_esc
    else:
        rotors = None
        defaults = {"us": SCALES["pwm"], "pct": SCALES["percent"]}
        if cols.throttle_unit not in defaults:
            raise DataFormatError(
                f"no sidecar {side_name}: it gives the throttle scale of '{column}'",
                file=table.path,
            )
        scale = defaults[cols.throttle_unit]
        if cols.throttle_unit == "us":
            log.warning("%s: no sidecar %s; assuming PWM 1000..2000 us", table.path, side_name)
            info["assumed"] = f"no sidecar: throttle scale PWM 1000..2000 us assumed for '{column}'"
    outside = np.flatnonzero(
        (cols.throttle_native < scale.lo - scale.span / 2)
        | (cols.throttle_native > scale.hi + scale.span / 2)
    )
    if outside.size:
        k = int(outside[0])
        raise DataFormatError(
            f"throttle {cols.throttle_native[k]:g} is far outside the scale '{scale.name}' "
            f"{scale.lo:g}..{scale.hi:g} {scale.unit}; expected values on that scale",
            file=table.path,
            line=int(cols.line[k]),
            column=column,
        )
    if "partial" in info:
        log.warning("%s: %s", table.path, info["partial"])
    return _finish(
        table,
        "thrustmap",
        scale,
        cols.throttle_native,
        cols.thrust_n,
        cols.voltage_v,
        time_s=cols.time_s,
        current_a=cols.current_a,
        rpm=cols.rpm,
        rotors_on_esc=rotors,
        meta=info,
        # steps as recorded; none recorded (a hand-made log): plateaus from the throttle
        step=None
        if cols.step is None or not (cols.step >= 0).any()
        else np.where(cols.stopping, -1, cols.step),
        settled=cols.settled,
    )


#: name -> (description, reader). Tried in this order; a reader returns None when the header
#: is not its format, and raises DataFormatError when it is but something is wrong.
FORMATS: dict[str, tuple[str, Callable[[_Table], Dataset | None]]] = {
    "thrustmap": (
        "thrustmap Ds log: time_s, throttle_<unit>, thrust_n, voltage_v + JSON sidecar",
        _thrustmap_ds,
    ),
    "rcbenchmark": (
        "RCbenchmark/Tyto app log: 'ESC signal (µs)' or 'ESC (µs)', 'Thrust (N|kgf|gf)', 'Voltage (V)'",
        _rcbenchmark,
    ),
    "flight-stand": (
        "Flight Stand export: '<powertrain> - ESC throttle (μs)', '... - force Fz (thrust) (N)', '... - voltage (V)'",
        _flight_stand,
    ),
    "crazyflie": ("Crazyflie system-id log: 'weight[g]', 'pwm', 'vbat[V]'", _crazyflie),
}


def load_dataset(path: str | Path, column_map: ColumnMap | None = None) -> Dataset:
    """Load one stand log; detect its format from the header unless a column map is given."""
    table = read_table(path)
    if column_map is not None:
        return _with_column_map(table, column_map)
    for reader in (r for _, r in FORMATS.values()):
        ds = reader(table)
        if ds is not None:
            log.info("%s: %s format, %d samples", table.path, ds.format, len(ds))
            return ds
    tried = "; ".join(f"{name} ({desc})" for name, (desc, _) in FORMATS.items())
    shown = ", ".join(repr(h) for h in table.header[:8])
    raise DataFormatError(
        f"unrecognised stand log header [{shown}]; formats tried: {tried}; "
        "for another CSV give a column map (--col-throttle/--col-thrust/--col-voltage)",
        file=table.path,
        line=table.lines[0] - 1,
    )


def _with_column_map(table: _Table, cm: ColumnMap) -> Dataset:
    def index(name: str | None, what: str) -> int | None:
        if name is None:
            return None
        want = normalise_header(name)
        hits = [i for i, k in enumerate(table.keys) if k == want]
        if not hits:
            raise DataFormatError(
                f"column map: no column '{name}' for {what}; columns are: "
                + ", ".join(repr(h) for h in table.header),
                file=table.path,
            )
        if len(hits) > 1:
            raise DataFormatError(
                f"duplicated header '{name}' (columns {', '.join(str(h + 1) for h in hits)})",
                file=table.path,
            )
        return hits[0]

    ti, fi, vi = (
        index(cm.throttle, "throttle"),
        index(cm.thrust, "thrust"),
        index(cm.voltage, "voltage"),
    )
    assert ti is not None and fi is not None and vi is not None
    factor = THRUST_UNITS.get(cm.thrust_unit.lower())
    if factor is None:
        raise DataFormatError(
            f"unknown thrust unit '{cm.thrust_unit}'; expected one of: N, kgf, gf, g, lbf, ozf",
            file=table.path,
        )
    check_header_unit(table.header[fi], cm.thrust_unit, file=table.path)
    current = index(cm.current, "current")
    if current is None:  # a current column the map did not name still checks the thrust unit
        hit = _find(table, r"current \((a|amps?)\)")
        current = None if hit is None else hit[0]
    return _assemble(
        table,
        "column-map",
        cm.throttle_scale,
        {
            "throttle": ti,
            "thrust": fi,
            "voltage": vi,
            "time": index(cm.time, "time"),
            "current": current,
            "rpm": index(cm.rpm, "rpm"),
        },
        factor,
        rotors_on_esc=cm.rotors_on_esc,
    )


def load_datasets(
    paths: Sequence[str | Path], column_map: ColumnMap | None = None
) -> list[Dataset]:
    if not paths:
        raise DataFormatError("no input files given; expected one or more stand logs")
    return [load_dataset(p, column_map) for p in paths]


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
