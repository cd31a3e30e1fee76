"""A stand log as a table: delimited text read with its line numbers (delimiter detected,
binaries and torn last rows refused or dropped), columns found by header, cells read as
numbers (decimal commas and thousands separators told apart), thrust units."""

from __future__ import annotations

import csv
import logging
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from thrustmap.core import stand_recording
from thrustmap.core.errors import DataFormatError
from thrustmap.core.physical import (  # the physical ranges live in one place
    G0,
)
from thrustmap.fitting.dataset import FloatArray

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


@dataclass
class Table:
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


def read_table(path: str | Path) -> Table:
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
    if rows and not text.endswith(("\n", "\r")) and _torn(rows, stand_recording.is_ds_header(keys)):
        note = f"last row (line {numbers[-1]}) has no line end and is cut short: dropped"
        notes.append(note + " (a partial write?)")
        log.warning("%s: %s (a partial write?)", name, note)
        rows.pop()
        numbers.pop()
    if not rows:
        raise DataFormatError("header only, no data rows", file=name, line=first + 1)
    return Table(name, header, keys, rows, numbers, delimiter, notes)


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


def find_column(table: Table, pattern: str) -> tuple[int, re.Match[str]] | None:
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


def _uses_decimal_comma(table: Table) -> bool:
    """A ';'-separated re-save from a locale that writes 1.234,5: some cell has a decimal comma."""
    if table.decimal_comma is None:
        table.decimal_comma = table.delimiter == ";" and any(
            _DECIMAL_COMMA.fullmatch(c.strip()) for row in table.rows for c in row
        )
    return table.decimal_comma


def column_values(table: Table, index: int, *, allow_empty: bool = False) -> FloatArray:
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


def thrust_unit_factor(table: Table, index: int, unit: str) -> float:
    factor = THRUST_UNITS.get(unit.lower())
    if factor is None:
        raise DataFormatError(
            f"unknown thrust unit '{unit}'; expected one of: N, kgf, gf, g, lbf, ozf",
            file=table.path,
            column=table.header[index],
        )
    return factor


def need_column(table: Table, pattern: str, what: str, fmt: str) -> tuple[int, re.Match[str]]:
    hit = find_column(table, pattern)
    if hit is None:
        raise DataFormatError(f"{fmt} log has no {what} column", file=table.path)
    return hit
