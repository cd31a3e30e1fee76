"""The fleet table: one row per log, in Parquet (pyarrow), written atomically."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from thrustmap.core.errors import DataFormatError
from thrustmap.core.files import atomic_write_bytes
from thrustmap.fleet.task import Outcome

TABLE_NAME = "fleet.parquet"


def _schema() -> Any:
    import pyarrow as pa

    return pa.schema(
        [
            ("path", pa.string()),
            ("size_bytes", pa.int64()),
            ("mtime_ns", pa.int64()),
            ("sha256", pa.string()),
            ("options_key", pa.string()),
            ("status", pa.string()),
            ("reason", pa.string()),
            ("df_path", pa.string()),
            ("format", pa.string()),
            ("flights", pa.int32()),
            ("samples", pa.int64()),
            ("duration_s", pa.float64()),
            ("kept_s", pa.float64()),
            ("dropped_s", pa.map_(pa.string(), pa.float64())),
            ("warnings", pa.list_(pa.string())),
            ("airframe", pa.string()),
            ("airframe_key", pa.string()),
            ("mass_kg", pa.float64()),
            ("rotors", pa.int32()),
            ("voltage_min_v", pa.float64()),
            ("voltage_max_v", pa.float64()),
            ("seconds", pa.float64()),
            ("reused", pa.bool_()),
        ]
    )


def write_table(outcomes: list[Outcome], path: str | Path) -> None:
    """Write the outcomes (sorted by path) as Parquet, atomically."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    rows = [o.to_dict() for o in sorted(outcomes, key=lambda o: o.path)]
    for r in rows:
        r["dropped_s"] = sorted(r["dropped_s"].items())
    schema = _schema()
    table = pa.Table.from_pylist(rows, schema=schema)
    sink = pa.BufferOutputStream()
    pq.write_table(table, sink, compression="zstd")
    atomic_write_bytes(path, sink.getvalue().to_pybytes())


def read_table(path: str | Path) -> list[Outcome]:
    """The outcomes of a fleet table (refused with one line when it is not one)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    p = Path(path)
    if not p.is_file():
        raise DataFormatError(
            "fleet table not found (run `thrustmap fleet extract` first)", file=str(p)
        )
    try:
        table = pq.read_table(p)
    except (OSError, pa.ArrowException) as exc:
        raise DataFormatError(
            f"not a fleet table: {' '.join(str(exc).split())[:200]}", file=str(p)
        ) from None
    missing = [n for n in _schema().names if n not in table.column_names]
    if missing:
        raise DataFormatError("not a fleet table", file=str(p), column=missing[0])
    out = []
    for r in table.to_pylist():
        r["dropped_s"] = dict(r["dropped_s"] or [])
        r["warnings"] = list(r["warnings"] or [])
        for k in ("mass_kg", "voltage_min_v", "voltage_max_v"):
            if r[k] is None:
                r[k] = math.nan
        out.append(Outcome.from_dict(r))
    return out
