"""The Df table (columns of numpy arrays, pandas on first use), its CSV text, and what is read
off it."""

from __future__ import annotations

import csv
import io
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from thrustmap.core.errors import DataFormatError
from thrustmap.fitting.df.options import G0, FlightReport
from thrustmap.flightlogs.series import nanmedian

if TYPE_CHECKING:  # pandas is imported where a table is asked for: `flightlog extract` runs
    import pandas as pd  # without it (its import alone took 0.3 s of a 0.7 s extraction)


Columns = dict[str, npt.NDArray[Any]]


class Df:
    """The Df table, its sidecar (``sources``) and the per-flight reports.

    ``table`` is a pandas DataFrame, built from the extracted columns on first use (the
    extraction itself and ``write_df`` need no pandas); ``Df(table, sources, reports)``
    still takes a DataFrame."""

    def __init__(
        self,
        table: pd.DataFrame | None = None,
        sources: dict[str, Any] | None = None,
        reports: list[FlightReport] | None = None,
        *,
        columns: Columns | None = None,
    ) -> None:
        self._table = table
        self._columns = columns
        self.sources: dict[str, Any] = sources if sources is not None else {}
        self.reports: list[FlightReport] = reports if reports is not None else []

    @property
    def table(self) -> pd.DataFrame:
        if self._table is None:
            import pandas as pd

            self._table = pd.DataFrame(self._columns or {})
            self._columns = None
        return self._table

    @table.setter
    def table(self, value: pd.DataFrame) -> None:
        self._table, self._columns = value, None

    def column(self, name: str) -> npt.NDArray[Any]:
        """One column as a numpy array, without building the pandas table (KeyError when the
        Df has no such column)."""
        if self._table is not None:
            return np.asarray(self._table[name].to_numpy())
        return np.asarray((self._columns or {})[name])

    def __len__(self) -> int:
        if self._table is not None:
            return len(self._table)
        cols = self._columns or {}
        return len(next(iter(cols.values()))) if cols else 0

    def __repr__(self) -> str:
        return f"Df({len(self)} samples, {len(self.reports)} flight(s))"

    def csv_text(self) -> str:
        """The Df CSV: written by pandas when the table was given (or touched) as pandas, else
        from the columns exactly as pandas would write them."""
        if self._table is not None:
            return str(self._table.to_csv(index=False, float_format="%.6g"))
        return _csv_text(self._columns or {})


def concat_columns(tables: list[Columns]) -> Columns:
    """Rows of every flight, columns in order of first appearance, NaN where a flight lacks one
    (as pandas.concat)."""
    names: list[str] = []
    for t in tables:
        names.extend(k for k in t if k not in names)
    out: Columns = {}
    for k in names:
        parts = []
        for t in tables:
            n = len(t["time_s"])
            if k in t:
                parts.append(t[k])
            else:
                parts.append(
                    np.full(
                        n, np.nan if k != "flight" else "", dtype=object if k == "flight" else float
                    )
                )
        out[k] = np.concatenate(parts) if parts else np.zeros(0)
    return out


def hover_throttle(table: pd.DataFrame) -> float:
    """The normalised collective command needed to hover: median of norm · g / a_up."""
    if "thrust_cmd_norm" not in table.columns or not len(table):
        raise DataFormatError("Df has no normalised thrust command to estimate hover throttle")
    ratio = table["thrust_cmd_norm"].to_numpy(float) * G0 / table["accel_up_mps2"].to_numpy(float)
    return float(nanmedian(ratio))


def _csv_text(columns: Columns) -> str:
    """The Df CSV as pandas writes it (``float_format='%.6g'``, NaN as an empty field)."""
    buf = io.StringIO()
    names = list(columns)
    if not names:
        return "\n"
    csv.writer(buf, lineterminator="\n").writerow(names)
    cells = []
    for k in names:
        v = columns[k]
        if v.dtype == object or v.dtype.kind in "US":
            cells.append([_csv_cell(str(x)) for x in v])
        else:
            cells.append(["" if x != x else f"{x:.6g}" for x in np.asarray(v, float).tolist()])
    buf.writelines(",".join(row) + "\n" for row in zip(*cells, strict=True))
    return buf.getvalue()


def _csv_cell(text: str) -> str:
    if any(c in text for c in ',"\n\r'):
        return '"' + text.replace('"', '""') + '"'
    return text
