"""``load_dataset``: one stand log, its format detected from the header or read through the
user's ``ColumnMap``."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from thrustmap.core.errors import DataFormatError
from thrustmap.core.identity import Identity, refuse_repeats
from thrustmap.core.physical import (  # the physical ranges live in one place
    check_header_unit,
    header_thrust_unit,
)
from thrustmap.core.units import SCALES, ThrottleScale
from thrustmap.fitting.dataset import Dataset
from thrustmap.fitting.loaders.assemble import assemble
from thrustmap.fitting.loaders.checks import check_unnamed_thrust_unit
from thrustmap.fitting.loaders.formats import FORMATS
from thrustmap.fitting.loaders.table import (
    THRUST_UNITS,
    Table,
    find_column,
    normalise_header,
    read_table,
)

log = logging.getLogger(__name__)


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


def load_dataset(path: str | Path, column_map: ColumnMap | None = None) -> Dataset:
    """Load one stand log; detect its format from the header unless a column map is given."""
    _refuse_json(Path(path))
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


def _with_column_map(table: Table, cm: ColumnMap) -> Dataset:
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
        hit = find_column(table, r"current \((a|amps?)\)")
        current = None if hit is None else hit[0]
    ds = assemble(
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
    if header_thrust_unit(table.header[fi]) is None:  # the unit is the user's word alone
        check_unnamed_thrust_unit(ds, cm.thrust_unit)
    return ds


def _refuse_json(path: Path) -> None:
    """A JSON file (a Ds log's sidecar, a map, a manifest) given as a stand log is named as
    such, not parsed as a one-column CSV."""
    try:
        with open(path, "rb") as f:
            head = f.read(64).lstrip(b"\xef\xbb\xbf \t\r\n")
    except OSError:
        return  # read_table names what is wrong with the path
    if head[:1] in (b"{", b"["):
        raise DataFormatError(
            "a JSON file (a stand log's sidecar, a map?), not a stand log; expected the CSV "
            "(a thrustmap Ds log's sidecar is read with its .csv)",
            file=str(path),
        )


def _without_sidecars(paths: Sequence[str | Path]) -> list[str | Path]:
    """The paths less the Ds sidecars (``run.meta.json``) whose log (``run.csv``) is given too:
    a glob such as ``thrustmap-demo/sr/*`` names both, and the log reads its own sidecar."""
    given = {Path(p).resolve() for p in paths}
    out = []
    for p in paths:
        name = Path(p).name
        if name.endswith(".meta.json"):
            log_csv = Path(p).with_name(name[: -len(".meta.json")] + ".csv").resolve()
            if log_csv in given:
                log.info("%s: the sidecar of %s, read with it", p, log_csv.name)
                continue
        out.append(p)
    return out


def load_datasets(
    paths: Sequence[str | Path], column_map: ColumnMap | None = None
) -> list[Dataset]:
    """Every stand log of a pool (a fit, a comparison, a report): the same content given twice
    is refused naming both (``core.identity``), so no log counts twice."""
    if not paths:
        raise DataFormatError("no input files given; expected one or more stand logs")
    datasets = [load_dataset(p, column_map) for p in _without_sidecars(paths)]
    refuse_repeats((Identity(ds.path, ds.sha256) for ds in datasets), "stand log")
    return datasets
