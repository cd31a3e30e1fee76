"""Flight CSVs: the seed paper's schema, and any CSV given a column map.

Seed paper (Aerostack2 flights), one row per sample, collective thrust in N::

    Thrust sended (N),Thrust measured (N),Voltage (V),Acc (m/s²),m (Kg),Throttle (%),
    Position_z (m),Time (s)

``Throttle (%)`` is the command every motor received (one column for all rotors), so it is kept
as a one-column ``motor_outputs`` in percent with ``metadata["motor_outputs_collective"]``.

Generic CSV: ``read_generic(path, columns={"time_s": "t", "voltage_v": "vbat", ...})`` maps the
canonical names (``time_s``, ``voltage_v``, ``accel_up_mps2``, ``thrust_cmd_n``,
``thrust_cmd_norm``, ``motor_outputs`` (comma-separated column names), ``armed``, ``landed``) to
the file's columns; without a map the file must use the canonical names itself. Options
``time_scale`` (e.g. 1e-6 for µs), ``accel_scale`` (e.g. -1 for an FRD z axis) and
``motor_scale`` (a :data:`thrustmap.core.units.SCALES` name) normalise units and signs.
"""

from __future__ import annotations

import io
import logging
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from thrustmap.core.errors import DataFormatError
from thrustmap.core.units import SCALES, scale
from thrustmap.flightlogs.series import (
    FlightLog,
    FloatArray,
    Signal,
    question_specific_force,
)

log = logging.getLogger(__name__)

G0 = 9.80665
PAPER_COLUMNS = (
    "Thrust sended (N)",
    "Thrust measured (N)",
    "Voltage (V)",
    "Acc (m/s²)",
    "m (Kg)",
    "Throttle (%)",
    "Position_z (m)",
    "Time (s)",
)
#: the columns the paper reader cannot do without
PAPER_REQUIRED = ("Thrust sended (N)", "Voltage (V)", "Acc (m/s²)", "Time (s)")
CANONICAL = (
    "time_s",
    "voltage_v",
    "accel_up_mps2",
    "thrust_cmd_n",
    "thrust_cmd_norm",
    "motor_outputs",
    "armed",
    "landed",
)
#: height above which a paper-CSV sample counts as airborne (no armed/landed in that schema)
AIRBORNE_Z_M = 0.2


def _first_line(head: bytes) -> str:
    text = head.decode("utf-8", errors="replace").lstrip("\ufeff")
    return text.splitlines()[0] if text.strip() else ""


def _split_header(line: str) -> list[str]:
    sep = ";" if line.count(";") > line.count(",") else ","
    return [c.strip().strip('"') for c in line.split(sep)]


def sniff(path: Path, head: bytes) -> bool:
    cols = set(_split_header(_first_line(head)))
    return all(c in cols for c in PAPER_REQUIRED)


def sniff_generic(path: Path, head: bytes) -> bool:
    cols = set(_split_header(_first_line(head)))
    return {"time_s", "voltage_v", "accel_up_mps2"} <= cols and (
        "thrust_cmd_n" in cols
        or "thrust_cmd_norm" in cols
        or any(c.startswith("motor") for c in cols)
    )


def _load_table(path: Path) -> tuple[pd.DataFrame, list[str]]:
    """Parse a numeric CSV; a short or non-numeric last row is a corrupt tail (warned, dropped)."""
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise DataFormatError(f"cannot read flight CSV: {exc.strerror}", file=str(path)) from None
    text = raw.decode("utf-8", errors="replace").lstrip("\ufeff")
    if not text.strip():
        raise DataFormatError("flight CSV is empty", file=str(path))
    lines = text.splitlines()
    header = _split_header(lines[0])
    sep = ";" if lines[0].count(";") > lines[0].count(",") else ","
    warnings: list[str] = []
    numbered = [(k + 1, ln) for k, ln in enumerate(lines) if k and ln.strip()]
    body = [ln for _, ln in numbered]
    line_no = [k for k, _ in numbered]  # file line of each body row (blank lines skipped)
    if not body:
        raise DataFormatError("flight CSV has a header but no data rows", file=str(path), line=2)

    # A log cut mid-write leaves a short or garbled tail: drop it, say so.
    def bad(line: str) -> bool:
        fields = line.split(sep)
        if len(fields) != len(header):
            return True
        try:
            [float(f) for f in fields if f.strip()]
        except ValueError:
            return True
        return False

    tail = 0
    while tail < len(body) and bad(body[len(body) - 1 - tail]):
        tail += 1
    if tail == len(body):
        raise DataFormatError(
            f"no data row has the {len(header)} numeric fields the header names",
            file=str(path),
            line=2,
        )
    if tail:
        warnings.append(
            f"corrupt tail: last {tail} row(s) are short or not numeric (from line "
            f"{line_no[len(body) - tail]}); ignored"
        )
        body = body[: len(body) - tail]
    for i, line in enumerate(body):
        if len(line.split(sep)) != len(header):
            raise DataFormatError(
                f"row has {len(line.split(sep))} fields, the header names {len(header)}",
                file=str(path),
                line=line_no[i],
            )
    try:
        df = pd.read_csv(io.StringIO("\n".join(body)), sep=sep, header=None, names=header)
    except (pd.errors.ParserError, ValueError) as exc:
        raise DataFormatError(f"malformed CSV: {exc}", file=str(path)) from None
    for col in df.columns:
        if not pd.api.types.is_numeric_dtype(df[col]):
            num = pd.to_numeric(df[col], errors="coerce")
            bad_rows = np.flatnonzero(num.isna().to_numpy() & df[col].notna().to_numpy())
            if len(bad_rows):
                row = int(bad_rows[0])
                raise DataFormatError(
                    f"expected a number, got {_short(df[col].iloc[row])}",
                    file=str(path),
                    line=line_no[row],
                    column=str(col),
                )
            df[col] = num
    if not len(df):
        raise DataFormatError("flight CSV holds no complete data row", file=str(path))
    return df, warnings


def _short(value: Any, limit: int = 40) -> str:
    text = repr(value)
    return text if len(text) <= limit else f"{text[:limit]}... ({len(text)} characters)"


def _column(df: pd.DataFrame, name: str, path: Path) -> FloatArray:
    if name not in df.columns:
        raise DataFormatError(
            f"missing column; found: {', '.join(map(str, df.columns))}", file=str(path), column=name
        )
    return np.asarray(df[name].to_numpy(dtype=float), dtype=float)


def _sorted(time_s: FloatArray, path: Path) -> tuple[FloatArray, np.ndarray[Any, Any]]:
    """Order rows by time and drop duplicate timestamps (keep the first)."""
    if not np.all(np.isfinite(time_s)):
        raise DataFormatError("time column holds empty or non-finite values", file=str(path))
    order = np.argsort(time_s, kind="stable")
    t = time_s[order]
    keep = np.concatenate([[True], np.diff(t) > 0])
    return t[keep], order[keep]


def read(path: Path, **options: Any) -> list[FlightLog]:
    """Read a seed-paper flight CSV (collective thrust in N, Throttle in %)."""
    df, warnings = _load_table(path)
    time_s, idx = _sorted(_column(df, "Time (s)", path), path)
    time_s = time_s - time_s[0]

    def sig(col: str, unit: str) -> Signal:
        return Signal(time_s, _column(df, col, path)[idx], unit, col)

    # in g (mean ≈ 1): converted; gravity removed (mean ≈ 0): g0 put back; else refused
    accel, why = question_specific_force(
        sig("Acc (m/s²)", "m/s^2"), str(path), gravity_removed=True
    )
    warnings.extend(why)
    flight = FlightLog(
        path=str(path),
        format="paper-csv",
        voltage_v=sig("Voltage (V)", "V"),
        accel_up_mps2=accel,
        thrust_cmd_n=sig("Thrust sended (N)", "N"),
        warnings=warnings,
    )
    if "Throttle (%)" in df.columns:
        th = _column(df, "Throttle (%)", path)[idx]
        flight.motor_outputs = Signal(time_s, th[:, None], "%", "Throttle (%)")
        flight.motor_output_scale = SCALES["percent"]
        flight.metadata["motor_outputs_collective"] = True
    if "Thrust measured (N)" in df.columns:
        flight.extras["thrust_measured_n"] = sig("Thrust measured (N)", "N")
    if "m (Kg)" in df.columns:
        mass = _column(df, "m (Kg)", path)
        if np.isfinite(mass).any():
            flight.metadata["mass_kg"] = float(np.nanmedian(mass))
    if "Position_z (m)" in df.columns:
        z = _column(df, "Position_z (m)", path)[idx]
        flight.extras["position_z_m"] = Signal(time_s, z, "m", "Position_z (m)")
        flight.landed = Signal(
            time_s, (z < AIRBORNE_Z_M).astype(float), "bool", f"Position_z (m) < {AIRBORNE_Z_M}"
        )
    return [flight]


def read_generic(
    path: Path,
    *,
    columns: dict[str, str] | None = None,
    time_scale: float = 1.0,
    accel_scale: float = 1.0,
    motor_scale: str | None = None,
    **_: Any,
) -> list[FlightLog]:
    """Read any flight CSV through a column map (canonical name -> the file's column)."""
    df, warnings = _load_table(path)
    cmap = {c: c for c in CANONICAL if c in df.columns}
    cmap.update(columns or {})
    unknown = set(cmap) - set(CANONICAL)
    if unknown:
        from thrustmap.core.errors import ConfigError

        raise ConfigError(
            f"unknown column-map keys {sorted(unknown)}; expected some of: {', '.join(CANONICAL)}"
        )
    for need in ("time_s", "voltage_v", "accel_up_mps2"):
        if need not in cmap:
            raise DataFormatError(
                f"no column for '{need}': give a column map entry {need}=<column>",
                file=str(path),
                column=need,
            )
    time_s, idx = _sorted(_column(df, cmap["time_s"], path) * time_scale, path)

    def sig(key: str, unit: str, factor: float = 1.0) -> Signal | None:
        if key not in cmap:
            return None
        return Signal(time_s, _column(df, cmap[key], path)[idx] * factor, unit, cmap[key])

    accel = sig("accel_up_mps2", "m/s^2", accel_scale)
    assert accel is not None
    accel, why = question_specific_force(accel, str(path))
    warnings.extend(why)
    flight = FlightLog(
        path=str(path),
        format="csv",
        voltage_v=sig("voltage_v", "V"),
        accel_up_mps2=accel,
        thrust_cmd_n=sig("thrust_cmd_n", "N"),
        thrust_cmd_norm=sig("thrust_cmd_norm", "1"),
        armed=sig("armed", "bool"),
        landed=sig("landed", "bool"),
        warnings=warnings,
    )
    if "motor_outputs" in cmap:
        names = [c.strip() for c in cmap["motor_outputs"].split(",") if c.strip()]
        outs = np.stack([_column(df, c, path)[idx] for c in names], axis=1)
        flight.motor_outputs = Signal(time_s, outs, "native", ",".join(names))
        if motor_scale is None:
            raise DataFormatError(
                "motor output columns need their throttle scale (motor_scale=pwm|dshot|...)",
                file=str(path),
                column=names[0],
            )
        flight.motor_output_scale = scale(motor_scale)
    if (
        flight.thrust_cmd_n is None
        and flight.thrust_cmd_norm is None
        and flight.motor_outputs is None
    ):
        raise DataFormatError(
            "no thrust command: map thrust_cmd_n, thrust_cmd_norm or motor_outputs",
            file=str(path),
        )
    return [flight]
