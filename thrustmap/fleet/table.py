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
    schema = _schema()
    columns = [_column(f.type, [r[f.name] for r in rows]) for f in schema]
    table = pa.Table.from_arrays(columns, schema=schema)
    sink = pa.BufferOutputStream()
    pq.write_table(table, sink, compression="zstd")
    atomic_write_bytes(path, sink.getvalue().to_pybytes())


def _column(kind: Any, values: list[Any]) -> Any:
    """One column as an Arrow array, built from its buffers.

    Not ``pa.Table.from_pylist`` nor ``pa.array``: both import pandas (pyarrow asks whether the
    values are a pandas object), 0.2-0.35 s of the command's own time after the last log, as
    long as 30 small logs take (benchmarks/bench_fleet.py). The Parquet file is byte for byte
    the one ``from_pylist`` gives (tests/test_fleet.py)."""
    import numpy as np
    import pyarrow as pa

    n = len(values)
    if pa.types.is_string(kind):
        return _strings(values)
    if pa.types.is_boolean(kind):
        bits = np.packbits(np.asarray(values, dtype=bool), bitorder="little")
        return pa.Array.from_buffers(kind, n, [None, pa.py_buffer(bits)])
    if pa.types.is_map(kind):
        keys = [k for d in values for k in sorted(d)]  # each map sorted by key
        items = np.asarray([d[k] for d in values for k in sorted(d)], dtype=np.float64)
        return pa.MapArray.from_arrays(
            _offsets([len(d) for d in values]),
            _strings(keys),
            pa.Array.from_buffers(kind.item_type, len(items), [None, pa.py_buffer(items)]),
            type=kind,
        )
    if pa.types.is_list(kind):
        flat = [s for lst in values for s in lst]
        return pa.ListArray.from_arrays(
            _offsets([len(lst) for lst in values]), _strings(flat), type=kind
        )
    dtype = {pa.int32(): np.int32, pa.int64(): np.int64, pa.float64(): np.float64}[kind]
    data = np.asarray(values, dtype=dtype)
    return pa.Array.from_buffers(kind, n, [None, pa.py_buffer(data)])


def _offsets(lengths: list[int]) -> Any:
    import numpy as np
    import pyarrow as pa

    offsets = np.zeros(len(lengths) + 1, dtype=np.int64)
    np.cumsum(lengths, out=offsets[1:])
    if offsets[-1] >= 2**31:
        raise DataFormatError("fleet table: a column is over 2 GiB")
    return pa.Array.from_buffers(
        pa.int32(), len(lengths) + 1, [None, pa.py_buffer(offsets.astype(np.int32))]
    )


def _strings(values: list[str]) -> Any:
    import pyarrow as pa

    data = [v.encode() for v in values]
    offsets = _offsets([len(d) for d in data])
    return pa.StringArray.from_buffers(
        len(data), offsets.buffers()[1], pa.py_buffer(b"".join(data))
    )


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
        # not pq.read_table: it imports pandas (for pandas metadata), 0.2-0.35 s of every re-run
        with pq.ParquetFile(p) as f:
            table = f.read(use_pandas_metadata=False)
    except (OSError, pa.ArrowException) as exc:
        raise DataFormatError(
            f"not a fleet table: {' '.join(str(exc).split())[:200]}", file=str(p)
        ) from None
    names = _schema().names
    missing = [n for n in names if n not in table.column_names]
    if missing:
        raise DataFormatError("not a fleet table", file=str(p), column=missing[0])
    columns = [table.column(n).to_pylist() for n in names]
    out = []
    for values in zip(*columns, strict=True):
        r = dict(zip(names, values, strict=True))
        r["dropped_s"] = dict(r["dropped_s"] or [])
        r["warnings"] = list(r["warnings"] or [])
        for k in ("mass_kg", "voltage_min_v", "voltage_max_v"):
            if r[k] is None:
                r[k] = math.nan
        out.append(Outcome.from_dict(r))
    return out
