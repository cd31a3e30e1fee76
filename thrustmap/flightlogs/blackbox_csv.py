"""The CSV written by Betaflight's official ``blackbox_decode`` -> :class:`FlightLog`.

Layout: one header row ``loopIteration, time (us), ..., vbatLatest (V), ..., motor[0], ...,
flightModeFlags (flags), ...`` (", " separated, units in parentheses), then one row per main
frame with the latest slow-frame values repeated. Header values (acc_1G, vbatref, motorOutput,
firmware) come from a ``<name>.headers.csv`` beside it (``--save-headers``: ``fieldname,
fieldvalue`` then ``key,"value"`` rows) or from ``key,value`` preamble rows above the field row
(Blackbox Explorer's export); without them acc_1G is inferred and the vbat scale decided from the
data alone. Unit normalisation is shared with the binary reader (:mod:`blackbox`).
"""

from __future__ import annotations

import csv
import io
import logging
import re
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from thrustmap.core.errors import DataFormatError
from thrustmap.flightlogs.blackbox import BlackboxTable, FloatArray, to_flightlog
from thrustmap.flightlogs.series import FlightLog

log = logging.getLogger(__name__)

#: blackbox_decode's names for flightModeFlags bits (bit 0 is the ARM box in Betaflight >= 3.2
#: although the decoder still calls it ANGLE_MODE).
FLIGHT_MODE_NAMES = [
    "ANGLE_MODE", "HORIZON_MODE", "MAG", "BARO", "GPS_HOME", "GPS_HOLD", "HEADFREE", "UNUSED",
    "PASSTHRU", "RANGEFINDER_MODE", "FAILSAFE_MODE",
]  # fmt: skip
_UNIT_RE = re.compile(r"^(.*?)\s*\(([^()]*)\)$")


def _cells(line: str) -> list[str]:
    return [c.strip().strip('"').strip() for c in next(csv.reader([line]))]


def _is_field_row(cells: list[str]) -> bool:
    return (
        bool(cells)
        and cells[0] == "loopIteration"
        or (any(c.startswith("time (") for c in cells) and "loopIteration" in cells)
    )


def sniff(path: Path, head: bytes) -> bool:
    text = head.decode("latin-1", errors="replace")
    for line in text.splitlines()[:200]:
        if line.lstrip('"').startswith("loopIteration") and "time" in line:
            return True
    return False


def _read_headers_csv(path: Path) -> dict[str, str]:
    out: dict[str, str] = {}
    with open(path, newline="", encoding="latin-1") as f:
        for row in csv.reader(f):
            if len(row) >= 2 and row[0].strip() != "fieldname":
                out[row[0].strip()] = ",".join(row[1:]).strip().strip('"')
    return out


def _headers_file(path: Path) -> Path | None:
    name = path.name
    stem = name[:-4] if name.lower().endswith(".csv") else name
    for cand in (path.with_name(stem + ".headers.csv"), path.with_name(stem + ".headers")):
        if cand.is_file() and cand != path:
            return cand
    return None


def _flags(column: pd.Series[Any], what: str) -> np.ndarray[Any, np.dtype[np.int64]]:
    numeric = pd.to_numeric(column, errors="coerce")
    if numeric.notna().all():
        return numeric.to_numpy(dtype=np.int64)
    bits = {name: 1 << i for i, name in enumerate(FLIGHT_MODE_NAMES)}
    out = np.zeros(len(column), dtype=np.int64)
    for i, value in enumerate(column.astype(str)):
        for token in value.strip().split("|"):
            token = token.strip()
            if token.isdigit():
                out[i] |= int(token)
            elif token in bits:
                out[i] |= bits[token]
            elif token:
                raise DataFormatError(f"unknown flag '{token}' in row {i + 1}", column=what)
    return out


def read(
    path: Path | str,
    *,
    acc_1g: float | None = None,
    vbat_scale_v: float | None = None,
    headers: dict[str, str] | None = None,
    **_options: Any,
) -> list[FlightLog]:
    """One flight per blackbox_decode CSV (the decoder writes one CSV per log)."""
    p = Path(path)
    try:
        text = p.read_text(encoding="latin-1")
    except OSError as exc:
        raise DataFormatError(f"cannot read CSV: {exc.strerror}", file=str(p)) from None
    lines = text.splitlines()
    start = next((i for i, ln in enumerate(lines[:500]) if _is_field_row(_cells(ln))), None)
    if start is None:
        raise DataFormatError(
            "not a blackbox_decode CSV: no header row starting with 'loopIteration'", file=str(p)
        )
    hdr: dict[str, str] = {}
    hfile = _headers_file(p)
    if hfile is not None:
        hdr.update(_read_headers_csv(hfile))
    for ln in lines[:start]:  # Blackbox Explorer style preamble: "key","value"
        cells = next(csv.reader([ln]), [])
        if len(cells) >= 2:
            hdr[cells[0].strip()] = ",".join(cells[1:]).strip()
    if headers:
        hdr.update(headers)
    frame = pd.read_csv(
        io.StringIO("\n".join(lines[start:])), skipinitialspace=True, dtype=str, na_filter=False
    )
    if frame.empty:
        raise DataFormatError("blackbox_decode CSV has a header row but no data rows", file=str(p))
    fields: dict[str, FloatArray] = {}
    units: dict[str, str] = {}
    raw_cols: dict[str, pd.Series[Any]] = {}
    for header in frame.columns:
        m = _UNIT_RE.match(str(header).strip())
        name, unit = (m.group(1), m.group(2)) if m else (str(header).strip(), "raw")
        raw_cols[name] = frame[header]
        units[name] = unit
    warnings: list[str] = []
    if "time" not in raw_cols:
        raise DataFormatError("no 'time' column", file=str(p), line=start + 1)
    time_factor = {"us": 1.0, "ms": 1e3, "s": 1e6}.get(units["time"])
    if time_factor is None:
        raise DataFormatError(f"time in unknown unit '{units['time']}'", file=str(p), column="time")
    mode_flags = None
    for name, col in raw_cols.items():
        if units[name] == "flags":
            if name == "flightModeFlags":
                mode_flags = _flags(col, name)
            continue
        fields[name] = np.asarray(pd.to_numeric(col, errors="coerce"), dtype=float)
    time_us = fields.pop("time") * time_factor
    bad = ~np.isfinite(time_us)
    if bad.any():
        first = int(np.argmax(bad))
        warnings.append(
            f"{int(bad.sum())} row(s) without a numeric time skipped (first at line {start + 2 + first})"
        )
    table = BlackboxTable(
        headers=hdr,
        time_us=time_us,
        fields=fields,
        units=units,
        mode_time_us=time_us[~bad] if mode_flags is not None else None,
        mode_flags=mode_flags[~bad] if mode_flags is not None else None,
        warnings=warnings,
        metadata={"headers_source": str(hfile) if hfile else ("preamble" if start else "none")},
    )
    m_index = re.search(r"\.(\d+)\.csv$", p.name)
    index = int(m_index.group(1)) - 1 if m_index else 0
    return [to_flightlog(table, str(p), "blackbox-csv", index, acc_1g, vbat_scale_v)]
