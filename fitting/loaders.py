"""Load Ds (bench data) from stand logs, auto-detected by header.

Formats: RCbenchmark (Tyto app) logs and their spreadsheet re-saves, Flight Stand exports,
Crazyflie system-id logs, the project's own Ds log (:mod:`thrustmap.dslog`), and any CSV through an
explicit ``ColumnMap``. Every error names the file, the line or column, and what was expected.
"""

from __future__ import annotations

import csv
import hashlib
import logging
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from thrustmap import dslog
from thrustmap.errors import DataFormatError
from thrustmap.fitting.dataset import STEP_SUMMARY, BoolArray, Dataset, FloatArray, IntArray
from thrustmap.units import SCALES, ThrottleScale

log = logging.getLogger(__name__)

G0 = 9.80665
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
    parsed = list(csv.reader(lines[first:], delimiter=delimiter))
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
    if not rows:
        raise DataFormatError("header only, no data rows", file=name, line=first + 1)
    keys = [normalise_header(h) for h in header]
    return _Table(name, header, keys, rows, numbers, delimiter)


def _find(table: _Table, pattern: str) -> tuple[int, re.Match[str]] | None:
    rx = re.compile(pattern)
    hits = [(i, m) for i, k in enumerate(table.keys) if (m := rx.fullmatch(k))]
    if len(hits) > 1:
        cols = ", ".join(f"{table.header[i]!r} (column {i + 1})" for i, _ in hits)
        raise DataFormatError(
            f"duplicated header: {cols}; expected one such column", file=table.path
        )
    return hits[0] if hits else None


def _column(table: _Table, index: int, *, allow_empty: bool = False) -> FloatArray:
    """Convert column ``index`` to floats; name the line and column of the first bad cell."""
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
    if allow_empty:
        cells = [c if c else "nan" for c in cells]
    try:
        values = np.asarray(cells, dtype=float)
    except ValueError:
        values = np.empty(len(cells))
        decimal_comma = table.delimiter == ";"
        for k, (cell, line) in enumerate(zip(cells, table.lines, strict=True)):
            try:
                values[k] = float(cell.replace(",", ".") if decimal_comma else cell)
            except ValueError:
                what = "empty cell" if not cell else f"'{cell[:30]}' is not a number"
                raise DataFormatError(
                    f"{what}; expected a number", file=table.path, line=line, column=col
                ) from None
    if not allow_empty:
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            raise DataFormatError(
                f"'{cells[bad[0]]}' is not a finite number; expected a measured value",
                file=table.path,
                line=table.lines[bad[0]],
                column=col,
            )
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
    thrust_n = _normalise_sign(thrust_n, throttle, meta, table.path)
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
    fmt = "rcbenchmark" if t is not None else "rcbenchmark-resaved"
    return _finish(
        table,
        fmt,
        SCALES["pwm"],
        _column(table, th[0]),
        _column(table, thrust[0]) * factor,
        _column(table, volt[0]),
        time_s=None if t is None else _column(table, t[0]),
        current_a=None if cur is None else _column(table, cur[0], allow_empty=True),
        rpm=None if rpm is None else _column(table, rpm[0], allow_empty=True),
    )


def _flight_stand(table: _Table) -> Dataset | None:
    th = _find(table, rf"(.+) - esc throttle \({MU}s\)")
    if th is None:
        return None
    prefix = re.escape(th[1].group(1))
    thrust = _need(
        table, rf"{prefix} - force fz \(thrust\) \(([^)]*)\)", "'force Fz (thrust)'", "Flight Stand"
    )
    volt = _need(table, rf"{prefix} - voltage \(v\)", "'voltage (V)'", "Flight Stand")
    factor = _thrust_factor(table, thrust[0], thrust[1].group(1))
    t = _find(table, r"time \(s\)")
    # Continuous recordings are sparse (each sensor at its own rate): hold each value forward,
    # keep the rows where a thrust reading arrived.
    cols = {
        k: _column(table, i, allow_empty=True)
        for k, i in (("th", th[0]), ("thrust", thrust[0]), ("v", volt[0]))
    }
    have_thrust = np.isfinite(cols["thrust"])
    for k in ("th", "v"):
        cols[k] = _ffill(cols[k])
    keep = have_thrust & np.isfinite(cols["th"]) & np.isfinite(cols["v"])
    if not keep.any():
        raise DataFormatError("no row has thrust, throttle and voltage together", file=table.path)
    sub = _Table(
        table.path,
        table.header,
        table.keys,
        [r for r, k in zip(table.rows, keep, strict=True) if k],
        [n for n, k in zip(table.lines, keep, strict=True) if k],
        table.delimiter,
    )
    return _finish(
        sub,
        "flight-stand",
        SCALES["pwm"],
        cols["th"][keep],
        cols["thrust"][keep] * factor,
        cols["v"][keep],
        time_s=None if t is None else _column(table, t[0], allow_empty=True)[keep],
        meta={"powertrain": th[1].group(1)},
    )


def _ffill(a: FloatArray) -> FloatArray:
    idx = np.where(np.isfinite(a), np.arange(len(a)), 0)
    np.maximum.accumulate(idx, out=idx)
    out = a[idx]
    out[~np.isfinite(a) & (np.cumsum(np.isfinite(a)) == 0)] = np.nan
    return np.asarray(out, dtype=float)


def _crazyflie(table: _Table) -> Dataset | None:
    w = _find(table, r"weight\[g\]")
    pwm = _find(table, r"pwm")
    vbat = _find(table, r"vbat\[v\]")
    if w is None or pwm is None or vbat is None:
        return None
    cur = _find(table, r"i\[a\]")
    # weight[g] is the TOTAL of four motors; the map is per rotor.
    thrust_n = _column(table, w[0]) * G0 / 1000.0 / 4.0
    return _finish(
        table,
        "crazyflie",
        SCALES["crazyflie"],
        _column(table, pwm[0]),
        thrust_n,
        _column(table, vbat[0]),
        current_a=None if cur is None else _column(table, cur[0], allow_empty=True),
        rotors_on_esc=4,
        meta={"thrust_note": "weight[g] of 4 motors divided by 4"},
    )


def _thrustmap_ds(table: _Table) -> Dataset | None:
    """thrustmap's own Ds log: decoded by :mod:`thrustmap.dslog`, checked against its sidecar."""
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
        step=np.where(cols.stopping, -1, cols.step) if cols.step is not None else None,
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
    t_i, c_i = index(cm.time, "time"), index(cm.current, "current")
    return _finish(
        table,
        "column-map",
        cm.throttle_scale,
        _column(table, ti),
        _column(table, fi) * factor,
        _column(table, vi),
        time_s=None if t_i is None else _column(table, t_i),
        current_a=None if c_i is None else _column(table, c_i, allow_empty=True),
        rotors_on_esc=cm.rotors_on_esc,
    )


def load_datasets(
    paths: Sequence[str | Path], column_map: ColumnMap | None = None
) -> list[Dataset]:
    if not paths:
        raise DataFormatError("no input files given; expected one or more stand logs")
    return [load_dataset(p, column_map) for p in paths]
