"""The Df file: the CSV and its JSON sidecar, written atomically and read back checked."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from thrustmap.core.errors import ConfigError, DataFormatError
from thrustmap.core.files import atomic_write_text
from thrustmap.core.jsonfile import load_json
from thrustmap.fitting.df.table import Df

if TYPE_CHECKING:  # pandas is imported where a table is asked for: `flightlog extract` runs
    import pandas as pd  # without it (its import alone took 0.3 s of a 0.7 s extraction)


def sidecar_path(csv_path: str | Path) -> Path:
    return Path(csv_path).with_suffix(".json")


def write_df(df: Df, path: str | Path) -> Path:
    """Write the Df CSV and its sidecar, each atomically; the sidecar is never the CSV itself."""
    p = Path(path)
    side = sidecar_path(p)
    if side.resolve() == p.resolve():
        raise ConfigError(
            f"the Df output needs a name its sidecar ({side.name}) does not share; use .csv",
            file=str(p),
        )
    atomic_write_text(p, df.csv_text())
    atomic_write_text(side, json.dumps(df.sources, indent=2, default=str) + "\n")
    return side


def _positive_int(value: Any) -> bool:
    """A count: an integer ≥ 1 (a JSON 4.0 is accepted, 4.5, "four", true are not)."""
    if isinstance(value, bool):
        return False
    if isinstance(value, int):
        return value >= 1
    return isinstance(value, float) and value.is_integer() and value >= 1


def _check_sidecar(side: dict[str, Any], path: str) -> None:
    """Refuse sidecar fields the γ fit relies on when they cannot be what they name."""
    flights = side.get("flights", {})
    if not isinstance(flights, dict):
        raise DataFormatError(
            "Df sidecar: 'flights' must be an object", file=path, column="flights"
        )
    for fid, meta in flights.items():
        if not isinstance(meta, dict):
            raise DataFormatError(
                "Df sidecar: expected an object per flight", file=path, column=f"flights.{fid}"
            )
        for key in ("rotors", "mass_kg"):
            value = meta.get(key)
            if value is None:
                continue
            if key == "rotors" and not _positive_int(value):
                raise DataFormatError(
                    f"Df sidecar: rotor count {value!r} is not a whole number ≥ 1",
                    file=path,
                    column=f"flights.{fid}.rotors",
                )
            if key == "mass_kg" and (
                isinstance(value, bool) or not isinstance(value, int | float) or not 0 < value < 1e5
            ):
                raise DataFormatError(
                    f"Df sidecar: mass {value!r} is not a positive number of kg",
                    file=path,
                    column=f"flights.{fid}.mass_kg",
                )
    opts = side.get("options")
    if (
        isinstance(opts, dict)
        and opts.get("rotors") is not None
        and not _positive_int(opts["rotors"])
    ):
        raise DataFormatError(
            f"Df sidecar: rotor count {opts['rotors']!r} is not a whole number ≥ 1",
            file=path,
            column="options.rotors",
        )


def _refuse_json(p: Path) -> None:
    """A JSON file given as a Df (its sidecar, a map) is named as such, not parsed as CSV."""
    try:
        with open(p, "rb") as f:
            head = f.read(64).lstrip(b"\xef\xbb\xbf \t\r\n")
    except OSError:
        return  # read_csv names what is wrong with the path
    if head[:1] in (b"{", b"["):
        csv = p.with_suffix(".csv")
        hint = f"; the Df is {csv.name} beside it" if csv.is_file() and csv != p else ""
        raise DataFormatError(
            "a JSON file (a Df sidecar or a map?), not a Df CSV; expected the .csv that "
            f"flightlog extract wrote{hint}",
            file=str(p),
        )


def read_df(path: str | Path) -> tuple[pd.DataFrame, dict[str, Any]]:
    """A Df CSV and its sidecar (empty dict when the sidecar is absent)."""
    import pandas as pd

    p = Path(path)
    _refuse_json(p)
    try:
        table = pd.read_csv(p, dtype=str, keep_default_na=False, engine="c")
    except FileNotFoundError:
        raise DataFormatError("Df file not found", file=str(p)) from None
    except OSError as exc:
        raise DataFormatError(f"cannot read Df file: {exc.strerror}", file=str(p)) from None
    except pd.errors.ParserError:  # (pandas' tokenizer words name no cause a user knows)
        raise DataFormatError(
            "not a Df CSV: its rows do not form one table under its first line (an export's "
            "text, another tool's file?); expected the .csv that flightlog extract wrote",
            file=str(p),
        ) from None
    except (pd.errors.EmptyDataError, ValueError) as exc:
        reason = " ".join(str(exc).split())[:200]
        raise DataFormatError(f"not a Df CSV: {reason}", file=str(p)) from None
    for need in ("voltage_v", "force_n"):
        if need not in table.columns:
            raise DataFormatError(
                "not a Df CSV (expected columns time_s, voltage_v, accel_up_mps2, force_n, "
                "thrust_cmd_n and/or thrust_cmd_norm)",
                file=str(p),
                column=need,
            )
    for col in table.columns:
        if col == "flight":
            continue
        text = table[col].str.strip()
        num = pd.to_numeric(text.where(text != "", "nan"), errors="coerce")
        bad = num.isna().to_numpy() & ~text.str.lower().isin(["", "nan"]).to_numpy()
        with np.errstate(invalid="ignore"):
            bad |= np.isinf(num.to_numpy(dtype=float))
        if bad.any():
            row = int(np.flatnonzero(bad)[0])
            cell = str(table[col].iloc[row])
            shown = cell if len(cell) <= 40 else f"{cell[:40]}... ({len(cell)} characters)"
            raise DataFormatError(
                f"expected a finite number, got {shown!r}", file=str(p), line=row + 2, column=col
            )
        table[col] = num.astype(float)
    side: dict[str, Any] = {}
    sp = sidecar_path(p)
    if sp.exists() and sp.resolve() != p.resolve():
        loaded = load_json(sp, what="Df sidecar")
        if not isinstance(loaded, dict):
            raise DataFormatError("Df sidecar: expected a JSON object", file=str(sp))
        side = loaded
        _check_sidecar(side, str(sp))
    if "flight" not in table.columns:
        table.insert(0, "flight", p.name)
    return table, side
