"""One log of a fleet: the rules of ``flightlog extract``, an outcome that never raises.

:func:`process_log` is what a Dask worker runs. It reads one log, extracts its Df with
:func:`thrustmap.fitting.df.extract` (the same library call ``thrustmap flightlog extract``
makes, so the fleet follows exactly the same rules), writes the Df (CSV + sidecar) and a small
outcome JSON into ``OUT_DIR/df/``, and returns the outcome: samples kept, seconds dropped by each
rule, warnings, the airframe it belongs to, or the one-line reason the log was refused. A bad
log (corrupt, unknown format, no mass, a bug in a reader) gives an outcome, never an exception.

Files are named by the log's content hash and the options key, so a re-run (or another worker)
that meets the same content with the same options returns the stored outcome without reading
the log again.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import stat
import tempfile
import time
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from thrustmap.core.errors import ConfigError, DataFormatError, ThrustmapError

log = logging.getLogger(__name__)

OUTCOME_VERSION = 1
#: ArduPilot / PX4 / Betaflight parameters that shape the thrust curve or the motor outputs
#: (learned values such as MOT_THST_HOVER or MPC_THR_HOVER change from flight to flight and are
#: not part of an airframe)
THRUST_CURVE_PARAMS = (
    "MOT_THST_EXPO",
    "MOT_SPIN_MIN",
    "MOT_SPIN_MAX",
    "MOT_SPIN_ARM",
    "MOT_PWM_MIN",
    "MOT_PWM_MAX",
    "MOT_PWM_TYPE",
    "MOT_BAT_VOLT_MAX",
    "MOT_BAT_VOLT_MIN",
    "MOT_BAT_CURR_MAX",
    "FRAME_CLASS",
    "FRAME_TYPE",
    "RC3_MIN",
    "RC3_MAX",
    "THR_MDL_FAC",
    "MC_BAT_SCALE_EN",
    "CA_ROTOR_COUNT",
    "PWM_MIN",
    "PWM_MAX",
    "MAV_TYPE",
)
_PARAM_PREFIXES = ("PWM_MAIN_MIN", "PWM_MAIN_MAX", "PWM_AUX_MIN", "PWM_AUX_MAX", "SERVO")
#: blackbox header values that shape the thrust curve
_BLACKBOX_KEYS = ("thrust_linear", "motorOutput", "motor_pwm_protocol", "motor_idle")
AUTOPILOT = {
    "ulog": "PX4",
    "dataflash": "ArduPilot",
    "tlog": "MAVLink",
    "blackbox": "Betaflight",
    "blackbox-csv": "Betaflight",
    "rosbag": "Aerostack2",
}


@dataclass(frozen=True)
class LogTask:
    """What a worker needs for one log (small and picklable)."""

    path: str
    out_dir: str
    options_key: str
    df_options: dict[str, Any]  # thrustmap.fitting.df.DfOptions as a dict
    map_path: str | None = None
    fmt: str | None = None
    max_log_bytes: int = 1 << 30
    force: bool = False  # a flight on another pack than the map's: extracted, recorded


@dataclass
class Outcome:
    """One log's row of the fleet table."""

    path: str
    size_bytes: int = 0
    mtime_ns: int = 0
    sha256: str = ""
    options_key: str = ""
    status: str = "refused"  # ok | empty | refused
    reason: str = ""  # why it was refused, or why its Df is empty
    df_path: str = ""  # relative to the output folder
    format: str = ""
    flights: int = 0
    samples: int = 0
    duration_s: float = 0.0
    kept_s: float = 0.0
    dropped_s: dict[str, float] = field(default_factory=dict)  # rule -> seconds (all flights)
    warnings: list[str] = field(default_factory=list)
    airframe: str = ""  # JSON of the airframe description
    airframe_key: str = ""
    mass_kg: float = float("nan")
    rotors: int = 0
    voltage_min_v: float = float("nan")
    voltage_max_v: float = float("nan")
    seconds: float = 0.0  # time this run spent on the log (0 when reused)
    reused: bool = False

    def to_dict(self) -> dict[str, Any]:
        """The fields as a plain dict (the map and the list copied). Not ``dataclasses.asdict``:
        its deep copy took 44 us a log, called three times per log (the worker's outcome, its
        stored copy, the table), 7 ms of the table's 11 ms for 165 logs."""
        d = {name: getattr(self, name) for name in _FIELDS}
        d["dropped_s"] = dict(self.dropped_s)
        d["warnings"] = list(self.warnings)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Outcome:
        names = set(cls.__dataclass_fields__)
        return cls(**{k: v for k, v in d.items() if k in names})


_FIELDS = tuple(f.name for f in fields(Outcome))


def file_sha256(path: str | os.PathLike[str], chunk: int = 1 << 20) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(chunk):
            h.update(block)
    return h.hexdigest()


def stem_for(sha256: str, options_key: str) -> str:
    return f"{sha256[:20]}-{options_key[:10]}"


def one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return text[:400] + ("..." if len(text) > 400 else "")


def airframe_of(flights: list[Any], mass_kg: float | None, rotors: int) -> dict[str, Any]:
    """What makes logs one airframe: autopilot, frame and motor outputs, the parameters that
    shape the thrust curve, and the mass when given."""
    fl = flights[0]
    meta = fl.metadata
    params = meta.get("params") or {}
    shaping = {
        k: float(v)
        for k, v in sorted(params.items())
        if (k in THRUST_CURVE_PARAMS or k.startswith(_PARAM_PREFIXES))
        and isinstance(v, (int, float))
    }
    for k in _BLACKBOX_KEYS:
        if k in meta:
            shaping[k] = meta[k]
    scale = fl.motor_output_scale
    return {
        "autopilot": AUTOPILOT.get(fl.format, fl.format),
        "format": fl.format,
        "rotors": rotors,
        "motor_channels": str(meta.get("motor_channels", "")),
        "motor_output_scale": None if scale is None else scale.to_dict(),
        "params": shaping,
        "mass_kg": mass_kg,
    }


def airframe_key(airframe: dict[str, Any]) -> str:
    text = json.dumps(airframe, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:12]


def _stat(path: str) -> tuple[int, int]:
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise DataFormatError("flight log not found (removed during the run?)", file=path) from None
    except OSError as exc:
        raise DataFormatError(f"cannot read the flight log: {exc.strerror}", file=path) from None
    if not stat.S_ISREG(st.st_mode):
        raise DataFormatError("not a regular file (a FIFO or device is not read)", file=path)
    return st.st_size, st.st_mtime_ns


def process_log(task: LogTask) -> dict[str, Any]:
    """Run one log through the ``flightlog extract`` rules; the outcome as a plain dict.

    Never raises for anything about the log: a refusal is an outcome with its one-line reason.
    """
    started = time.perf_counter()
    out = Outcome(path=task.path, options_key=task.options_key)
    try:
        out.size_bytes, out.mtime_ns = _stat(task.path)
        if out.size_bytes > task.max_log_bytes:
            out.reason = (
                f"{task.path}: {out.size_bytes / 2**20:.0f} MiB is over the per-log limit of "
                f"{task.max_log_bytes / 2**20:.0f} MiB (--max-log-mb): not read, so a worker's "
                "memory stays bounded"
            )
            return _finish(out, started)
        out.sha256 = file_sha256(task.path)
        stored = _load_stored(task, out)
        if stored is not None:
            return stored
        _extract(task, out)
    except ThrustmapError as exc:
        out.status, out.reason = "refused", one_line(exc)
        if exc.file is None:  # the reason always names the log
            out.reason = f"{task.path}: {out.reason}"
    except MemoryError:
        out.status, out.reason = "refused", f"{task.path}: out of memory while reading the log"
    except Exception as exc:  # a bug in a reader must not stop the fleet: recorded, named
        log.debug("fleet: %s failed", task.path, exc_info=True)
        out.status = "refused"
        out.reason = f"{task.path}: internal error: {type(exc).__name__}: {one_line(exc)}"
    if out.sha256:
        _store(task, out)
    return _finish(out, started)


def process_batch(tasks: list[LogTask]) -> list[dict[str, Any]]:
    """Several small logs in one Dask task, one after the other (still one log in memory at a
    time): a Dask task costs milliseconds of scheduling, as much as a small log's extraction."""
    return [process_log(t) for t in tasks]


def _finish(out: Outcome, started: float) -> dict[str, Any]:
    out.seconds = time.perf_counter() - started
    return out.to_dict()


def _outcome_path(task: LogTask, sha256: str) -> Path:
    return Path(task.out_dir) / "df" / f"{stem_for(sha256, task.options_key)}.outcome.json"


def _load_stored(task: LogTask, out: Outcome) -> dict[str, Any] | None:
    """The outcome a previous run stored for this content and these options, if complete."""
    p = _outcome_path(task, out.sha256)
    try:
        d = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(d, dict) or d.get("version") != OUTCOME_VERSION:
        return None
    stored = Outcome.from_dict(d.get("outcome", {}))
    if stored.sha256 != out.sha256 or stored.options_key != task.options_key:
        return None
    if stored.df_path and not (Path(task.out_dir) / stored.df_path).is_file():
        return None
    stored.path, stored.size_bytes, stored.mtime_ns = out.path, out.size_bytes, out.mtime_ns
    stored.seconds, stored.reused = 0.0, True
    return stored.to_dict()


def _store(task: LogTask, out: Outcome) -> None:
    """Write the outcome beside the Df, atomically (a temporary file renamed over it) but not
    fsync'd: it is a cache for resuming, and a torn or missing one only means the log is redone
    (``_load_stored`` rejects anything it cannot parse). The Df itself is written by
    ``write_df``, durably."""
    path = _outcome_path(task, out.sha256)
    text = json.dumps({"version": OUTCOME_VERSION, "outcome": out.to_dict()}, default=str) + "\n"
    tmp = None
    try:
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".outcome-", suffix=".tmp")
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
        os.replace(tmp, path)
        tmp = None
    except OSError as exc:  # the outcome still reaches the table; only resuming suffers
        out.warnings.append(f"outcome not stored for resume: {exc.strerror or exc}")
    finally:
        if tmp is not None:
            with contextlib.suppress(OSError):
                os.unlink(tmp)


def _extract(task: LogTask, out: Outcome) -> None:
    import numpy as np

    from thrustmap.fitting.df.dffile import write_df
    from thrustmap.fitting.df.extraction import extract, refusal_lines
    from thrustmap.fitting.df.options import MIN_DF_SAMPLES
    from thrustmap.fitting.df_options import DfOptions
    from thrustmap.fitting.mapfile import ThrustMap
    from thrustmap.flightlogs.detect import read_log

    opts = DfOptions(**task.df_options)
    tmap = ThrustMap.load(task.map_path) if task.map_path else None
    flights = read_log(task.path, format=task.fmt)
    out.format = flights[0].format
    out.flights = len(flights)
    df = extract(flights, opts, tmap)  # a flash dump's unusable logs: skipped, listed below
    if tmap is not None:  # the checks of `flightlog extract` against the map
        _check_vehicle(df, tmap, task.force, out)
    df.sources["logs"] = [{"path": task.path, "sha256": out.sha256}]
    out.warnings.extend(refusal_lines(df.sources.get("refused", [])))
    rel = Path("df") / f"{stem_for(out.sha256, task.options_key)}.csv"
    write_df(df, Path(task.out_dir) / rel)
    out.df_path = rel.as_posix()
    out.samples = len(df)  # the columns, not the pandas table: a worker never imports pandas
    for r in df.reports:
        out.duration_s += r.duration_s
        out.kept_s += r.kept_s
        for s in r.steps:
            out.dropped_s[s.name] = out.dropped_s.get(s.name, 0.0) + s.dropped_s
        out.warnings.extend(w for w in r.warnings if w not in out.warnings)
        if r.voltage_unknown is not None and r.voltage_unknown not in out.warnings:
            out.warnings.append(r.voltage_unknown)
    flights_meta = df.sources.get("flights", {})
    masses = {m.get("mass_kg") for m in flights_meta.values() if m.get("mass_kg") is not None}
    mass = float(masses.pop()) if len(masses) == 1 else None
    rotor_counts = {int(m["rotors"]) for m in flights_meta.values() if m.get("rotors")}
    out.rotors = rotor_counts.pop() if len(rotor_counts) == 1 else 0
    out.mass_kg = float("nan") if mass is None else mass
    given_mass = task.df_options.get("mass_kg")
    af = airframe_of(flights, given_mass if given_mass is not None else mass, out.rotors)
    out.airframe = json.dumps(af, sort_keys=True, default=str)
    out.airframe_key = airframe_key(af)
    if out.samples:
        v = np.asarray(df.column("voltage_v"), float)
        v = v[np.isfinite(v)]
        if len(v):
            out.voltage_min_v, out.voltage_max_v = float(v.min()), float(v.max())
        out.status = "ok"
        if out.samples < MIN_DF_SAMPLES:
            out.warnings.append(
                f"only {out.samples} Df samples (< {MIN_DF_SAMPLES}): too few for a γ fit alone"
            )
    else:
        out.status = "empty"
        worst = sorted(out.dropped_s.items(), key=lambda kv: -kv[1])[:3]
        out.reason = "no steady flight (0 Df samples): " + (
            ", ".join(f"{k} −{v:.1f} s" for k, v in worst) or "no flight time"
        )


def _check_vehicle(df: Any, tmap: Any, force: bool, out: Outcome) -> None:
    """The checks ``flightlog extract`` makes against the map, in its order: the flight's pack
    (``ThrustMap.pack_refusal``), then each flight's mass (``ThrustMap.hover_refusal``). A
    refusal is the log's outcome; with ``force`` the log is extracted, the reasons recorded in
    the Df sidecar (``forced``) and among the log's warnings."""
    pack = tmap.pack_refusal(df.column("voltage_v")) if len(df) else None
    whys = [pack] if pack is not None else []
    flights = df.sources.get("flights", {}).values() if pack is None else []
    for meta in flights:  # on another motor's map, the mass's hover thrust means nothing
        mass, rotors = meta.get("mass_kg"), meta.get("rotors")
        if isinstance(mass, (int, float)) and isinstance(rotors, int) and rotors >= 1:
            why = tmap.hover_refusal(float(mass), rotors)
            if why is not None and why not in whys:
                whys.append(why)
    if whys and not force:
        raise ConfigError(f"--map: {whys[0]}; not extracted (--force goes on anyway)")
    for why in whys:
        df.sources["forced"] = [*df.sources.get("forced", []), why]
        out.warnings.append(f"forced (--force), recorded: {why}")
