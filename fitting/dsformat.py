"""The project's own Ds log: a CSV with unit-carrying column names plus a JSON sidecar.

``run.csv`` holds one row per stand sample (written and flushed as it arrives, so a crash loses
nothing); ``run.meta.json`` beside it says what the numbers mean and how the run ended:

    {"format": "thrustmap.ds", "version": 1,
     "throttle_scale": {"name": "pwm", "lo": 1000, "hi": 2000, "unit": "us"},
     "rotors_on_esc": 1, "strategy": "SR", "motor": 0,
     "devices": {...identity of stand and throttle output...},
     "plan": {...}, "limits": {...}, "started_utc": "...", "ended_utc": "...",
     "outcome": {"status": "completed" | "aborted" | "running", "reason": "..."}}

A sidecar still saying ``running`` means the process died mid-run: the log loads, marked partial.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Mapping
from datetime import datetime, timezone
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

import numpy as np

from thrustmap.errors import DataFormatError
from thrustmap.units import SCALES, ThrottleScale

if TYPE_CHECKING:
    from thrustmap.fitting.dataset import Dataset
    from thrustmap.fitting.loaders import _Table

log = logging.getLogger(__name__)

DS_FORMAT = "thrustmap.ds"
DS_VERSION = 1
#: Columns after time_s and throttle_<unit>; empty cells mean "not measured".
DATA_COLUMNS = (
    "thrust_n",
    "voltage_v",
    "current_a",
    "rpm",
    "torque_nm",
    "temperature_c",
    "vibration_g",
    "step",
    "phase",
)


def sidecar_path(csv_path: str | Path) -> Path:
    p = Path(csv_path)
    return p.with_name(p.stem + ".meta.json")


def _now_utc() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="milliseconds")


def _write_json_atomic(path: Path, data: Mapping[str, Any]) -> None:
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w", encoding="utf-8") as f:
        json.dump(data, f, indent=2)
        f.write("\n")
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


class DsWriter:
    """Append-only Ds log writer: every row is flushed as written; the sidecar says how it ended."""

    def __init__(
        self, path: str | Path, throttle_scale: ThrottleScale, meta: Mapping[str, Any]
    ) -> None:
        self.path = Path(path)
        self.meta_path = sidecar_path(self.path)
        self.throttle_scale = throttle_scale
        self.throttle_column = f"throttle_{throttle_scale.unit.replace('%', 'pct')}"
        self.rows = 0
        self.meta: dict[str, Any] = {
            "format": DS_FORMAT,
            "version": DS_VERSION,
            "throttle_scale": throttle_scale.to_dict(),
            **dict(meta),
            "started_utc": _now_utc(),
            "outcome": {"status": "running", "reason": ""},
        }
        self.path.parent.mkdir(parents=True, exist_ok=True)
        _write_json_atomic(self.meta_path, self.meta)
        self._file: IO[str] | None = open(self.path, "w", encoding="utf-8", newline="")  # noqa: SIM115
        self._file.write(",".join(("time_s", self.throttle_column, *DATA_COLUMNS)) + "\n")
        self._file.flush()

    def write(
        self, time_s: float, throttle_native: float, values: Mapping[str, float | int | str | None]
    ) -> None:
        if self._file is None:
            raise ValueError(f"{self.path}: write after finish")
        cells = [f"{time_s:.6f}", f"{throttle_native:.6g}"]
        for name in DATA_COLUMNS:
            v = values.get(name)
            cells.append("" if v is None else (v if isinstance(v, str) else f"{v:.7g}"))
        self._file.write(",".join(cells) + "\n")
        self._file.flush()
        self.rows += 1

    def finish(self, status: str, reason: str = "", extra: Mapping[str, Any] | None = None) -> None:
        """Close the CSV and record the outcome (``completed`` or ``aborted``) in the sidecar."""
        if self._file is not None:
            self._file.flush()
            os.fsync(self._file.fileno())
            self._file.close()
            self._file = None
        self.meta.update(dict(extra or {}))
        self.meta["ended_utc"] = _now_utc()
        self.meta["samples"] = self.rows
        self.meta["outcome"] = {"status": status, "reason": reason}
        _write_json_atomic(self.meta_path, self.meta)


def read_sidecar(csv_path: str | Path) -> dict[str, Any] | None:
    p = sidecar_path(csv_path)
    if not p.exists():
        return None
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DataFormatError(f"sidecar is not valid JSON ({exc})", file=str(p)) from None
    if not isinstance(data, dict) or data.get("format") != DS_FORMAT:
        raise DataFormatError(f"sidecar is not a {DS_FORMAT} document", file=str(p))
    return data


def from_table(table: _Table) -> Dataset | None:
    from thrustmap.fitting.loaders import _column, _finish

    keys = table.keys
    if not ({"time_s", "thrust_n", "voltage_v"} <= set(keys)):
        return None
    throttle_cols = [i for i, k in enumerate(keys) if k.startswith("throttle_")]
    if len(throttle_cols) != 1:
        raise DataFormatError(
            "thrustmap Ds log needs exactly one throttle_<unit> column", file=table.path
        )
    ti = throttle_cols[0]
    unit = keys[ti].removeprefix("throttle_")
    meta = read_sidecar(table.path)
    if meta is not None:
        scale = ThrottleScale.from_dict(meta.get("throttle_scale", {}))
    elif unit == "us":
        scale = SCALES["pwm"]
        log.warning(
            "%s: no sidecar %s; assuming PWM 1000..2000 us",
            table.path,
            sidecar_path(table.path).name,
        )
    elif unit == "pct":
        scale = SCALES["percent"]
    else:
        raise DataFormatError(
            f"no sidecar {sidecar_path(table.path).name}: it gives the throttle scale of '{table.header[ti]}'",
            file=table.path,
        )
    info: dict[str, Any] = {}
    rotors = None
    if meta is not None:
        outcome = meta.get("outcome", {})
        info["outcome"] = outcome
        info["strategy"] = meta.get("strategy")
        rotors = meta.get("rotors_on_esc")
        if outcome.get("status") == "running":
            info["partial"] = "the run never finished (process died?): log kept as recorded"
        elif outcome.get("status") == "aborted":
            info["partial"] = f"run aborted: {outcome.get('reason', '')}"
        if "partial" in info:
            log.warning("%s: %s", table.path, info["partial"])

    def col(name: str, allow_empty: bool = False) -> np.ndarray[Any, np.dtype[np.float64]] | None:
        return _column(table, keys.index(name), allow_empty=allow_empty) if name in keys else None

    thrust, volt, t = col("thrust_n"), col("voltage_v"), col("time_s")
    assert thrust is not None and volt is not None
    return _finish(
        table,
        "thrustmap",
        scale,
        _column(table, ti),
        thrust,
        volt,
        time_s=t,
        current_a=col("current_a", True),
        rpm=col("rpm", True),
        rotors_on_esc=rotors,
        meta=info,
    )
