"""Df files pooled for one γ fit (``gamma fit DF...``, ``fleet gamma``): read each, refuse
the same Df or the same flight given twice (``core.identity``), refuse a Df whose T_c came
through another stand map than the one given, then concatenate and merge the sidecars."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from thrustmap.core.errors import DataFormatError
from thrustmap.core.identity import Identity, file_sha256, refuse_repeats
from thrustmap.fitting.df.dffile import read_df

if TYPE_CHECKING:
    import pandas as pd

    from thrustmap.fitting.mapfile import ThrustMap

log = logging.getLogger(__name__)


def flight_identities(table: pd.DataFrame, side: dict[str, Any], name: str) -> list[Identity]:
    """Each flight of one Df as its log's sha256 (with the flight's index in a file of several
    logs) and the time span of its samples. Flights whose log the sidecar does not name (a Df
    from an older version) are left out: they can be told apart by the file hash only."""
    logs = side.get("logs") or []
    by_path = {str(x.get("path")): str(x.get("sha256") or "") for x in logs if isinstance(x, dict)}
    by_name = {Path(p).name: sha for p, sha in by_path.items()}
    paths = {
        str(r.get("flight")): str(r.get("path") or "")
        for r in side.get("reports") or []
        if isinstance(r, dict)
    }
    out = []
    for fid in side.get("flights") or {}:
        path = paths.get(fid, "")
        sha = by_path.get(path) or by_name.get(Path(path).name if path else fid.split("#")[0])
        rows = table[table["flight"] == fid]
        if not sha or not len(rows) or "time_s" not in rows.columns:
            continue
        t = rows["time_s"].to_numpy(float)
        index = fid.rsplit("#", 1)[1] if "#" in fid else "0"
        out.append(
            Identity(f"flight {fid} of {name}", f"{sha}#{index}", (float(t.min()), float(t.max())))
        )
    return out


def check_map(side: dict[str, Any], tmap: ThrustMap, df_path: Path, map_path: str) -> None:
    """Refuse a Df whose thrust command came through another stand map than ``tmap``: the γ
    of one map attached to another is wrong by their difference. A Df extracted with the
    same bench map (with or without a γ block) passes; one from before the map was recorded
    is said to be unchecked. A Df whose T_c did not come through a map (the log's own newtons,
    or no T_c column: ``gamma fit`` computes it through the map given) has nothing to check."""
    source = str((side.get("columns") or {}).get("thrust_cmd_n") or "")
    if "stand map" not in source:
        return
    if "map" not in side:
        log.warning(
            "%s: its sidecar does not record the map it was extracted with (an older Df): "
            "whether its thrust command matches %s cannot be checked",
            df_path,
            map_path,
        )
        return
    rec = side.get("map")
    if not isinstance(rec, dict):
        return  # extracted without a map: T_c came from the log itself, or comes from this map
    if rec.get("sha256") == tmap.file_sha256 or rec.get("bench_sha256") == tmap.bench_sha256:
        return
    if not rec.get("bench_sha256") and not rec.get("sha256"):
        return
    was = str(rec.get("path") or "a map")
    raise DataFormatError(
        f"extracted with {was} (sha256 {str(rec.get('sha256'))[:12]}…), not with {map_path} "
        f"(sha256 {tmap.file_sha256[:12]}…): its thrust command came through the other map, so "
        "a γ fitted here would correct the wrong map; give the map it was extracted with, or "
        "extract the flight again with --map " + map_path,
        file=str(df_path),
    )


def pool_dfs(
    paths: Sequence[Path], tmap: ThrustMap | None = None, map_path: str = ""
) -> tuple[pd.DataFrame, dict[str, Any]]:
    """The Df files pooled: each read and checked, repeats refused (``core.identity``), the
    tables concatenated in order and the sidecars' columns and flights merged."""
    import pandas as pd

    tables = []
    side: dict[str, Any] = {}
    files: list[Identity] = []
    flights: list[Identity] = []
    for p in paths:
        table, s = read_df(p)  # (names a file that is missing or not a Df first)
        files.append(Identity(str(p), file_sha256(p)))
        if not len(table):
            raise DataFormatError(f"no samples in {p.name}: " + _empty_reason(s), file=str(p))
        if tmap is not None:
            check_map(s, tmap, p, map_path)
        flights.extend(flight_identities(table, s, str(p)))
        tables.append(table)
        for k in ("columns", "flights"):
            side.setdefault(k, {}).update(s.get(k, {}))
    refuse_repeats(files, "Df file")
    refuse_repeats(flights, "flight")
    return pd.concat(tables, ignore_index=True), side


def _empty_reason(side: dict[str, Any]) -> str:
    """Why a Df has no samples, from its sidecar's reports."""
    parts = []
    for r in side.get("reports", []):
        if not isinstance(r, dict):
            continue
        steps = [s for s in r.get("steps", []) if isinstance(s, dict) and s.get("dropped_s", 0)]
        dropped = ", ".join(
            f"{s.get('name')} −{float(s.get('dropped_s', 0)):.1f} s ({s.get('reason')})"
            for s in steps
        )
        parts.append(
            f"{r.get('flight')}: kept {float(r.get('kept_s', 0)):.1f} s"
            + (": " + dropped if dropped else "")
        )
    return "; ".join(parts) or "the Df is empty (no steady flight in its log)"
