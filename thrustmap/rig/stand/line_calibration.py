"""A line stand's load-cell calibration: the file ``thrustmap stand calibrate`` writes and a
preset reads (``--calibration cal.json`` on ``probe``, ``--line-calibration`` on ``sweep``).

Format (JSON, version 1)::

    {"format": "thrustmap-line-calibration", "version": 1, "preset": "tiny-thrust-stand",
     "field": "thrust_n", "tare_counts": -5190.4, "counts_per_n": -43033.0,
     "mass_kg": 0.1, "samples": 50, "noise_counts": 21.3, "created_utc": "..."}

``counts_per_n`` is the change of the raw column per newton of pull on the cell (its sign is
the cell's: many stands read a pulling propeller as fewer counts). Applying it replaces the
preset's column scale: ``si = (raw - tare_counts) / counts_per_n``.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import statistics
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

from thrustmap.core.errors import ConfigError, DataFormatError
from thrustmap.core.jsonfile import load_json
from thrustmap.core.physical import G0
from thrustmap.protocols.stands.line import LineStandSpec

FORMAT = "thrustmap-line-calibration"
VERSION = 1
#: a known mass between a gram and 50 kg (a whoop cell to a 50 kg heavy-lift cell)
MASS_KG = (0.001, 50.0)
#: the loaded mean must differ from the rest mean by this many rest standard deviations
MIN_SIGNAL_TO_NOISE = 10.0


@dataclass(frozen=True)
class LineCalibration:
    preset: str
    field: str
    tare_counts: float
    counts_per_n: float
    mass_kg: float
    samples: int
    noise_counts: float
    created_utc: str = ""

    def apply(self, spec: LineStandSpec, source: str = "calibration") -> LineStandSpec:
        """``spec`` reading the calibrated field in SI (refused for another stand's file)."""
        if self.preset != spec.name:
            raise ConfigError(
                f"{source}: a calibration of '{self.preset}', but the stand is read as "
                f"'{spec.name}'"
            )
        if self.field not in spec.columns:
            raise ConfigError(f"{source}: '{spec.name}' has no column for {self.field}")
        return spec.with_load_cell(self.field, self.tare_counts, 1.0 / self.counts_per_n)


def raw_spec(spec: LineStandSpec, field: str = "thrust_n") -> LineStandSpec:
    """``spec`` reading ``field`` as raw counts (scale 1, no tare): what calibrate measures."""
    if field not in spec.columns:
        raise ConfigError(f"line stand '{spec.name}' has no column for {field}")
    return spec.with_load_cell(field, 0.0, 1.0)


def calibration_from_counts(
    spec: LineStandSpec,
    rest_counts: Sequence[float],
    loaded_counts: Sequence[float],
    mass_kg: float,
    field: str = "thrust_n",
) -> LineCalibration:
    """Tare on ``rest_counts``; counts per newton from ``loaded_counts`` with ``mass_kg`` pulling
    the cell the way thrust does. Refuses a mass outside ``MASS_KG`` and a load that the cell
    does not tell from its noise."""
    lo, hi = MASS_KG
    if not (math.isfinite(mass_kg) and lo <= mass_kg <= hi):
        raise ConfigError(f"--mass-g {mass_kg * 1000:g}: expected {lo * 1000:g}..{hi * 1000:g} g")
    if len(rest_counts) < 3 or len(loaded_counts) < 3:
        raise ConfigError(
            f"calibrating '{spec.name}': too few readings "
            f"({len(rest_counts)} at rest, {len(loaded_counts)} loaded; need 3 of each)"
        )
    tare = statistics.fmean(rest_counts)
    loaded = statistics.fmean(loaded_counts)
    noise = max(statistics.stdev(rest_counts), statistics.stdev(loaded_counts))
    if abs(loaded - tare) < MIN_SIGNAL_TO_NOISE * max(noise, 0.5):
        raise ConfigError(
            f"calibrating '{spec.name}': the {mass_kg * 1000:g} g mass moved the cell by "
            f"{loaded - tare:.1f} counts, within its noise ({noise:.1f} counts): is it on the cell?"
        )
    return LineCalibration(
        preset=spec.name,
        field=field,
        tare_counts=tare,
        counts_per_n=(loaded - tare) / (mass_kg * G0),
        mass_kg=mass_kg,
        samples=min(len(rest_counts), len(loaded_counts)),
        noise_counts=noise,
        created_utc=_dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
    )


def write_line_calibration(path: str | Path, cal: LineCalibration) -> None:
    """Write ``cal`` to ``path``; never over an existing file."""
    data = {"format": FORMAT, "version": VERSION, **asdict(cal)}
    try:
        with open(path, "x", encoding="utf-8") as f:
            json.dump(data, f, indent=2)
            f.write("\n")
    except FileExistsError:
        raise ConfigError(f"{path}: exists; not overwritten (give another -o)") from None


def load_line_calibration(path: str | Path) -> LineCalibration:
    """Read a calibration file; errors name the file and the key."""
    source = str(path)
    try:
        data = load_json(path, what="line stand calibration")
    except DataFormatError as exc:
        raise ConfigError(exc.message, file=source, line=exc.line) from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise ConfigError(f'expected "format": "{FORMAT}"', file=source)
    if data.get("version") != VERSION:
        raise ConfigError(f"version {data.get('version')!r}: expected {VERSION}", file=source)
    values: dict[str, float] = {}
    for key in ("tare_counts", "counts_per_n", "mass_kg"):
        value = data.get(key)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"key '{key}': expected a number, got {value!r}", file=source)
        if not math.isfinite(value) or (key != "tare_counts" and value == 0):
            raise ConfigError(f"key '{key}': expected a finite non-zero number", file=source)
        values[key] = float(value)
    for key in ("preset", "field"):
        if not isinstance(data.get(key), str):
            raise ConfigError(f"key '{key}': expected a string", file=source)
    samples = data.get("samples", 0)
    noise = data.get("noise_counts", 0.0)
    return LineCalibration(
        preset=data["preset"],
        field=data["field"],
        tare_counts=values["tare_counts"],
        counts_per_n=values["counts_per_n"],
        mass_kg=values["mass_kg"],
        samples=int(samples) if isinstance(samples, int) else 0,
        noise_counts=float(noise) if isinstance(noise, (int, float)) else 0.0,
        created_utc=str(data.get("created_utc", "")),
    )
