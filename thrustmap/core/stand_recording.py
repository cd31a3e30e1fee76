"""The Ds log: thrustmap's own stand recording, a CSV plus a JSON sidecar.

The bench runner writes it (:class:`DsWriter`); the fitting loader reads it (:func:`parse`,
:func:`read_sidecar`). Neither side owns the format: both use this module.

``run.csv`` holds one row per stand sample, written and flushed as it arrives (a crash loses
nothing already written). Columns: ``time_s``, ``throttle_<unit>`` (the scale's unit, ``%`` as
``pct``), then :data:`DATA_COLUMNS`; an empty cell means "not measured". ``step`` is the index of
the plan segment the sample belongs to, ``phase`` its label; the runner appends ``-settled`` to
the label once a settling hold has settled, and labels the spin-down after the stop ``stop``.

``run.meta.json`` beside it says what the numbers mean and how the run ended::

    {"format": "thrustmap.ds", "version": 1,
     "throttle_scale": {"name": "pwm", "lo": 1000, "hi": 2000, "unit": "us"},
     "rotors_on_esc": 1, "strategy": "SR", "motor": 0,
     "devices": {...}, "plan": {...}, "limits": {...}, "started_utc": "...", "ended_utc": "...",
     "samples": 287, "stop_verified": true,
     "outcome": {"status": "completed" | "aborted" | "running", "reason": "..."}}

A sidecar still saying ``running`` means the process died mid-run: the log loads, marked partial.
The sidecar is replaced atomically. It is written with spare room at its end (JSON allows
trailing blanks) so that, when the disk is too full for a new file, a compact record of the
outcome can still be written in place: the reason and the stop verification are never lost.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields
from datetime import datetime, timezone
from pathlib import Path
from typing import IO, Any

import numpy as np
import numpy.typing as npt

from thrustmap.core.errors import ConfigError, DataFormatError, ThrustmapError
from thrustmap.core.files import atomic_write_text
from thrustmap.core.jsonfile import Fields, load_json
from thrustmap.core.units import ThrottleScale

log = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

DS_FORMAT = "thrustmap.ds"
DS_VERSION = 1
SETTLED_SUFFIX = "-settled"
STOP_PHASE = "stop"
OUTCOMES = ("running", "completed", "aborted")
#: Blanks kept at the end of the first sidecar: room for the compact outcome record.
SIDECAR_RESERVE_BYTES = 1024


@dataclass(frozen=True)
class DsRow:
    """One Ds log row. A field that was not measured is None (an empty cell)."""

    time_s: float
    throttle_native: float
    thrust_n: float | None = None
    voltage_v: float | None = None
    current_a: float | None = None
    rpm: float | None = None
    torque_nm: float | None = None
    temperature_c: float | None = None
    vibration_g: float | None = None
    step: int | None = None
    phase: str | None = None

    def cells(self) -> list[str]:
        out = [f"{self.time_s:.6f}", f"{self.throttle_native:.6g}"]
        for name in DATA_COLUMNS:
            v = getattr(self, name)
            if v is None or (isinstance(v, float) and not math.isfinite(v)):
                out.append("")
            elif name == "phase":
                if not isinstance(v, str) or any(c in v for c in ',"\r\n'):
                    raise ValueError(f'Ds log phase {v!r}: expected a label without , " or EOL')
                out.append(v)
            elif isinstance(v, bool) or not isinstance(v, (int, float, np.number)):
                raise TypeError(f"Ds log field '{name}' must be a number, got {type(v).__name__}")
            else:
                out.append(f"{v:.7g}")
        return out


#: Columns after time_s and throttle_<unit>, in file order.
DATA_COLUMNS: tuple[str, ...] = tuple(
    f.name for f in fields(DsRow) if f.name not in ("time_s", "throttle_native")
)
_FIELDS = frozenset(DATA_COLUMNS)


def row_from(
    time_s: float, throttle_native: float, values: Mapping[str, float | int | str | None]
) -> DsRow:
    """A :class:`DsRow` from named values; an unknown name is an error, never an empty column."""
    unknown = sorted(set(values) - _FIELDS)
    if unknown:
        raise ValueError(
            f"unknown Ds log field(s) {', '.join(unknown)}; expected: {', '.join(DATA_COLUMNS)}"
        )
    return DsRow(time_s, throttle_native, **values)  # type: ignore[arg-type]


def throttle_column(scale: ThrottleScale) -> str:
    return f"throttle_{scale.unit.replace('%', 'pct')}"


def sidecar_path(csv_path: str | Path) -> Path:
    p = Path(csv_path)
    return p.with_name(p.stem + ".meta.json")


def _now_utc() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="milliseconds")


def _os_reason(exc: OSError) -> str:
    return exc.strerror or str(exc)


class DsWriter:
    """Append-only Ds log writer: every row is flushed as written; the sidecar says how it ended.

    Never overwrites a recording: the CSV and its sidecar must not exist yet. A write error
    (disk full) raises :class:`~thrustmap.core.errors.ConfigError` naming the file; :meth:`finish`
    still records the outcome and the error in the sidecar.
    """

    def __init__(
        self, path: str | Path, throttle_scale: ThrottleScale, meta: Mapping[str, Any]
    ) -> None:
        self.path = Path(path)
        self.meta_path = sidecar_path(self.path)
        self.throttle_scale = throttle_scale
        self.throttle_column = throttle_column(throttle_scale)
        self.rows = 0
        self.write_error: str | None = None
        self.meta: dict[str, Any] = {
            "format": DS_FORMAT,
            "version": DS_VERSION,
            "throttle_scale": throttle_scale.to_dict(),
            **dict(meta),
            "started_utc": _now_utc(),
            "outcome": {"status": "running", "reason": ""},
        }
        for p in (self.path, self.meta_path):
            if p.exists():
                raise ConfigError("a recording exists here; refusing to overwrite it", file=str(p))
        self.path.parent.mkdir(parents=True, exist_ok=True)
        text = json.dumps(self.meta, indent=2) + "\n"
        atomic_write_text(self.meta_path, text + " " * SIDECAR_RESERVE_BYTES + "\n")
        try:
            self._file: IO[str] | None = open(  # noqa: SIM115 - closed in finish()
                self.path, "x", encoding="utf-8", newline=""
            )
            self._file.write(",".join(("time_s", self.throttle_column, *DATA_COLUMNS)) + "\n")
            self._file.flush()
        except OSError as exc:
            raise ConfigError(
                f"cannot write the Ds log: {_os_reason(exc)}", file=str(self.path)
            ) from None

    def write(
        self, time_s: float, throttle_native: float, values: Mapping[str, float | int | str | None]
    ) -> None:
        """Append one sample given as named values (names from :data:`DATA_COLUMNS`)."""
        self.write_row(row_from(time_s, throttle_native, values))

    def write_row(self, row: DsRow) -> None:
        if self._file is None:
            raise ValueError(f"{self.path}: write after finish")
        if self.write_error is not None:
            raise ConfigError(f"cannot write the Ds log: {self.write_error}", file=str(self.path))
        line = ",".join(row.cells()) + "\n"
        try:
            self._file.write(line)
            self._file.flush()
        except OSError as exc:
            self.write_error = _os_reason(exc)
            raise ConfigError(
                f"cannot write the Ds log after {self.rows} rows: {self.write_error}",
                file=str(self.path),
            ) from None
        self.rows += 1

    def note(self, extra: Mapping[str, Any]) -> None:
        """Add ``extra`` to the sidecar while the run goes on (an adaptive plan's record of each
        point), so a run that is killed keeps it. The outcome stays ``running``; a disk error is
        logged, never raised (the samples matter more than the note)."""
        self.meta.update(dict(extra))
        try:
            atomic_write_text(
                self.meta_path,
                json.dumps(self.meta, indent=2) + "\n" + " " * SIDECAR_RESERVE_BYTES + "\n",
            )
        except ThrustmapError as exc:
            log.warning("cannot update the Ds log's sidecar: %s", exc)

    def finish(self, status: str, reason: str = "", extra: Mapping[str, Any] | None = None) -> None:
        """Close the CSV and record the outcome (``completed`` or ``aborted``) in the sidecar.

        Never raises for a disk problem: the outcome goes into the sidecar (replaced atomically,
        or compactly in place when the disk is full), and failing that into the log."""
        if status not in OUTCOMES:
            raise ValueError(f"Ds outcome status {status!r}; expected one of {OUTCOMES}")
        if self._file is not None:
            try:
                self._file.flush()
                os.fsync(self._file.fileno())
            except OSError as exc:
                self.write_error = self.write_error or _os_reason(exc)
            with contextlib.suppress(OSError):
                self._file.close()
            self._file = None
        self.meta.update(dict(extra or {}))
        self.meta["ended_utc"] = _now_utc()
        self.meta["samples"] = self.rows
        outcome: dict[str, Any] = {"status": status, "reason": reason}
        if self.write_error is not None:
            outcome["csv_error"] = self.write_error
            if status == "completed":
                outcome["status"] = "aborted"
                outcome["reason"] = f"the Ds log could not be written: {self.write_error}"
        self.meta["outcome"] = outcome
        try:
            atomic_write_text(self.meta_path, json.dumps(self.meta, indent=2) + "\n")
        except ThrustmapError as exc:
            self._record_in_place(str(exc))

    def _record_in_place(self, why: str) -> None:
        """The disk has no room for a new file: overwrite the sidecar's own bytes with a compact
        outcome record, padded with blanks to the old length (no new blocks needed)."""
        keep = (
            "format",
            "version",
            "throttle_scale",
            "rotors_on_esc",
            "strategy",
            "motor",
            "started_utc",
            "ended_utc",
            "samples",
            "stop_verified",
            "stop_latency_s",
        )
        compact: dict[str, Any] = {k: self.meta[k] for k in keep if k in self.meta}
        outcome = dict(self.meta["outcome"])
        compact["outcome"] = outcome
        compact["sidecar_note"] = "compact record written in place after a disk error"
        try:
            with open(self.meta_path, "r+b") as f:
                size = os.fstat(f.fileno()).st_size
                for limit in (400, 120, 0):
                    outcome["reason"] = str(self.meta["outcome"].get("reason", ""))[:limit]
                    data = json.dumps(compact, separators=(",", ":")).encode("utf-8")
                    if len(data) <= size:
                        break
                else:
                    raise OSError("no room in the sidecar for the outcome")
                f.write(data + b" " * (size - len(data)))
                f.flush()
                os.fsync(f.fileno())
            log.warning("%s: %s; outcome recorded compactly in place", self.meta_path, why)
        except OSError as exc:
            log.critical(
                "%s: the run's outcome could not be recorded (%s): status %s, reason %r, "
                "stop verified %s",
                self.meta_path,
                _os_reason(exc),
                outcome.get("status"),
                self.meta["outcome"].get("reason"),
                self.meta.get("stop_verified"),
            )


# -- reading -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class DsSidecar:
    """What a Ds sidecar says, typed. ``segments`` is the plan's segment types in step order."""

    path: str
    throttle_scale: ThrottleScale
    rotors_on_esc: int | None
    strategy: str | None
    status: str
    reason: str
    samples: int | None
    stop_verified: bool | None
    segments: tuple[str, ...]


def read_sidecar(csv_path: str | Path) -> DsSidecar | None:
    """The sidecar beside ``csv_path``, checked field by field; None when there is none."""
    p = sidecar_path(csv_path)
    if not p.exists():
        return None
    src = str(p)
    f = Fields(load_json(p, max_bytes=16 * 1024 * 1024, what="Ds sidecar"), source=src)
    if f.string("format", "") != DS_FORMAT:
        raise DataFormatError(f"sidecar is not a {DS_FORMAT} document (field 'format')", file=src)
    f.integer("version", minimum=1, maximum=DS_VERSION)
    ts = f.sub("throttle_scale")
    try:
        scale = ThrottleScale(
            ts.string("name"), ts.number("lo"), ts.number("hi"), ts.string("unit")
        )
    except ConfigError as exc:
        raise DataFormatError(f"field 'throttle_scale': {exc.message}", file=src) from None
    rotors = (
        f.integer("rotors_on_esc", 0, minimum=1, maximum=64) if f.has("rotors_on_esc") else None
    )
    strategy = f.string("strategy", "") or None
    outcome = f.sub("outcome") if f.has("outcome") else None
    status = outcome.string("status", choices=OUTCOMES) if outcome is not None else "running"
    reason = outcome.string("reason", "") if outcome is not None else ""
    samples = f.integer("samples", 0, minimum=0) if f.has("samples") else None
    stop_verified = f.boolean("stop_verified") if f.has("stop_verified") else None
    segments: list[str] = []
    if f.has("plan"):
        plan = f.sub("plan")
        if plan.has("segments"):
            segs = plan.raw("segments")
            if not isinstance(segs, list):
                raise plan.error("expected a list", "segments")
            for i, seg in enumerate(segs):
                s = Fields(seg, source=src, path=f"plan.segments[{i}]")
                segments.append(s.string("type", "hold", choices=("hold", "ramp")))
    return DsSidecar(
        src, scale, rotors, strategy, status, reason, samples, stop_verified, tuple(segments)
    )


@dataclass(frozen=True)
class DsColumns:
    """The CSV part of a Ds log as arrays (NaN where a cell is empty; ``step`` -1 there)."""

    throttle_unit: str
    throttle_native: FloatArray
    thrust_n: FloatArray
    voltage_v: FloatArray
    time_s: FloatArray
    line: IntArray
    current_a: FloatArray | None
    rpm: FloatArray | None
    step: IntArray | None
    settled: BoolArray  # the runner had marked the hold settled
    stopping: BoolArray  # the spin-down recorded after the stop


def is_ds_header(keys: Sequence[str]) -> bool:
    return {"time_s", "thrust_n", "voltage_v"} <= set(keys)


def parse(
    header: Sequence[str], rows: Sequence[Sequence[str]], lines: Sequence[int], source: str
) -> DsColumns:
    """Decode Ds log rows (``header`` as written, ``lines`` the 1-based line of each row)."""
    keys = [h.strip().lower() for h in header]
    throttle_cols = [i for i, k in enumerate(keys) if k.startswith("throttle_")]
    if len(throttle_cols) != 1:
        raise DataFormatError(
            "thrustmap Ds log needs exactly one throttle_<unit> column", file=source
        )
    for i, k in enumerate(keys):
        if keys.index(k) != i:
            raise DataFormatError(f"duplicated column '{header[i]}'", file=source)

    def cells(i: int) -> list[str]:
        return [r[i].strip() if i < len(r) else "" for r in rows]

    def numbers(name: str, *, required: bool) -> FloatArray | None:
        if name not in keys:
            return None
        i = keys.index(name)
        out = np.full(len(rows), np.nan)
        for k, cell in enumerate(cells(i)):
            if not cell:
                if required:
                    raise DataFormatError(
                        "empty cell; expected a number", file=source, line=lines[k], column=name
                    )
                continue
            try:
                v = float(cell)
            except ValueError:
                raise DataFormatError(
                    f"'{cell[:30]}' is not a number", file=source, line=lines[k], column=name
                ) from None
            if not math.isfinite(v):
                raise DataFormatError(
                    f"'{cell[:30]}' is not a finite number; expected a measured value",
                    file=source,
                    line=lines[k],
                    column=name,
                )
            out[k] = v
        return out

    ti = throttle_cols[0]
    throttle = numbers(keys[ti], required=True)
    thrust = numbers("thrust_n", required=True)
    volt = numbers("voltage_v", required=True)
    time_s = numbers("time_s", required=True)
    assert throttle is not None and thrust is not None and volt is not None and time_s is not None
    step_f = numbers("step", required=False)
    step = None
    if step_f is not None:
        bad = np.flatnonzero(
            np.isfinite(step_f) & ((step_f < 0) | (step_f > 1e6) | (step_f != np.round(step_f)))
        )
        if bad.size:
            raise DataFormatError(
                "expected a plan step index (0, 1, 2, ...)",
                file=source,
                line=lines[bad[0]],
                column="step",
            )
        step = np.where(np.isfinite(step_f), step_f, -1).astype(np.int64)
    phase = cells(keys.index("phase")) if "phase" in keys else [""] * len(rows)
    return DsColumns(
        throttle_unit=keys[ti].removeprefix("throttle_"),
        throttle_native=throttle,
        thrust_n=thrust,
        voltage_v=volt,
        time_s=time_s,
        line=np.asarray(lines, dtype=np.int64),
        current_a=numbers("current_a", required=False),
        rpm=numbers("rpm", required=False),
        step=step,
        settled=np.array([p.endswith(SETTLED_SUFFIX) for p in phase], dtype=bool),
        stopping=np.array([p == STOP_PHASE for p in phase], dtype=bool),
    )
