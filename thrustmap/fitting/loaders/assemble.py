"""From a table's columns to a checked Dataset: dense or sparse rows (the last command and
voltage carried forward within a bounded age), then the unit checks."""

from __future__ import annotations

import hashlib
import logging
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from thrustmap.core.errors import DataFormatError
from thrustmap.core.units import ThrottleScale
from thrustmap.fitting.dataset import STEP_SUMMARY, BoolArray, Dataset, FloatArray, IntArray
from thrustmap.fitting.loaders.checks import (
    check_one_cell,
    check_pulse_us,
    check_thrust,
    check_voltage,
    is_step_summary,
    normalise_sign,
)
from thrustmap.fitting.loaders.table import Table, column_values

log = logging.getLogger(__name__)


def _sha256(path: str) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


@dataclass(frozen=True)
class StandColumns:
    """A stand log's columns, one value per row kept: throttle in the log's own scale, the rest
    in SI units; the optional ones None when the log has none."""

    throttle: FloatArray
    thrust_n: FloatArray
    voltage_v: FloatArray
    time_s: FloatArray | None = None
    current_a: FloatArray | None = None
    rpm: FloatArray | None = None
    step: IntArray | None = None  # the recorded plateau of each row (None: found from throttle)
    settled: BoolArray | None = None


def finish_dataset(
    table: Table,
    fmt: str,
    scale: ThrottleScale,
    cols: StandColumns,
    *,
    rotors_on_esc: int | None = None,
    meta: dict[str, Any] | None = None,
) -> Dataset:
    """The columns checked (voltage, thrust sign and size, one cell) into a Dataset."""
    throttle, thrust_n, voltage_v = cols.throttle, cols.thrust_n, cols.voltage_v
    time_s, current_a, step = cols.time_s, cols.current_a, cols.step
    meta = dict(meta or {})
    _check_time_order(table, time_s)
    voltage_v = check_voltage(table, voltage_v, meta)
    if table.notes:
        meta["read_notes"] = list(table.notes)
    thrust_n = normalise_sign(thrust_n, throttle, meta, table.path)
    check_thrust(table, thrust_n, voltage_v, current_a, rotors_on_esc)
    if fmt != "crazyflie":  # (a Crazyflie is 1S by design)
        check_one_cell(table, thrust_n / max(rotors_on_esc or 1, 1), voltage_v, current_a, meta)
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
        rpm=cols.rpm,
        rotors_on_esc=rotors_on_esc,
        step=step,
        settled=cols.settled,
        sha256=_sha256(table.path),
        meta=meta,
    )


#: rows whose time steps back that a dense log may have (clock jitter) before it is refused
TIME_BACK_MAX_SHARE = 0.01


def _check_time_order(table: Table, time_s: FloatArray | None) -> None:
    """Rows in time order: a log sorted by another column (a spreadsheet's "sort by thrust")
    or two logs pasted out of order has no plateaus or ramps left to find, and was once
    refused as a thrust that "never leaves the load cell's noise" (its noise measured across
    shuffled rows). A stand's clock may jitter back by a millisecond now and then (the xNova
    logs do once, on their third row): up to ``TIME_BACK_MAX_SHARE`` of the rows pass."""
    if time_s is None or time_s.size < 2:
        return
    dt = np.diff(time_s)
    back = np.flatnonzero(dt < 0)
    if back.size <= max(2, TIME_BACK_MAX_SHARE * time_s.size):
        return
    k = int(back[0]) + 1
    raise DataFormatError(
        f"time goes backwards ({time_s[k]:g} s after {time_s[k - 1]:g} s; {back.size} such "
        "rows); expected rows in time order (sorted by another column, or logs pasted out of "
        "order?)",
        file=table.path,
        line=table.lines[k],
    )


#: Sparse logs (each sensor written when it updates): how old a carried-forward command or
#: voltage may be, in seconds where the log has a time column, else in rows.
CARRY_THROTTLE_S = 0.5
CARRY_VOLTAGE_S = 2.0
CARRY_THROTTLE_ROWS = 5
CARRY_VOLTAGE_ROWS = 20
#: A log is sparse (not a dense log with a hole) when this share of rows lacks a required cell.
SPARSE_MIN_FRACTION = 0.1


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


def assemble(
    table: Table,
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
    raw = {k: column_values(table, i, allow_empty=True) for k, i in cols.items() if i is not None}
    if scale.unit == "us":
        raw["throttle"] = check_pulse_us(table, cols["throttle"] or 0, raw["throttle"])
    required = ("throttle", "thrust", "voltage")
    gaps = ~np.all([np.isfinite(raw[k]) for k in required], axis=0)
    if float(gaps.mean()) < SPARSE_MIN_FRACTION:
        for k in (*required, "time"):  # a dense log with a few holes: the first one is an error
            if cols.get(k) is not None:
                column_values(table, cols[k] or 0)
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
        # a sensor row logged a few ms out of order (the Tyto app's continuous logs: 4 of
        # 15 875 rows in alspitz/esc_test's) is clock jitter, as in a dense log
        _check_time_order(table, t)
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

    cols_kept = StandColumns(
        raw["throttle"][keep],
        raw["thrust"][keep] * thrust_factor,
        raw["voltage"][keep],
        time_s=opt("time"),
        current_a=opt("current", current_factor),
        rpm=opt("rpm"),
    )
    return finish_dataset(table, fmt, scale, cols_kept, rotors_on_esc=rotors_on_esc, meta=meta)
